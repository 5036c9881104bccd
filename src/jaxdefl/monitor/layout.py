"""Frames as the monitor sees them: (frame,) times and (frame, series) values, series = plate × axis.

Series s is plate ``plates[s // len(axes)]``, axis ``axes[s % len(axes)]``. Conversion to and from
the trajectory-table schema (``t, plate, x, y, z``), and the batch fit of a span of frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["Layout", "frames_from_table", "fit_span"]


@dataclass(frozen=True)
class Layout:
    plates: tuple[int, ...]
    axes: tuple[str, ...]

    @property
    def n(self) -> int:
        return len(self.plates) * len(self.axes)

    def plate_of(self) -> np.ndarray:
        return np.repeat(np.asarray(self.plates, np.int64), len(self.axes))

    def axis_of(self) -> np.ndarray:
        return np.tile(np.asarray(self.axes, object), len(self.plates))

    def label(self, s: int) -> str:
        return f"plate {self.plate_of()[s]} {self.axis_of()[s]}"

    def to_table(self, t: np.ndarray, Y: np.ndarray, segment: str = "") -> pd.DataFrame:
        """Trajectory table (segment, t, plate, <axes>) of frames ``t`` (frame,), ``Y`` (frame, S)."""
        nf, npl, na = len(t), len(self.plates), len(self.axes)
        vals = Y.reshape(nf, npl, na)
        df = pd.DataFrame(
            {
                "segment": segment,
                "t": np.repeat(t, npl),
                "plate": np.tile(np.asarray(self.plates, np.int64), nf),
            }
        )
        for k, a in enumerate(self.axes):
            df[a] = vals[:, :, k].ravel()
        return df


def frames_from_table(
    df: pd.DataFrame, layout: Layout | None = None
) -> tuple[np.ndarray, np.ndarray, Layout]:
    """(t (frame,), Y (frame, S), layout) from a validated trajectory table (rows of one instant
    form a frame; a plate missing at an instant is NaN)."""
    if layout is None:
        axes = tuple(a for a in ("z", "x", "y") if a in df.columns)
        layout = Layout(tuple(int(p) for p in np.unique(df["plate"].to_numpy())), axes)
    t_all = df["t"].to_numpy(np.float64)
    t, fi = np.unique(t_all, return_inverse=True)
    pl_index = {p: i for i, p in enumerate(layout.plates)}
    pi = np.array([pl_index.get(int(p), -1) for p in df["plate"].to_numpy()])
    keep = pi >= 0
    na = len(layout.axes)
    Y = np.full((len(t), len(layout.plates) * na), np.nan)
    for k, a in enumerate(layout.axes):
        if a in df.columns:
            Y[fi[keep], pi[keep] * na + k] = df[a].to_numpy(np.float64)[keep]
    return t, Y, layout


def fit_span(t: np.ndarray, Y: np.ndarray, layout: Layout) -> pd.DataFrame:
    """The batch estimates (`jaxdefl.fit`) of a span of frames, one row per series in layout order."""
    from ..fit import estimate_table
    from ..io import validate_trajectory

    df = validate_trajectory(layout.to_table(t, Y, segment="span"), "<monitor span>")
    est = estimate_table(df, axes=layout.axes).table
    est = est.set_index(["plate", "axis"])
    idx = list(zip(layout.plate_of().tolist(), layout.axis_of().tolist(), strict=True))
    return est.reindex(idx).reset_index()
