"""Reproduce the thesis' motion-artefact study (Section 6.1, Figs. 6.1-6.9) through the simulator.

    python experiments/motion_artefacts.py --out motion_artefacts.csv [--figure FILE.png]

Writes the table (motion_hz, frame_rate_hz, amplitude_error_mm, phase_lag_deg, ...) and a figure
of the amplitude error against the frame rate (Fig. 6.9) plus true/biased ranges (Figs. 6.1, 6.5).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from jaxdefl.simulate.artefacts import motion_artefact_ranges, motion_artefact_study  # noqa: E402

THESIS = {(1.0, 10.0): -0.061, (3.0, 10.0): -0.53, (3.0, 20.0): -0.14}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True, help="output CSV")
    ap.add_argument("--figure", type=Path, default=None, help="output PNG (default: next to the CSV)")
    ap.add_argument("--amplitude-mm", type=float, default=4.0)
    ap.add_argument("--modulation-mhz", type=float, default=29.0)
    ap.add_argument("--duration", type=float, default=5.0, help="simulated seconds per case")
    args = ap.parse_args(argv)

    table = motion_artefact_study(
        amplitude_mm=args.amplitude_mm, modulation_mhz=args.modulation_mhz, duration_s=args.duration
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out, index=False, float_format="%.6f")
    print(table[["motion_hz", "frame_rate_hz", "amplitude_error_mm", "phase_lag_deg"]].to_string(index=False))
    for (f0, fs), ref in THESIS.items():
        row = table[(table.motion_hz == f0) & (table.frame_rate_hz == fs)].iloc[0]
        print(f"f0={f0:g} Hz fs={fs:g} Hz: simulated {row.amplitude_error_mm:+.4f} mm, thesis {ref:+.3f} mm")

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for f0, mk in ((1.0, "o-"), (3.0, "s-")):
        sub = table[table.motion_hz == f0]
        axes[0].plot(sub.frame_rate_hz, sub.amplitude_error_mm, mk, label=f"motion {f0:g} Hz")
    for (_, fs), ref in THESIS.items():
        axes[0].plot(fs, ref, "kx", ms=9)
    axes[0].set(
        xlabel="frame rate (Hz)",
        ylabel="amplitude error (mm)",
        title=f"Fig. 6.9: {args.amplitude_mm:g} mm motion (x: thesis)",
    )
    axes[0].axhline(0, color="0.7", lw=0.8)
    axes[0].legend()
    for ax, (f0, fs) in zip(axes[1:], ((1.0, 10.0), (3.0, 10.0)), strict=True):
        t, true, biased = motion_artefact_ranges(f0, fs, args.amplitude_mm, args.modulation_mhz, 2.0)
        ax.plot(t - t[0], true, "o-", ms=3, label="true range")
        ax.plot(t - t[0], biased, "s-", ms=3, label="biased range")
        ax.set(xlabel="time (s)", ylabel="range (mm)", title=f"f0 = {f0:g} Hz, fs = {fs:g} Hz")
        ax.legend()
    fig.tight_layout()
    fig_path = args.figure or args.out.with_suffix(".png")
    fig.savefig(fig_path, dpi=120)
    print(f"wrote {args.out} and {fig_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
