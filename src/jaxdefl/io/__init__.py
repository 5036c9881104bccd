"""Reading and writing tables and recordings."""

from .trajectory import read_reference, read_trajectory, validate_trajectory, write_trajectory

__all__ = ["read_reference", "read_trajectory", "validate_trajectory", "write_trajectory"]
