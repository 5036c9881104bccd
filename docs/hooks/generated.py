"""mkdocs hook: the reference pages generated from the code at build time.

A page asks for a generated block with an HTML comment on a line of its own:

- ``<!-- generated: cli -->``: every command of ``jaxdefl`` with its usage, help and options,
  walked from the click command tree that typer builds (`jaxdefl.cli.app`);
- ``<!-- generated: effects -->``: the effect vocabulary from its registry
  (`jaxdefl.effects.REGISTRY`: one module per id);
- ``<!-- generated: schema NAME -->``: the fields of ``src/jaxdefl/schemas/NAME.schema.json``
  as a table, and the schema itself.

Nothing is copied by hand, so the pages cannot drift from the code. The hook imports the
package from this checkout's ``src/`` (not whichever jaxdefl is installed).
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCHEMAS = ROOT / "src" / "jaxdefl" / "schemas"
_MARKER = re.compile(r"^<!-- generated: (\w+)(?: ([\w.-]+))? -->$", re.MULTILINE)


def on_config(config, **kwargs):
    src = str(ROOT / "src")
    if src not in sys.path:
        sys.path.insert(0, src)
    return config


def on_page_markdown(markdown, page, config, files, **kwargs):
    def render(m: re.Match) -> str:
        kind, arg = m.group(1), m.group(2)
        if kind == "cli":
            return cli_reference()
        if kind == "effects":
            return effect_reference()
        if kind == "schema" and arg:
            return schema_reference(arg)
        raise ValueError(f"{page.file.src_path}: unknown generated block {m.group(0)!r}")

    return _MARKER.sub(render, markdown)


# ---------------------------------------------------------------------------------------------
# the command line


def _cell(text) -> str:
    """Text fit for one markdown table cell."""
    return " ".join(str(text).split()).replace("|", "\\|")


def _is_argument(p) -> bool:
    return getattr(p, "param_type_name", "") == "argument"


def _param_names(p) -> str:
    if _is_argument(p):
        return f"`{p.name.upper()}`"
    return " / ".join(f"`{n}`" for n in [*p.opts, *p.secondary_opts])


_TYPE_WORDS = {"str": "text", "int": "integer", "float": "number", "Path": "path", "bool": "flag"}


def _param_type(p) -> str:
    """The value a parameter takes (typer's own command classes, or click's)."""
    if getattr(p, "is_flag", False):
        return "flag"
    t = getattr(p, "type", None)
    choices = getattr(t, "choices", None)
    if choices:
        return " \\| ".join(f"`{c}`" for c in choices)
    if t is not None and getattr(t, "name", None):
        return t.name.lower()
    ann = getattr(getattr(p, "type_descriptor", None), "annotation", None)
    name = getattr(ann, "__name__", str(ann))
    return _TYPE_WORDS.get(name, name)


def _param_default(p) -> str:
    d = p.default
    if d is None or callable(d) or getattr(p, "required", False):
        return ""
    if getattr(p, "is_flag", False) and p.secondary_opts:
        return f"`{p.opts[0] if d else p.secondary_opts[0]}`"
    if isinstance(d, bool):
        return "on" if d else "off"
    return f"`{d}`"


def cli_reference() -> str:
    import typer

    from jaxdefl.cli import app

    root = typer.main.get_command(app)
    out = [
        "Generated from the command tree of `jaxdefl.cli` at build time; "
        "`jaxdefl COMMAND --help` prints the same.",
        "",
        "## `jaxdefl`",
        "",
        _cell(root.help or ""),
        "",
        "| option | help |",
        "| --- | --- |",
    ]
    for p in root.params:
        out.append(f"| {_param_names(p)} | {_cell(getattr(p, 'help', '') or '')} |")
    commands = getattr(root, "commands", {})
    out += ["", "Commands: " + ", ".join(f"[`{n}`](#{n})" for n in commands), ""]
    for name, cmd in commands.items():
        args = [
            p.name.upper() if p.required else f"[{p.name.upper()}]" for p in cmd.params if _is_argument(p)
        ]
        usage = " ".join(["jaxdefl", name, "[OPTIONS]", *args])
        out += [f"## `{name}` {{ #{name} }}", "", "```text", usage, "```", ""]
        if cmd.help:
            out += [cmd.help.strip(), ""]
        rows = [p for p in cmd.params if not getattr(p, "hidden", False) and p.name != "help"]
        if rows:
            out += ["| argument / option | type | default | help |", "| --- | --- | --- | --- |"]
            for p in rows:
                req = " (required)" if getattr(p, "required", False) else ""
                out.append(
                    f"| {_param_names(p)}{req} | {_param_type(p)} | {_param_default(p)} "
                    f"| {_cell(getattr(p, 'help', '') or '')} |"
                )
            out.append("")
    return "\n".join(out)


# ---------------------------------------------------------------------------------------------
# the effect vocabulary


def _param_text(p) -> str:
    s = f"`{p.name}` ({p.unit}"
    if p.choices:
        s += "; " + ", ".join(f"`{c}`" for c in p.choices)
    if p.default is not None:
        s += f"; default {p.default}"
    return s + ")"


def effect_reference() -> str:
    from jaxdefl.effects import EFFECT_IDS, INJECTABLE, LEVELS, REGISTRY, SENSORS

    out = [
        f"Generated from the effect vocabulary `jaxdefl.effects.REGISTRY` ({len(REGISTRY)} ids, one "
        f"module each: {len(INJECTABLE)} the simulator injects, {len(EFFECT_IDS)} the diagnosis "
        "names) at build time.",
        "",
        "## Simulated effects",
        "",
        "An `[[effect]]` table of a simulation config is `id` and these parameters; a parameter "
        "with a default may be left out. Levels: " + ", ".join(f"`{lv}`" for lv in LEVELS) + ".",
        "",
        "| id | level | parameters (unit; default) | meaning | diagnosed |",
        "| --- | --- | --- | --- | --- |",
    ]
    for eid in INJECTABLE:
        entry = REGISTRY[eid]
        params = "<br>".join(_param_text(p) for p in entry.params)
        told = "no" if not entry.detectable else ("yes, against an LDS" if entry.needs_reference else "yes")
        out.append(f"| `{eid}` {{ #{eid} }} | {entry.level} | {params} | {_cell(entry.meaning)} | {told} |")
    out += [
        "",
        "## Diagnosed effects",
        "",
        "Every id `jaxdefl diagnose` can name (the `id` of an entry of `effects` in DIAG.json): the "
        "sensors that can produce it (on a record of another kind the diagnosis does not name it), "
        "whether the structure itself can make it (else only a measurement does), and whether "
        "`jaxdefl reconcile` can simulate it as reported. Ids the simulator does not inject are marked. "
        "Ids sharing a footprint are rivals: each rival of a named effect is fitted to the same "
        "residual, and DIAG.json's `rivals` and `not_told_from` say how far apart they are (see the "
        "diagnose guide).",
        "",
        "| id | meaning | sensors | structural | needs an LDS | simulated | footprint |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for eid in EFFECT_IDS:
        entry = REGISTRY[eid]
        sim = f"[yes](#{eid})" if entry.injectable else "**no**"
        sensors = "any" if set(entry.sensors) == set(SENSORS) else ", ".join(entry.sensors)
        out.append(
            f"| `{eid}` | {_cell(entry.meaning)} | {sensors} "
            f"| {'yes' if entry.structural else 'no'} | {'yes' if entry.needs_reference else 'no'} | {sim} "
            f"| {'; '.join(entry.footprint)} |"
        )
    only = [eid for eid in EFFECT_IDS if not REGISTRY[eid].injectable]
    if only:
        out += ["", "Diagnosed only: " + ", ".join(f"`{e}`" for e in only) + "."]
    return "\n".join(out)


# ---------------------------------------------------------------------------------------------
# the JSON Schemas


def _type_of(node: dict) -> str:
    t = node.get("type")
    if "enum" in node:
        return " \\| ".join(f"`{json.dumps(v)}`" for v in node["enum"])
    if isinstance(t, list):
        return " or ".join(t)
    if "anyOf" in node or "oneOf" in node:
        return " or ".join(_type_of(n) for n in node.get("anyOf", node.get("oneOf")))
    if "$ref" in node:
        return node["$ref"].rsplit("/", 1)[-1]
    return t or "any"


def _rows(node: dict, path: str, required: bool, defs: dict, depth: int = 0):
    if "$ref" in node and node["$ref"].startswith("#/$defs/"):
        node = {**defs[node["$ref"].rsplit("/", 1)[-1]], **{k: v for k, v in node.items() if k != "$ref"}}
    yield path, _type_of(node), required, node.get("description", "")
    if depth > 3:
        return
    props = node.get("properties", {})
    req = set(node.get("required", []))
    for name, sub in props.items():
        yield from _rows(sub, f"{path}.{name}" if path else name, name in req, defs, depth + 1)
    for pattern, sub in node.get("patternProperties", {}).items():
        yield from _rows(sub, f"{path}.<{pattern}>" if path else f"<{pattern}>", False, defs, depth + 1)
    items = node.get("items")
    if isinstance(items, dict) and (items.get("properties") or items.get("$ref")):
        yield from _rows(items, f"{path}[]", True, defs, depth + 1)


def schema_reference(name: str) -> str:
    path = SCHEMAS / f"{name}.schema.json"
    schema = json.loads(path.read_text())
    defs = schema.get("$defs", {})
    out = [
        _cell(schema.get("description", "")),
        "",
        "| field | type | required | meaning |",
        "| --- | --- | --- | --- |",
    ]
    for field, typ, req, desc in _rows(schema, "", True, defs):
        if not field:
            continue
        out.append(f"| `{field}` | {typ} | {'yes' if req else ''} | {_cell(desc)} |")
    body = json.dumps(schema, indent=2, ensure_ascii=False)
    out += [
        "",
        f'??? note "The schema: `src/jaxdefl/schemas/{path.name}`"',
        "",
        "    ```json",
        *("    " + line for line in body.splitlines()),
        "    ```",
        "",
    ]
    return "\n".join(out)
