import re

import numpy as np
import pandas as pd
import pytest

from jaxdefl import InputError
from jaxdefl.io import layout_note, read_trajectory, timestamp_note, validate_trajectory, write_trajectory


def _csv(tmp_path, text, name="traj.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_round_trip_keeps_epoch_microseconds(tmp_path, make_table):
    df = make_table(duration_s=5, axes=("z", "x", "y"))
    p = tmp_path / "t.csv"
    write_trajectory(validate_trajectory(df), p)
    back = read_trajectory(p)
    np.testing.assert_allclose(back["t"].to_numpy(), df["t"].to_numpy(), rtol=0, atol=1e-6)
    np.testing.assert_allclose(back["z"].to_numpy(), df["z"].to_numpy(), atol=1e-6)


def test_parquet_equals_csv(tmp_path, make_table):
    df = make_table(duration_s=3, n_plates=2)
    write_trajectory(validate_trajectory(df), tmp_path / "a.parquet")
    write_trajectory(validate_trajectory(df), tmp_path / "a.csv")
    a = read_trajectory(tmp_path / "a.parquet")
    b = read_trajectory(tmp_path / "a.csv")
    np.testing.assert_allclose(a["z"], b["z"], atol=1e-6)
    assert a["plate"].tolist() == b["plate"].tolist()


def test_units_are_converted(tmp_path):
    p = _csv(tmp_path, "t_ms,plate,z [m]\n0,1,0.001\n50,1,0.002\n")
    df = read_trajectory(p)
    assert df["t"].tolist() == [0.0, 0.05]
    np.testing.assert_allclose(df["z"], [1.0, 2.0])


def test_unknown_unit(tmp_path):
    p = _csv(tmp_path, "t,plate,z_in\n0,1,1\n")
    with pytest.raises(InputError, match=r"traj.csv: column 'z_in' has unknown unit 'in'"):
        read_trajectory(p)


def test_missing_column(tmp_path):
    p = _csv(tmp_path, "t,plate\n0,1\n")
    with pytest.raises(InputError, match=r"traj.csv: missing column\(s\) z"):
        read_trajectory(p)


def test_non_numeric_value_names_row_and_column(tmp_path):
    p = _csv(tmp_path, "t,plate,z\n0,1,1.0\n0.05,1,abc\n")
    with pytest.raises(InputError, match=r"row 3 column 'z': expected a number, got 'abc'"):
        read_trajectory(p)


def test_bad_plate_number(tmp_path):
    p = _csv(tmp_path, "t,plate,z\n0,1.5,1.0\n")
    with pytest.raises(InputError, match=r"row 2 column 'plate': expected an integer plate number"):
        read_trajectory(p)


def test_empty_time(tmp_path):
    p = _csv(tmp_path, "t,plate,z\n,1,1.0\n")
    with pytest.raises(InputError, match=r"row 2 column 't': expected a time in s"):
        read_trajectory(p)


def test_time_going_backwards(tmp_path):
    p = _csv(tmp_path, "t,plate,z\n0,1,1\n0.1,1,2\n0.05,1,3\n")
    with pytest.raises(InputError, match=r"row 4: t must increase within plate 1, got t=0.05 after t=0.1"):
        read_trajectory(p)


def test_conflicting_duplicate(tmp_path):
    p = _csv(tmp_path, "t,plate,z\n0,1,1\n0,1,2\n")
    with pytest.raises(InputError, match=r"row 3: plate 1 repeats t=0.0 of row 2 with different values"):
        read_trajectory(p)


def test_exact_duplicates_are_dropped(tmp_path):
    p = _csv(tmp_path, "t,plate,z\n0,1,1\n0,1,1\n0.05,1,2\n")
    df = read_trajectory(p)
    assert df["t"].tolist() == [0.0, 0.05]


def test_empty_plate_stays_for_a_status(tmp_path):
    # a plate without one valid sample is kept: its windows get too_few_samples, the rest are fitted
    p = _csv(tmp_path, "t,plate,z\n0,1,1\n0,2,\n0.05,2,nan\n")
    df = read_trajectory(p)
    assert sorted(df["plate"].unique()) == [1, 2]
    assert df.loc[df["plate"] == 2, "z"].isna().all()


def test_nan_means_missing(tmp_path):
    df = read_trajectory(_csv(tmp_path, "t,plate,z\n0,1,1\n0.05,1,\n0.1,1,NaN\n0.15,1,2\n"))
    assert np.isnan(df["z"]).sum() == 2


def test_missing_file_and_format(tmp_path):
    with pytest.raises(InputError, match=r"nope.csv: file not found"):
        read_trajectory(tmp_path / "nope.csv")
    (tmp_path / "a.xlsx").write_text("x")
    with pytest.raises(InputError, match=r"unknown table format '.xlsx'"):
        read_trajectory(tmp_path / "a.xlsx")


def test_empty_table_and_duplicate_column(tmp_path):
    with pytest.raises(InputError, match=r"the table has no rows"):
        read_trajectory(_csv(tmp_path, "t,plate,z\n"))
    with pytest.raises(InputError, match=r"column 'z' appears twice"):
        validate_trajectory(pd.DataFrame({"t": [0.0], "plate": [1], "z": [1.0], "z_mm": [1.0]}))


def test_segments_sort_independently(tmp_path):
    p = _csv(tmp_path, "segment,t,plate,z\nday2,0,1,5\nday1,10,1,1\nday1,11,1,2\nday2,1,1,6\n")
    df = read_trajectory(p)
    assert df["segment"].tolist() == ["day1", "day1", "day2", "day2"]


def test_unreadable_table(tmp_path):
    p = tmp_path / "broken.parquet"
    p.write_bytes(b"not a parquet file at all")
    with pytest.raises(InputError, match=r"broken.parquet: cannot be read as a table"):
        read_trajectory(p)


# -- reclock on rows out of sample order (issue 25 item 11) -------------------------------------


def _jittered_logger(seed: int, n: int = 400, dt: float = 0.05) -> pd.DataFrame:
    """Two plates sampled on one clock, stamps rounded to the ms and jittered by 0.1 frame."""
    rng = np.random.default_rng(seed)
    t_true = 1.7e9 + dt * np.arange(n)
    rows = []
    for plate in (3, 7):
        stamps = np.round(t_true + rng.normal(0, 0.1 * dt, n), 3)
        rows.append(
            pd.DataFrame({"t": stamps, "plate": plate, "z": np.sin(2 * np.pi * 3 * (t_true - t_true[0]))})
        )
    return pd.concat(rows, ignore_index=True)


@pytest.mark.parametrize("seed", [0, 1])
def test_reclock_sorts_a_shuffled_table_and_says_so(tmp_path, seed):
    df = _jittered_logger(seed)
    (tmp_path / "ordered.csv").write_text(df.to_csv(index=False, float_format="%.3f"))
    shuffled = df.sample(frac=1.0, random_state=seed)
    (tmp_path / "shuffled.csv").write_text(shuffled.to_csv(index=False, float_format="%.3f"))
    a = read_trajectory(tmp_path / "ordered.csv", timestamps="reclock")
    b = read_trajectory(tmp_path / "shuffled.csv", timestamps="reclock")
    assert b.attrs["timestamps"]["series_sorted"] == 2
    assert a.attrs["timestamps"]["series_sorted"] == 0
    assert "sorted by t within their plate" in timestamp_note(b.attrs["timestamps"])
    # sorting by the stamps gives the samples back (the jitter is below half a frame): the
    # recovered clock and the values agree with the table written in order
    np.testing.assert_allclose(b["t"], a["t"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(b["z"], a["z"], atol=1e-12)
    assert np.all(np.diff(b[b["plate"] == 3]["t"]) > 0)


def test_strict_refusal_never_suggests_the_policy_given(tmp_path):
    p = _csv(tmp_path, "t,plate,z\n0,1,1\n0.05,1,2\n0.05,1,3\n0.1,1,4\n")
    with pytest.raises(InputError, match="rerun with --timestamps reclock .* or --timestamps merge"):
        read_trajectory(p)
    # a series too short to reclock keeps its stamps: the refusal names merge, not reclock again
    with pytest.raises(InputError, match=r"rerun with --timestamps merge \(true duplicates\)$"):
        read_trajectory(_csv(tmp_path, "t,plate,z\n0,1,1\n0,1,2\n", "short.csv"), timestamps="reclock")


# -- wide logger tables (issue 25 item 13) ------------------------------------------------------


def _logger(n=600, dt_ms=50, seed=0):
    """A displacement logger's export: time in ms, one column per LDS channel, one dead channel."""
    rng = np.random.default_rng(seed)
    t_ms = np.arange(n) * dt_ms
    z = {
        f"LDS{k}": 1.2 * k * np.sin(2 * np.pi * 3.07 * t_ms / 1000) + rng.normal(0, 0.01, n)
        for k in (1, 2, 4)
    }
    z["LDS4"][::7] = np.nan  # dropped samples
    return pd.DataFrame({"time_ms": t_ms, **z}).round(4)


def _long_by_hand(wide: pd.DataFrame, time: str, factor_s: float, z_factor: float = 1.0) -> pd.DataFrame:
    """The long table a user would write by hand (an independent melt)."""
    rows = []
    for col in wide.columns.drop(time):
        plate = int("".join(ch for ch in col if ch.isdigit()))
        rows.append(pd.DataFrame({"t": wide[time] * factor_s, "plate": plate, "z": wide[col] * z_factor}))
    return pd.concat(rows, ignore_index=True)


@pytest.mark.parametrize("suffix", ["csv", "parquet"])
def test_a_wide_logger_table_reads_as_its_long_table(tmp_path, suffix):
    wide = _logger()
    p = tmp_path / f"logger.{suffix}"
    wide.to_csv(p, index=False) if suffix == "csv" else wide.to_parquet(p)
    got = read_trajectory(p)
    want = validate_trajectory(_long_by_hand(wide, "time_ms", 1e-3))
    pd.testing.assert_frame_equal(got[want.columns], want, check_exact=False, atol=1e-9, rtol=0)
    assert got.attrs["layout"] == {
        "layout": "wide",
        "time": "time_ms",
        "channels": {"LDS1": 1, "LDS2": 2, "LDS4": 4},
    }
    note = layout_note(got.attrs["layout"], p)
    assert "time_ms -> t; LDS1 -> plate 1, LDS2 -> plate 2, LDS4 -> plate 4" in note


def test_wide_headers_carry_units_and_segments(tmp_path):
    wide = _logger(n=50).rename(columns={"time_ms": "Time (s)"})
    wide["Time (s)"] = wide["Time (s)"] / 1000
    wide = wide.rename(columns={c: f"{c[:3]} {c[3:]} [m]" for c in wide.columns if c.startswith("LDS")})
    wide["segment"] = "day3"
    p = tmp_path / "units.csv"
    wide.to_csv(p, index=False)
    got = read_trajectory(p)
    want = validate_trajectory(_long_by_hand(wide.drop(columns="segment"), "Time (s)", 1.0, 1000.0))
    np.testing.assert_allclose(got["z"], want["z"], atol=1e-9)
    np.testing.assert_allclose(got["t"], want["t"], atol=1e-12)
    assert set(got["segment"]) == {"day3"} and sorted(got["plate"].unique()) == [1, 2, 4]


def test_a_wide_table_error_names_its_file_line(tmp_path):
    p = _csv(tmp_path, "time_ms,LDS1,LDS2\n0,1,2\n50,1,x\n")
    with pytest.raises(InputError, match=r"traj.csv: row 3 column 'LDS2': expected a number, got 'x'"):
        read_trajectory(p)
    p = _csv(tmp_path, "time_ms,LDS1,LDS2\n0,1,2\n,1,2\n")
    with pytest.raises(InputError, match=r"traj.csv: row 3 column 'time_ms': expected a time"):
        read_trajectory(p)


def test_fit_of_a_wide_table_equals_the_fit_of_its_long_table(tmp_path, capsys):
    from jaxdefl.cli import main

    wide = _logger()
    wide.to_csv(tmp_path / "logger.csv", index=False)
    _long_by_hand(wide, "time_ms", 1e-3).to_csv(tmp_path / "long.csv", index=False)
    assert main(["fit", str(tmp_path / "logger.csv"), "--out", str(tmp_path / "a.csv")]) == 0
    assert "LDS1 -> plate 1" in capsys.readouterr().err
    assert main(["fit", str(tmp_path / "long.csv"), "--out", str(tmp_path / "b.csv")]) == 0
    a, b = pd.read_csv(tmp_path / "a.csv"), pd.read_csv(tmp_path / "b.csv")
    pd.testing.assert_frame_equal(a, b)
    assert np.allclose(a["amplitude_mm"], [1.2, 2.4, 4.8], atol=5e-3)


@pytest.mark.parametrize(
    "header, names",
    [
        ("t,left,right", ["'left', 'right'", "no plate number"]),
        ("time_ms,LDS1,CAM2", ["'LDS1', 'CAM2'", "one sensor's plates once each"]),
        ("time_ms,LDS1,LDS 1", ["'LDS1', 'LDS 1'"]),
        ("t,z", ["missing column(s) plate (got t, z)"]),
    ],
)
def test_an_ambiguous_table_names_its_columns_the_layouts_and_a_conversion_that_works(
    tmp_path, header, names
):
    cols = header.split(",")
    body = "\n".join(
        ",".join(f"{0.05 * i:.2f}" if j == 0 else str(j + i % 3) for j in range(len(cols))) for i in range(40)
    )
    p = _csv(tmp_path, header + "\n" + body + "\n", "amb.csv")
    with pytest.raises(InputError) as err:
        read_trajectory(p)
    msg = str(err.value)
    assert len(msg.splitlines()) == 1 and msg.startswith(f"{p}: ")
    for name in names:
        assert name in msg
    assert "long table (t, plate, z" in msg and "wide logger table" in msg
    # the one-line conversion the message gives makes a table that reads
    conversion = re.search(r"(?:to convert \(plates 1.. in column order\)|for one plate): (.*)$", msg).group(
        1
    )
    g = tmp_path / "converted.csv"
    eval(conversion, {"pd": pd, "f": p, "g": g})  # noqa: S307 - our own message
    back = read_trajectory(g)
    assert sorted(back["plate"].unique()) == list(range(1, len(cols)))
    assert len(back) == 40 * (len(cols) - 1)
