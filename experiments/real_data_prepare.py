"""Write the real recordings of the tests (issues 13 and 23) as trajectory tables jaxdefl reads.

Five public records, each with its provenance note in ``tests/data/<name>.md``:

- ``brfd``: the friction damper (below, the default source kind);
- ``ds4``: a shaker-driven steel cantilever, multi-tone forcing (100, 120, 150 Hz), the tip
  accelerometer in g (High-Rate-SHM-Working-Group Dataset-4, the authors' 400-Hz
  ``data_set_K_downsampled_by_128.lvm``), cut to ``--t0``-``--t1``;
- ``dropbear``: the DROPBEAR beam with a movable roller (Dataset-8, 5 kHz text file), one channel
  (``--channel lowg`` the low-g accelerometer in V, ``--channel pinloc`` the roller position
  sensor in V), cut to ``--t0``-``--t1`` and every ``--every``-th sample kept.

    python experiments/real_data_prepare.py data_set_2_downsampled_by_128.lvm \
        tests/data/ds4_multitone_step.csv --kind ds4 --t0 8 --t1 12 --every 1
    python experiments/real_data_prepare.py test0.txt tests/data/dropbear_roller_staircase.csv \
        --kind dropbear --channel pinloc --every 100
    python experiments/real_data_prepare.py test0.txt tests/data/dropbear_free_decay.csv \
        --kind dropbear --channel lowg --t0 1.9 --t1 2.9 --every 5

The values are written as the source holds them (shortest round-trip decimal), under ``z_mm``
because jaxdefl reads one length unit: for the accelerometers and the position sensor that column
is g or volts, not millimetres (the source column beside it says which). Nothing is filtered.

The friction damper:

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


DS4_HEADER = (
    "# Steel cantilever, electromagnetic shaker, multi-tone forcing 100/120/150 Hz (ARTS-Lab);\n"
    "# PujaChowdhury/Dataset-4-Univariate-signal-with-non-stationarity @ "
    "06a0d36fb448ca58ed0ce365d2464b442fa3638e,\n"
    "# data/data_I/test_{test}/{path}; t {t0:g}-{t1:g} s of the authors' 400-Hz series, "
    "time shifted to start at 0.\n"
    "# Licence CC BY-SA 4.0 (this adaptation too): Chowdhury, Downey, Bakos, Conrad (2021).\n"
    "# z_mm holds the tip acceleration in g (accel_g), not mm; see tests/data/{name}.md\n"
)
DROPBEAR_HEADER = (
    "# DROPBEAR beam with a movable roller support, slow positional displacement, 10 steps (ARTS-Lab);\n"
    "# High-Rate-SHM-Working-Group/Dataset-8-DROPBEAR-Acceleration-vs-Roller-Displacement @ "
    "28955a71b7b00cbca47dec9f0ff8fd9adc591cf3,\n"
    "# data/Slow Postional Displacement/trial data/10steps/{path}; channel {channel}, "
    "t {t0:g}-{t1:g} s, every {every}th sample of 5 kHz, time shifted to 0.\n"
    "# Licence CC BY-SA 4.0 (this adaptation too): Vereen, Downey, Dodson, Moura (2023).\n"
    "# z_mm holds the {what} in volts ({col}), not mm; see tests/data/{name}.md\n"
)
DROPBEAR_CHANNELS = {
    "lowg": (0, "low-g accelerometer output", "lowg_v"),
    "pinloc": (2, "roller position sensor output", "pinloc_v"),
}


def read_ds4(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Time (s) and acceleration (g) of a Dataset-4 LabVIEW file (X_Value, Voltage, Force, Acceleration)."""
    rows = np.loadtxt(path, skiprows=23, ndmin=2)
    return rows[:, 0], rows[:, 3]


def read_dropbear(path: Path, channel: str) -> tuple[np.ndarray, np.ndarray]:
    """Time (s) and one channel (V) of a Dataset-8 text file (Low G Accel, Accel, PinLoc, Time)."""
    rows = np.loadtxt(path, skiprows=9, ndmin=2)
    return rows[:, -1], rows[:, DROPBEAR_CHANNELS[channel][0]]


def write_generic(t: np.ndarray, v: np.ndarray, col: str, header: str, out: Path) -> None:
    lines = [header, f"t,plate,z_mm,{col}\n"]
    for ti, vi in zip(t.tolist(), v.tolist(), strict=True):
        lines.append(f"{round(ti, 9)!r},1,{vi!r},{vi!r}\n")
    out.write_text("".join(lines))


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
    ap.add_argument("--kind", choices=("brfd", "ds4", "dropbear"), default="brfd")
    ap.add_argument("--channel", choices=tuple(DROPBEAR_CHANNELS), default="lowg")
    ap.add_argument("--t0", type=float, default=-np.inf, help="first time kept (s, source clock)")
    ap.add_argument("--t1", type=float, default=np.inf, help="times kept are < t1 (s)")
    args = ap.parse_args(argv)
    if args.kind != "brfd":
        if args.kind == "ds4":
            t, v = read_ds4(args.source)
        else:
            t, v = read_dropbear(args.source, args.channel)
        keep = (t >= args.t0 - 1e-9) & (t < args.t1 - 1e-9)
        t, v = t[keep][:: args.every], v[keep][:: args.every]
        fmt = dict(
            path=args.source.name,
            test=args.source.name[9:10],
            t0=t[0],
            t1=t[-1],
            name=args.out.stem,
            every=args.every,
        )
        if args.kind == "ds4":
            write_generic(t - t[0], v, "accel_g", DS4_HEADER.format(**fmt), args.out)
        else:
            _, what, col = DROPBEAR_CHANNELS[args.channel]
            header = DROPBEAR_HEADER.format(channel=args.channel, what=what, col=col, **fmt)
            write_generic(t - t[0], v, col, header, args.out)
        print(f"{args.out}: {t.size} rows, median spacing {np.median(np.diff(t)):.7g} s")
        return
    t, disp = read_source(args.source)
    t, disp = t[:: args.every], disp[:: args.every]
    if np.any(np.diff(t) <= 0):
        raise SystemExit(f"{args.source}: time does not increase")
    write_table(t, disp, args.out)
    print(f"{args.out}: {t.size} rows, {t[0]:g}-{t[-1]:g} s, median spacing {np.median(np.diff(t)):.7g} s")


if __name__ == "__main__":
    main()
