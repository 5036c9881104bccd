import numpy as np
import pandas as pd

from jaxdefl.fit import estimate_windows
from jaxdefl.io import validate_trajectory
from jaxdefl.series import make_windows
from jaxdefl.uncertainty import CYCLES_MIN, DROPOUT_MAX, SNR_MIN, honesty_features, honesty_flags


def _estimates(cases):
    """One plate and segment per (duration_s, amp, sigma, dropout) case."""
    from conftest import harmonic_table

    frames = [harmonic_table(duration_s=d, amp=a, sigma=s, dropout=do, seed=i, t0=1.7e9 + 1e4 * i)
              .assign(plate=i + 1, segment=f"s{i}") for i, (d, a, s, do) in enumerate(cases)]
    df = validate_trajectory(pd.concat(frames, ignore_index=True))
    return estimate_windows(make_windows(df, axes=("z",)), fap_max=1.0)


def test_flags_name_the_reason():
    est = _estimates([
        (30.0, 2.5, 0.75, 0.03),   # thesis vertical SNR: ok
        (30.0, 0.25, 0.75, 0.03),  # A/σ_A about 4: low_snr
        (1.5, 2.5, 0.10, 0.0),     # 4.6 cycles: few_cycles
        (30.0, 2.5, 0.75, 0.75),   # 75 % of frames lost: heavy_dropouts
        (30.0, 0.0, 0.75, 0.03),   # nothing there: not fitted or low_snr
    ])
    flags = honesty_flags(est)
    feat = honesty_features(est)
    assert flags[0] == "ok"
    assert flags[1] == "low_snr" and feat["snr"][1] < SNR_MIN
    assert flags[2] == "few_cycles" and feat["cycles"][2] < CYCLES_MIN
    assert flags[3] == "heavy_dropouts" and feat["missing"][3] > DROPOUT_MAX
    assert flags[4] in ("low_snr", "not_fitted")
    assert abs(feat["missing"][0] - 0.03) < 0.02
    assert abs(feat["cycles"][0] - 30 * 3.0672) < 0.5
    assert flags.dtype.kind == "U" and flags.shape == (5,)


def test_reasons_combine_and_unfitted_windows_say_so():
    est = _estimates([(1.5, 0.3, 0.75, 0.0), (30.0, 2.5, 0.75, 0.03)])
    est.fit.converged[1] = False  # as for a window the fit gave up on
    flags = honesty_flags(est)
    assert flags[0] == "low_snr+few_cycles"
    assert flags[1] == "not_fitted"
    assert np.all(honesty_features(est)["n"] > 0)
