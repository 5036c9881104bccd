"""The effect ids of the DIAG.json contract (DESIGN.md), shared by the diagnosis and the
concealed-effect generator without either importing the other."""

EFFECT_IDS = (
    "motion_artefact",
    "harmonic_distortion",
    "drift",
    "level_jump",
    "amplitude_modulation",
    "frequency_modulation",
    "timing_error",
    "extra_periodic",
    "outliers",
    "heteroscedastic_noise",
    "quantization",
    "mode_shape",
    "clipping",
    # issue 12's vocabulary (camera shake, crack)
    "camera_shake",
    "stiffness_change",
)
