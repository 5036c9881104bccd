"""Write the real recording of the tests (issue 13) as a trajectory table jaxdefl reads.

Source: a sinusoidal characterization test of the banded rotary friction device (BRFD), ARTS-Lab,
University of South Carolina: 2 Hz, 0.5 in, 30 lb band tension, the
actuator's measured displacement logged at 1024 Hz (``dt`` 0.0009765625 s). Repository
ARTS-Laboratory/Dataset-Friction-Damper-with-Backlash, file
``data/dataset-3/characterization tests/2Hz30lbtension0.5amplitude.json`` (commit
800c30ebdc2a944f49afe43809ae355d39c7fe4f), CC BY-SA 4.0. Provenance, licence and what the
columns mean: ``tests/data/brfd_sine_2hz.md``.

The JSON holds ``{"data": [[t (s), displacement (in), friction force (kip), velocity (in/s),
actuator force 1 (lb), actuator force 2 (lb)], ...], "dt": ..., "displacement units": "in", ...}``.
This script keeps every ``--every``-th sample (8: 128 Hz, a fast camera's rate; 449 rows for the
3.5-s record) of time and displacement, and writes

    t, plate, z_mm, displacement_in

``t`` and ``displacement_in`` exactly as the source holds them (Python's shortest round-trip
repr), ``z_mm`` = 25.4 x ``displacement_in`` (jaxdefl reads mm; it has no inch unit), ``plate`` 1.
Nothing else is changed: no filtering, no detrending, no resampling beyond the decimation.

    python experiments/real_data_prepare.py SOURCE.json tests/data/brfd_sine_2hz.csv
    python experiments/real_data_prepare.py ROWS.csv tests/data/brfd_sine_2hz.csv --every 1

A ``.csv`` source is two columns ``t_s, displacement_in`` already decimated (how the vendored file
was made: the 449 rows were copied from a stored copy of the JSON, every 8th sample, because this
machine has no network; ``--every 1`` then keeps them all).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

INCH_MM = 25.4
HEADER = (
    "# BRFD sinusoidal characterization test, 2 Hz, 0.5 in, 30 lb band tension (ARTS-Lab);\n"
    "# ARTS-Laboratory/Dataset-Friction-Damper-with-Backlash @ 800c30ebdc2a944f49afe43809ae355d39c7fe4f,\n"
    "# data/dataset-3/characterization tests/2Hz30lbtension0.5amplitude.json; every 8th sample (128 Hz).\n"
    "# Licence CC BY-SA 4.0 (this adaptation too): Coble, Huggins, Cao, Ricles, Downey (2022).\n"
    "# z_mm = 25.4 * displacement_in; see tests/data/brfd_sine_2hz.md\n"
)


def read_source(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Time (s) and displacement (in) of the source, as stored."""
    if path.suffix.lower() == ".json":
        doc = json.loads(path.read_text())
        if doc.get("displacement units", "in") != "in" or doc.get("time units", "s") != "s":
            raise SystemExit(f"{path}: expected displacement in inches and time in s")
        rows = np.asarray(doc["data"], dtype=float)
        return rows[:, 0], rows[:, 1]
    rows = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return rows[:, 0], rows[:, 1]


def write_table(t: np.ndarray, disp_in: np.ndarray, out: Path) -> None:
    lines = [HEADER, "t,plate,z_mm,displacement_in\n"]
    for ti, di in zip(t.tolist(), disp_in.tolist(), strict=True):
        lines.append(f"{ti!r},1,{INCH_MM * di!r},{di!r}\n")
    out.write_text("".join(lines))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path, help="the BRFD JSON, or a t_s,displacement_in CSV")
    ap.add_argument("out", type=Path)
    ap.add_argument("--every", type=int, default=8, help="keep every N-th sample (default 8)")
    args = ap.parse_args(argv)
    t, disp = read_source(args.source)
    t, disp = t[:: args.every], disp[:: args.every]
    if np.any(np.diff(t) <= 0):
        raise SystemExit(f"{args.source}: time does not increase")
    write_table(t, disp, args.out)
    print(f"{args.out}: {t.size} rows, {t[0]:g}-{t[-1]:g} s, median spacing {np.median(np.diff(t)):.7g} s")


if __name__ == "__main__":
    main()
