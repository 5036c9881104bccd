"""Frames/s of plate extraction on SR4000-sized frames (176x144): full detection (torch + kornia on
(B, 1, H, W) frame tensors), real-time (tracked) mode, and an OpenCV per-frame pipeline doing
the same steps, in the same run; then the labelling and index kernels against their peers.

    .venv/bin/python experiments/bench_extract.py [--frames 2048] [--chunk 256] [--threads 1]
                                                  [--device cpu] [--repeat 5]

Frames come from the simulator (Experiment II, 3 Hz, SR4000 at 20 Hz), tiled to --frames.
The OpenCV pipeline per frame: z from range (eq. 3.10), depth band relative to the beam top,
Otsu on the masked amplitude (cv2.threshold, 8-bit), connectedComponentsWithStats, area
filter, 3x3 erosion, per-region mean of the 3D points. The three are timed in turns (best of
--repeat rounds), so a change in the load of a shared machine hits all of them alike. Peak
memory: the process's max RSS (mostly the simulator's rendering) and the peak of the arrays
allocated by one `detect_chunk` call (tracemalloc; numpy only, torch's are not traced).

The kernel peers, on the chunk's band-masked frames (before Otsu), best of --repeat:
8-connected labelling by `label_components` (run-based union-find in torch), kornia's
`connected_components_union_find` and `connected_components` (max-pooling, a label travels one
pixel per step: 40 steps, and the labels it leaves are counted), and scipy.ndimage.label on the
stacked frames; the erosion
by `erode` (kornia, a row then a column) and by kornia with the 3x3 square at once; index
lists by `flat_indices` (numpy on the CPU) and torch's `nonzero`.

Figures: see docs/benchmarks.md (Extraction), measured with the command above.
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc

import cv2
import numpy as np
import torch

from jaxdefl.frames import (
    PlateGeometry,
    Tracker,
    calibrate_scene,
    detect_chunk,
    erode,
    flat_indices,
    label_components,
)
from jaxdefl.simulate import render_frames


def opencv_pipeline(scene, frames, amplitude):
    inv, xr, yr = scene.inv_norm, scene.xr, scene.yr
    lo, hi = scene.band
    kern = np.ones((3, 3), np.uint8)
    out = []
    for f, a in zip(frames, amplitude, strict=True):
        z = f * inv
        top = np.median(z.reshape(-1)[scene.top_idx])
        rel = z - top
        band = (rel > lo) & (rel < hi)
        am = np.where(band, a, 0)
        a8 = cv2.convertScaleAbs(am, alpha=255.0 / max(float(am.max()), 1e-6))
        _, fg = cv2.threshold(a8, 0, 1, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        fg &= band.astype(np.uint8)
        n, lab, stats, cents = cv2.connectedComponentsWithStats(fg, connectivity=8)
        keep = np.zeros(n, bool)
        keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= 0.6 * scene.area.min()
        er = cv2.erode(fg, kern, borderType=cv2.BORDER_CONSTANT, borderValue=0)
        sel = (er > 0) & keep[lab]
        lb = lab[sel]
        zz = z[sel]
        cnt = np.maximum(np.bincount(lb, minlength=n), 1)
        out.append(
            np.stack(
                [
                    np.bincount(lb, zz * xr[sel], n) / cnt,
                    np.bincount(lb, zz * yr[sel], n) / cnt,
                    np.bincount(lb, zz, n) / cnt,
                ],
                1,
            )
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=2048)
    ap.add_argument("--chunk", type=int, default=256)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    t, rng, amp, facts = render_frames("configs/exp2_tof_3hz.toml", duration_s=12.8)
    reps = int(np.ceil(args.frames / len(t)))
    rng = np.tile(rng, (reps, 1, 1))[: args.frames].astype(np.float32)
    amp = np.tile(amp, (reps, 1, 1))[: args.frames].astype(np.float32)
    intr = {k: facts[k] for k in ("fx", "fy", "cx", "cy")}
    geo = PlateGeometry(250.0 * np.arange(13) + 200.0, 1700.0)
    t0 = time.perf_counter()
    scene = calibrate_scene(rng[:64], amp[:64], intr, "range", geo, device=args.device)
    t_cal = time.perf_counter() - t0
    n = args.frames

    def full():
        for s in range(0, n, args.chunk):
            detect_chunk(scene, rng[s : s + args.chunk], amp[s : s + args.chunk])

    tr = Tracker(scene)

    def tracked():
        for s in range(0, n, args.chunk):
            tr.centroids(rng[s : s + args.chunk])

    def ocv():
        opencv_pipeline(scene, rng, amp)

    fns = {"full": full, "tracked": tracked, "opencv": ocv}
    for fn in fns.values():  # warm-up
        fn()
    best = _best(fns, args.repeat)
    rate = {k: n / v for k, v in best.items()}
    found = np.isfinite(detect_chunk(scene, rng[:256], amp[:256])[..., 2]).mean()
    tracemalloc.start()
    detect_chunk(scene, rng[: args.chunk], amp[: args.chunk])
    peak_chunk = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(
        f"frames {n} of {rng.shape[2]}x{rng.shape[1]}, chunk {args.chunk}, threads {args.threads}, "
        f"device {args.device}, "
        f"best of {args.repeat}; calibration {t_cal * 1e3:.0f} ms, plates {scene.plates.tolist()}, "
        f"found {found:.3f}"
    )
    print(
        f"full detection (torch + kornia):      {rate['full']:9.0f} frames/s  "
        f"({best['full'] / n * args.chunk * 1e3:.1f} ms per chunk)"
    )
    print(f"real-time (tracked):                  {rate['tracked']:9.0f} frames/s")
    print(f"OpenCV per-frame pipeline:            {rate['opencv']:9.0f} frames/s")
    print(
        f"ratios: full / OpenCV {rate['full'] / rate['opencv']:.2f}, "
        f"real-time / OpenCV {rate['tracked'] / rate['opencv']:.1f}, "
        f"real-time / 20000 {rate['tracked'] / 20000:.1f}"
    )
    print(
        f"peak memory: max RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB, "
        f"detect_chunk numpy arrays {peak_chunk / 2**20:.1f} MB per chunk"
    )
    _kernel_peers(scene, rng[: args.chunk], args.repeat, args.device)


def _best(fns: dict, repeat: int) -> dict:
    """Best wall time of every function, timed in turns (warm-up first)."""
    for fn in fns.values():
        fn()
    best = dict.fromkeys(fns, np.inf)
    for _ in range(repeat):
        for name, fn in fns.items():
            s = time.perf_counter()
            fn()
            if torch.cuda.is_available():
                torch.cuda.synchronize()
            best[name] = min(best[name], time.perf_counter() - s)
    return best


def _kernel_peers(scene, frames, repeat: int, device: str) -> None:
    import kornia
    import scipy.ndimage as ndi

    r0, r1 = scene.rows
    b = frames.shape[0]
    f = torch.as_tensor(frames, device=device)
    inv = torch.as_tensor(scene.inv_norm, device=device)
    z = f[:, None, r0:r1] * inv[r0:r1]
    top = torch.nanmedian((f.reshape(b, -1) * inv.reshape(-1))[:, scene.top_idx], dim=1).values
    rel = z - top[:, None, None, None]
    fg = (rel > scene.band[0]) & (rel < scene.band[1])
    tall = np.pad(fg[:, 0].cpu().numpy(), ((0, 0), (0, 1), (0, 0))).reshape(-1, fg.shape[-1])
    fns = {
        "label_components (runs, torch)": lambda: label_components(fg),
        "kornia connected_components_union_find": lambda: kornia.contrib.connected_components_union_find(fg),
        "scipy.ndimage.label (stacked frames)": lambda: ndi.label(tall, structure=np.ones((3, 3))),
        "erode (kornia, row then column)": lambda: erode(fg),
        "kornia erosion, 3x3 square": lambda: kornia.morphology.erosion(
            fg.float(), torch.ones(3, 3, device=device), border_type="constant", border_value=0.0
        ),
        "flat_indices": lambda: flat_indices(fg),
        "torch nonzero": lambda: fg.reshape(-1).nonzero(),
    }
    best = _best(fns, repeat)
    slow = {
        "kornia connected_components (40 steps)": lambda: kornia.contrib.connected_components(fg.float(), 40)
    }
    best.update(_best(slow, 1))  # seconds per call: timed once
    print(
        f"kernels on one chunk ({b} x {r1 - r0} x {fg.shape[-1]} band pixels, {fg.float().mean():.2f} set):"
    )
    for name, t in best.items():
        print(f"  {name:42s} {t * 1e3:8.2f} ms")
    pooled = kornia.contrib.connected_components(fg.float(), 40)
    n_ours, n_scipy = label_components(fg)[1], ndi.label(tall, np.ones((3, 3)))[1]
    n_pooled = torch.unique(pooled[pooled > 0]).numel()
    print(f"  components: {n_ours} (scipy {n_scipy}); kornia's 40 pooling steps leave {n_pooled} labels")


if __name__ == "__main__":
    main()
