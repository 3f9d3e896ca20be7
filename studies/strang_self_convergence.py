"""Self-convergence in dt of an inhomogeneous run at time order 1 and 2 (Strang + Richardson).

``python studies/strang_self_convergence.py`` writes ``studies/results/strang_self_convergence.{csv,md}``:
``inhom_gamma3_lambda4`` on a coarse 32 x 41 grid without refinement (beta = 100) to t = 0.4 with
dt = 0.1, 0.05, 0.025, 0.0125 at each order, and the L1 norm of the difference between successive
final densities (sum over the grid points, unweighted) with the observed orders.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.scene.model import shipped_scene

OUT = Path(__file__).parent / "results"
BASE = {"refine": None, "v.n": 41, "x.n": 32, "t_end": 0.4, "collision.beta": 100.0}
DTS = (0.1, 0.05, 0.025, 0.0125)


def main() -> None:
    rows = []
    for order in (1, 2):
        finals = []
        for dt in DTS:
            t0 = time.perf_counter()
            run = simulate(shipped_scene("inhom_gamma3_lambda4", {**BASE, "time.order": order, "time.dt": dt}))
            d = run.diagnostics
            finals.append(run.f)
            rows.append({"order": order, "dt": dt, "seconds": time.perf_counter() - t0,
                         "mass_drift": float(abs(d.mass.iloc[-1] - d.mass.iloc[0])),
                         "min_f": float(run.f.min()), "verdict": run.verdict["reason"]})  # fmt: skip
        for i in range(len(DTS) - 1):
            rows[-len(DTS) + i]["diff_to_next"] = float(np.abs(finals[i] - finals[i + 1]).sum())
    df = pd.DataFrame(rows)
    df["observed_order"] = np.log2(df.diff_to_next / df.diff_to_next.shift(-1)).where(df.order == df.order.shift(-1))
    OUT.mkdir(exist_ok=True)
    df.to_csv(OUT / "strang_self_convergence.csv", index=False)
    record_csv(OUT / "strang_self_convergence.csv")
    write_markdown(OUT / "strang_self_convergence.md",
        "# Self-convergence in dt, inhom_gamma3_lambda4 at 32 x 41, no refinement, beta = 100, t = 0.4\n\n"
        + df.to_markdown(index=False, floatfmt=".3g")
        + "\n"
    )
    print(df.to_string())


if __name__ == "__main__":
    main()
