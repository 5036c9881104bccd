"""Frames stage: batched target extraction on frame tensors (B, 1, H, W) with torch + kornia.

The only stage that imports torch.
"""

from .ellipse import Ellipse, fit_ellipse
from .kernels import (
    check_frames,
    erode,
    label_components,
    otsu_threshold,
    points_from_depth,
    points_from_range,
    region_stats,
)

__all__ = [
    "Ellipse", "check_frames", "erode", "fit_ellipse", "label_components", "otsu_threshold",
    "points_from_depth", "points_from_range", "region_stats",
]
