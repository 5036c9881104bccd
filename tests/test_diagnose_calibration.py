"""The search's calibrated acceptance (`_search.Calibration`) against simulated null maxima."""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from jaxdefl.diagnose import Proposal
from jaxdefl.diagnose._search import ALPHA_NAMED, Calibration
from jaxdefl.diagnose.detectors.screening import changepoint_trials


def _proposal(n_params: int, scan_params: int, trials: float) -> Proposal:
    return Proposal(
        effect="extra_periodic",
        series=[0],
        states={},
        n_params=n_params,
        p_value=0.0,
        parameters={},
        t_start=0.0,
        t_end=1.0,
        band_hz=None,
        explanation="",
        trials=trials,
        scan_params=scan_params,
    )


def test_critical_value_holds_the_family_wise_level_over_a_scan():
    # A line scanned over 200 independent frequencies (3 parameters, the frequency among them):
    # the maximum of 200 χ²_2 statistics, with 11 effects screened, exceeds the critical value
    # in at most α / 11 of the null records (Monte Carlo, 20000 records).
    cal = Calibration(11)
    p = _proposal(3, 1, 200.0)
    crit = cal.critical(p)
    assert crit == stats.chi2.isf(ALPHA_NAMED / (11 * 200.0), 2)
    rng = np.random.default_rng(5)
    mx = rng.chisquare(2, size=(20000, 200)).max(axis=1)
    rate = float(np.mean(mx > crit))
    level = ALPHA_NAMED / 11
    assert 0.6 * level < rate < 1.2 * level
    # cached per search, and more trials ask for more
    assert cal.critical(p) == crit and cal.critical(_proposal(3, 1, 2000.0)) > crit


def test_changepoint_trials_match_a_simulated_cusum_maximum():
    # The maximum over 2000 splits of the standardised mean-change statistic of white noise:
    # Siegmund's effective number of splits gives its tail within the Monte Carlo error, far
    # below the 2000 splits a Bonferroni count would charge.
    rng = np.random.default_rng(11)
    n, edge, reps = 2000, 0.01, 2500
    lo = int(edge * n)
    m = np.arange(1, n)
    x = rng.standard_normal((reps, n))
    c = np.cumsum(x - x.mean(axis=1, keepdims=True), axis=1)[:, :-1]
    stat = (c * c / (m * (n - m) / n))[:, lo : n - 1 - lo]
    mx = stat.max(axis=1)
    u = 12.0
    sim = float(np.mean(mx > u))
    pred = changepoint_trials(edge, n - 2 * lo, u=u) * float(stats.chi2.sf(u, 1))
    assert abs(sim - pred) < 4 * math.sqrt(pred * (1 - pred) / reps) + 0.1 * pred
    # the default (u = 25) errs on the safe side and stays far below the count of splits
    assert changepoint_trials(edge, n - 2 * lo, u=u) < changepoint_trials(edge, n - 2 * lo) < 200
