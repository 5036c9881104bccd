"""Reports: figures and markdown summaries."""

from .figures import plot_fit, plot_periodogram

__all__ = ["plot_fit", "plot_periodogram"]
