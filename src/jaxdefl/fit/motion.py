"""Response of a four-phase ToF camera to harmonic motion: the motion artefact (thesis 5.47-5.52).

The SR4000 takes its four correlation samples C_0..C_3 one after the other within each frame,
at t_k = t_frame + o_k T (T the frame period, o_k the tap offsets; evenly spread by default).
For motion small against the non-ambiguity range, linearising eq. 5.51 in the phase shifts of
eq. 5.49 gives the measured range of a pixel whose true phase is φ as

    ρ̂ = sin²φ (ρ(t_0) + ρ(t_2)) / 2 + cos²φ (ρ(t_1) + ρ(t_3)) / 2,

a weighted mean of the range at the tap times. Averaged over the pixels of a plate (φ spread
over many cycles of the non-ambiguity range, so sin²φ and cos²φ average to 1/2), a harmonic
motion e^{iωt} is measured as H(ω) e^{iωt} with

    H(ω) = [e^{iω(t_0+t_2)/2} cos(ω(t_2-t_0)/2) + e^{iω(t_1+t_3)/2} cos(ω(t_3-t_1)/2)] / 2,

relative to the frame time. The amplitude is scaled by |H| (the gain loss) and delayed by
arg H. For evenly spread taps |H| = cos(ωT/4) cos(ωT/8): a 4 mm motion loses 0.061 mm at 1 Hz
and 10 Hz frames, 0.53 mm at 3 Hz and 10 Hz, 0.14 mm at 3 Hz and 20 Hz (thesis Fig. 6.9).
"""

from __future__ import annotations

import numpy as np

__all__ = ["EVEN_TAPS", "motion_artefact_response"]

EVEN_TAPS = (0.0, 0.25, 0.5, 0.75)


def motion_artefact_response(
    f0_hz, frame_rate_hz: float, tap_offsets=EVEN_TAPS
) -> tuple[np.ndarray, np.ndarray]:
    """(gain, lag_rad) of the measured harmonic at ``f0_hz``: A_measured = gain * A_true."""
    w = 2 * np.pi * np.asarray(f0_hz, dtype=np.float64)
    t = np.asarray(tap_offsets, dtype=np.float64) / float(frame_rate_hz)
    if t.shape != (4,):
        raise ValueError(f"tap_offsets: expected four offsets, got {tap_offsets!r}")
    h = 0.5 * (
        np.exp(1j * w * (t[0] + t[2]) / 2) * np.cos(w * (t[2] - t[0]) / 2)
        + np.exp(1j * w * (t[1] + t[3]) / 2) * np.cos(w * (t[3] - t[1]) / 2)
    )
    return np.abs(h), np.angle(h)
