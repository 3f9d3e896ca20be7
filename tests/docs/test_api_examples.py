"""Every public name of ``jko_cvx`` shows how it is used: its docstring has a numpydoc ``Examples``
section with a doctest, and that doctest is one the suite runs (``--doctest-modules`` collects it
from the module that defines the name), so the example cannot drift from the code."""

from __future__ import annotations

import doctest
import importlib
import inspect
import re

import pytest

import jko_cvx

PUBLIC = [n for n in jko_cvx.__all__ if not n.startswith("__")]
HEADER = re.compile(r"^(\S[^\n]*)\n(-+)$", re.MULTILINE)  # a numpydoc section title and its underline


def examples_section(doc: str) -> str | None:
    """The text of the ``Examples`` section of a (cleaned) numpydoc docstring, None without one."""
    heads = [m for m in HEADER.finditer(doc) if len(m.group(2)) == len(m.group(1).strip())]
    for i, m in enumerate(heads):
        if m.group(1).strip() == "Examples":
            end = heads[i + 1].start() if i + 1 < len(heads) else len(doc)
            return doc[m.end() : end]
    return None


def test_the_section_parser():
    doc = "Summary.\n\nParameters\n----------\nx : int\n\nExamples\n--------\n>>> 1 + 1\n2\n\nNotes\n-----\nEnd."
    assert examples_section(doc) == "\n>>> 1 + 1\n2\n\n"
    assert examples_section("Summary.\n\n>>> 1 + 1\n2\n") is None  # a doctest outside the section
    assert examples_section("Summary.\n\nExamples\n-----\n>>> 1\n1\n") is None  # not a numpydoc title


@pytest.mark.parametrize("name", PUBLIC)
def test_public_name_has_an_example(name):
    obj = getattr(jko_cvx, name)
    doc = obj.__doc__  # the docstring autodoc shows (the class's own, not an inherited one)
    assert doc, f"jko_cvx.{name} has no docstring"
    section = examples_section(inspect.cleandoc(doc))
    assert section is not None, f"jko_cvx.{name}: the docstring has no 'Examples' section (numpydoc)"
    assert any(line.lstrip().startswith(">>>") for line in section.splitlines()), (
        f"jko_cvx.{name}: its Examples section holds no '>>>' line"
    )


@pytest.mark.parametrize("name", PUBLIC)
def test_the_example_runs_in_the_suite(name):
    """``--doctest-modules`` finds the example in the module that defines the name (not only here)."""
    obj = getattr(jko_cvx, name)
    module = importlib.import_module(obj.__module__)
    assert module.__name__.startswith("jko_cvx."), f"jko_cvx.{name} is defined outside the package"
    tests = {t.name: t for t in doctest.DocTestFinder().find(module) if t.examples}
    assert f"{module.__name__}.{obj.__qualname__}" in tests, (
        f"jko_cvx.{name}: no doctest of it is collected from {module.__name__}"
    )
