"""The documentation builds with warnings as errors, and its generated references are complete.

One clean build (a copy of ``docs/`` in a temporary directory, so the checkout's generated stubs
play no part) serves every check: the API page names every ``jko_cvx.__all__`` entry, the scene
reference every key the parser knows, the CLI page every subcommand and option, the statuses page
every :class:`Status`.  The list of scene keys is itself checked against the parser: each key, set
to a value of the wrong type, must be refused by name (not as an unknown key), and every table
dataclass of the schema must be in it.
"""

from __future__ import annotations

import copy
import dataclasses
import html
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("sphinx")
pytest.importorskip("myst_nb")
pytest.importorskip("furo")

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS / "_ext"))
import jko_references as references  # noqa: E402  (docs/_ext/jko_references.py: the generators)

import jko_cvx  # noqa: E402
from jko_cvx.scene import schema  # noqa: E402
from jko_cvx.scene.initial import INITIAL_KINDS  # noqa: E402
from jko_cvx.scene.model import scene_from_dict  # noqa: E402

SPHINX = (sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html")


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    """The HTML output of a clean ``sphinx -W --keep-going`` build of a copy of ``docs/``.

    The tutorials are not executed here (``tests/docs/test_tutorials.py`` runs their cells);
    ``.ci/run`` builds once more with them executed."""
    tmp = tmp_path_factory.mktemp("docs")
    src = tmp / "docs"
    shutil.copytree(
        DOCS, src, ignore=shutil.ignore_patterns("_build", "generated", "api.rst", "__pycache__", ".doctrees")
    )
    out = tmp / "html"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run(
        [*SPHINX, "-D", "nb_execution_mode=off", str(src), str(out)],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 0, f"sphinx failed:\n{proc.stdout}\n{proc.stderr}"
    assert "WARNING" not in proc.stderr and "ERROR" not in proc.stderr, proc.stderr
    return out


def _literals(page: Path) -> set[str]:
    """The inline literals of a built page (``v.L`` renders as <span class="pre">v.L</span>)."""
    return {html.unescape(m) for m in re.findall(r'<span class="pre">([^<]*)</span>', page.read_text())}


def _text(page: Path) -> str:
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", page.read_text())).split())


def test_api_page_names_every_public_name(built):
    names = [n for n in jko_cvx.__all__ if not n.startswith("__")]
    api = (built / "reference" / "api.html").read_text()
    missing = [n for n in names if f'href="generated/jko_cvx.{n}.html"' not in api]
    assert not missing, f"not in the API page: {missing}"
    empty = [
        n
        for n in names
        if f'id="jko_cvx.{n}"' not in (built / "reference" / "generated" / f"jko_cvx.{n}.html").read_text()
    ]
    assert not empty, f"generated pages without the object's description: {empty}"


def test_api_pages_show_the_examples(built):
    """Each public name's page renders its docstring's Examples section (tests/docs/test_api_examples.py)."""
    names = [n for n in jko_cvx.__all__ if not n.startswith("__")]
    pages = {n: (built / "reference" / "generated" / f"jko_cvx.{n}.html").read_text() for n in names}
    bare = [n for n, page in pages.items() if 'rubric">Examples' not in page or "&gt;&gt;&gt;" not in page]
    assert not bare, f"generated pages without a rendered Examples section and doctest: {bare}"


def _tables(cls: type) -> set[type]:
    found = set()
    for sub in cls.__subclasses__():
        found |= {sub, *_tables(sub)}
    return found


def test_every_schema_table_is_documented():
    documented = {cls for _, cls, _ in references.scene_tables()}
    undocumented = {c.__qualname__ for c in _tables(schema.Table) if dataclasses.is_dataclass(c)} - {
        c.__qualname__ for c in documented
    }
    assert not undocumented, f"schema tables missing from the scene reference: {sorted(undocumented)}"
    assert set(INITIAL_KINDS.values()) <= documented


_BASE = {
    "gamma": 1.0,
    "t_end": 0.1,
    "v": {"L": 2.0, "n": 9},
    "x": {"L": 1.0, "n": 4},
    "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
    "time": {"dt": 0.01},
    "refine": {"v": {}, "x": {}},
}


class _WrongType:
    def __repr__(self) -> str:
        return "<wrong type>"


@pytest.mark.parametrize("dotted", references.scene_keys())
def test_each_documented_key_is_one_the_parser_knows(dotted):
    """Set to a value no rule accepts, the key is refused by its own name: the parser knows it."""
    scene_from_dict(_BASE)  # the base is valid
    d = copy.deepcopy(_BASE)
    *path, last = dotted.split(".")
    if path == ["initial"] and last != "kind":
        kind = next(k for k, cls in INITIAL_KINDS.items() if last in cls.__dataclass_fields__)
        fields = dataclasses.fields(INITIAL_KINDS[kind])
        d["initial"] = {"kind": kind, **{f.name: [1.0] if f.metadata["rule"].kind == "floats" else 1.0 for f in fields}}
    table = d
    for part in path:
        table = table.setdefault(part, {})
    table[last] = _WrongType()
    with pytest.raises(schema.SceneError) as err:
        scene_from_dict(d)
    msg = str(err.value)
    assert not msg.startswith("unknown"), msg
    assert msg.startswith(dotted), msg


def test_scene_reference_names_every_key(built):
    literals = _literals(built / "reference" / "scene.html")
    missing = [k for k in references.scene_keys() if k not in literals]
    assert not missing, f"scene keys missing from the built reference: {missing}"
    from jko_cvx.scene.options import METHOD_OPTIONS, SOLVER_OPTIONS

    options = {f"collision.options.{n}" for rules in METHOD_OPTIONS.values() for n in rules}
    options |= {f"collision.options.solver_options.{n}" for rules in SOLVER_OPTIONS.values() for n in rules}
    assert not options - literals, sorted(options - literals)


def test_cli_page_names_every_subcommand_and_option(built):
    import argparse

    from jko_cvx.cli import build_parser

    text = _text(built / "reference" / "cli.html")
    (sub,) = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    assert len(sub.choices) >= 8  # run, export, solve, solvers, reproduce, study, compare, verify
    for name, parser in sub.choices.items():
        assert f"jko-cvx {name}" in text, name
        for action in parser._actions:
            for opt in action.option_strings:
                assert opt in text, f"jko-cvx {name} {opt}"


def test_statuses_page_names_every_status(built):
    from jko_cvx.collision.result import Status

    text = _text(built / "reference" / "statuses.html")
    for s in Status:
        assert s.name in text and " ".join(s.value.split()) in text, s.name


def test_statuses_page_names_every_stop_reason_and_verification_outcome(built):
    from jko_cvx.engine import verify as verify_module
    from jko_cvx.engine.verdict import StopReason

    text = _text(built / "reference" / "statuses.html")
    for r in StopReason:
        assert r.name in text and r.value in text, r.name
    # every outcome constant the module defines has a meaning, and the page shows it
    constants = {v for k, v in vars(verify_module).items() if k.isupper() and isinstance(v, str) and v.islower()}
    assert set(verify_module.OUTCOMES) >= {"agree", "differ", "ill-conditioned", "method failed", "reference failed"}
    assert constants <= set(verify_module.OUTCOMES) | {"reference"}, constants - set(verify_module.OUTCOMES)
    for name, meaning in verify_module.OUTCOMES.items():
        assert name in text and " ".join(meaning.split()) in text, name


def test_results_pages_are_built_with_every_file(built):
    """Each generated results page is in the site (the toctree of results/index), naming its files."""
    import jko_results

    index = _text(built / "results" / "index.html")
    for page in jko_results.PAGES:
        assert page.title in index, page.name
        text = _text(built / "results" / "generated" / f"{page.name}.html")
        missing = [rel for rel in page.files() if f"studies/results/{rel}" not in text]
        assert not missing, (page.name, missing)
        for entry in page.entries:
            for fig in entry.figures:
                assert (built / "_images" / fig.rsplit("/", 1)[-1]).is_file(), fig
