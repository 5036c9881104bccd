"""Save the estimates of the current code on a small fixed dataset, for
`tests/test_fit_reference.py` (results unchanged to 1e-6 σ across speed work, issue 27).

The dataset is built by `reference_dataset` (13 plates x 3 axes, 3 one-minute windows at 20 Hz,
3 % drop-outs, one plate of pure noise, one plate's window of a single spike): windowed and
whole-record estimates of the harmonic model. Run from the repository root:

    PYTHONPATH=src python experiments/make_fit_reference.py

It was run on commit 1f08985 (before the speed work of issue 27) to write
``tests/data/fit_reference.npz``; rerun it only to move the reference on purpose.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

NUMERIC = [
    "t_start",
    "t_end",
    "plate",
    "n",
    "f0_hz",
    "sigma_f0_hz",
    "amplitude_mm",
    "sigma_amplitude_mm",
    "phase_rad",
    "offset_mm",
    "sigma_residual_mm",
    "peak_fap",
    "r2",
    "whiteness_p",
    "sigma_amplitude_white_mm",
    "sigma_f0_white_hz",
]
OUT = Path(__file__).resolve().parents[1] / "tests" / "data" / "fit_reference.npz"


def reference_dataset(seed: int = 27, minutes: int = 3, fs: float = 20.0) -> pd.DataFrame:
    """A small fixed trajectory table with the campaign's shapes and a few hard cases."""
    rng = np.random.default_rng(seed)
    n = int(minutes * 60 * fs)
    t = 1.7e9 + np.arange(n) / fs
    t = t[rng.random(n) > 0.03]
    rows = []
    for plate in range(1, 14):
        shape = np.sin(np.pi * plate / 14)
        f0 = 3.0672 + 0.01 * rng.standard_normal()
        ph = rng.uniform(0, 2 * np.pi)
        c = np.cos(2 * np.pi * f0 * (t - t[0]) + ph)
        gain = 0.0 if plate == 7 else 1.0  # plate 7: noise only
        z = 2.4 * gain * shape * c + 0.76 * rng.standard_normal(t.size) + 0.3
        x = 0.5 * gain * c + 0.5 * rng.standard_normal(t.size)
        y = 0.05 * gain * c + 0.017 * rng.standard_normal(t.size)
        if plate == 3:
            z[t.size // 2] += 40.0  # one spike
        rows.append(pd.DataFrame(dict(t=t, plate=plate, x=x, y=y, z=z)))
    return pd.concat(rows, ignore_index=True)


def reference_estimates(df: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """Windowed and whole-record estimates, through a CSV file and the table reader."""
    import tempfile

    from jaxdefl.fit import estimate_table
    from jaxdefl.io import read_trajectory, write_trajectory

    with tempfile.TemporaryDirectory() as tmp:
        write_trajectory(df, Path(tmp) / "traj.csv")
        df = read_trajectory(Path(tmp) / "traj.csv")
    axes = ("z", "x", "y")
    return {
        "windows": estimate_table(df, axes=axes, window_s=60.0).table,
        "whole": estimate_table(df, axes=axes).table,
    }


def main():
    out = {}
    for name, tab in reference_estimates(reference_dataset()).items():
        for col in NUMERIC:
            out[f"{name}/{col}"] = tab[col].to_numpy(dtype=float)
        out[f"{name}/status"] = tab["status"].to_numpy(dtype=str)
        out[f"{name}/axis"] = tab["axis"].to_numpy(dtype=str)
    np.savez_compressed(OUT, **out)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
