"""Bulk reprocessing of campaigns: units of work, resumable outputs, dask scale-out."""

from .campaign import Campaign, Processing, Recording, load_campaign
from .runner import run_campaign
from .store import is_finished, read_manifest

__all__ = [
    "Campaign",
    "Processing",
    "Recording",
    "is_finished",
    "load_campaign",
    "read_manifest",
    "run_campaign",
]
