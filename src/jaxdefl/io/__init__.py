"""Reading and writing tables and recordings."""

from .trajectory import (
    TIMESTAMP_POLICIES,
    check_timestamp_policy,
    layout_note,
    load_table,
    read_reference,
    read_trajectory,
    timestamp_note,
    validate_trajectory,
    write_trajectory,
)

__all__ = [
    "TIMESTAMP_POLICIES",
    "check_timestamp_policy",
    "layout_note",
    "load_table",
    "read_reference",
    "read_trajectory",
    "timestamp_note",
    "validate_trajectory",
    "write_trajectory",
]
