"""Windows: padded arrays with masks, shape (window, sample), time centred per window."""

from .windows import Windows, frame_clock, make_windows, windows_like

__all__ = ["Windows", "frame_clock", "make_windows", "windows_like"]
