"""``fig:gk1_final``: f(t = 0.5, v) for g1 (gamma = 1), delta = 0.2, delta0 = 0.5, dt = 0.01.

The caption's parameters; N_v = 121 and L = 2 as in ``tab:bu``, the log-Fisher weight
beta = 1000 of the records (:mod:`jko_cvx.studies.reproduce.records`), no stopping criterion (the
figure is drawn at the analytic blow-up time T = 0.5).  The paper: f(0.5, v) "nearly
converges to a Dirac delta function centered at v = 0".  Recorded: max f, min dv, the
share of the mass within |v| <= 0.01 and 0.05, and the centre of mass.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.blowup_tables import blowup_scene
from jko_cvx.studies.solvers.figures import pyplot

__all__ = ["gk1_final_scene", "reproduce_gk1_final"]


def gk1_final_scene(t_end: float = 0.5):
    """The ``fig:gk1_final`` scene (g1, delta = 0.2, delta0 = 0.5, dt = 0.01, beta = 1000)."""
    s = blowup_scene("g1", 0.0, 0.01, beta=1000.0)
    return s.replace({"refine.v": dataclasses.replace(s.refine.v, delta=0.2, delta0=0.5), "t_end": t_end})


def reproduce_gk1_final(out: Path, quick: bool = False, **_sweep_opts: Any) -> pd.DataFrame:
    """Write ``gk1_final.{csv,md,png}`` (``quick``: to t = 0.3)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    run = simulate(gk1_final_scene(0.3 if quick else 0.5))
    seconds = time.perf_counter() - t0
    v, f, h = run.vgrid.points, run.f, run.vgrid.h
    mass = float(f @ h)
    record = {
        "t": run.t,
        "max f": float(f.max()),
        "min dv": float(run.vgrid.dv.min()),
        "mass share at abs(v) <= 0.01": float((f * h)[np.abs(v) <= 0.01].sum() / mass),
        "mass share at abs(v) <= 0.05": float((f * h)[np.abs(v) <= 0.05].sum() / mass),
        "centre of mass": float((f * h) @ v / mass),
        "failed steps": int((run.diagnostics.failed > 0).sum()),
        "seconds": seconds,
    }
    pd.DataFrame({"v": v, "f": f}).to_csv(out / "gk1_final.csv", index=False)
    record_csv(out / "gk1_final.csv")
    lines = [
        "# fig:gk1_final: g1, delta = 0.2, delta0 = 0.5, dt = 0.01, N_v = 121, beta = 1000",
        "",
        pd.DataFrame([record]).to_markdown(index=False, floatfmt=".4g"),
        "",
        "f(t, v) at the final grid: `gk1_final.csv`.",
    ]
    write_markdown(out / "gk1_final.md", "\n".join(lines) + "\n")
    _figure(v, f, run.t, out / "gk1_final.png")
    return pd.DataFrame([record])


def _figure(v, f, t, path: Path) -> None:
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    axes[0].plot(v, f, ".-", ms=3)
    axes[0].set_title(f"fig:gk1_final: f(t = {t:.2f}, v)", fontsize=9)
    zoom = np.abs(v) <= 0.1
    axes[1].plot(v[zoom], f[zoom], ".-", ms=3)
    axes[1].set_title("zoom |v| <= 0.1 (grid points marked)", fontsize=9)
    for ax in axes:
        ax.set_xlabel("v")
        ax.set_ylabel("f")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
