"""Shape buckets: pad array sizes to a few values so that jitted kernels compile rarely."""

from __future__ import annotations

import math

__all__ = ["bucket", "chunk_rows", "pow2_at_least", "pow2_at_most"]


def bucket(n: int) -> int:
    """Smallest size >= n of the form m * 2**k with 8 <= m <= 16 (at most 12.5 % padding)."""
    n = max(int(n), 1)
    if n <= 16:
        return n
    step = 1 << (n.bit_length() - 4)
    return -(-n // step) * step


def pow2_at_least(n: int) -> int:
    return 1 << max(0, math.ceil(math.log2(max(n, 1))))


def pow2_at_most(n: int) -> int:
    """The largest power of two <= max(n, 1)."""
    return 1 << int(math.log2(max(n, 1)))


def chunk_rows(n: int, most: int) -> int:
    """Rows per call for ``n`` rows in calls of a power-of-two size of at most ``most``: the
    largest such size whose last call pads by at most an eighth of ``n`` (or 8 rows), so that
    few shapes are compiled and little padding is computed (585 rows: 5 calls of 128, not 2 of
    512)."""
    n = max(int(n), 1)
    c = min(pow2_at_least(n), pow2_at_most(most))
    while c > 1 and -(-n // c) * c - n > max(n // 8, 8):
        c //= 2
    return c
