"""How large the Fisher weight beta must be, as a function of the data's width.

gamma = 1, :math:`f_0 = e^{-k v^2}` (amplitude 1, so T = 0.5 for every k) with widths
:math:`w = 1/\\sqrt{2k}` = 0.5, 0.25, 0.125, on uniform grids :math:`[-8w, 8w]` with N = 121
(the same points per width), fixed dt = 0.0025 to t = 0.25, Newton, against the exact
solution (:func:`jko_cvx.exact.exact_gamma1`).  Without the Fisher term the problem is
scale invariant (v -> v/w leaves the discrete JKO step unchanged), so the error at
beta = inf is the same for every width; the ratio ``error / error(beta = inf)`` is the
Fisher bias alone.  The Fisher term does not scale like the rest: its weight relative to
the Wasserstein term grows as the data narrow, so a weight adequate for w = 0.5 is not for
w = 0.125.  The guidance in the documentation (the solver and Fisher-weight guides) is read off ``fisher_width.md``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.evolve import evolve_fixed_grid
from jko_cvx.exact import GaussianMixture, exact_gamma1
from jko_cvx.grid import Grid
from jko_cvx.kernels import PowerKernel
from jko_cvx.studies.sweep import run_sweep

__all__ = ["fisher_width_error", "reproduce_fisher_width"]

WIDTHS = (0.5, 0.25, 0.125)
BETAS = (10.0, 30.0, 100.0, 300.0, 1000.0, float("inf"))
DT, T_END, N = 0.0025, 0.25, 121


def fisher_width_error(width: float, beta: float, fisher: str) -> dict[str, Any]:
    """One point: relative L1 error against the exact solution at t = 0.25."""
    k = 1 / (2 * width**2)
    f0 = GaussianMixture([1.0], [k], [0.0])
    grid = Grid.uniform(-8 * width, 8 * width, N)
    t0 = time.perf_counter()
    run = evolve_fixed_grid(grid, PowerKernel(1.0), f0.pdf(grid.points), DT, T_END, beta=beta, fisher=fisher, tol=1e-10)
    exact = exact_gamma1(f0, float(run.times[-1]), grid.points)
    err = float(grid.h @ np.abs(run.f[-1] - exact) / (grid.h @ exact))
    return {"error": err, "completed": run.completed, "seconds": time.perf_counter() - t0}


def reproduce_fisher_width(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """Write ``fisher_width.{csv,md}`` (``quick``: log form, widths 0.5 and 0.125, beta 30 and inf)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if quick:
        points = [{"width": w, "beta": b, "fisher": "log"} for w in (0.5, 0.125) for b in (30.0, float("inf"))]
    else:
        points = [{"width": w, "beta": b, "fisher": f} for f in ("log", "perspective") for w in WIDTHS for b in BETAS]
    df = run_sweep(fisher_width_error, points, out / "cache" / "fisher_width", desc="fisher width", **sweep_opts)
    df = df.drop(columns=["cached"], errors="ignore")
    ref = df[np.isinf(df.beta)].set_index(["fisher", "width"]).error
    df["error / error(beta = inf)"] = [
        e / ref[(f, w)] for e, f, w in zip(df.error, df.fisher, df.width, strict=True)
    ]
    df.to_csv(out / "fisher_width.csv", index=False)
    record_csv(out / "fisher_width.csv")
    table = df.pivot_table(index=["fisher", "beta"], columns="width", values="error / error(beta = inf)")
    need = []
    for (fisher, width), block in df[np.isfinite(df.beta)].groupby(["fisher", "width"]):
        ok = block[block["error / error(beta = inf)"] <= 1.06].beta
        best = ok.min() if len(ok) else np.nan
        need.append({"fisher": fisher, "width": width, "smallest beta with bias <= 6 %": best})
    need_df = pd.DataFrame(need)
    lines = [
        "# The Fisher bias against the data's width (gamma = 1, dt = 0.0025, t = 0.25, N = 121)",
        "",
        (__doc__ or "").split("\n\n", 1)[0].strip(),
        "",
        "error / error(beta = inf) (columns: width w):",
        "",
        table.to_markdown(floatfmt=".3g"),
        "",
        need_df.to_markdown(index=False, floatfmt=".4g"),
        "",
        "error(beta = inf) per width: "
        + ", ".join(f"{w:g}: {ref[('log', w)]:.3g}" for w in sorted({w for _, w in ref.index}, reverse=True)),
    ]
    write_markdown(out / "fisher_width.md", "\n".join(lines) + "\n")
    return df
