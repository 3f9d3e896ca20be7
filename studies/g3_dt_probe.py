"""How the gamma = 3 inhomogeneous runs depend on the time step: the watched quantities against dt.

``python studies/g3_dt_probe.py [--cases lam:n:dt ...]`` runs the shipped ``inhom_gamma3_lambda{4,10}``
scenes (121 x 121 in the paper; here N x N with N = 61 and 121) to their ``t_end`` with the step dt
halved from the shipped 0.05, everything else as shipped, and writes
``studies/results/reproduce/g3_dt_probe.{csv,md}``: per run the peak of max f and its time, max f at the end,
the smallest x and v spacings of the mapped grids, the verdict and the seconds.  A point already in
the CSV (same lambda, N, dt, and the same package commit) is not run again, so the probe can be
extended case by case.

This is a probe, not the grid-convergence study: it asks whether the paper's "no blow-up" verdict
for gamma = 3 and the quantities it rests on (max f, min dx against eps_x = 1e-5) settle as dt
shrinks on a fixed grid.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import pandas as pd

from jko_cvx.engine.loop import simulate
from jko_cvx.environment import environment, environment_line, record_csv, write_markdown
from jko_cvx.scene.model import shipped_scene

OUT = Path(__file__).parent / "results" / "reproduce"  # evidence of the conclusions table
CSV = OUT / "g3_dt_probe.csv"
DEFAULT_CASES = tuple(
    [(4.0, 61, dt) for dt in (0.05, 0.025, 0.0125, 0.00625)]
    + [(4.0, 121, dt) for dt in (0.05, 0.025, 0.0125)]
    + [(10.0, 61, dt) for dt in (0.05, 0.025, 0.0125, 0.00625)]
    + [(10.0, 121, dt) for dt in (0.05, 0.025)]
)


def run_case(lam: float, n: int, dt: float) -> dict:
    """One run of the shipped scene at lambda ``lam`` on n x n with step dt."""
    t0 = time.perf_counter()
    run = simulate(shipped_scene(f"inhom_gamma3_lambda{lam:g}", {"v.n": n, "x.n": n, "time.dt": dt}))
    d = run.diagnostics
    peak = int(d.max_f.to_numpy().argmax())
    return {
        "lambda": lam, "n": n, "dt": dt, "steps": int(len(d) - 1),
        "max_f_peak": float(d.max_f.iloc[peak]), "t_peak": float(d.t.iloc[peak]),
        "max_f_final": float(d.max_f.iloc[-1]), "min_dx": float(d.min_dx.min()), "min_dv": float(d.min_dv.min()),
        "blowup": bool(run.verdict.blowup), "reason": run.verdict.reason,
        "failed_steps": int(run.failed_steps), "seconds": time.perf_counter() - t0,
    }  # fmt: skip


def _report(df: pd.DataFrame) -> str:
    lines = [
        "# gamma = 3 inhomogeneous runs against the time step",
        "",
        "The shipped scenes `inhom_gamma3_lambda4` and `_lambda10` (eps_x = eps_v = 1e-5, beta = 1000, log Fisher "
        "form, Newton), on N x N grids, to t_end = 4 with the step dt halved from the shipped 0.05; everything else "
        "as shipped.  `python studies/g3_dt_probe.py` (one BLAS thread).  Rows were added over several sessions: "
        "each row's `commit` names the code that ran it, and rows of earlier sessions may come from another machine "
        "or BLAS kernel (the environment lines are those of the last write).",
        "",
        df.sort_values(["lambda", "n", "dt"], ascending=[True, True, False]).to_markdown(index=False, floatfmt=".4g"),
        "",
    ]
    for (lam, n), g in df.groupby(["lambda", "n"]):
        g = g.sort_values("dt", ascending=False)
        if len(g) > 1:
            ratios = ", ".join(f"{r:.2f}" for r in (g.max_f_peak.to_numpy()[1:] / g.max_f_peak.to_numpy()[:-1]))
            lines.append(
                f"- lambda = {lam:g}, {n} x {n}: peak max f {g.max_f_peak.iloc[0]:.4g} at dt = {g.dt.iloc[0]:g} to "
                f"{g.max_f_peak.iloc[-1]:.4g} at dt = {g.dt.iloc[-1]:g} (ratio per halving: {ratios}); min dx "
                f"{g.min_dx.iloc[0]:.3g} to {g.min_dx.iloc[-1]:.3g}; blow-up flagged in {int(g.blowup.sum())} of "
                f"{len(g)}."
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cases", nargs="*", default=None, help="lam:n:dt triples (default: the probe's set)")
    args = parser.parse_args(argv)
    cases = DEFAULT_CASES if args.cases is None else [tuple(float(x) for x in c.split(":")) for c in args.cases]
    commit = environment().get("git_commit")
    done = pd.read_csv(CSV) if CSV.exists() else pd.DataFrame()
    rows = done.to_dict("records")
    for lam, n, dt in cases:
        n = int(n)
        have = [r for r in rows if (r["lambda"], r["n"], r["dt"]) == (lam, n, dt) and r.get("commit") == commit]
        if have:
            continue
        rows = [r for r in rows if (r["lambda"], r["n"], r["dt"]) != (lam, n, dt)]
        row = {**run_case(lam, n, dt), "commit": commit}
        rows.append(row)
        print(f"lambda {lam:g} n {n} dt {dt:g}: peak max f {row['max_f_peak']:.4g}, min dx {row['min_dx']:.3g}, "
              f"{row['reason']} ({row['seconds']:.0f} s)", flush=True)  # fmt: skip
        df = pd.DataFrame(rows)
        df.to_csv(CSV, index=False)  # after every run: a killed probe keeps what it ran
        record_csv(CSV)
    df = pd.DataFrame(rows)
    write_markdown(OUT / "g3_dt_probe.md", _report(df))
    print(environment_line())


if __name__ == "__main__":
    main()
