"""The open world: residual structure that no named effect explains, located and modelled by
generic terms, reported under ``"unnamed"`` and never given a vocabulary name.

After the named search (`_search`) the residuals are searched again, greedily, with three
generic terms, each chosen by BIC:

- ``line``: a sinusoid at the peak of the residual periodograms summed over an axis' series,
  each normalised by its running median (the local noise level, whatever its colour), when that
  peak is significant after the frequencies scanned (α = 0.01); per-series amplitudes, shared
  frequency, optionally decaying, e^{−λ(t − t_s)} from the
  series' start (a free vibration: its damping ratio ζ = λ / 2πf is reported). Sparse: one line
  per round, the next one from the new residual.
- ``envelope``: a smooth complex envelope u(t) of the loading line, shared by the series that
  carry the motion: y += a_s Re[u(t) e^{i arg_s(t)}], u a cubic B-spline with K interior knots
  (K by BIC), or an exponential e^{−λ(t − t_ref)} (a free decay: ζ reported).
- ``trend``: a slow additive cubic B-spline in time per series (K by BIC), its constant free;
  or one common to an axis' series (a camera's sway), which may go finer (`COMMON_KNOTS`, down
  to 4 loading periods a knot span): it pays its coefficients once for the axis.

Evidence. The noise of the residual is modelled as AR(1) on the frame clock, ρ estimated per
series from the lag-1 autocorrelation of the residual's first differences (−(1 − ρ)/2 for
AR(1); slow structure hardly moves it) and re-estimated after the term is added, σ profiled.
So coloured noise is not taken for structure. Terms shared by the plates are discounted by the
frame correlation's design effect (`_correlation`). A term is accepted when

    ΔBIC = −2 Δlog L + k log N < −10

(N all samples of the record, k every parameter added: frequencies, decay rates, amplitudes,
spline coefficients). Reported: where (plates, axes, time span, band), the term's parameters,
ΔBIC and the residual RMS of the series it touches before and after.


The package: `terms` (the generic terms and their parameters' σ's), `noise` (their noise model),
`report` (their report text), `search` (the greedy search and backfitting).
"""

from .noise import ar1_loglik, ar1_rho, ar1_whiten, colored_gain
from .report import UnnamedTerm
from .search import KINDS, MAX_TERMS, apply_term, best_term, search_unnamed
from .terms import KNOTS, term_sigmas

__all__ = [
    "KINDS",
    "KNOTS",
    "MAX_TERMS",
    "UnnamedTerm",
    "apply_term",
    "ar1_loglik",
    "ar1_rho",
    "ar1_whiten",
    "best_term",
    "colored_gain",
    "search_unnamed",
    "term_sigmas",
]
