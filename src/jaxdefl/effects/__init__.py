"""The effect vocabulary: one module per effect id, read by the simulator, the diagnosis and the
reconciliation.

Each public module ``jaxdefl.effects.<id>`` holds one `Entry` (``ENTRY``): the id, its meaning,
the sensors that can produce it, whether the structure itself can make it, its parameters with
their units, its injection at the level where its physics acts and ``from_diagnosis`` (a DIAG.json
report -> the ``[[effect]]`` table that simulates it). The modules are discovered at import into
`REGISTRY` (id -> entry, in rank order). Adding an effect = its module here (+ its detector in
``jaxdefl.diagnose.detectors``, + its test in the conformance suite's cases when it is detectable).

- `EFFECT_IDS`: the ids ``jaxdefl diagnose`` names (the DIAG.json vocabulary), in rank order;
- `INJECTABLE`: the ids the simulator injects, by level, then rank.
"""

from __future__ import annotations

import importlib
import pkgutil

from ._entry import FRAME_LEVELS, LEVELS, SENSORS, Entry, Motion, Param, Reading, Report

__all__ = [
    "EFFECT_IDS",
    "FRAME_LEVELS",
    "INJECTABLE",
    "LEVELS",
    "REGISTRY",
    "SENSORS",
    "Entry",
    "Motion",
    "Param",
    "Reading",
    "Report",
    "ids_where",
]


def _discover() -> dict[str, Entry]:
    entries = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        entry = importlib.import_module(f"{__name__}.{info.name}").ENTRY
        if entry.id != info.name:
            raise ImportError(
                f"{__name__}.{info.name}: its ENTRY's id is {entry.id!r}, not the module's name"
            )
        entries.append(entry)
    ranks = sorted(e.rank for e in entries)
    if len(set(ranks)) != len(ranks):
        raise ImportError(f"{__name__}: two effects share a rank ({ranks})")
    return {e.id: e for e in sorted(entries, key=lambda e: e.rank)}


REGISTRY: dict[str, Entry] = _discover()
EFFECT_IDS: tuple[str, ...] = tuple(e.id for e in REGISTRY.values() if e.detectable)
INJECTABLE: tuple[str, ...] = tuple(
    e.id
    for e in sorted(
        (e for e in REGISTRY.values() if e.injectable), key=lambda e: (LEVELS.index(e.level), e.rank)
    )
)


def ids_where(**facts) -> frozenset[str]:
    """The ids whose entry has every given attribute value (``ids_where(needs_reference=True)``)."""
    return frozenset(e.id for e in REGISTRY.values() if all(getattr(e, k) == v for k, v in facts.items()))
