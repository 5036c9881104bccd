"""Resource bounds: the memory a command may plan to use, and the disk space it may write.

Every flag or config key that sizes work (oversampling, duration, chunk frames, windows) is
turned into an estimate of bytes before the work starts, and refused with a message naming the
flag and the size when the estimate passes the budget (`check_memory`) or the free disk space
(`check_disk`).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from ._errors import ConfigError

__all__ = [
    "MEMORY_BUDGET_BYTES",
    "available_memory",
    "check_available_memory",
    "check_disk",
    "check_memory",
    "free_bytes",
    "size_text",
]

# What one command may plan to hold at once, besides the interpreter and its libraries.
MEMORY_BUDGET_BYTES = 4 << 30


def size_text(n: float) -> str:
    """Bytes in the largest binary unit that keeps them >= 1 (``3.2 GiB``)."""
    for unit, k in (("TiB", 40), ("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if n >= 1 << k:
            return f"{n / (1 << k):.1f} {unit}"
    return f"{int(n)} B"


def check_memory(need: float, what: str, fix: str) -> None:
    """Refuse ``need`` bytes over `MEMORY_BUDGET_BYTES`: ``what`` names the flag and the work
    (``--duration 1e+09: 2e10 frames``), ``fix`` says what to do instead."""
    if need > MEMORY_BUDGET_BYTES:
        raise ConfigError(
            f"{what} would need ~{size_text(need)} of memory; expected at most "
            f"{size_text(MEMORY_BUDGET_BYTES)} ({fix})"
        )


def free_bytes(path: Path | str) -> int:
    """Free space of the file system that holds ``path`` (or its nearest existing ancestor)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


def check_disk(need: float, out: Path | str, what: str, fix: str) -> None:
    """Refuse writing ``need`` bytes under ``out`` when its file system has less free space."""
    free = free_bytes(out)
    if need > free:
        raise ConfigError(
            f"{what} would write up to ~{size_text(need)} to {out}, which has {size_text(free)} free ({fix})"
        )


def available_memory() -> int | None:
    """Memory the system can give a new allocation without swapping (MemAvailable), or None."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def check_available_memory(need: float, what: str, fix: str) -> None:
    """Refuse work whose size is set by its input, not by a flag (``need`` bytes), when the
    system has less memory available: it would otherwise end in swapping or the OOM killer."""
    free = available_memory()
    if free is not None and need > free:
        raise ConfigError(
            f"{what} would need ~{size_text(need)} of memory; {size_text(free)} are available ({fix})"
        )
