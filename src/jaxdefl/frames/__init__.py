"""Frames stage: batched target extraction on frame tensors (B, 1, H, W) with torch + kornia.

The only stage that imports torch.
"""

from .ellipse import Ellipse, fit_ellipse
from .extract import Extractor, extract_frames, extract_recording, extract_to_table, resolve_device
from .floor import bilinear, floor_targets
from .kernels import (
    check_frames,
    erode,
    flat_indices,
    label_components,
    opening,
    otsu_threshold,
    region_stats,
)
from .pipeline import PlateGeometry, Scene, SceneError, calibrate_scene, detect_chunk, ray_factors
from .track import Tracker

__all__ = [
    "Ellipse",
    "Extractor",
    "PlateGeometry",
    "Scene",
    "SceneError",
    "Tracker",
    "bilinear",
    "calibrate_scene",
    "check_frames",
    "detect_chunk",
    "erode",
    "extract_frames",
    "extract_recording",
    "extract_to_table",
    "flat_indices",
    "fit_ellipse",
    "floor_targets",
    "label_components",
    "opening",
    "otsu_threshold",
    "ray_factors",
    "region_stats",
    "resolve_device",
]
