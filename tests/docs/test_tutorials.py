"""Every tutorial page runs: its ``python`` code blocks, executed in order in one namespace.

The pages state their claims as ``assert`` statements in those blocks, so a tutorial whose
numbers drift from the package fails here.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

TUTORIALS = Path(__file__).resolve().parents[2] / "docs" / "tutorials"
_BLOCK = re.compile(r"^```python\n(.*?)^```$", re.S | re.M)


def code_blocks(page: Path) -> list[str]:
    """The page's fenced ``python`` blocks, in order."""
    return _BLOCK.findall(page.read_text())


@pytest.mark.parametrize("page", sorted(TUTORIALS.glob("*.md")), ids=lambda p: p.stem)
def test_tutorial_runs(page, tmp_path, monkeypatch):
    blocks = code_blocks(page)
    assert blocks, f"{page.name} has no python code block"
    monkeypatch.chdir(tmp_path)  # whatever a tutorial writes lands here
    namespace: dict = {"__name__": "__main__"}
    for i, code in enumerate(blocks, 1):
        exec(compile(code, f"{page.name}[block {i}]", "exec"), namespace)
