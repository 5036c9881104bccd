"""A ToF camera's lag behind its frame stamps depends on the plate's modulation phase (issue 23).

The phase is atan2(C₃ − C₁, C₀ − C₂): a motion reaches it through the (1, 3) tap pair with weight
cos²φ₀ and through the (0, 2) pair with weight sin²φ₀. The references here are a slow numpy
four-tap demodulation (eq. 3.5-3.8) and a camera table made by it.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from jaxdefl.diagnose import build_context
from jaxdefl.diagnose.detectors.shared_fits import quadrature_weight, tap_response
from jaxdefl.settings import DiagnoseSettings

C_MM_S = 299_792_458.0e3
OFFSETS = (0.0, 0.25, 0.5, 0.75)


def four_tap_range(t_frame, r0_mm, amp_mm, f_hz, fm_mhz, spread_s, phase=0.0):
    """Measured range (mm) of a surface at r0 + amp sin(2π f t + phase), four taps at
    OFFSETS·spread after each frame time, demodulated as eq. 3.6-3.8 (no noise)."""
    k = 4 * math.pi * fm_mhz * 1e6 / C_MM_S  # rad per mm of range
    t = t_frame[:, None] + np.asarray(OFFSETS)[None, :] * spread_s
    phi = k * (r0_mm + amp_mm * np.sin(2 * math.pi * f_hz * t + phase))
    c = 0.5 * np.cos(phi + np.arange(4) * math.pi / 2)  # C_k = A/2 cos(φ + kπ/2), A = 1, B = 0
    phase_meas = np.unwrap(np.arctan2(c[:, 3] - c[:, 1], c[:, 0] - c[:, 2]))
    return phase_meas / k


def harmonic(t, y, f_hz):
    a = np.c_[np.ones_like(t), np.cos(2 * math.pi * f_hz * t), np.sin(2 * math.pi * f_hz * t)]
    c = np.linalg.lstsq(a, y, rcond=None)[0]
    return complex(c[1], -c[2])  # y ≈ Re[Z e^{iωt}]


@pytest.mark.parametrize("r0_mm", [2215.0, 2338.0, 2500.0, 2841.0])
@pytest.mark.parametrize(("f_hz", "spread_s"), [(1.0219, 0.05), (3.068, 0.05), (3.0, 0.1)])
def test_tap_response_follows_the_modulation_phase(r0_mm, f_hz, spread_s):
    t = np.arange(0, 20.0, 0.05)
    amp = 0.5  # small against the 5-m ambiguity range: the linear regime of the derivation
    measured = harmonic(t, four_tap_range(t, r0_mm, amp, f_hz, 29.0, spread_s), f_hz)
    true = harmonic(t, r0_mm + amp * np.sin(2 * math.pi * f_hz * t), f_hz)
    q = quadrature_weight(r0_mm, 29.0)
    h = tap_response(2 * math.pi * f_hz, spread_s, OFFSETS, quadrature=q)
    ratio = measured / true
    assert abs(ratio - h) < 2e-4 * abs(h)
    # the equal-pair response is what the mean over the modulation phase gives, not this plate
    if abs(q - 0.5) > 0.2:
        assert abs(ratio - tap_response(2 * math.pi * f_hz, spread_s, OFFSETS)) > 10 * abs(ratio - h)


def test_quadrature_derivative_matches_finite_difference():
    w, T, q = 2 * math.pi * 3.0, 0.05, 0.83
    h, dh = tap_response(w, T, OFFSETS, derivative=True, quadrature=q)
    eps = 1e-7
    up, down = (tap_response(w, T + d, OFFSETS, quadrature=q) for d in (eps, -eps))
    fd = (up - down) / (2 * eps)
    assert abs(dh - fd) < 1e-6 * abs(dh)


def _camera_and_lds(r0_mm: float, f_hz: float = 3.068, seconds: float = 60.0, seed: int = 0):
    """Two plates seen by a 20-Hz, 29-MHz ToF camera at range ≈ r0 along the z axis, and their LDS."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, seconds, 0.05)
    rows, lds = [], []
    t_l = np.arange(0, seconds, 1 / 300)
    for plate, amp in ((5, 2.0), (7, 2.2)):
        z = four_tap_range(t, r0_mm, amp, f_hz, 29.0, 0.05) + rng.normal(0, 0.3, t.size)
        rows.append(pd.DataFrame({"t": 1.7e9 + t, "plate": plate, "x": 0.0, "y": 0.0, "z": z}))
        zl = r0_mm + amp * np.sin(2 * math.pi * f_hz * t_l) + rng.normal(0, 0.002, t_l.size)
        lds.append(pd.DataFrame({"t": 1.7e9 + t_l, "plate": plate, "z": zl}))
    return pd.concat(rows, ignore_index=True), pd.concat(lds, ignore_index=True)


@pytest.mark.parametrize("r0_mm", [2215.0, 2500.0])
def test_nominal_lag_is_the_plates_own(r0_mm):
    """The tied nominal harmonic holds the camera's lag at the plate's range: its phase is the
    camera's own within noise, where equal pairs would be off by several degrees."""
    cam, lds = _camera_and_lds(r0_mm)
    settings = DiagnoseSettings(sensor="tof", frame_rate_hz=20.0, modulation_mhz=29.0, tap_offsets=OFFSETS)
    ctx, _, _ = build_context(cam, lds, settings)
    q = quadrature_weight(r0_mm, 29.0)
    equal = tap_response(2 * math.pi * 3.068, 0.05, OFFSETS)
    own = tap_response(2 * math.pi * 3.068, 0.05, OFFSETS, quadrature=q)
    gap = abs(np.angle(own / equal))
    assert gap > math.radians(2.0)  # the case can tell them apart
    for i, s in enumerate(ctx.series):
        if not s.tied:
            continue
        nom, free = ctx.nominal[i], ctx.free[i]
        zn = complex(nom.C, -nom.D) * np.exp(1j * nom.omega * (30.0 - nom.t_ref))
        zf = complex(free.C, -free.D) * np.exp(1j * free.omega * (30.0 - free.t_ref))
        assert abs(np.angle(zf / zn)) < 0.2 * gap
