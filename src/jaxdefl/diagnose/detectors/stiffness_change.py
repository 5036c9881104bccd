"""``stiffness_change``: a crack — the beam's stiffness drops at one instant, for every plate alike.

Physics: a flexural crack opens (or a bond, a support, a bearing gives) at t_c; the beam's
stiffness k falls by a relative s (−0.01: 1 % lost). Its natural frequency goes as √k, and under
load control its deflection as 1/k: from t_c on the motion of every plate and axis is
(1 + a) A cos(θ(t)) with a = 1/(1 + s) − 1 and, where the loading follows the beam's resonance,
its frequency f0 (1 + φ) with φ = √(1 + s) − 1; the load's phase stays continuous at t_c. The
simulator injects the same (`jaxdefl.simulate.injection`, ``stiffness_change``: ``t_s``,
``stiffness_change``, or ``f0_change`` / ``amplitude_change``). Against the other changes of the
motion: a step at one instant, not a steady trend or a periodic swing of the amplitude
(`amplitude_modulation`) or of the frequency (`frequency_modulation`: a linear drift is a
quadratic phase, a crack's new frequency a hinge), and a change of the motion, not of the
measured level (`level_jump`: an additive step).

Signature test: the residuals demodulated in phase and in quadrature at each series' carrier
and combined across series on the frame clock (`shared_fits.Carriers`, weights a²/σ̂²). For every
split t_c (5 % of the record kept at each end) the amplitude step's statistic is the in-phase
grid against H(t − t_c) (its mean taken out: the harmonic's own amplitude holds it) and the
frequency change's the quadrature grid against the hinge (t − t_c)₊ (a line in time taken out:
the harmonic's phase and frequency hold it); χ²₁ each, by cumulative sums over all splits at
once, over the grids' long-run variance (their variance against white noise, which frame-common
noise raises, times (1 + ρ)/(1 − ρ)). Three variants: ``amplitude`` (a step of the amplitude
alone: load control, the frequency the actuator's), ``stiffness`` (the two tied by s) and
``free`` (both, 3 parameters). p-value Bonferroni over the loading cycles in the scanned span
(neighbouring splits are nearly the same test) and the variants.

Model term: y += a_s [(1 + a H(t − t_c)) cos(arg_s + δω (t − t_mid) + ω_s φ (t − t_c)₊) − cos arg_s],
arg_s and a_s the series' nominal harmonic (or its current motion), H a step 0.05 s wide so that
Levenberg-Marquardt (`Carriers.fit`) refines t_c with the sizes; δω re-estimates the nominal
frequency, which the new frequency biased (the nominal's own parameter: not counted). Parameters:
t_c and s (``stiffness``), t_c and a (``amplitude``), t_c, a and φ (``free``), counted once; BIC
decides between the variants and the neighbouring effects.

Reported: ``t_s`` (t_c), ``stiffness_change`` (s: from φ when the frequency moved, else from the
amplitude under load control), ``f0_change``, ``amplitude_change``. Plausible: a first crack of
a reinforced-concrete beam costs 5-30 % of its stiffness; later cracks 0.1-2 %.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from ...effects.stiffness_change import ENTRY
from .._base import Context, Detector, Proposal, State
from .screening import bonferroni, chi2_sf, scanned
from .shared_fits import Carriers, param

__all__ = ["StiffnessChange", "EFFECT"]

EDGE = 0.05
WIDTH_S = 0.05  # width of the smooth step (s): sharp on the loading period, smooth for the solver
# stricter than the screens' `jaxdefl._numerics.P_MAX`: a step scanned over time, variants and bands
P_STEP = 1e-3
VARIANTS = ("amplitude", "stiffness", "free")
N_PARAMS = {"amplitude": 2, "stiffness": 2, "free": 3}


def _step(t, tc):
    x = (t - tc) / WIDTH_S
    return jax.nn.sigmoid(x), WIDTH_S * jax.nn.softplus(x)


def _moved(aux, t, gain, phi, tc, domega):
    h, hinge = _step(t, tc)
    arg = aux["arg"] + domega * (t - aux["half"]) + aux["omega"] * phi * hinge
    return aux["a"] * ((1.0 + gain * h) * jnp.cos(arg) - aux["cos"])


def _amplitude_term(theta, t, aux):
    """θ = (a, t_c): the amplitude steps by a relative a."""
    return _moved(aux, t, theta[0], 0.0, theta[1], 0.0)


def _stiffness_term(theta, t, aux):
    """θ = (s, t_c, δω): amplitude × 1/(1 + s), frequency × √(1 + s) from t_c."""
    s = theta[0]
    return _moved(aux, t, 1.0 / (1.0 + s) - 1.0, jnp.sqrt(1.0 + s) - 1.0, theta[1], theta[2])


def _free_term(theta, t, aux):
    """θ = (a, φ, t_c, δω)."""
    return _moved(aux, t, theta[0], theta[1], theta[2], theta[3])


def _tail(x: np.ndarray) -> np.ndarray:
    """Σ_{k > m} x_k for every split m (after frame m), m = 0 .. n − 2."""
    c = np.cumsum(x[::-1])[::-1]
    return c[1:]


def _long_run(g: np.ndarray) -> float:
    a, b = g[:-1], g[1:]
    den = math.sqrt(float(np.sum(a * a) * np.sum(b * b))) or 1e-300
    rho = min(max(float(np.sum(a * b)) / den, 0.0), 0.95)
    return (1.0 + rho) / (1.0 - rho)


class StiffnessChange(Detector):
    id = ENTRY.id
    sensors, structural, needs_reference = ENTRY.sensors, ENTRY.structural, ENTRY.needs_reference
    meaning = "a crack: the motion's amplitude steps (its frequency shifts) at one instant on every plate"
    plausible, plausible_unit, gate_params = 1e-3, "motion", 2  # 0.1 % of the stiffness at mid-record

    def plausible_rms(self, ctx: Context, i: int) -> float:
        """A loss of ``plausible`` of the stiffness at mid-record: the amplitude step (RMS half
        the step's) or the phase of the new frequency, a hinge less its line (RMS 0.072 ωφT,
        at most 1 rad), whichever is larger, on the series' motion."""
        a = ctx.nominal[i].amplitude / math.sqrt(2)
        step = 0.5 * self.plausible
        phase = min(1.0, 0.072 * ctx.nominal[i].omega * 0.5 * self.plausible * ctx.duration_s)
        return a * max(step, phase)

    def propose(self, ctx: Context, states: list[State]) -> list[Proposal]:
        if self.cannot_tell(ctx) is not None:
            return []
        if any(self.id in st.effects for st in states):
            return []
        car = Carriers.cached(ctx, states)
        if not car.items or ctx.n_frames < 64:
            return []
        scan = self._scan(ctx, car)
        if scan is None:
            return []
        # the full fit (the costly part) only for the variants whose screening BIC is near the best
        n_total = sum(s.n for s in ctx.series)
        crit = {v: float(np.max(scan["stat"][v])) - N_PARAMS[v] * math.log(n_total) for v in VARIANTS}
        best = max(crit.values())
        out = []
        for variant in (v for v in VARIANTS if crit[v] >= best - 10.0):
            prop = self._variant(ctx, states, car, scan, variant)
            if prop is not None:
                out.append(scanned(prop, scan["n_scan"] * len(VARIANTS), 1))  # change times × variants
        return out

    # -- the scan over split times ------------------------------------------------------------
    def _scan(self, ctx: Context, car: Carriers):
        nf = ctx.n_frames
        t = np.arange(nf) * ctx.dt_s
        grids = {}
        for kind in ("in_phase", "quadrature"):
            g, _ = car.grid(kind)
            q = np.zeros(nf)
            for it in car.items:
                s = ctx.series[it.i]
                x = car.column(it, kind)
                q += np.bincount(s.k, weights=it.w * x * x / it.scan.s2, minlength=nf)[:nf]
            present = q > 0
            # the grid's variance against white noise: frame-common noise and the noise's
            # spectrum near f0 change it
            kappa = max(1.0, float(np.sum(g[present] ** 2) / max(np.sum(q), 1e-300)))
            kappa *= _long_run(g[present])
            grids[kind] = (g, q, kappa)
        lo = max(int(math.ceil(EDGE * nf)), 2)
        hi = nf - 1 - lo
        if hi <= lo:
            return None
        # amplitude step: H − its q-weighted mean, against the in-phase grid
        g, q, kap_a = grids["in_phase"]
        qt, gt = _tail(q), _tail(g)
        qs, gs = float(q.sum()), float(g.sum())
        num_a = gt - qt / max(qs, 1e-300) * gs
        den_a = np.maximum(qt - qt * qt / max(qs, 1e-300), 1e-300)
        # frequency change: the hinge (t − t_c)₊ with a line in time taken out, quadrature grid
        g, q, kap_f = grids["quadrature"]
        m = np.array([[q.sum(), (q * t).sum()], [(q * t).sum(), (q * t * t).sum()]])
        alpha = np.linalg.solve(m + 1e-12 * np.trace(m) * np.eye(2), [g.sum(), (g * t).sum()])
        gq = g - q * (alpha[0] + alpha[1] * t)
        tc = (np.arange(nf - 1) + 0.5) * ctx.dt_s
        num_f = _tail(gq * t) - tc * _tail(gq)
        q0, q1, q2 = _tail(q), _tail(q * t), _tail(q * t * t)
        uu = q2 - 2 * tc * q1 + tc * tc * q0
        b0, b1 = q1 - tc * q0, q2 - tc * q1
        minv = np.linalg.inv(m + 1e-12 * np.trace(m) * np.eye(2))
        den_f = np.maximum(
            uu - (minv[0, 0] * b0 * b0 + 2 * minv[0, 1] * b0 * b1 + minv[1, 1] * b1 * b1), 1e-300
        )
        # the line the nominal frequency and phase took from the hinge: its slope per unit φω
        slope = minv[1, 0] * b0 + minv[1, 1] * b1
        sl = slice(lo, hi)
        na, da, nq, dq = num_a[sl], den_a[sl], num_f[sl], den_f[sl]
        w0 = 2 * math.pi * ctx.f0_hz
        sa, sf = na * na / da / kap_a, nq * nq / dq / kap_f
        # the stiffness: coefficients (a, ωφ) = s (−1, ω/2), linearised
        num_s = -na / kap_a + 0.5 * w0 * nq / kap_f
        den_s = da / kap_a + (0.5 * w0) ** 2 * dq / kap_f
        return {
            "stat": {"amplitude": sa, "free": sa + sf, "stiffness": num_s * num_s / den_s},
            "s0": num_s / den_s,
            "slope": slope[sl],
            "tc": tc[sl],
            "a": (num_a[sl], den_a[sl], kap_a),
            "f": (num_f[sl], den_f[sl], kap_f),
            "n_scan": max(1.0, (hi - lo) * ctx.dt_s * ctx.f0_hz),
        }

    def _variant(self, ctx, states, car, scan, variant) -> Proposal | None:
        (na, da, _), (nq, dq, _) = scan["a"], scan["f"]
        w0 = 2 * math.pi * ctx.f0_hz
        stat = scan["stat"][variant]
        dof = 2 if variant == "free" else 1
        j = int(np.argmax(stat))
        p_value = bonferroni(float(chi2_sf(stat[j], dof)), scan["n_scan"] * len(VARIANTS))
        if p_value >= P_STEP:
            return None
        tc = float(scan["tc"][j])
        a0 = float(na[j] / da[j])  # the amplitude step's relative size (columns carry a)
        phi0 = float(nq[j] / dq[j]) / w0
        # δω starts where the nominal frequency would be without the hinge's line
        dw0 = -w0 * phi0 * float(scan["slope"][j])
        dt10 = 10 * ctx.dt_s
        if variant == "amplitude":
            term, theta0, scale = _amplitude_term, [a0, tc], [max(abs(a0), 1e-4), dt10]
        elif variant == "stiffness":
            s0 = float(scan["s0"][j])
            dw0 = -w0 * 0.5 * s0 * float(scan["slope"][j])
            term, theta0 = _stiffness_term, [s0, tc, dw0]
            scale = [max(abs(s0), 1e-6), dt10, max(abs(dw0), 1e-6)]
        else:
            term = _free_term
            theta0 = [a0, phi0, tc, dw0]
            scale = [max(abs(a0), 1e-4), max(abs(phi0), 1e-6), dt10, max(abs(dw0), 1e-6)]
        res = car.fit(term, np.array(theta0), np.array(scale))
        if not res.converged or not np.all(np.isfinite(res.theta)):
            return None
        th, cov = np.asarray(res.theta), np.asarray(res.cov)
        k_tc = 1 if variant != "free" else 2
        t_c = float(th[k_tc])
        if not (0.0 < t_c < ctx.duration_s):
            return None
        n_params = N_PARAMS[variant]
        kept, new, gains = car.proposal_states(states, res, self.id, n_params)
        if not kept:
            return None
        sd = lambda k: math.sqrt(max(float(cov[k, k]), 0.0))  # noqa: E731
        if variant == "amplitude":
            a, sa_, phi, sphi = float(th[0]), sd(0), 0.0, None
            s = 1.0 / (1.0 + a) - 1.0
            ss = sa_ / (1.0 + a) ** 2
        elif variant == "stiffness":
            s, ss = float(th[0]), sd(0)
            a, sa_ = 1.0 / (1.0 + s) - 1.0, ss / (1.0 + s) ** 2
            phi, sphi = math.sqrt(1.0 + s) - 1.0, 0.5 * ss / math.sqrt(1.0 + s)
        else:
            a, sa_, phi, sphi = float(th[0]), sd(0), float(th[1]), sd(1)
            s, ss = (1.0 + phi) ** 2 - 1.0, 2.0 * (1.0 + phi) * sphi
        plates = sorted({ctx.series[i].plate for i in kept})
        what = (
            f"the beam lost {100 * -s:.2f} % of its stiffness (a crack opening)"
            if s < 0
            else f"the beam became {100 * s:.2f} % stiffer (a support or the load path changed)"
        )
        freq = (
            f" and the loading frequency by {100 * phi:+.3f} % ({1e3 * phi * ctx.f0_hz:+.2f} mHz)"
            if variant != "amplitude"
            else ""
        )
        explanation = (
            f"At t = {t_c:.1f} s the motion of plate(s) {', '.join(map(str, plates))} changes at once: "
            f"its amplitude by {100 * a:+.2f} %{freq}, and stays so — {what}."
        )
        return Proposal(
            effect=self.id,
            series=kept,
            states=new,
            n_params=n_params,
            p_value=p_value,
            parameters={
                "t_s": param(t_c, sd(k_tc)),
                "stiffness_change": param(s, ss),
                "f0_change": param(phi, sphi),
                "amplitude_change": param(a, sa_),
            },
            t_start=t_c,
            t_end=float(ctx.duration_s),
            band_hz=[ctx.f0_hz * min(1.0, 1.0 + phi), ctx.f0_hz * max(1.0, 1.0 + phi)],
            explanation=explanation,
            detail={
                "variant": variant,
                "loglik_gain": {ctx.series[i].key: float(g) for i, g in gains.items()},
            },
        )


EFFECT = StiffnessChange()
