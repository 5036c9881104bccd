"""The simulator's own chain as the null of a diagnosis (issue 23).

A recording that comes with its simulation config is compared, effect by effect, with what the
same search finds on *twins*: clips the frame simulator renders from that config with no effect
(`simulate_to_dir`), extracted by the same `extract_recording` and diagnosed by the same
`run_diagnosis` with the same settings (and the twin's own LDS when the recording has one). What
the configured sensor and the extraction do by themselves — a ToF camera's mixed-pixel frames on
the plate under the camera, a Kinect's session jumps and depth lattice, its noise structure —
shows up in the twins as strongly as in the recording, and is the sensor's nominal physics, not
missing physics.

The null of an effect id: each twin's evidence for it (its largest likelihood-ratio statistic
``lr``, 0 where the twin's search did not name it) per second of record, scaled to the
recording's length (evidence of a systematic artefact grows with the samples). The band is a
prediction bound at 1 − α/m (α = 0.05, m the effect ids: the multiplicity correction) from the
K twins' scaled values: mean + t₁₋α/m,K−1 √(var (1 + 1/K) + 4 mean + 2) (Student's t: the
twins' spread is itself estimated), the last two terms the χ² sampling noise of a statistic
whose non-centrality is that mean. A named effect counts as missing
physics only where its ``lr`` exceeds that band (`apply_chain_null`); otherwise it moves to
``nominal_physics`` with its band.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from .._effect_ids import EFFECT_IDS
from ..settings import DiagnoseSettings

__all__ = ["ChainNull", "apply_chain_null", "chain_null"]

ALPHA = 0.05
TWIN_SEED = 900_000  # twins' seeds: far from any recording's
TWIN_ROOT = Path(__file__).resolve().parents[1]


@dataclass
class ChainNull:
    """Per effect id, the K twins' evidence per second (0 where a twin did not name it)."""

    per_second: dict[str, list[float]]
    clip_s: float
    k: int

    def band(self, eid: str, duration_s: float) -> float:
        """The 1 − α/m prediction bound of ``eid``'s lr on a record of ``duration_s``."""
        from scipy import stats

        v = np.asarray(self.per_second.get(eid, [0.0] * self.k), float) * duration_s
        if not v.size or not np.any(v > 0):
            return 0.0
        if v.size < 2:
            return float("inf")
        z = float(stats.t.isf(ALPHA / len(EFFECT_IDS), v.size - 1))
        mean = float(v.mean())
        return mean + z * math.sqrt(float(v.var(ddof=1)) * (1 + 1 / v.size) + 4 * mean + 2)


def _twin_clip(
    config: str,
    session,
    clip_s: float,
    seed: int,
    with_reference: bool,
    clips: Path | None,
    camera: str | None = None,
):
    """One twin's extracted trajectories and LDS (None without a reference): rendered and
    extracted, or read from ``clips`` (the clip cache: a change of the diagnosis alone does not
    render the clips again). ``camera``: the camera of a several-camera config whose trajectories
    are wanted; every camera of the render is extracted and kept (the next camera's null reads
    them)."""
    import pandas as pd

    from ..frames import extract_recording
    from ..io import read_reference
    from ..io.recording import open_recording
    from ..simulate import load_config, simulate_to_dir, usable_reference

    name = "traj.parquet" if camera is None else f"traj_{camera}.parquet"
    if clips is not None and (clips / name).exists():
        traj = pd.read_parquet(clips / name)
        ref = pd.read_parquet(clips / "lds.parquet") if with_reference else None
        return traj, ref
    cfg = load_config(config, session)
    with tempfile.TemporaryDirectory(prefix="jaxdefl_twin_") as tmp:
        out = simulate_to_dir(config, Path(tmp) / "sim", clip_s, seed, progress=False, session=session)
        zarrs = (
            {None: out / "recording.zarr"}
            if camera is None
            else {c: out / f"{c}.zarr" for c in cfg.camera_names}
        )
        trajs = {c: extract_recording(open_recording(z), progress=False) for c, z in zarrs.items()}
        ref = None
        if with_reference:  # as the recording's: without the plate whose LDS is defective
            ref = usable_reference(read_reference(out / "lds.csv"), cfg)[0]
    if clips is not None:
        clips.mkdir(parents=True, exist_ok=True)
        if ref is not None:
            ref.to_parquet(clips / "lds.parquet")
        for c, t in sorted(trajs.items(), key=lambda kv: kv[0] == camera):  # the wanted one last
            tmp_path = clips / "traj.tmp.parquet"
            t.to_parquet(tmp_path)
            tmp_path.replace(clips / ("traj.parquet" if c is None else f"traj_{c}.parquet"))  # whole
    return trajs[camera], ref


def _twin(args) -> dict[str, float]:
    """One twin: render, extract (or read the cached clip), diagnose; {id: largest lr} (a
    worker process's job)."""
    config, session, clip_s, seed, settings, with_reference, clips, camera = args
    from ..diagnose import run_diagnosis

    traj, ref = _twin_clip(config, session, clip_s, seed, with_reference, clips, camera)
    diag = run_diagnosis(traj, ref, settings).to_json()
    best: dict[str, float] = {}
    for e in diag["effects"]:
        best[e["id"]] = max(best.get(e["id"], 0.0), float(e.get("lr") or 0.0))
    return best


# the code a twin's findings depend on: the simulator, the extraction and the diagnosis
_TWIN_CODE = ("simulate", "frames", "io", "series", "fit", "spectral", "diagnose")
_CLIP_CODE = ("simulate", "frames", "io")  # what the clips (rendered, extracted) depend on
_ORCHESTRATION = ("pipeline.py", "cli.py", "progress.py", "__main__.py")


def _source_digest(folders: tuple[str, ...] = _TWIN_CODE) -> str:
    """A digest of the code that makes the twins (a cached null is stale when it changes)."""
    h = hashlib.sha256()
    top = [p for p in sorted(TWIN_ROOT.glob("*.py")) if p.name not in _ORCHESTRATION]
    files = top + [p for d in folders for p in sorted((TWIN_ROOT / d).rglob("*.py"))]
    for p in files:
        h.update(p.read_bytes())
    return h.hexdigest()[:16]


def chain_null(
    config: Path | str,
    settings: DiagnoseSettings,
    clip_s: float = 60.0,
    k: int = 4,
    with_reference: bool = False,
    session: str | None = None,
    workers: int = 2,
    cache: Path | None = None,
    camera: str | None = None,
) -> ChainNull:
    """The null of ``k`` twins of ``clip_s`` seconds of ``config`` (in ``workers`` processes);
    of one ``camera`` of a several-camera config (``settings`` then that camera's), its twins the
    same renders as the other cameras'.

    Twins depend on the config, the settings and the code only, so they are kept in ``cache``
    (default ``$JAXDEFL_CACHE`` or ``~/.cache/jaxdefl``: ``chain_null/`` the findings,
    ``chain_clips/`` the rendered and extracted clips, which depend on the simulator and the
    extraction alone) and reused."""
    config = Path(config)
    key = json.dumps(
        [config.read_text(), session, clip_s, k, asdict(settings), with_reference, _source_digest()]
        + ([camera] if camera is not None else []),
        sort_keys=True,
        default=str,
    )
    root = cache or Path(os.environ.get("JAXDEFL_CACHE", Path.home() / ".cache" / "jaxdefl"))
    path = root / "chain_null" / (hashlib.sha256(key.encode()).hexdigest()[:24] + ".json")
    if path.exists():
        d = json.loads(path.read_text())
        return ChainNull(d["per_second"], d["clip_s"], d["k"])
    clip_key = json.dumps([config.read_text(), session, clip_s, with_reference, _source_digest(_CLIP_CODE)])
    clips = root / "chain_clips" / hashlib.sha256(clip_key.encode()).hexdigest()[:24]
    jobs = [
        (str(config), session, clip_s, TWIN_SEED + j, settings, with_reference, clips / str(j), camera)
        for j in range(k)
    ]
    if workers > 1 and k > 1:
        # spawn: jax and torch do not survive a fork
        with ProcessPoolExecutor(min(workers, k), mp_context=get_context("spawn")) as pool:
            found = list(pool.map(_twin, jobs))
    else:
        found = [_twin(j) for j in jobs]
    per_second = {eid: [f.get(eid, 0.0) / clip_s for f in found] for eid in EFFECT_IDS}
    null = ChainNull(per_second, clip_s, k)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(asdict(null)))
    tmp.replace(path)
    return null


def apply_chain_null(diag: dict, null: ChainNull, duration_s: float) -> dict:
    """DIAG.json with every effect's ``null_lr_95`` (the twins' band, `ChainNull.band`) and the
    effects within it moved from ``effects`` to ``nominal_physics`` (the sensor's own physics)."""
    kept, nominal = [], []
    for e in diag["effects"]:
        band = null.band(e["id"], duration_s)
        e["null_lr_95"] = band
        if float(e.get("lr") or 0.0) > band:
            kept.append(e)
        else:
            nominal.append(
                dict(
                    id=e["id"],
                    plates=e.get("plates", []),
                    axes=e.get("axes", []),
                    lr=e.get("lr"),
                    null_lr_95=band,
                    reason=(
                        f"within what the configured sensor and the extraction make by themselves: "
                        f"lr {float(e.get('lr') or 0):.1f} against {band:.1f} on {null.k} simulated "
                        f"{null.clip_s:g}-s twins of the config (scaled to this record's length)"
                    ),
                )
            )
    out = dict(diag)
    out["effects"] = kept
    if "minor" in diag:  # the ids under the report's "minor" heading: of what is still named
        out["minor"] = [e["id"] for e in kept if (e.get("relevance") or {}).get("minor")]
    out["nominal_physics"] = [*diag.get("nominal_physics", []), *nominal]
    out["chain_null"] = {
        "twins": null.k,
        "clip_s": null.clip_s,
        "band": "Student-t prediction bound at 1 - 0.05/m of the twins' lr per second x duration",
        "null_lr_95": {eid: null.band(eid, duration_s) for eid in EFFECT_IDS},
    }
    return out
