"""The fast CSV reader (pyarrow) reads what pandas' reader reads, and leaves the rest to it."""

import numpy as np
import pandas as pd
import pytest

from jaxdefl._errors import InputError
from jaxdefl.io import load_table, read_trajectory, validate_trajectory
from jaxdefl.io.trajectory import _read_numeric_csv


def _table(rng, n=500):
    t = 1.7e9 + np.arange(n) / 20 + rng.normal(0, 1e-4, n)
    z = rng.normal(1900, 1, n)
    z[7] = np.nan
    return pd.DataFrame(
        {
            "segment": np.where(np.arange(n) < n // 2, "day1", "day2"),
            "t": t,
            "plate": 3,
            "x": rng.normal(size=n),
            "z": z,
        }
    )


def test_arrow_and_pandas_read_the_same_table(tmp_path):
    df = _table(np.random.default_rng(0))
    path = tmp_path / "t.csv"
    df.to_csv(path, index=False, float_format="%.17g", na_rep="")
    fast = _read_numeric_csv(path)
    assert fast is not None
    slow = pd.read_csv(path, comment="#")
    pd.testing.assert_frame_equal(fast, slow, check_exact=True)
    # and the validated tables agree to the last bit
    pd.testing.assert_frame_equal(
        validate_trajectory(fast, path), validate_trajectory(slow, path), check_exact=True
    )
    pd.testing.assert_frame_equal(read_trajectory(path), validate_trajectory(slow, path), check_exact=True)


@pytest.mark.parametrize(
    "text",
    [
        "# logger v2\nt,plate,z\n1.7e9,1,1900\n1.7e9,1,1901\n",  # a comment line
        "t,plate,z\n1.7e9,1,1900\n1.7e9,1,true\n",  # a true/false cell: pandas' messages
        "t,plate,z,z\n1.7e9,1,1900,3\n",  # a repeated column name
        'segment,t,plate,z\n"a,b",1.7e9,1,1900\n',  # a quoted cell
        "t,plate,z\n2026-01-01T00:00:00,1,1900\n",  # ISO times stay strings for the validator
    ],
)
def test_anything_but_plain_numbers_goes_to_pandas(tmp_path, text):
    path = tmp_path / "t.csv"
    path.write_text(text)
    assert _read_numeric_csv(path) is None
    if text.startswith("t,plate,z,z"):  # pandas would read the second z as z.1: refused instead
        with pytest.raises(InputError, match=r"column 'z' appears twice"):
            load_table(path)
        return
    pd.testing.assert_frame_equal(load_table(path), pd.read_csv(path, comment="#"))
