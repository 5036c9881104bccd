"""Reading and writing tables and recordings."""

from .trajectory import load_table, read_reference, read_trajectory, validate_trajectory, write_trajectory

__all__ = ["load_table", "read_reference", "read_trajectory", "validate_trajectory", "write_trajectory"]
