"""Every tutorial page runs: its ``{code-cell} python`` cells, executed in order in one namespace.

The pages are MyST-NB text notebooks, which the documentation build executes for their output and
figures; this test runs the same cells without a Jupyter kernel (the suite's docs build skips the
execution).  The pages state their claims as ``assert`` statements in those cells, so a tutorial
whose numbers drift from the package fails here.
"""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt

TUTORIALS = Path(__file__).resolve().parents[2] / "docs" / "tutorials"
_BLOCK = re.compile(r"^```\{code-cell\} python\n(.*?)^```$", re.S | re.M)
_NOTEBOOK = re.compile(r"\A---\nfile_format: mystnb\nkernelspec:\n  name: python3\n")


def code_blocks(page: Path) -> list[str]:
    """The page's ``{code-cell} python`` cells, in order."""
    return _BLOCK.findall(page.read_text())


@pytest.mark.parametrize("page", sorted(TUTORIALS.glob("*.md")), ids=lambda p: p.stem)
def test_tutorial_runs(page, tmp_path, monkeypatch):
    text = page.read_text()
    assert _NOTEBOOK.match(text), f"{page.name} is not a MyST-NB notebook (front matter): the build would not run it"
    blocks = code_blocks(page)
    assert blocks, f"{page.name} has no code cell"
    assert "```python" not in text, f"{page.name}: a plain python block is neither run nor tested"
    monkeypatch.chdir(tmp_path)  # whatever a tutorial writes lands here
    namespace: dict = {"__name__": "__main__"}
    for i, code in enumerate(blocks, 1):
        exec(compile(code, f"{page.name}[block {i}]", "exec"), namespace)
    plt.close("all")
