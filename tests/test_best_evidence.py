"""The evidence a detection curve is drawn against: the best possible detector's (GLS) noncentrality
under the recording's own noise covariance (`jaxdefl.simulate.effects.best_evidence`)."""

from __future__ import annotations

import numpy as np
import pytest

from jaxdefl.simulate.effects import (
    CleanRecording,
    RecordingSpec,
    best_evidence,
    draw_effect,
    effect_strength,
)


@pytest.mark.parametrize(("common", "los"), [(0.6, 0.0), (0.5, 0.9), (0.0, 0.85)])
def test_noise_correlation_is_the_drawn_one(common, los):
    spec = RecordingSpec(sensor="tof", duration_s=600, n_plates=5, frame_common=common, line_of_sight=los)
    base = CleanRecording(spec, 11)
    eps = base.eps.reshape(base.eps.shape[0], -1)
    emp = np.corrcoef(eps.T)
    n = eps.shape[0]
    assert n > 10_000
    # the sampling s.e. of a correlation is (1 - ρ²)/√n <= 0.01: 5 s.e.
    assert np.max(np.abs(emp - base.noise_correlation())) < 5.0 / np.sqrt(n)


def test_independent_noise_gives_the_white_signal():
    base = CleanRecording(RecordingSpec(sensor="tof", duration_s=120, n_plates=9), 5)
    for eid in ("drift", "level_jump", "mode_shape", "stiffness_change"):
        e = draw_effect(eid, base, np.random.default_rng(3), target_ratio=1e-6, signal_min=50.0)
        assert best_evidence(base, e) == pytest.approx(effect_strength(base, e)[1], rel=1e-9)


def test_a_common_effect_is_discounted_by_the_design_effect_and_a_single_plate_one_gains():
    m, c = 9, 0.6
    spec = RecordingSpec(
        sensor="tof", duration_s=120, n_plates=m, frame_common=c, plate_noise_spread=0.0, noisy_plate=0
    )
    base = CleanRecording(spec, 5)
    drift = draw_effect("drift", base, np.random.default_rng(3), target_ratio=1e-6, signal_min=50.0)
    assert drift["plates"] == list(range(1, m + 1)) and drift["axes"] == ["z"]
    # every plate the same δ and σ: δᵀΣ⁻¹δ = δᵀδ / (σ² (1 + (m − 1) c))
    white = effect_strength(base, drift)[1]
    assert best_evidence(base, drift) == pytest.approx(white / (1 + (m - 1) * c), rel=1e-6)
    # one plate: the others measure the common noise, Σ⁻¹'s diagonal (1 + (m − 2) c)/((1 − c)(1 + (m − 1) c))
    jump = {
        "id": "level_jump",
        "kind": "one_plate",
        "plates": [4],
        "axes": ["z"],
        "parameters": {"t_jump_s": 60.0, "size_mm": 0.2},
    }
    gain = (1 + (m - 2) * c) / ((1 - c) * (1 + (m - 1) * c))
    assert best_evidence(base, jump) == pytest.approx(effect_strength(base, jump)[1] * gain, rel=1e-6)


def test_draw_effect_scales_to_the_best_evidence():
    spec = RecordingSpec(sensor="tof", duration_s=120, n_plates=9, frame_common=0.7)
    base = CleanRecording(spec, 8)
    for eid in ("amplitude_modulation", "extra_periodic", "clipping"):
        e = draw_effect(
            eid, base, np.random.default_rng(4), target_ratio=1e-6, signal_min=80.0, evidence="best"
        )
        assert best_evidence(base, e) == pytest.approx(80.0, rel=0.02)
    with pytest.raises(ValueError, match="evidence"):
        draw_effect("drift", base, np.random.default_rng(4), evidence="gls")
