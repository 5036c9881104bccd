"""Windows: padded arrays with masks, shape (window, sample), time centred per window."""

from .windows import Windows, check_window_plan, frame_clock, make_windows, windows_like

__all__ = ["Windows", "check_window_plan", "frame_clock", "make_windows", "windows_like"]
