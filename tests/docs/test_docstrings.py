"""The installed package's text states facts, not project history: no issue numbers, no round
tags, no paths of the repository's result files (an installed package has no ``studies/``)."""

import re
from pathlib import Path

import pytest

import jko_cvx

PACKAGE = Path(jko_cvx.__file__).resolve().parent
HISTORY = re.compile(r"\b[Ii]ssue \d+\b|\bh\d{2}\b|studies/(results|README|[a-z_]+\.py)")
# the solver studies' own module docstring may say where the repository keeps their shipped outputs
ALLOWED = {("studies/solvers/__init__.py", "studies/results")}


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_project_history_in_the_package(path):
    rel = path.relative_to(PACKAGE).as_posix()
    found = [
        f"{rel}:{i}: {line.strip()}"
        for i, line in enumerate(path.read_text().splitlines(), 1)
        if (m := HISTORY.search(line)) and (rel, m.group(0)) not in ALLOWED
    ]
    assert not found, "\n".join(found)
