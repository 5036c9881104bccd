import numpy as np
import pandas as pd
import pytest

from jaxdefl import InputError
from jaxdefl.io import read_trajectory, timestamp_note, validate_trajectory, write_trajectory


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
