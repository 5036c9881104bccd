"""The layering contract, read from the source (AST; no import needed).

- Stages (io, series, spectral, fit, uncertainty, diagnose, simulate, frames, report) never
  import the orchestrators (`pipeline`, `bulk`, `cli`); `bulk` never imports `pipeline` or `cli`.
- No private name crosses a module: ``from .x import _name`` is allowed only for a package's
  own private *modules* (``from . import _jax``), never for an underscored function or class.
- Importing ``jaxdefl`` alone loads no JAX, torch or pandas (checked in a fresh interpreter).
- The status vocabulary is one enum (`jaxdefl.status.Status`): no other module spells a status.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import docstring_ids

SRC = Path(__file__).resolve().parents[1] / "src" / "jaxdefl"
STAGES = (
    "io",
    "series",
    "spectral",
    "fit",
    "uncertainty",
    "diagnose",
    "simulate",
    "frames",
    "report",
    "monitor",
    "reconcile",
)
ORCHESTRATORS = ("pipeline", "bulk", "cli")


def _module(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path):
    """(imported module, [names], line) of every import in ``path``, relative ones resolved."""
    tree = ast.parse(path.read_text())
    mod = _module(path)
    package = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, [], node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            yield target, [a.name for a in node.names], node.lineno


def _is_module(dotted: str) -> bool:
    p = SRC.parent.joinpath(*dotted.split("."))
    return p.with_suffix(".py").exists() or (p / "__init__.py").exists()


FILES = sorted(SRC.rglob("*.py"))


def _top(mod: str) -> str | None:
    parts = mod.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "jaxdefl" else None


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(SRC)))
def test_layers_point_one_way(path):
    here = _top(_module(path))
    bad = []
    for target, _, line in _imports(path):
        there = _top(target)
        if there is None or there == here:
            continue
        if here in STAGES and there in ORCHESTRATORS:
            bad.append(f"line {line}: stage {here} imports {target}")
        if here == "bulk" and there in ("pipeline", "cli"):
            bad.append(f"line {line}: bulk imports {target}")
    assert not bad, bad


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(SRC)))
def test_no_private_names_across_modules(path):
    bad = []
    for target, names, line in _imports(path):
        if not target.startswith("jaxdefl"):
            continue
        for n in names:
            if n.startswith("_") and not n.startswith("__") and not _is_module(f"{target}.{n}"):
                bad.append(f"line {line}: from {target} import {n}")
    assert not bad, bad


def test_importing_the_package_is_light():
    code = (
        "import sys, jaxdefl, jaxdefl.cli; "
        "print(','.join(m for m in ('jax', 'torch', 'pandas', 'kornia') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "", out.stdout


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(SRC)))
def test_statuses_are_named_not_spelled(path):
    from jaxdefl.status import STATUSES

    if path.name == "status.py":
        return
    tree = ast.parse(path.read_text())
    docstrings = docstring_ids(tree)
    spelled = [
        f"line {n.lineno}: {n.value!r}"
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and n.value in STATUSES and id(n) not in docstrings
    ]
    assert not spelled, spelled


def _runtime_edges() -> dict[str, set[str]]:
    """Module -> the jaxdefl modules it imports when run: every import, at the top or inside a
    function, except those under ``if TYPE_CHECKING:`` (types only, never executed)."""
    edges: dict[str, set[str]] = {}
    for path in FILES:
        tree = ast.parse(path.read_text())
        typing_only = {
            id(n)
            for node in ast.walk(tree)
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
            for stmt in node.body
            for n in ast.walk(stmt)
        }
        here = _module(path)
        out = edges.setdefault(here, set())
        for node in ast.walk(tree):
            if id(node) in typing_only or not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            package = here if path.name == "__init__.py" else here.rpartition(".")[0]
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
                targets = [stem] + [f"{stem}.{a.name}" for a in node.names]
            else:
                targets = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            out.update(t for t in targets if t.startswith("jaxdefl") and t != here and _is_module(t))
    return edges


def test_no_import_cycles():
    """No module imports itself back through others, not even through an import inside a
    function (which only hides the cycle): the strongly connected components of the import
    graph are single modules (a package's ``__init__`` counts as its own module)."""
    edges = _runtime_edges()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(v: str) -> None:  # Tarjan's algorithm
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in edges.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while (w := stack.pop()) != v:
                comp.append(w)
            if comp:
                cycles.append(sorted([v, *comp]))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    assert cycles == []


def test_import_linter_contracts_hold():
    """The layer contracts of pyproject.toml (``[tool.importlinter]``), checked by import-linter
    on the whole package: settings imports no stage, the effect vocabulary imports no stage, no
    stage imports an orchestrator, and no two sibling packages import each other."""
    import tomllib

    root = SRC.parents[1]
    n_contracts = len(
        tomllib.loads((root / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"]
    )
    code = (
        "import sys\nfrom importlinter.cli import lint_imports\n"
        "sys.exit(lint_imports(config_filename='pyproject.toml', no_cache=True, no_logo=True))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(SRC.parent)}
    done = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"{n_contracts} kept, 0 broken" in done.stdout
