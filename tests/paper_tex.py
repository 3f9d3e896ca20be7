"""Numbers read from the paper's LaTeX source (an oracle independent of the package's copy).

The paper lives beside the repository (``../shared/paper/granular_blowup_paper.tex``, see
README.md); set ``JKO_CVX_PAPER`` to its path elsewhere.  Tests that need it skip without it.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

_ROOT = Path(__file__).resolve().parent.parent
_CANDIDATES = [
    Path(os.environ.get("JKO_CVX_PAPER", "")),
    _ROOT.parent / "shared" / "paper" / "granular_blowup_paper.tex",
    Path("/work/shared/paper/granular_blowup_paper.tex"),
]


def paper_available() -> bool:
    return any(p.is_file() for p in _CANDIDATES)


def paper_source() -> str:
    for p in _CANDIDATES:
        if p.is_file():
            return p.read_text()
    pytest.skip("the paper's LaTeX source is not available (set JKO_CVX_PAPER)")


def _table_body(label: str) -> str:
    tex = paper_source()
    end = tex.index(f"\\label{{{label}}}")
    start = tex.rindex("\\begin{tabular}", 0, end)
    return tex[start : tex.index("\\end{tabular}", start)]


def _numbers(cells: list[str]) -> list[float]:
    return [float(c) for c in (c.strip() for c in cells) if re.fullmatch(r"[0-9.]+", c)]


def _eps(cell: str) -> float:
    m = re.search(r"1e-3(?:/(\d+))?", cell)
    return 1e-3 / (int(m.group(1)) if m.group(1) else 1)


def blowup_table(label: str) -> dict[tuple[str, float, float], float]:
    """``tab:bu`` / ``tab:bu_tb2``: T_b keyed by (data, eps_v, dt)."""
    body = _table_body(label)
    rows = [r for r in body.split("\\\\") if "epsilon_v" in r or "Delta t" in r]
    dts = [float(x) for x in re.findall(r"Delta t = ([0-9.]+)", rows[0])]
    out, data = {}, "g4"
    for row in rows[1:]:
        g = re.search(r"g_(\d)\(v\)", row)
        data = f"g{g.group(1)}" if g else data
        cells = row.split("&")
        eps_cell = next(c for c in cells if "epsilon_v" in c)
        values = _numbers(cells[cells.index(eps_cell) + 1 :])
        assert len(values) == len(dts), row
        for dt, val in zip(dts, values, strict=True):
            out[(data, _eps(eps_cell), dt)] = val
    return out


def g2bu_table() -> dict[float, float]:
    """``tab:g2bu``: T_b keyed by lambda."""
    body = _table_body("tab:g2bu").replace("\n", " ")
    lam_row = body[body.index("$\\lambda$") : body.index("\\\\")]
    tb_row = body[body.index("$T_b$") :]
    lams = _numbers(lam_row.split("&")[1:])
    tbs = _numbers(tb_row.split("\\\\")[0].split("&")[1:])
    assert len(lams) == len(tbs) == 9
    return dict(zip(lams, tbs, strict=True))
