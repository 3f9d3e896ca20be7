"""``docs/architecture.md`` is true of the code: imports go downward only, and the page names every home.

The layer of each home (a package or a top-level module of ``jko_cvx``) is read from the page's
table, the one place it is written; every module is parsed with ``ast`` (nothing is imported).
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "jko_cvx"
PAGE = ROOT / "docs" / "architecture.md"

# a table row: | 3 scene | `jko_cvx/scene/` | what it owns |
_ROW = re.compile(r"^\|\s*(\d+)\s+([^|]*?)\s*\|\s*`(jko_cvx/[^`]*)`\s*\|")
# a path or dotted module name quoted in the page
_NAMED = re.compile(r"`((?:jko_cvx|tests)(?:[./][\w.]*)*/?)`")


@dataclass(frozen=True)
class Layer:
    rank: int
    name: str

    def __str__(self) -> str:
        return f"layer {self.rank} ({self.name})"


@dataclass(frozen=True)
class Edge:
    module: str  # dotted name of the importing module
    line: int
    target: str  # dotted name of the imported module
    type_checking: bool
    attribute: str | None = None  # the name taken from the module, where it is not a submodule


def page_layers(text: str) -> dict[str, Layer]:
    """Home -> layer, from the page's table; a home is ``jko_cvx.x`` (package or module) or ``jko_cvx``."""
    homes = {}
    for line in text.splitlines():
        m = _ROW.match(line)
        if m:
            rank, name, path = int(m[1]), m[2], m[3]
            home = "jko_cvx" if path == "jko_cvx/__init__.py" else path.removesuffix("/").removesuffix(".py")
            home = home.replace("/", ".")
            assert home not in homes, f"{path} has two rows in {PAGE.name}"
            homes[home] = Layer(rank, name)
    return homes


def module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def module_path(name: str) -> Path | None:
    """The file of module ``name`` (``jko_cvx.x.y``), or None where there is none."""
    base = ROOT.joinpath(*name.split("."))
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None


def modules() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    inside = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            inside.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return inside


def imports(source: str, name: str, is_package: bool = False) -> list[Edge]:
    """Every import of a ``jko_cvx`` module in ``source`` (module ``name``), wherever it is written.

    ``from M import a`` is an import of ``M.a`` where that is a module, else of ``M``.
    """
    tree = ast.parse(source)
    package = name if is_package else name.rpartition(".")[0]
    type_checking = _type_checking_nodes(tree)
    edges = []
    for node in ast.walk(tree):
        tc = id(node) in type_checking
        if isinstance(node, ast.Import):
            edges += [Edge(name, node.lineno, a.name, tc) for a in node.names if a.name.split(".")[0] == "jko_cvx"]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                source_module = ".".join(base + ([node.module] if node.module else []))
            else:
                source_module = node.module or ""
            if source_module.split(".")[0] != "jko_cvx":
                continue
            for alias in node.names:
                sub = f"{source_module}.{alias.name}"
                is_module = alias.name != "*" and module_path(sub) is not None
                target, attribute = (sub, None) if is_module else (source_module, alias.name)
                edges.append(Edge(name, node.lineno, target, tc, attribute))
    return sorted(set(edges), key=lambda e: (e.line, e.target, e.attribute or ""))


def defines(module: str, attribute: str) -> bool:
    """Whether ``module`` binds ``attribute`` at module level (or, where the module has a ``__getattr__``,
    names it in that function or in its ``__all__``: the lazily loaded names)."""
    tree = ast.parse(module_path(module).read_text())
    bound, lazy, exported = set(), set(), set()
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            bound.add(node.name)
            if node.name == "__getattr__":
                lazy |= {c.value for c in ast.walk(node) if isinstance(c, ast.Constant) and isinstance(c.value, str)}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            bound |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names = {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
            bound |= names
            if "__all__" in names and node.value is not None:
                exported |= {c.value for c in ast.walk(node.value) if isinstance(c, ast.Constant)}
        elif isinstance(node, (ast.If, ast.Try, ast.With, ast.For, ast.While)):
            for field in ("body", "orelse", "finalbody", "handlers"):
                stack += getattr(node, field, [])
        elif isinstance(node, ast.ExceptHandler):
            stack += node.body
    if "__getattr__" in bound:
        lazy |= exported
    return "*" in bound or attribute in bound or attribute in lazy


def imports_of(path: Path) -> list[Edge]:
    return imports(path.read_text(), module_name(path), path.name == "__init__.py")


def layer_of(module: str, homes: dict[str, Layer]) -> tuple[str, Layer] | None:
    """The home of a module (the longest home that is the module or contains it) and its layer.

    The root ``jko_cvx`` is the home of ``jko_cvx/__init__.py`` only, not of the packages below it.
    """
    if module == "jko_cvx":
        return ("jko_cvx", homes["jko_cvx"]) if "jko_cvx" in homes else None
    parts = module.split(".")
    for n in range(len(parts), 1, -1):
        home = ".".join(parts[:n])
        if home in homes:
            return home, homes[home]
    return None


HOMES = page_layers(PAGE.read_text())


def test_the_page_has_a_layer_table():
    assert len(HOMES) >= 10, f"no layer table found in {PAGE}"
    assert "jko_cvx" in HOMES, "the public API (jko_cvx/__init__.py) needs a row"


def test_every_package_and_top_level_module_has_a_row():
    tops = {module_name(p) for p in PACKAGE.glob("*.py")}
    tops |= {module_name(p / "__init__.py") for p in PACKAGE.iterdir() if (p / "__init__.py").is_file()}
    missing = sorted(tops - set(HOMES))
    assert not missing, f"not in {PAGE.relative_to(ROOT)}'s layer table: {missing}"
    unhomed = [module_name(p) for p in modules() if layer_of(module_name(p), HOMES) is None]
    assert not unhomed, f"modules with no home in the layer table: {unhomed}"


def test_every_module_the_page_names_exists():
    text = PAGE.read_text()
    named = sorted(set(_NAMED.findall(text)))
    assert named, "the page names no module"
    missing = []
    for name in named:
        if "/" in name:
            exists = (ROOT / name).exists()
        else:  # a dotted module name
            exists = module_path(name) is not None
        if not exists:
            missing.append(name)
    assert not missing, f"{PAGE.relative_to(ROOT)} names what does not exist: {missing}"


@pytest.mark.parametrize("path", modules(), ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_go_downward_only(path):
    here = layer_of(module_name(path), HOMES)
    assert here is not None, f"{path.relative_to(ROOT)} has no row in {PAGE.relative_to(ROOT)}"
    rel = path.relative_to(ROOT)
    upward: dict[tuple[int, str, bool], list[str | None]] = {}
    unknown = []
    for edge in imports_of(path):
        if module_path(edge.target) is None:
            unknown.append(f"{rel}:{edge.line} imports {edge.target}, which is not a module of jko_cvx")
            continue
        if edge.attribute and not defines(edge.target, edge.attribute):
            unknown.append(f"{rel}:{edge.line} imports {edge.attribute} from {edge.target}, which neither "
                           f"defines it nor has a submodule of that name")
        there = layer_of(edge.target, HOMES)
        if there is None:
            continue  # reported by test_every_package_and_top_level_module_has_a_row
        if there[1].rank > here[1].rank:
            upward.setdefault((edge.line, edge.target, edge.type_checking), []).append(edge.attribute)
    lines = []
    for (line, target, tc), names in upward.items():
        what = target + (f" ({', '.join(n for n in names if n)})" if any(names) else "")
        there = layer_of(target, HOMES)
        note = " under TYPE_CHECKING" if tc else ""
        lines.append(f"{rel}:{line} imports {what}{note}: {here[0]} is {here[1]}, {there[0]} is {there[1]}")
    assert not lines + unknown, "\n".join(lines + unknown)


def test_the_checker_sees_every_kind_of_import():
    """The parser on planted source: module level, in a function, under TYPE_CHECKING, from a package."""
    src = (
        "from typing import TYPE_CHECKING\n"
        "import jko_cvx.grid\n"
        "from jko_cvx import collision, __version__\n"
        "if TYPE_CHECKING:\n"
        "    from jko_cvx.scene.model import Scene\n"
        "def f():\n"
        "    from jko_cvx.engine.loop import simulate\n"
        "    from . import moments\n"
    )
    edges = imports(src, "jko_cvx.mesh.moments")
    assert [(e.line, e.target, e.type_checking) for e in edges] == [
        (2, "jko_cvx.grid", False),
        (3, "jko_cvx", False),
        (3, "jko_cvx.collision", False),
        (5, "jko_cvx.scene.model", True),
        (7, "jko_cvx.engine.loop", False),
        (8, "jko_cvx.mesh.moments", False),
    ]
    assert defines("jko_cvx", "__version__") and defines("jko_cvx", "load_run")
    assert not defines("jko_cvx", "no_such_name")
    assert layer_of("jko_cvx.scene.model", HOMES)[0] == "jko_cvx.scene"
    assert layer_of("jko_cvx", HOMES)[0] == "jko_cvx"
    assert layer_of("jko_cvx.studies.reproduce.paper", HOMES)[0] == "jko_cvx.studies"
