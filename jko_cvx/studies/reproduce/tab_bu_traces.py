"""Traces of the ``tab:bu`` / ``tab:bu_tb2`` entries that lie after the exact blow-up time.

Each case reruns one table entry (the sweep point :func:`~jko_cvx.studies.reproduce.blowup_tables.blowup_time`,
same scene) with a snapshot after every step and records, per step, what the paper's
mesh rule sees: max f and where it sits, min dv, the ends ``r1 = min S``, ``r2 = max S`` of
the concentration set :math:`S = \\{v_j > 0 : f_j > \\delta_0 \\max f\\}` (``eqn:Sr``,
``rrr``), and f at the ends of the map's linear piece (the grid points at :math:`s = \\delta`
for ``mu1``, :math:`s = 1/2 \\mp \\delta/2` for ``mu2``), where the spacing jumps (C^0 junction).

Two mechanisms, both of the paper's grid-point set rule on its C^0-junction maps:

* **g3, dt = 0.00125, eps_v <= 1e-3/4 (0.15125, exact 0.125); g2, dt = 0.0025.**  Mass piles up at the
  outer junction of ``mu1`` (where the spacing jumps): f there
  reaches max f, so the set S keeps reaching the junction, r stays put and min dv
  stalls while max f grows; it fires only when the spike at the junction itself has been
  resolved.  With beta = 1000 the same entry fires at 0.12625 (case ``g3 beta=1000``).
* **g4 (two bumps), dt = 0.005 and dt = 0.0025 at eps_v = 1e-3/8.**  The bump drifts
  inward while the lower end r1 of S stays at a grid point of the previous grid (the next
  grid point below is a coarse cell away, under the threshold: the set can lose points but
  not gain them); the peak reaches the linear piece's lower end, where the spacing jumps, the
  set is rebuilt wider and min dv jumps back up, so the run fires late.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.grid import Grid
from jko_cvx.mesh.maps import concentration_set
from jko_cvx.studies.reproduce.blowup_tables import TAB_BU_BETA, TAB_BU_TB2_BETA, blowup_scene
from jko_cvx.studies.reproduce.paper import EXACT_T

__all__ = ["CASES", "reproduce_tab_bu_traces", "trace_entry"]

# (label, data, eps_v, dt, beta)
CASES = (
    ("g3", "g3", 1e-3 / 4, 0.00125, TAB_BU_BETA),
    ("g3 beta=1000", "g3", 1e-3 / 4, 0.00125, 1000.0),
    ("g2 dt=0.0025", "g2", 1e-3 / 8, 0.0025, TAB_BU_BETA),
    ("g4 dt=0.005", "g4", 1e-3, 0.005, TAB_BU_TB2_BETA),
    ("g4 dt=0.0025", "g4", 1e-3 / 8, 0.0025, TAB_BU_TB2_BETA),
)


def _junctions(n: int, bumps: int, delta: float) -> list[int]:
    """Grid indices of the linear piece's ends on the positive side (uniform s on [-1, 1])."""
    s = np.linspace(-1.0, 1.0, n)
    ends = [delta] if bumps == 1 else [0.5 - delta / 2, 0.5 + delta / 2]
    return [int(np.argmin(np.abs(s - e))) for e in ends]


def trace_entry(data: str, eps_v: float, dt: float, beta: float) -> pd.DataFrame:
    """Per-step records of one table entry (see the module docstring); ``attrs['T_b']`` its T_b."""
    scene = blowup_scene(data, eps_v, dt, beta)
    scene = scene.replace({"output.every": 1})
    run = simulate(scene)
    spec = scene.refine.v
    idx = _junctions(scene.vgrid().n, spec.bumps, spec.delta)
    rows = []
    for snap in run.snapshots:
        grid, f = Grid(snap["v"]), snap["f"]
        v = grid.points
        r1, r2 = concentration_set(grid, f, spec.delta0, both_ends=True)
        k = int(np.argmax(np.where(v > 0, f, -np.inf)))
        row = {
            "t": snap["t"],
            "max_f": float(f.max()),
            "argmax_v (v > 0)": float(v[k]),
            "min_dv": float(grid.dv.min()),
            "r1 = min S": r1,
            "r2 = max S": r2,
        }
        for name, j in zip(("f(lower junction)/max f", "f(upper junction)/max f")[-len(idx) :], idx, strict=True):
            row[name] = float(f[j] / f.max())
            row[name.replace("f(", "v(").replace(")/max f", ")")] = float(v[j])
        rows.append(row)
    df = pd.DataFrame(rows)
    df.attrs["T_b"] = float(run.verdict["T_b"]) if run.blowup else float("nan")
    return df


def reproduce_tab_bu_traces(out: Path, quick: bool = False, **_sweep_opts: Any) -> pd.DataFrame:
    """Write ``tab_bu_traces.{csv,md}``: the cases of :data:`CASES` (``quick``: every other one)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    frames, lines = [], ["# Traces of the table entries after the exact blow-up time", ""]
    lines += [(__doc__ or "").split("\n\n", 2)[2].strip(), ""]
    lines += ["| case | eps_v | dt | beta | T_b | exact T | largest f(junction)/max f before T_b | min dv then |"]
    lines += ["|:--|--:|--:|--:|--:|--:|--:|--:|"]
    cases = CASES[::2] if quick else CASES
    for label, data, eps, dt, beta in cases:
        df = trace_entry(data, eps, dt, beta)
        junction = next(c for c in df.columns if c.startswith("f("))  # outer (mu1) or lower (mu2) end
        before = df.iloc[:-1]
        j = int(before[junction].idxmax())
        lines.append(
            f"| {label} | {eps:.4g} | {dt:g} | {beta:g} | {df.attrs['T_b']:.5g} | {EXACT_T[data]:g} | "
            f"{before[junction].max():.3f} (t = {before.t[j]:.5g}) | {before.min_dv[j]:.3g} |"
        )
        frames.append(df.assign(case=label, data=data, eps_v=eps, dt=dt, beta=beta, T_b=df.attrs["T_b"]))
    table = pd.concat(frames, ignore_index=True)
    table.to_csv(out / "tab_bu_traces.csv", index=False)
    record_csv(out / "tab_bu_traces.csv")
    lines += ["", f"Wall time {time.perf_counter() - t0:.1f} s (one process)."]
    write_markdown(out / "tab_bu_traces.md", "\n".join(lines) + "\n")
    return table
