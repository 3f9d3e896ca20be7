"""The scene key reference and the scene template, generated from the schema so that they cannot drift.

Every key a scene may hold is a field of a table dataclass of :mod:`jko_cvx.scene.schema` (or of an
``initial.kind`` of :mod:`jko_cvx.scene.initial`) declared with :func:`~jko_cvx.scene.schema.key`:
its :class:`~jko_cvx.scene.schema.Rule` (type, range, enumeration), its default and its one-line
meaning.  This module reads them, and only them:

* :func:`key_entries` -- one :class:`KeyEntry` per dotted key (key, type, allowed values, default,
  meaning); :func:`option_entries` the ``collision.options`` allow-lists of :mod:`jko_cvx.scene.options`;
* :func:`keys_text` -- the plain-text reference ``jko-cvx scene keys`` prints;
* :func:`scene_template` -- the commented TOML template ``jko-cvx scene template`` prints: every key
  with its meaning, type, allowed values and default as comments, set to the value of an example
  scene (the built-in default scene, or a shipped inhomogeneous one) or commented out where the
  example leaves it absent; ``load_scene`` accepts it as written;
* :func:`scene_reference_rst` -- the documentation's scene TOML reference (``docs/_ext``).
"""

from __future__ import annotations

import dataclasses
import math
import re
import textwrap
from dataclasses import dataclass
from typing import Any

__all__ = [
    "KeyEntry",
    "key_entries",
    "keys_text",
    "option_entries",
    "rst_heading",
    "rst_list_table",
    "scene_keys",
    "scene_reference_rst",
    "scene_tables",
    "scene_template",
    "toml_value",
]

TEMPLATE_KINDS = {"homogeneous": "the built-in default scene", "inhomogeneous": "the shipped inhom_gamma3_lambda4"}
"""The template's kinds and the example scene whose values each sets."""


def scene_tables() -> list[tuple[str, type, str]]:
    """(dotted table path, dataclass, heading) of every table a scene may hold, in document order."""
    from jko_cvx.scene.initial import INITIAL_KINDS
    from jko_cvx.scene.schema import (
        CollisionTable,
        OutputTable,
        RefineAxisTable,
        RefineTable,
        SceneTable,
        StopTable,
        TimeTable,
        VTable,
        XTable,
    )

    tables: list[tuple[str, type, str]] = [("", SceneTable, "Top level"), ("v", VTable, "[v]"), ("x", XTable, "[x]")]
    for kind, cls in INITIAL_KINDS.items():
        tables.append(("initial", cls, f'[initial] with kind = "{kind}"'))
    tables += [
        ("time", TimeTable, "[time]"),
        ("refine", RefineTable, "[refine]"),
        ("refine.v", RefineAxisTable, "[refine.v]"),
        ("refine.x", RefineAxisTable, "[refine.x]"),
        ("collision", CollisionTable, "[collision]"),
        ("stop", StopTable, "[stop]"),
        ("output", OutputTable, "[output]"),
    ]
    return tables


def _keyed(cls: type) -> list[dataclasses.Field]:
    """The fields of a table that are scene keys (they carry a Rule; RefineTable's v and x are sub-tables)."""
    return [f for f in dataclasses.fields(cls) if "rule" in f.metadata]


@dataclass(frozen=True)
class KeyEntry:
    """One scene key: dotted name, type, allowed values, default (a TOML literal, ``required`` or
    ``absent``), one-line meaning, and the heading of its table."""

    key: str
    type: str
    allowed: str
    default: str
    meaning: str
    table: str


def toml_value(val: Any) -> str:
    """``val`` as a TOML literal (``true``, ``inf``, ``"newton"``, ``[1.0, 2.0]``, ``{}``)."""
    if isinstance(val, bool):
        return str(val).lower()
    if isinstance(val, float):
        return ("inf" if val > 0 else "-inf") if math.isinf(val) else repr(val)
    if isinstance(val, int):
        return str(val)
    if isinstance(val, str):
        return '"' + val.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(val, list | tuple):
        return "[" + ", ".join(toml_value(v) for v in val) + "]"
    if isinstance(val, dict):
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in val.items()) + "}"
    raise TypeError(f"no TOML literal for {val!r}")


def _default(f: dataclasses.Field) -> str:
    if f.default is dataclasses.MISSING:
        return "required"
    return "absent" if f.default is None else toml_value(f.default)


def _type(rule: Any) -> str:
    return {"floats": "list of floats"}.get(rule.kind, rule.kind)


def _summary(cls: type) -> str:
    """The first line of an initial kind's docstring, after its ``initial.kind = ...`` label."""
    first = (cls.__doc__ or "").strip().split("\n")[0]
    return re.split(r"``\)?: ", first, maxsplit=1)[-1].rstrip(".")


def _kind_entry() -> KeyEntry:
    from jko_cvx.scene.initial import INITIAL_KINDS

    what = "; ".join(f"{k}: {_summary(c)}" for k, c in INITIAL_KINDS.items())
    return KeyEntry("initial.kind", "str", f"one of {sorted(INITIAL_KINDS)}", "required",
                    f"the initial datum's kind ({what})", "[initial]")  # fmt: skip


def key_entries() -> list[KeyEntry]:
    """Every scene key, in document order (``initial.kind`` before the keys of each kind)."""
    out: list[KeyEntry] = []
    for where, cls, title in scene_tables():
        if where == "initial" and not any(e.key == "initial.kind" for e in out):
            out.append(_kind_entry())
        for f in _keyed(cls):  # a key two initial kinds share (a, b) has one entry per kind, under its heading
            rule = f.metadata["rule"]
            dotted = f"{where}.{f.name}" if where else f.name
            out.append(KeyEntry(dotted, _type(rule), rule.describe(), _default(f), f.metadata.get("doc", ""), title))
    return out


def scene_keys() -> list[str]:
    """Every dotted scene key the reference documents (the options of ``collision.options`` aside)."""
    return list(dict.fromkeys(e.key for e in key_entries()))


def option_entries() -> list[tuple[str, str, str, str]]:
    """``(dotted key, method or solver, type, allowed values)`` of every ``collision.options`` key."""
    from jko_cvx.scene.options import METHOD_OPTIONS, SOLVER_OPTIONS

    out = [(f"collision.options.{n}", f"method {m}", _type(r), r.describe()) for m, rules in METHOD_OPTIONS.items()
           for n, r in rules.items()]  # fmt: skip
    out += [(f"collision.options.solver_options.{n}", f"solver {s}", _type(r), r.describe())
            for s, rules in SOLVER_OPTIONS.items() for n, r in rules.items()]  # fmt: skip
    return out


# ---- jko-cvx scene keys ------------------------------------------------------------------------------


def keys_text() -> str:
    """The plain-text key reference: one line per key (key, type, default, allowed values), its meaning
    indented below; then the ``collision.options`` allow-lists."""
    entries = key_entries()
    w = max(len(e.key) for e in entries) + 2
    lines = [f"{'key':<{w}}{'type':<16}{'default':<16}allowed values", "-" * 100]
    for e in entries:
        lines.append(f"{e.key:<{w}}{e.type:<16}{e.default:<16}{e.allowed}")
        kind = e.table.split(" with ", 1)[1] if " with " in e.table else ""
        lines.append(f"    {e.meaning}{f' ({kind})' if kind else ''}")
    opts = option_entries()
    w = max(len(o[0]) for o in opts) + 2
    lines += ["", "-- collision.options: what a scene may pass to each method (default: the method's own)", ""]
    lines += [f"{k:<{w}}{who:<18}{t:<8}{allowed}" for k, who, t, allowed in opts]
    return "\n".join(lines) + "\n"


# ---- jko-cvx scene template --------------------------------------------------------------------------


def _example(kind: str) -> dict[str, Any]:
    """The example's document as written (not the loaded scene's: a default the loader resolves, such as
    ``refine.v.centre = "auto"`` or the method's momentum constraint, must stay absent so that it is
    resolved again for the datum and method the user writes)."""
    from jko_cvx.scene.model import default_document, shipped_document

    if kind not in TEMPLATE_KINDS:
        raise ValueError(f"kind must be one of {sorted(TEMPLATE_KINDS)}, got {kind!r}")
    return default_document() if kind == "homogeneous" else shipped_document("inhom_gamma3_lambda4")


def _comment(text: str, width: int = 100) -> list[str]:
    return textwrap.wrap(text, width, initial_indent="# ", subsequent_indent="# ")


def _placeholder(entry: KeyEntry) -> str:
    """A value for a key the example leaves absent (its line is commented out)."""
    return {"bool": "true", "table": "{}"}.get(entry.type, entry.default)


def _key_lines(entry: KeyEntry, doc: dict[str, Any] | None, off: bool) -> list[str]:
    """One key: its meaning and rule as comments, then ``name = value`` (commented out when ``off``)."""
    name = entry.key.rsplit(".", 1)[-1]
    has = doc is not None and doc.get(name) is not None
    value = toml_value(doc[name]) if has else _placeholder(entry)
    lines = [*_comment(entry.meaning), f"# type: {entry.type}; allowed: {entry.allowed}; default: {entry.default}"]
    return [*lines, f"{'# ' if off or not has else ''}{name} = {value}"]


def scene_template(kind: str = "homogeneous") -> str:
    """The commented TOML template of a ``kind`` scene (see the module docstring)."""
    # a name and description of its own: a copy run as written must not take the example's run directory
    # (runs/<name>) nor head its output with the example's description
    example = {**_example(kind), "name": f"my_{kind}_scene",
               "description": f"my scene, from the {kind} template (values of {TEMPLATE_KINDS[kind]})"}  # fmt: skip
    inhom = _example("inhomogeneous")  # values for the tables a homogeneous scene leaves out
    entries = key_entries()
    by_table: dict[str, list[KeyEntry]] = {}
    for e in entries:
        by_table.setdefault(e.key.rsplit(".", 1)[0] if "." in e.key else "", []).append(e)
    top = {e.key: e for e in by_table[""]}
    out = [
        f"# jko-cvx scene template ({kind}), generated from the scene schema (jko_cvx.scene.schema): every key",
        "# with its meaning, type, allowed values and default.  Values: those of "
        f"{TEMPLATE_KINDS[kind]}; a key",
        "# commented out is absent (its default applies).  `jko-cvx scene keys` prints the same reference;",
        "# `jko-cvx run FILE` runs this file as written.",
        "",
    ]
    for e in by_table[""]:
        if e.type != "table":
            out += [*_key_lines(e, example, False), ""]
    initial_kind = example["initial"]["kind"]
    for table in dict.fromkeys(t for t in by_table if t):
        node: Any = example
        for part in table.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        off = node is None
        if off:  # the example has no such table: show it commented out, with the values of the other example
            node = inhom
            for part in table.split("."):
                node = node.get(part) if isinstance(node, dict) else None
        parent = top.get(table) or next((e for e in entries if e.key == table), None)
        head = parent.meaning if parent is not None else f"mesh refinement of the {table[-1]}-grid (absent: fixed)"
        out += [*_comment(head + ("; absent from this scene (uncomment to set)" if off else "")),
                f"{'# ' if off else ''}[{table}]"]  # fmt: skip
        for e in by_table[table]:
            if table == "initial" and e.key != "initial.kind" and not e.table.endswith(f'"{initial_kind}"'):
                continue  # another kind's key
            out += _key_lines(e, node, off)
        if table == "initial":
            out.append("# the keys of the other kinds: jko-cvx scene keys")
        out.append("")
    return "\n".join(out)



# ---- the documentation's reference (reST) ------------------------------------------------------------


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", r"\|")


def rst_list_table(header: list[str], rows: list[list[str]], widths: str) -> list[str]:
    """A reST ``list-table`` (one header row) as lines."""
    out = [".. list-table::", "   :header-rows: 1", f"   :widths: {widths}", ""]
    for row in [header, *rows]:
        out.append(f"   * - {_cell(row[0])}")
        out += [f"     - {_cell(c)}" for c in row[1:]]
    return [*out, ""]


def rst_heading(text: str, char: str) -> list[str]:
    """A reST section heading as lines."""
    return [text, char * len(text), ""]


def _rst_default(default: str) -> str:
    return {"required": "**required**", "absent": "absent"}.get(default, f"``{default}``")


def scene_reference_rst() -> list[str]:
    """The reST of the scene key reference: one table per scene table, then the ``collision.options``."""
    from jko_cvx.scene.options import METHOD_OPTIONS, SOLVER_OPTIONS

    entries = key_entries()
    lines: list[str] = []
    for where, cls, title in scene_tables():
        lines += rst_heading(title, "-")
        lines += [_cell((cls.__doc__ or "").strip().split("\n\n")[0]), ""]
        rows = [[f"``{e.key}``", e.type, e.allowed, _rst_default(e.default), e.meaning] for e in entries
                if e.table == title or (e.key == "initial.kind" and where == "initial")]  # fmt: skip
        lines += rst_list_table(["key", "type", "allowed values", "default", "meaning"], rows, "20 8 24 10 38")
    lines += rst_heading("collision.options", "-")
    lines += ["The options a scene may pass to each collision method (``collision.method``).", ""]
    for method, rules in METHOD_OPTIONS.items():
        rows = [[f"``collision.options.{name}``", _type(r), r.describe()] for name, r in rules.items()]
        lines += rst_heading(f'method = "{method}"', "~")
        lines += rst_list_table(["key", "type", "allowed values"], rows, "40 15 45") if rows else ["(none)", ""]
    lines += rst_heading("collision.options.solver_options", "-")
    lines += [
        'Per solver (``collision.options.solver`` for method ``"conic"``, default CLARABEL; IPOPT for '
        'method ``"nlp"``): the keys a scene may pass through to it.',
        "",
    ]
    for solver, rules in SOLVER_OPTIONS.items():
        rows = [[f"``collision.options.solver_options.{name}``", _type(r), r.describe()] for name, r in rules.items()]
        lines += rst_heading(solver, "~")
        lines += rst_list_table(["key", "type", "allowed values"], rows, "45 15 40")
    return lines
