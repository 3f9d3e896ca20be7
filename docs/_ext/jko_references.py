"""References generated from the code at build time, so that they cannot drift from it.

* ``.. scene-reference::`` -- every scene TOML key, read from the table dataclasses of
  :mod:`jko_cvx.scene.schema` and :mod:`jko_cvx.scene.initial` (each field's :class:`Rule`: type,
  allowed values, default) and the ``collision.options`` allow-lists of :mod:`jko_cvx.scene.options`;
* ``.. cli-reference::`` -- every subcommand and option of :func:`jko_cvx.cli.build_parser`;
* ``.. status-table::`` -- every member of :class:`jko_cvx.collision.result.Status` and its message;
* ``docs/reference/api.rst`` -- written before autosummary runs, one entry per name of
  ``jko_cvx.__all__``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path
from typing import Any

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import nested_parse_with_titles

# ---- the scene TOML keys --------------------------------------------------------------------------


def scene_tables() -> list[tuple[str, type, str]]:
    """(dotted table path, dataclass, heading) of every table a scene may hold, in document order."""
    from jko_cvx.scene.initial import INITIAL_KINDS
    from jko_cvx.scene.schema import (
        CollisionTable,
        OutputTable,
        RefineAxisTable,
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
        ("refine.v", RefineAxisTable, "[refine.v] and [refine.x]"),
        ("collision", CollisionTable, "[collision]"),
        ("stop", StopTable, "[stop]"),
        ("output", OutputTable, "[output]"),
    ]
    return tables


def scene_keys() -> list[str]:
    """Every dotted scene key the reference documents (the options of ``collision.options`` aside)."""
    keys: list[str] = []
    for where, cls, _ in scene_tables():
        axes = ("refine.v", "refine.x") if where == "refine.v" else (where,)
        names = [f.name for f in dataclasses.fields(cls)]
        keys += [f"{a}.{n}" if a else n for a in axes for n in names]
    keys += ["initial.kind", "refine.concentration_set"]
    return list(dict.fromkeys(keys))


def _default(f: dataclasses.Field) -> str:
    if f.default is dataclasses.MISSING:
        return "**required**"
    val = f.default
    if val is None:
        return "absent"
    if isinstance(val, bool):
        return f"``{str(val).lower()}``"
    if isinstance(val, float) and math.isinf(val):
        return "``inf``"
    if isinstance(val, str):
        return f'``"{val}"``'
    if isinstance(val, tuple):
        return f"``{list(val)}``"
    return f"``{val}``"


def _type(rule: Any) -> str:
    return {"floats": "list of floats", "table": "table"}.get(rule.kind, rule.kind)


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", r"\|")


def _list_table(header: list[str], rows: list[list[str]], widths: str) -> list[str]:
    out = [".. list-table::", "   :header-rows: 1", f"   :widths: {widths}", ""]
    for row in [header, *rows]:
        out.append(f"   * - {_cell(row[0])}")
        out += [f"     - {_cell(c)}" for c in row[1:]]
    return [*out, ""]


def _heading(text: str, char: str) -> list[str]:
    return [text, char * len(text), ""]


def scene_reference_rst() -> list[str]:
    """The reST of the scene key reference."""
    from jko_cvx.mesh.policy import CONCENTRATION_SETS
    from jko_cvx.scene.initial import INITIAL_KINDS
    from jko_cvx.scene.options import METHOD_OPTIONS, SOLVER_OPTIONS
    from jko_cvx.scene.schema import RefineTable

    lines: list[str] = []
    for where, cls, title in scene_tables():
        lines += _heading(title, "-")
        lines += [_cell((cls.__doc__ or "").strip().split("\n\n")[0]), ""]
        rows = []
        if where == "initial":
            rows.append(
                ["``initial.kind``", "str", f'``"{cls.kind}"`` (one of {sorted(INITIAL_KINDS)})', "**required**"]
            )
        for f in dataclasses.fields(cls):
            rule = f.metadata["rule"]
            dotted = f"{where}.{f.name}" if where else f.name
            if where == "refine.v":  # one table for both axes
                rows.append(
                    [f"``refine.v.{f.name}``, ``refine.x.{f.name}``", _type(rule), rule.describe(), _default(f)]
                )
                continue
            rows.append([f"``{dotted}``", _type(rule), rule.describe(), _default(f)])
        if where == "refine.v":
            default = dataclasses.fields(RefineTable)[2].default
            rows.append(
                ["``refine.concentration_set``", "str", f"one of {sorted(CONCENTRATION_SETS)}", f'``"{default}"``']
            )
        lines += _list_table(["key", "type", "allowed values", "default"], rows, "30 12 40 18")
    lines += _heading("collision.options", "-")
    lines += ["The options a scene may pass to each collision method (``collision.method``).", ""]
    for method, rules in METHOD_OPTIONS.items():
        rows = [[f"``collision.options.{name}``", _type(r), r.describe()] for name, r in rules.items()]
        lines += _heading(f'method = "{method}"', "~")
        lines += _list_table(["key", "type", "allowed values"], rows, "40 15 45") if rows else ["(none)", ""]
    lines += _heading("collision.options.solver_options", "-")
    lines += [
        'Per solver (``collision.options.solver`` for method ``"conic"``, default CLARABEL; IPOPT for '
        'method ``"nlp"``): the keys a scene may pass through to it.',
        "",
    ]
    for solver, rules in SOLVER_OPTIONS.items():
        rows = [[f"``collision.options.solver_options.{name}``", _type(r), r.describe()] for name, r in rules.items()]
        lines += _heading(solver, "~")
        lines += _list_table(["key", "type", "allowed values"], rows, "45 15 40")
    return lines


# ---- the CLI ---------------------------------------------------------------------------------------


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _help_of(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Subcommand name -> its one-line help."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return {a.dest: a.help or "" for a in action._choices_actions}
    return {}


def cli_reference_rst() -> list[str]:
    """The reST of the CLI reference: the usage and help of ``jko-cvx`` and of every subcommand."""
    from jko_cvx.cli import build_parser

    parser = build_parser()
    lines = [".. code-block:: text", "", *("   " + ln for ln in parser.format_help().splitlines()), ""]
    helps = _help_of(parser)
    for name, sub in _subparsers(parser).items():
        lines += _heading(f"jko-cvx {name}", "-")
        lines += [helps.get(name, ""), "", ".. code-block:: text", ""]
        lines += ["   " + ln for ln in sub.format_help().splitlines()]
        lines.append("")
    return lines


# ---- the statuses ----------------------------------------------------------------------------------


def status_table_rst() -> list[str]:
    from jko_cvx.collision.result import Status

    rows = [[f"``{s.name}``", "yes" if s.success else "no", s.value] for s in Status]
    return _list_table(["status", "success", "meaning"], rows, "20 10 70")


# ---- the directives --------------------------------------------------------------------------------


class _Generated(SphinxDirective):
    has_content = False
    generate = staticmethod(lambda: [])

    def run(self) -> list[nodes.Node]:
        node = nodes.section()
        node.document = self.state.document
        nested_parse_with_titles(self.state, StringList(self.generate(), source="<generated>"), node)
        return node.children


class SceneReference(_Generated):
    generate = staticmethod(scene_reference_rst)


class CliReference(_Generated):
    generate = staticmethod(cli_reference_rst)


class StatusTable(_Generated):
    generate = staticmethod(status_table_rst)


# ---- the API page ----------------------------------------------------------------------------------


def write_api_page(app: Sphinx, config: Any) -> None:
    """``reference/api.rst``: an autosummary of every name of ``jko_cvx.__all__`` (before the sources are read)."""
    import jko_cvx

    names = [n for n in jko_cvx.__all__ if not n.startswith("__")]
    text = [
        "API reference",
        "=============",
        "",
        "Every public name of ``jko_cvx`` (``jko_cvx.__all__``); this page is generated at build time.",
        "",
        ".. currentmodule:: jko_cvx",
        "",
        ".. autosummary::",
        "   :toctree: generated",
        "",
        *(f"   {n}" for n in names),
        "",
    ]
    page = Path(app.srcdir) / "reference" / "api.rst"
    new = "\n".join(text)
    if not page.exists() or page.read_text() != new:  # unchanged: keep the mtime, no rebuild
        page.write_text(new)


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_directive("scene-reference", SceneReference)
    app.add_directive("cli-reference", CliReference)
    app.add_directive("status-table", StatusTable)
    app.connect("config-inited", write_api_page)  # before the source files are found and autosummary runs
    return {"parallel_read_safe": True, "parallel_write_safe": True}
