"""The conic reference's ``dc_split = "truncated"`` (the default) against ``"eigen"`` on 72 varied steps.

Each collision step is solved by ``method="conic"`` with both splits, side by side in one
process: gamma in {2.5, 3, 4}, N = 41 (random non-uniform grid on [-3, 3]) and 121 (uniform),
dt in {1e-3, 0.05, 0.5}, beta in {inf, 10} (perspective Fisher), strength in {1, 50}, f* a
two-bump density.  Recorded per step: both statuses, passes, CPU seconds, KKT residuals and
max |f_eigen - f_truncated| / max f_eigen.  The two splits share their fixed points (KKT points
of the same problem), so where both certify they must agree to the solvers' accuracy; the
question is whether the truncated majorant costs certification or passes.

Run: ``OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 python studies/conic_truncated_split.py`` (about
a minute and a half).  Writes ``studies/results/conic_truncated_split.csv`` and ``.md``.
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.threads import thread_environment

RESULTS = Path(__file__).parent / "results"


def steps() -> list[dict[str, object]]:
    rng = np.random.default_rng(0)
    rows = []
    for gamma, n, dt, beta, strength in itertools.product([2.5, 3.0, 4.0], [41, 121], [1e-3, 0.05, 0.5],
                                                           [np.inf, 10.0], [1.0, 50.0]):  # fmt: skip
        g = Grid(np.sort(np.r_[-3, 3, rng.uniform(-3, 3, n - 2)])) if n == 41 else Grid.uniform(-3, 3, n)
        f0 = np.exp(-2 * (g.points - 0.3) ** 2) + 0.5 * np.exp(-8 * (g.points + 1) ** 2)
        prob = CollisionProblem(g, PowerKernel(gamma), f0, dt, strength, beta, "perspective")
        row: dict[str, object] = {"gamma": gamma, "N": n, "dt": dt, "beta": beta, "strength": strength}
        res = {}
        for split in ("eigen", "truncated"):
            t0 = time.process_time()
            r = solve_collision(prob, method="conic", dc_split=split)
            res[split] = r
            row |= {f"status_{split}": r.status.name, f"passes_{split}": r.info["passes"],
                    f"cpu_s_{split}": time.process_time() - t0, f"kkt_{split}": float(r.kkt_residual)}  # fmt: skip
        row["df"] = float(np.abs(res["eigen"].f - res["truncated"].f).max() / res["eigen"].f.max())
        rows.append(row)
        print(row, flush=True)
    return rows


def main() -> None:
    df = pd.DataFrame(steps())
    RESULTS.mkdir(exist_ok=True)
    csv = RESULTS / "conic_truncated_split.csv"
    df.to_csv(csv, index=False)
    record_csv(csv)
    same = df.status_eigen == df.status_truncated
    both = (df.status_eigen == "CONVERGED") & (df.status_truncated == "CONVERGED")
    md = [
        "# The conic reference: truncated DC split against eigen (`studies/conic_truncated_split.py`)",
        "",
        f"CPU seconds (`time.process_time`), side by side in one process; threads: {thread_environment()}.",
        "",
        f"- same status on {int(same.sum())} of {len(df)} steps; both CONVERGED on {int(both.sum())}",
        f"- total CPU: eigen {df.cpu_s_eigen.sum():.3g} s, truncated {df.cpu_s_truncated.sum():.3g} s "
        f"(N = 121 only: {df[df.N == 121].cpu_s_eigen.sum():.3g} s against "
        f"{df[df.N == 121].cpu_s_truncated.sum():.3g} s)",
        f"- passes: eigen {int(df.passes_eigen.sum())}, truncated {int(df.passes_truncated.sum())}",
        f"- max |f_eigen - f_truncated| / max f where both converged: {df[both].df.max():.2g}",
        "",
        df.to_markdown(index=False, floatfmt=".3g"),
        "",
    ]
    write_markdown(RESULTS / "conic_truncated_split.md", "\n".join(md))
    print("\n".join(md[:9]))


if __name__ == "__main__":
    main()
