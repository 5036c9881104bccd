"""Distinct rows of a byte array: the drop-out masks and frame sets that windows share."""

from __future__ import annotations

import numpy as np

__all__ = ["unique_rows"]


def unique_rows(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct rows of the uint8 array ``a`` (row, byte) and the index of each row among them.

    Rows are told apart by a 64-bit hash (a sort of one number per row, not of whole rows);
    `np.unique` on the rows decides if two distinct rows ever share a hash.
    """
    words = np.zeros((a.shape[0], -(-a.shape[1] // 8) * 8), np.uint8)
    words[:, : a.shape[1]] = a
    words = words.view(np.uint64)
    mult = np.random.default_rng(0).integers(1, 2**63, words.shape[1], dtype=np.uint64) | np.uint64(1)
    key = (words * mult).sum(axis=1, dtype=np.uint64)
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    if not np.array_equal(a[first][inverse], a):
        return np.unique(a, axis=0, return_inverse=True)
    return a[first], inverse.ravel()
