"""Camera side or structure side (`jaxdefl.diagnose.attribution`, `jaxdefl attribute`): a drift
in one of two cameras is that camera's; a stiffness change is the structure's; a control has
nothing to attribute."""

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jaxdefl import InputError
from jaxdefl.cli import main
from jaxdefl.diagnose.attribution import attribute
from jaxdefl.settings import DiagnoseSettings

PLATES = {"cam3": range(1, 8), "cam4": range(7, 14)}
SPAN_MM = 3400.0


def registered(seed, *, drift_mm=0.0, crack_at_s=None, duration_s=90.0, fs=20.0, f0=3.0, sigma=0.12):
    """A registered two-camera trajectory (beam frame, one clock; plate 7 seen by both): the
    first bending shape at f0 with white noise; ``drift_mm`` a warm-up drift in cam3's ranges;
    ``crack_at_s`` a stiffness loss in the beam from then on (under load control at f0: 15 %
    more amplitude)."""
    rng = np.random.default_rng(seed)
    rows = []
    for k, (cam, plates) in enumerate(PLATES.items()):
        t = np.arange(int(duration_s * fs)) / fs + 0.013 * k  # the cameras' own frame instants
        phase = 2 * np.pi * f0 * t
        amp = np.ones_like(t)
        if crack_at_s is not None:  # load control at f0: the softer beam deflects more
            amp = np.where(t >= crack_at_s, 1.15, 1.0)
        for p in plates:
            x = 100.0 + (p - 1) * 266.0
            z = 4.0 * np.sin(np.pi * x / SPAN_MM) * amp * np.sin(phase) + sigma * rng.standard_normal(t.size)
            if cam == "cam3":
                z = z + drift_mm * np.exp(-t / 30.0)
            xs = x + 0.05 * rng.standard_normal(t.size)
            ys = 400.0 + 0.05 * rng.standard_normal(t.size)
            rows.append(
                pd.DataFrame(
                    {"segment": cam, "camera": cam, "t": 1.7e9 + t, "plate": p, "x": xs, "y": ys, "z": z}
                )
            )
    return pd.concat(rows, ignore_index=True)


def _by_id(a):
    return {f.id: f for f in a.findings}


def test_a_drift_in_one_camera_is_that_cameras():
    a = attribute(registered(1, drift_mm=2.0))
    assert a.shared_plates == [7]
    f = _by_id(a)
    assert "drift" in f, a.to_json()
    assert f["drift"].attribution == "camera" and f["drift"].side == "cam3", f["drift"].reason
    assert f["drift"].tests["cam3"].named and not f["drift"].tests["cam4"].named
    assert not any(g.attribution == "structure" for g in a.findings), a.to_json()


@pytest.mark.slow
def test_a_stiffness_change_is_the_structures():
    a = attribute(registered(2, crack_at_s=45.0))
    f = _by_id(a)
    assert "stiffness_change" in f, a.to_json()
    g = f["stiffness_change"]
    assert g.attribution == "structure", g.reason
    assert sorted(g.cameras) == ["cam3", "cam4"]  # one finding, named by both
    assert not any(h.attribution == "camera" for h in a.findings), a.to_json()


@pytest.mark.slow
def test_a_control_has_nothing_on_either_side():
    a = attribute(registered(3))
    assert not [f for f in a.findings if f.attribution != "undecided"], a.to_json()


def test_the_cli_writes_json_and_markdown_and_refuses_one_camera(tmp_path, capsys):
    df = registered(4, drift_mm=2.0)
    df.to_csv(tmp_path / "reg.csv", index=False)
    assert (
        main(
            ["attribute", str(tmp_path / "reg.csv"), "--out", str(tmp_path / "A.json"), "--effects", "drift"]
        )
        == 0
    )
    d = json.loads((tmp_path / "A.json").read_text())
    assert d["shared_plates"] == [7] and set(d["cameras"]) == {"cam3", "cam4"}
    assert [(f["id"], f["attribution"], f["camera"]) for f in d["findings"]] == [("drift", "camera", "cam3")]
    assert "| drift | cam3 | camera (cam3) |" in (tmp_path / "A.md").read_text()
    one = df[df["camera"] == "cam3"]
    one.to_csv(tmp_path / "one.csv", index=False)
    capsys.readouterr()
    assert main(["attribute", str(tmp_path / "one.csv"), "--out", str(tmp_path / "B.json")]) == 2
    err = [x for x in capsys.readouterr().err.splitlines() if x.startswith("jaxdefl: ")]
    assert len(err) == 1 and "names 1 camera; expected at least 2" in err[0], err
    with pytest.raises(InputError, match="has no 'camera' column"):
        attribute(df.drop(columns=["camera"]))


def test_plates_sampled_with_their_own_delays_go_back_on_the_cameras_frame_clock():
    """A registered table gives each plate the instant it stands for (a ToF camera's per-plate
    delay): the rows go back onto one clock, each plate's delay taken out, their mean kept."""
    from jaxdefl.diagnose.attribution import on_frame_clock

    rng = np.random.default_rng(5)
    dt = 0.05 * (1 + 40e-6)  # a registered clock: the camera's rate corrected
    frames = np.arange(600)
    delays = {1: 0.0125, 2: 0.0150, 3: 0.0210}
    rows = []
    for p, d in delays.items():
        k = np.sort(rng.choice(frames, 560, replace=False))  # each plate its own drop-outs
        rows.append(
            pd.DataFrame({"t": 1.7e9 + 0.2 + k * dt + d, "plate": p, "z": rng.standard_normal(k.size)})
        )
    part = pd.concat(rows, ignore_index=True)
    out, spread = on_frame_clock(part)
    assert spread == pytest.approx(0.0085, abs=1e-6)
    frame_of = {
        p: np.round((g["t"].to_numpy() - 1.7e9 - 0.2 - delays[p]) / dt) for p, g in part.groupby("plate")
    }
    mean_delay = np.mean(list(delays.values()))
    for p, g in out.groupby("plate"):
        np.testing.assert_allclose(g["t"].to_numpy() - 1.7e9, 0.2 + frame_of[p] * dt + mean_delay, atol=1e-6)
    np.testing.assert_array_equal(out["z"], part["z"])
    shared = part.assign(t=np.round((part["t"] - 1.7e9 - 0.2) / dt) * dt + 1.7e9)
    same, none = on_frame_clock(shared)
    assert none == 0.0 and same is shared


def test_what_a_cameras_twins_make_by_themselves_is_its_nominal_physics_not_a_finding():
    # the twins' null (`reconcile.chain`) applied per camera: a drift cam3's own twins show as
    # strongly (a warm-up the camera's config already has) is cam3's nominal physics; where the
    # twins show none, the same drift stays a camera-side finding
    from jaxdefl.reconcile.chain import ChainNull, apply_chain_null

    df = registered(1, drift_mm=2.0)

    def nulls(drift_per_s: float):
        null = {
            c: ChainNull({"drift": [drift_per_s * (1 + 0.1 * j) for j in range(4)]}, 60.0, 4) for c in PLATES
        }
        return {c: (lambda d, s, n=n: apply_chain_null(d, n, s)) for c, n in null.items()}

    strong = attribute(df, settings=DiagnoseSettings(effects="drift"), nulls=nulls(1e4))
    assert "drift" not in _by_id(strong), strong.to_json()
    assert strong.cameras["cam3"]["nominal_physics"] == ["drift"]
    none = attribute(df, settings=DiagnoseSettings(effects="drift"), nulls=nulls(0.0))
    f = _by_id(none)
    assert f["drift"].attribution == "camera" and f["drift"].side == "cam3", none.to_json()
    assert none.cameras["cam3"]["nominal_physics"] == []


def test_attribute_with_a_config_names_a_camera_it_does_not_have_and_refuses_one_camera(tmp_path, capsys):
    df = registered(5)
    df["camera"] = df["camera"].replace({"cam4": "cam9"})
    df.to_csv(tmp_path / "reg.csv", index=False)
    configs = Path(__file__).parents[1] / "configs"
    cases = (("exp1_two_cameras.toml", "camera 'cam9' is not in --config"), ("exp1.toml", "has one camera"))
    for name, message in cases:
        config = str(configs / name)
        capsys.readouterr()
        args = ["attribute", str(tmp_path / "reg.csv"), "--out", str(tmp_path / "A.json"), "--config", config]
        assert main(args) == 2
        err = [x for x in capsys.readouterr().err.splitlines() if x.startswith("jaxdefl: ")]
        assert len(err) == 1 and message in err[0], err
    assert not (tmp_path / "A.json").exists()


@pytest.mark.slow
def test_one_render_of_a_two_camera_config_makes_both_cameras_twins(tmp_path):
    # each camera's twins: the same renders of the several-camera config, that camera's clip
    # extracted (its own plates) and diagnosed with its own sensor facts; the second camera's null
    # reads the clips the first one's render left
    import pandas as pd

    from jaxdefl.pipeline import _camera_facts
    from jaxdefl.reconcile.chain import chain_null
    from jaxdefl.simulate import load_config

    config = Path(__file__).parents[1] / "configs" / "exp1_two_cameras.toml"
    cfg = load_config(config)

    def plates_of(d, cam):
        return set(pd.read_parquet(d / f"traj_{cam}.parquet")["plate"].unique())

    facts = {c: _camera_facts(config, c) for c in ("cam3", "cam4")}
    assert facts["cam3"]["modulation_mhz"] != facts["cam4"]["modulation_mhz"]  # 29 and 31 MHz
    s3 = DiagnoseSettings().with_camera(facts["cam3"])
    chain_null(config, s3, clip_s=5.0, k=2, with_reference=True, workers=1, cache=tmp_path, camera="cam3")
    clips = sorted((tmp_path / "chain_clips").glob("*/*"))
    assert len(clips) == 2
    for d in clips:
        for cam in ("cam3", "cam4"):
            plates = plates_of(d, cam)
            assert set(cfg.for_camera(cam).camera.plates) <= plates, (cam, plates)  # those in view
        p3, p4 = plates_of(d, "cam3"), plates_of(d, "cam4")
        assert 1 in p3 - p4 and 13 in p4 - p3, (p3, p4)
    before = {p: p.stat().st_mtime_ns for p in (tmp_path / "chain_clips").rglob("*.parquet")}
    s4 = DiagnoseSettings().with_camera(facts["cam4"])
    null = chain_null(
        config, s4, clip_s=5.0, k=2, with_reference=True, workers=1, cache=tmp_path, camera="cam4"
    )
    assert {p: p.stat().st_mtime_ns for p in (tmp_path / "chain_clips").rglob("*.parquet")} == before
    assert null.k == 2 and len(list((tmp_path / "chain_null").glob("*.json"))) == 2
