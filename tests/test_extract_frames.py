"""Extraction on small synthetic frame stacks, the recording readers and their error messages."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from jaxdefl._errors import InputError
from jaxdefl.frames import PlateGeometry, extract_frames, extract_to_table
from jaxdefl.io.recording import open_recording
from jaxdefl.settings import ExtractSettings

H, W = 64, 128
INTR = dict(fx=100.0, fy=100.0, cx=63.5, cy=31.5)
PLATE_COLS = [(8, 34), (50, 76), (92, 118)]  # three plates, numbered 4, 5, 6
PLATE_X_MM = 1200.0 + 790.0 * (np.arange(13) - 4)  # image spacing 42 px at 1880 mm
CAMERA_X_MM = 1200.0  # plate 5 (x = 1200) straight below the camera


def _scene(n=40, seed=0, hide=None):
    """Depth frames: floor 2700 mm, beam top 1900 mm (rows 8-23), plates 20 mm above it."""
    rng = np.random.default_rng(seed)
    t = 100.0 + np.arange(n) / 20.0
    defl = 2.0 * np.sin(2 * np.pi * 3.0 * (t - t[0]))
    z = np.full((n, H, W), 2700.0)
    z[:, 8:24, :] = 1900.0 + defl[:, None, None]
    for i, (c0, c1) in enumerate(PLATE_COLS):
        z[:, 24:36, c0:c1] = 1880.0 + defl[:, None, None] * (1 + 0.1 * i)
    if hide is not None:  # a plate occluded by something near the camera in some frames
        frames, (c0, c1) = hide
        z[frames, 20:40, c0 - 2 : c1 + 2] = 1500.0
    z += rng.normal(0, 1.0, z.shape)
    return t, z.astype(np.float32), defl


@pytest.mark.parametrize("realtime", [False, True])
def test_synthetic_depth_plates_numbered_by_position(realtime):
    t, z, defl = _scene()
    geo = PlateGeometry(PLATE_X_MM, CAMERA_X_MM)
    df = extract_frames(z, t, INTR, kind="depth", realtime=realtime, geometry=geo, chunk_frames=16)
    assert sorted(df.plate.unique()) == [4, 5, 6]
    for i, p in enumerate([4, 5, 6]):
        g = df[df.plate == p].sort_values("t")
        assert len(g) == len(t)
        truth = 1880.0 + defl * (1 + 0.1 * i)
        assert np.std(g.z.to_numpy() - truth) < 0.2
        assert abs(np.mean(g.z.to_numpy() - truth)) < 0.2


def test_without_geometry_plates_numbered_by_column():
    t, z, _ = _scene(n=20)
    df = extract_frames(z, t, INTR, kind="depth")
    assert sorted(df.plate.unique()) == [1, 2, 3]
    assert df.groupby("plate").x.mean().is_monotonic_increasing


@pytest.mark.parametrize("realtime", [False, True])
def test_occluded_plate_is_missing_not_mislabelled(realtime):
    hidden = np.arange(25, 30)
    t, z, _ = _scene(n=40, hide=(hidden, PLATE_COLS[1]))
    geo = PlateGeometry(PLATE_X_MM, CAMERA_X_MM)
    df = extract_frames(z, t, INTR, kind="depth", realtime=realtime, geometry=geo, chunk_frames=40)
    got = df[df.plate == 5].t.to_numpy()
    assert np.isin(t[hidden], got).sum() == 0
    assert len(got) == len(t) - len(hidden)
    assert (df.plate.value_counts()[[4, 6]] == len(t)).all()
    # the others keep their x: nothing renumbered
    assert df[df.plate == 4].x.std() < 5 and df[df.plate == 6].x.std() < 5


def test_range_frames_back_projected():
    """ToF range along the pixel rays: z recovered through eq. 3.10."""
    t, z, defl = _scene(n=20)
    v, u = np.mgrid[0:H, 0:W]
    norm = np.sqrt(((u - INTR["cx"]) / INTR["fx"]) ** 2 + ((v - INTR["cy"]) / INTR["fy"]) ** 2 + 1)
    rng = (z * norm).astype(np.float32)
    amp = np.where(z < 1890, 1000.0, np.where(z < 2000, 800.0, 50.0)).astype(np.float32)
    df = extract_frames(
        rng, t, INTR, kind="range", amplitude=amp, geometry=PlateGeometry(PLATE_X_MM, CAMERA_X_MM)
    )
    g = df[df.plate == 5].sort_values("t")
    assert len(g) == len(t)
    assert np.std(g.z.to_numpy() - (1880 + 1.1 * defl)) < 0.2


def test_no_plates_is_an_input_error(tmp_path):
    t = np.arange(5.0)
    z = np.full((5, H, W), 2000.0, np.float32)
    np.savez(tmp_path / "flat.npz", timestamps=t, depth=z, intrinsics=[100.0, 100.0, 63.5, 31.5])
    with pytest.raises(InputError, match=r"flat\.npz: no row of plates"):
        extract_to_table(tmp_path / "flat.npz", tmp_path / "out.csv")


# --- readers -----------------------------------------------------------------------------


def test_npz_roundtrip_and_cli_entry(tmp_path):
    t, z, _ = _scene(n=30)
    np.savez(
        tmp_path / "rec.npz",
        timestamps=t,
        depth=z,
        intrinsics=[100.0, 100.0, 63.5, 31.5],
        segment="s1",
        plate_x_mm=PLATE_X_MM,
        camera_x_mm=CAMERA_X_MM,
    )
    extract_to_table(tmp_path / "rec.npz", tmp_path / "traj.csv", ExtractSettings(chunk_frames=7))
    import pandas as pd

    df = pd.read_csv(tmp_path / "traj.csv")
    assert list(df.columns) == ["segment", "t", "plate", "x", "y", "z"]
    assert set(df.plate) == {4, 5, 6} and (df.segment == "s1").all() and len(df) == 90


def test_cli_extract_device_flag(tmp_path, capsys):
    """`jaxdefl extract --device cpu` gives the default's table; an unknown or absent device: exit 2."""
    import pandas as pd
    import torch

    from jaxdefl.cli import main

    t, z, _ = _scene(n=12)
    np.savez(tmp_path / "rec.npz", timestamps=t, depth=z, intrinsics=[100.0, 100.0, 63.5, 31.5])
    assert (
        main(["extract", str(tmp_path / "rec.npz"), "--out", str(tmp_path / "a.csv"), "--device", "cpu"]) == 0
    )
    assert main(["extract", str(tmp_path / "rec.npz"), "--out", str(tmp_path / "b.csv")]) == 0
    a, b = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")
    assert len(a) == 36
    np.testing.assert_allclose(a[["x", "y", "z"]], b[["x", "y", "z"]], atol=0.01)
    bad = [("gpu", "--device: expected cpu, cuda or cuda:N, got 'gpu'")]
    if not torch.cuda.is_available():
        bad.append(("cuda", "--device: cuda: CUDA is not available"))
    for dev, msg in bad:
        capsys.readouterr()
        code = main(["extract", str(tmp_path / "rec.npz"), "--out", str(tmp_path / "c.csv"), "--device", dev])
        err = capsys.readouterr().err
        assert code == 2 and msg in err, err
        assert not (tmp_path / "c.csv").exists()


def test_tum_folder(tmp_path):
    t, z, _ = _scene(n=6)
    lines = ["# depth maps", "# timestamp filename"]
    (tmp_path / "depth").mkdir()
    for i in range(len(t)):
        img = np.round(np.nan_to_num(z[i]) / 0.2).astype(np.uint16)
        img[0, 0] = 0  # no measurement
        cv2.imwrite(str(tmp_path / "depth" / f"{i}.png"), img)
        lines.append(f"{t[i]:.6f} depth/{i}.png")
    (tmp_path / "depth.txt").write_text("\n".join(lines) + "\n")
    (tmp_path / "camera.json").write_text(json.dumps(INTR))
    rec = open_recording(tmp_path)
    assert rec.kind == "depth" and rec.n_frames == 6 and (rec.height, rec.width) == (H, W)
    ch = next(rec.chunks(4))
    assert np.isnan(ch.frames[0, 0, 0]) and abs(ch.frames[0, 30, 20] - z[0, 30, 20]) <= 0.1
    rec2 = open_recording(tmp_path, depth_scale_mm=1.0)
    assert abs(next(rec2.chunks(1)).frames[0, 30, 20] - 5 * z[0, 30, 20]) <= 0.5


def test_zarr_reader(tmp_path):
    import zarr

    t, z, _ = _scene(n=10)
    g = zarr.open_group(str(tmp_path / "r.zarr"), mode="w")
    g.attrs.update(dict(INTR, width=W, height=H, segment="d1", n_frames=10))
    g.create_array("depth", data=z, chunks=(4, H, W))
    g.create_array("timestamps", data=t)
    rec = open_recording(tmp_path / "r.zarr")
    assert [len(c.t) for c in rec.chunks(4)] == [4, 4, 2] and rec.segment == "d1"


def _zarr(path, t, z, **attrs):
    import zarr

    g = zarr.open_group(str(path), mode="w")
    g.attrs.update(attrs)
    g.create_array("depth", data=z)
    g.create_array("timestamps", data=t)
    return path


def test_reader_errors(tmp_path):
    t, z, _ = _scene(n=4)
    with pytest.raises(InputError, match="nope.npz: recording not found"):
        open_recording(tmp_path / "nope.npz")
    np.savez(tmp_path / "a.npz", timestamps=t, depth=z)
    with pytest.raises(InputError, match="missing key 'intrinsics'"):
        open_recording(tmp_path / "a.npz")
    np.savez(tmp_path / "b.npz", timestamps=t[:3], depth=z, intrinsics=[1, 1, 0, 0])
    with pytest.raises(InputError, match=r"key 'timestamps' has shape \(3,\); expected \(4,\)"):
        open_recording(tmp_path / "b.npz")
    np.savez(tmp_path / "c.npz", timestamps=t[::-1], depth=z, intrinsics=[1, 1, 0, 0])
    with pytest.raises(InputError, match="timestamps must increase; frame 1"):
        open_recording(tmp_path / "c.npz")
    np.savez(tmp_path / "d.npz", timestamps=t, depth=z, intrinsics=[1, 1, 0])
    with pytest.raises(InputError, match=r"key 'intrinsics': expected \[fx, fy, cx, cy\]"):
        open_recording(tmp_path / "d.npz")
    (tmp_path / "e.npz").write_bytes(b"PK\x03\x04 truncated")
    with pytest.raises(InputError, match="e.npz: not a readable .npz file"):
        open_recording(tmp_path / "e.npz")
    p = _zarr(tmp_path / "f.zarr", t, z, fx=1, fy=1, cx=0, cy=0, n_frames=9)
    with pytest.raises(InputError, match="truncated: attribute n_frames=9 but 4 frames stored"):
        open_recording(p)
    p = _zarr(tmp_path / "g.zarr", t, z, fx=1, fy=1, cx=0)
    with pytest.raises(InputError, match="missing camera intrinsic 'cy'"):
        open_recording(p)
    p = _zarr(tmp_path / "h.zarr", t, z, fx=1, fy=1, cx=0, cy=0, width=W + 1)
    with pytest.raises(InputError, match=f"attribute width={W + 1} does not match"):
        open_recording(p)
    (tmp_path / "j.txt").write_text("x")
    with pytest.raises(InputError, match="unknown recording format"):
        open_recording(tmp_path / "j.txt")


def test_tum_errors(tmp_path):
    (tmp_path / "depth.txt").write_text("1.0 a.png\n")
    with pytest.raises(InputError, match="missing camera intrinsic 'fx'"):
        open_recording(tmp_path)
    (tmp_path / "camera.json").write_text(json.dumps(INTR))
    with pytest.raises(InputError, match=r"a.png: missing or not a readable PNG \(frame 0"):
        open_recording(tmp_path)
    (tmp_path / "depth.txt").write_text("1.0 a.png extra\n")
    with pytest.raises(InputError, match=r"depth.txt: line 1: expected 'timestamp filename'"):
        open_recording(tmp_path)
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((4, 4), np.uint8))
    (tmp_path / "depth.txt").write_text("1.0 a.png\n")
    with pytest.raises(InputError, match="expected a single-channel 16-bit PNG"):
        open_recording(tmp_path)
    cv2.imwrite(str(tmp_path / "a.png"), np.ones((4, 4), np.uint16))
    (tmp_path / "depth.txt").write_text("1.0 a.png\n2.0 b.png\n")
    rec = open_recording(tmp_path)
    with pytest.raises(InputError, match=r"b.png: missing or not a readable PNG \(frame 1"):
        next(rec.chunks(2))
