"""The configs shipped with the package (package data, found with `importlib.resources`).

``configs/`` at the top of a checkout links to the same files, so ``configs/exp1.toml`` works
there, and an installed package finds them by name: ``jaxdefl simulate exp1``.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["config_dir", "not_found_hint", "resolve_config", "shipped_names"]


def config_dir() -> Path:
    """The directory that holds the shipped configs (inside the installed package)."""
    return Path(str(resources.files("jaxdefl") / "configs"))


def shipped_names() -> list[str]:
    """Stems of the shipped configs, sorted (``exp1``, ``exp2_tof_3hz``, ...)."""
    return sorted(p.stem for p in config_dir().glob("*.toml"))


def resolve_config(path: Path | str, relative_to: Path | str | None = None) -> Path:
    """``path`` if it exists; otherwise a bare name (``exp1`` or ``exp1.toml``) of a shipped config.

    With ``relative_to`` (a directory: a campaign file's), a relative ``path`` is taken from
    there instead of the working directory, and wins over a shipped config of the same name.
    A path that exists nowhere is returned unchanged (from ``relative_to``), for the caller's
    "file not found" error (which `not_found_hint` completes)."""
    path = Path(path)
    near = Path(relative_to) / path if relative_to is not None else path
    if near.exists() or path.parent != Path("."):
        return near
    stem = path.name[: -len(".toml")] if path.name.endswith(".toml") else path.name
    shipped = config_dir() / f"{stem}.toml"
    return shipped if shipped.is_file() else near


def not_found_hint() -> str:
    """The tail of a "file not found" message: the shipped configs a user can name instead."""
    names = shipped_names()
    return f" (or the name of a shipped config: {', '.join(names)})" if names else ""
