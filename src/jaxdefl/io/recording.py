"""Frame recordings: Zarr stores, TUM RGB-D-style depth-PNG folders and .npz files.

Every reader validates the recording at open time and then yields it in chunks of frames
(`Recording.chunks`), so memory stays bounded by the chunk size (.npz excepted: NumPy loads a
whole array of a zip archive at once).

Formats
-------
- **Zarr** (what ``jaxdefl simulate`` writes): a group with arrays ``range`` (ToF radial range,
  mm) or ``depth`` (structured-light depth z, mm), shaped (frame, h, w); optional ``amplitude``
  (frame, h, w); ``timestamps`` (frame,) epoch seconds. Group attributes: ``fx, fy, cx, cy`` (px),
  optional ``width, height`` (checked), ``segment``.
- **TUM-style folder**: ``depth.txt`` with lines ``timestamp filename`` (``#`` comments), 16-bit
  PNGs whose value times ``depth_scale_mm`` is the depth z in mm (TUM RGB-D: 5000 units per metre,
  i.e. 0.2 mm; 0 = no measurement). Intrinsics and scale come from the arguments or from a
  ``camera.json`` in the folder (keys ``fx, fy, cx, cy``, optional ``depth_scale_mm``, ``segment``
  and the plate geometry keys below).
- **.npz**: keys ``timestamps`` (frame,), ``range`` or ``depth`` (frame, h, w) in mm, optional
  ``amplitude`` (frame, h, w), ``intrinsics`` = [fx, fy, cx, cy], optional ``segment`` (string),
  ``plate_x_mm``, ``camera_x_mm``.

Plate geometry (to number the plates as the experiment does, by position along the beam): the
attributes ``plate_x_mm`` (every plate's centre along the beam, mm, plate 1 first) and
``camera_x_mm`` (the camera's position along the same axis, its image columns running along
the beam). A simulator output directory provides them through its ``config.json``. Without them
plates are numbered 1, 2, ... in the order of the image columns of the first detection.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._errors import ConfigError, InputError, echo, one_line

__all__ = ["Recording", "FrameChunk", "open_recording", "TUM_DEPTH_SCALE_MM"]

TUM_DEPTH_SCALE_MM = 0.2  # TUM RGB-D depth PNGs: 5000 units per metre


@dataclass(frozen=True)
class FrameChunk:
    """Frames ``start .. start + len(t)`` of a recording; frames in mm, NaN = no measurement."""

    start: int
    t: np.ndarray  # (frame,) float64 s
    frames: np.ndarray  # (frame, h, w) float32
    amplitude: np.ndarray | None  # (frame, h, w) float32


@dataclass
class Recording:
    """An opened, validated recording. ``kind`` is "range" (ToF) or "depth" (structured light)."""

    path: Path
    kind: str
    n_frames: int
    height: int
    width: int
    intrinsics: dict  # fx, fy, cx, cy
    segment: str
    attrs: dict = field(default_factory=dict)
    plate_x_mm: np.ndarray | None = None
    camera_x_mm: float | None = None
    _read: Any = None  # (start, stop) -> (t, frames, amplitude | None)
    clock: dict | None = None  # what --timestamps reclock recovered (`_check_timestamps`)

    def chunks(self, chunk_frames: int = 256, start: int = 0) -> Iterator[FrameChunk]:
        """Yield the recording from frame ``start`` in chunks of at most ``chunk_frames`` frames."""
        if chunk_frames < 1:
            raise InputError(f"{self.path}: chunk_frames must be >= 1, got {chunk_frames}")
        for s in range(start, self.n_frames, chunk_frames):
            e = min(self.n_frames, s + chunk_frames)
            t, fr, amp = self._read(s, e)
            yield FrameChunk(s, t, fr, amp)


def _err(path: Path, what: str) -> InputError:
    return InputError(f"{path}: {what}")


def _intrinsics(path: Path, src: dict, where: str) -> dict:
    out = {}
    for k in ("fx", "fy", "cx", "cy"):
        if k not in src:
            raise _err(path, f"missing camera intrinsic {k!r} in {where}; expected fx, fy, cx, cy")
        try:
            v = float(src[k])
        except (TypeError, ValueError):
            raise _err(
                path, f"camera intrinsic {k!r} in {where}: expected a number, got {echo(src[k])}"
            ) from None
        if not np.isfinite(v) or (k in ("fx", "fy") and v <= 0):
            raise _err(
                path, f"camera intrinsic {k!r} in {where}: expected a finite number (> 0 for fx, fy), got {v}"
            )
        out[k] = v
    return out


def _check_timestamps(
    path: Path, t: np.ndarray, where: str = "timestamps", policy: str = "strict"
) -> dict | None:
    """Frame timestamps must be finite and increase (``strict``); with ``reclock`` they are a
    rounded or jittered writing of the frame clock and are replaced, in place, by the clock
    recovered from them (`jaxdefl.series.clock.fit_clock`; the report is returned)."""
    if policy not in ("strict", "reclock"):
        raise ConfigError(
            f"--timestamps {policy}: frame recordings take strict or reclock (merge averages table rows)"
        )
    if not np.all(np.isfinite(t)):
        i = int(np.flatnonzero(~np.isfinite(t))[0])
        raise _err(path, f"{where}: frame {i} has a non-finite timestamp")
    d = np.diff(t)
    if policy == "reclock" and t.size >= 3:
        from ..series.clock import fit_clock

        c = fit_clock(t - t[0])
        if np.isfinite(c.dt) and not np.any(d < -c.dt):
            t[:] = t[0] + c.t
            return {
                "policy": "reclock",
                "segments": [
                    {
                        "segment": "frames",
                        "series": 1,
                        "interval_s": c.dt,
                        "jitter_rms_s": c.jitter_rms,
                        "drift_ppm": c.drift_ppm,
                    }
                ],
            }
    if np.any(d <= 0):
        i = int(np.flatnonzero(d <= 0)[0]) + 1
        hint = (
            "" if policy == "reclock" else "; rerun with --timestamps reclock (a rounded or jittered clock)"
        )
        raise _err(
            path, f"{where}: timestamps must increase; frame {i} has t={t[i]:.6f} after {t[i - 1]:.6f}{hint}"
        )
    return None


def _geometry(rec: Recording, src: dict) -> None:
    if "plate_x_mm" in src and "camera_x_mm" in src:
        px = np.asarray(src["plate_x_mm"], np.float64).ravel()
        if px.size == 0 or not np.all(np.isfinite(px)) or np.any(np.diff(px) <= 0):
            raise _err(rec.path, f"plate_x_mm: expected increasing plate positions in mm, got {px.tolist()}")
        rec.plate_x_mm = px
        rec.camera_x_mm = float(np.asarray(src["camera_x_mm"]))


def _geometry_from_sim_config(rec: Recording, cfg_path: Path) -> None:
    """A simulator output directory: plate positions and camera position from config.json."""
    if rec.plate_x_mm is not None or not cfg_path.exists():
        return
    try:
        cfg = json.loads(cfg_path.read_text())
        pl, cam = cfg["plates"], cfg["camera"]
        n = int(pl["count"])
        rec.plate_x_mm = float(pl["x0_mm"]) + float(pl["spacing_mm"]) * np.arange(n)
        rec.camera_x_mm = float(cam["x_mm"])
    except (ValueError, KeyError, TypeError):
        return  # not a simulator config: ordinal numbering


def _frame_range(arr, i: int) -> str:
    """The frames of chunk ``i`` along the frame axis of ``arr``."""
    c = int(arr.chunks[0])
    return f"frames {i * c}..{min(int(arr.shape[0]), (i + 1) * c) - 1}"


def _check_chunks(path: Path, name: str, arr) -> None:
    """Every chunk of ``arr`` must be stored: Zarr reads a missing one as fill values, which
    would silently drop (or invent) frames. Names the array and the frames of the first gap."""
    root = path / arr.path
    grid = [-(-int(s) // int(c)) for s, c in zip(arr.shape, arr.chunks, strict=True)]
    for coords in np.ndindex(*grid):
        key = arr.metadata.encode_chunk_key(coords)
        if not (root / key).is_file():
            missing = sum(not (root / arr.metadata.encode_chunk_key(c)).is_file() for c in np.ndindex(*grid))
            more = f" (and {missing - 1} more chunk(s))" if missing > 1 else ""
            raise _err(
                path,
                f"array {name!r}: the chunk of {_frame_range(arr, coords[0])} is missing "
                f"({root / key}){more}; the recording is incomplete",
            )


def _read_frames(path: Path, name: str, arr, s: int, e: int) -> np.ndarray:
    """``arr[s:e]``; a chunk that cannot be decoded (truncated, corrupt) is named by its frames."""
    try:
        return np.asarray(arr[s:e])
    except Exception as err:
        c = int(arr.chunks[0])
        for i in range(s // c, -(-e // c)):  # find the chunk that fails
            try:
                arr[i * c : min(e, (i + 1) * c)]
            except Exception:
                bad = _frame_range(arr, i)
                break
        else:
            bad = f"frames {s}..{e - 1}"
        why = one_line(f"{type(err).__name__}: {err}", limit=120)
        raise _err(
            path, f"array {name!r}: the chunk of {bad} cannot be read ({why}); truncated or corrupt"
        ) from None


def _open_zarr(path: Path, timestamps: str = "strict") -> Recording:
    import zarr

    try:
        g = zarr.open_group(str(path), mode="r")
    except Exception as err:  # zarr raises several types for a non-store
        for meta in ("zarr.json", ".zgroup", ".zattrs"):
            f = path / meta
            if f.is_file():
                try:
                    json.loads(f.read_text())
                except (ValueError, OSError, UnicodeDecodeError):
                    raise InputError(f"{f}: not valid JSON (a corrupt Zarr metadata file)") from None
        raise _err(path, f"not a readable Zarr group ({type(err).__name__})") from None
    attrs = dict(g.attrs)
    keys = set(g.array_keys())
    kinds = [k for k in ("range", "depth") if k in keys]
    if len(kinds) != 1:
        raise _err(path, f"expected exactly one frame array 'range' or 'depth', found {sorted(keys)}")
    kind = kinds[0]
    if "timestamps" not in keys:
        raise _err(path, "missing array 'timestamps' (frame,) of epoch seconds")
    fr = g[kind]
    ts = g["timestamps"]
    if fr.ndim != 3:
        raise _err(path, f"array {kind!r}: expected shape (frame, h, w), got {fr.shape}")
    n, h, w = fr.shape
    if ts.ndim != 1 or ts.shape[0] != n:
        raise _err(
            path, f"array 'timestamps' has shape {ts.shape}; expected ({n},) to match {kind!r} {fr.shape}"
        )
    if kind == "range" and "amplitude" not in keys:
        # a ToF camera delivers range and amplitude together; the plates are found on the latter
        raise _err(path, "missing array 'amplitude' (frame, h, w): a ToF (range) recording needs it")
    amp = g["amplitude"] if "amplitude" in keys else None
    if amp is not None and amp.shape != fr.shape:
        raise _err(path, f"array 'amplitude' has shape {amp.shape}; expected {fr.shape} like {kind!r}")
    for k, v in (("width", w), ("height", h)):
        if k in attrs and int(attrs[k]) != v:
            raise _err(path, f"attribute {k}={attrs[k]} does not match the frames' {k} {v}")
    if "n_frames" in attrs and int(attrs["n_frames"]) != n:
        raise _err(path, f"truncated: attribute n_frames={attrs['n_frames']} but {n} frames stored")
    intr = _intrinsics(path, attrs, "the group attributes")
    arrays = {kind: fr, "timestamps": ts} | ({} if amp is None else {"amplitude": amp})
    for name, arr in arrays.items():
        _check_chunks(path, name, arr)
    t_all = _read_frames(path, "timestamps", ts, 0, n).astype(np.float64)
    clock = _check_timestamps(path, t_all, policy=timestamps)

    def read(s, e):
        f = _read_frames(path, kind, fr, s, e).astype(np.float32, copy=False)
        a = None if amp is None else _read_frames(path, "amplitude", amp, s, e).astype(np.float32, copy=False)
        return t_all[s:e], f, a

    rec = Recording(
        path, kind, n, h, w, intr, str(attrs.get("segment", path.stem)), attrs, _read=read, clock=clock
    )
    _geometry(rec, attrs)
    _geometry_from_sim_config(rec, path.parent / "config.json")
    return rec


def _open_npz(path: Path, timestamps: str = "strict") -> Recording:
    try:
        z = np.load(path, allow_pickle=False)
    except Exception as err:
        raise _err(path, f"not a readable .npz file ({type(err).__name__})") from None
    keys = set(z.files)
    kinds = [k for k in ("range", "depth") if k in keys]
    if len(kinds) != 1:
        raise _err(path, f"expected exactly one key 'range' or 'depth', found {sorted(keys)}")
    kind = kinds[0]
    for k in ("timestamps", "intrinsics"):
        if k not in keys:
            raise _err(path, f"missing key {k!r}")
    try:
        fr = z[kind]
        t = np.asarray(z["timestamps"], np.float64)
        intr_v = np.asarray(z["intrinsics"], np.float64).ravel()
        amp = z["amplitude"] if "amplitude" in keys else None
    except Exception as err:
        raise _err(path, f"corrupt or truncated archive ({type(err).__name__})") from None
    if fr.ndim != 3:
        raise _err(path, f"key {kind!r}: expected shape (frame, h, w), got {fr.shape}")
    n, h, w = fr.shape
    if t.shape != (n,):
        raise _err(
            path, f"key 'timestamps' has shape {t.shape}; expected ({n},) to match {kind!r} {fr.shape}"
        )
    if amp is not None and amp.shape != fr.shape:
        raise _err(path, f"key 'amplitude' has shape {amp.shape}; expected {fr.shape} like {kind!r}")
    if intr_v.size != 4:
        raise _err(path, f"key 'intrinsics': expected [fx, fy, cx, cy], got {intr_v.tolist()}")
    intr = _intrinsics(path, dict(zip(("fx", "fy", "cx", "cy"), intr_v, strict=True)), "key 'intrinsics'")
    clock = _check_timestamps(path, t, policy=timestamps)
    seg = str(z["segment"]) if "segment" in keys else path.stem

    def read(s, e):
        return (
            t[s:e],
            np.asarray(fr[s:e], np.float32),
            None if amp is None else np.asarray(amp[s:e], np.float32),
        )

    rec = Recording(path, kind, n, h, w, intr, seg, {}, _read=read, clock=clock)
    _geometry(rec, {k: z[k] for k in ("plate_x_mm", "camera_x_mm") if k in keys})
    return rec


def _read_png(path: Path) -> np.ndarray | None:
    """A PNG's pixels as stored (a 16-bit depth PNG as uint16), or None when the file is missing
    or not an image. Pillow (a base dependency) reads it: no OpenCV needed."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as img:
            if img.mode in ("I;16", "I;16B", "I;16L"):
                return np.asarray(img).astype(np.uint16)
            return np.asarray(img)
    except (OSError, UnidentifiedImageError, ValueError):
        return None


def _open_tum(
    path: Path, depth_scale_mm: float | None, intrinsics: dict | None, timestamps: str = "strict"
) -> Recording:
    listing = path / "depth.txt"
    if not listing.exists():
        raise _err(
            path, "not a recording: a folder needs depth.txt (TUM RGB-D style: 'timestamp filename' lines)"
        )
    cam: dict = {}
    cam_path = path / "camera.json"
    if cam_path.exists():
        try:
            cam = json.loads(cam_path.read_text())
        except ValueError as err:
            raise _err(cam_path, f"not valid JSON ({err})") from None
    if intrinsics is not None:
        cam = {**cam, **intrinsics}
    intr = _intrinsics(path, cam, "camera.json or the intrinsics argument")
    scale = float(
        depth_scale_mm if depth_scale_mm is not None else cam.get("depth_scale_mm", TUM_DEPTH_SCALE_MM)
    )
    if not scale > 0:
        raise _err(path, f"depth scale must be > 0 mm per unit, got {scale}")
    t, files = [], []
    for i, line in enumerate(listing.read_text().splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split()
        if len(parts) != 2:
            raise _err(listing, f"line {i}: expected 'timestamp filename', got {echo(s)}")
        try:
            t.append(float(parts[0]))
        except ValueError:
            raise _err(listing, f"line {i}: timestamp {echo(parts[0])} is not a number") from None
        files.append(path / parts[1])
    if not files:
        raise _err(listing, "no frames listed")
    t = np.asarray(t, np.float64)
    clock = _check_timestamps(listing, t, policy=timestamps)
    first = _read_png(files[0])
    if first is None:
        raise _err(files[0], "missing or not a readable PNG (frame 0 of depth.txt)")
    if first.ndim != 2 or first.dtype != np.uint16:
        raise _err(
            files[0], f"expected a single-channel 16-bit PNG, got {first.dtype} with shape {first.shape}"
        )
    h, w = first.shape

    def read(s, e):
        out = np.empty((e - s, h, w), np.float32)
        for j in range(s, e):
            img = _read_png(files[j])
            if img is None:
                raise _err(files[j], f"missing or not a readable PNG (frame {j} of depth.txt)")
            if img.shape != (h, w) or img.dtype != np.uint16:
                raise _err(
                    files[j],
                    f"frame {j}: expected a {w}x{h} 16-bit PNG like frame 0, got {img.dtype} {img.shape}",
                )
            d = img.astype(np.float32) * scale
            d[img == 0] = np.nan
            out[j - s] = d
        return t[s:e], out, None

    rec = Recording(
        path,
        "depth",
        len(files),
        h,
        w,
        intr,
        str(cam.get("segment", path.name)),
        cam,
        _read=read,
        clock=clock,
    )
    _geometry(rec, cam)
    return rec


def open_recording(
    path: Path | str,
    depth_scale_mm: float | None = None,
    intrinsics: dict | None = None,
    timestamps: str = "strict",
) -> Recording:
    """Open and validate a recording (.zarr store, TUM-style depth-PNG folder or .npz).

    Args:
        path: the recording. depth_scale_mm: mm per PNG unit (TUM folders; default camera.json's
            ``depth_scale_mm`` or 0.2). intrinsics: fx, fy, cx, cy overriding camera.json (TUM).
        timestamps: ``strict`` (frame times must increase) or ``reclock`` (rounded or jittered
            frame times replaced by the recovered clock; the report in `Recording.clock`).
    Raises:
        InputError: missing, corrupt, truncated or inconsistent recording (one line, names the file).
    """
    path = Path(path)
    if not path.exists():
        raise _err(path, "recording not found")
    if path.suffix.lower() == ".npz":
        return _open_npz(path, timestamps)
    if path.is_dir() and (path / "depth.txt").exists():
        return _open_tum(path, depth_scale_mm, intrinsics, timestamps)
    if path.is_dir() and (path / "recording.zarr").is_dir():
        return _open_zarr(path / "recording.zarr", timestamps)
    if path.is_dir():
        return _open_zarr(path, timestamps)
    raise _err(
        path, "unknown recording format; expected a .zarr store, a folder with depth.txt or an .npz file"
    )
