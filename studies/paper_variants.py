"""Issue 18: the paper's algorithms as written against this package's rules, one switch at a time.

``python studies/paper_variants.py [--quick] [--out DIR]`` (``PYTHONPATH`` at the repository root;
``OPENBLAS_NUM_THREADS=1``).  Writes to ``studies/results/reproduce/`` by default:

* ``paper_variants.{csv,md}``: the adaptive g1 runs of ``gk1_records`` (``alg:MR_JKO_ver2``
  as written, the paper's SQP, dt0 = 0.01, eps_t = 5e-6; delta0 = 0.5 to t = 0.7 and
  delta0 = 0.05 to t = 0.6) under each pair of

  - ``time.halve_on``: ``"any_failure"`` (the package: every step the engine does not accept
    halves dt) or ``"max_iterations"`` (the paper: only the exit flag e_f halves it; any
    other failure stops the run);
  - the SQP's ``safeguard``: ``"floor"`` (the package: fraction-to-the-boundary cut, zeta >=
    2 eps after a cut), ``"cut"`` (the cut, zeta as Algorithm 1 computes it) or ``"none"``
    (Algorithm 1 as written: no cut; an iterate with f_j <= 0 is NUMERICAL_ERROR).

  Two more rows vary the SQP's I_max (2000, 200; default 20000, the paper states none) under
  the paper's rules.  Columns: the failed attempts by status, the first failed attempt (t, status), the first
  halving (start of the first accepted step below dt0), retries, the smallest accepted dt,
  how the run ended and T_b.
* ``paper_variants_concentration.{csv,md}``: ``refine.concentration_set = "projections"``
  (the package) against ``"quadrant"`` (``alg:SPMCSL-JKO`` step 4; empty set: uniform grid)
  on ``inhom_gamma3`` lambda = 4 (the quick form, 61 x 61 to t = 2, and the shipped scene,
  121 x 121 to t = 4) and on the quick form of ``inhom_gamma1p5`` (lambda = 10 "before" and
  lambda = 5 "after", 41 x 41 and 61 x 61, with its density stop at sigma_v < 0.05, to t = 0.6):
  min dv, min dx, max f, the verdict and T_b, and the first time the v-grid is finer than the
  uniform one.

``--quick``: delta0 = 0.5 only, and the gamma = 3 scene only.  Results are cached per point
(``cache/paper_variants*``, keyed by the package's code) and reused on a rerun.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

import numpy as np

from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.gamma1p5 import COLLAPSE_SPREAD, QUICK_T_END, gamma1p5_scene
from jko_cvx.studies.reproduce.inhomogeneous import inhomogeneous_scene
from jko_cvx.studies.reproduce.records import record_run
from jko_cvx.studies.sweep import run_sweep

ROOT = Path(__file__).resolve().parent
VARIANTS = [
    ("any_failure", "floor"),
    ("max_iterations", "floor"),
    ("any_failure", "cut"),
    ("max_iterations", "cut"),
    ("any_failure", "none"),
    ("max_iterations", "none"),
]
I_MAX_PROBE = (2000, 200)
STATUSES = ("MAX_ITERATIONS", "NOT_CERTIFIED", "NONCONVEX", "NUMERICAL_ERROR")


def gk1_variant(delta0: float, t_end: float, halve_on: str, safeguard: str, max_iter: int = 20000) -> dict[str, Any]:
    """One adaptive g1 record (``records.record_run``) reduced to the columns of the table."""
    r = record_run("g1", delta0, "halving", t_end, halve_on, safeguard, None if max_iter == 20000 else max_iter)
    t, dt = r["t"], r["dt"]
    first = r["attempts"][0] if r["attempts"] else None
    return {
        **{f"failed {st}": int(r["failures"].get(st, 0)) for st in STATUSES},
        "first failure t": float("nan") if first is None else first["t"],
        "first failure": "" if first is None else "/".join(first["statuses"]) + f" ({first['then']})",
        "first halving t": next((a - b for a, b in zip(t[1:], dt[1:], strict=True) if b < 0.0099), float("nan")),
        "retries": int(sum(r["retries"])),
        "smallest dt": min(x for x in dt if x > 0) if len(dt) > 1 else float("nan"),
        "steps": len(t) - 1,
        "t reached": t[-1],
        "T_b": r["T_b"],
        "verdict": r["verdict"],
        "seconds": r["seconds"],
    }


def _inhom_scene(case: str, n: int, rule: str):
    """``gamma3_lambda4``: inhom_gamma3's scene on n x n (t = 2 at n = 61, the quick form; t = 4 at
    121, the shipped one); ``gamma1p5_before`` / ``_after``: the quick form's run on n x n."""
    over = {"refine.concentration_set": rule}
    if case == "gamma3_lambda4":  # inhomogeneous_scene takes no overrides; the rule is a plain field
        return inhomogeneous_scene(4.0, n, 2.0 if n < 121 else 4.0).replace({"refine.concentration_set": rule})
    sub = case.split("_")[1]  # gamma1p5_before / gamma1p5_after
    return gamma1p5_scene(sub, n, {**over, "stop.spread_v": COLLAPSE_SPREAD, "t_end": QUICK_T_END, "output.times": []})


def concentration_variant(case: str, n: int, rule: str) -> dict[str, Any]:
    """One quick inhomogeneous run under ``refine.concentration_set = rule``."""
    scene = _inhom_scene(case, n, rule)
    t0 = time.perf_counter()
    run = simulate(scene)
    d = run.diagnostics
    uniform_dv = 2 * scene.v.L / (scene.v.n - 1)
    refined = d.t[d.min_dv < uniform_dv * (1 - 1e-9)]
    return {
        "min dv": float(d.min_dv.min()),
        "min dv at end": float(d.min_dv.iloc[-1]),
        "min dx": float(d.min_dx.min()),
        "max f (peak)": float(d.max_f.max()),
        "mass drift": float(np.max(np.abs(d.mass / d.mass.iloc[0] - 1))),
        "first t with a refined v-grid": float(refined.iloc[0]) if len(refined) else float("nan"),
        "steps": len(d) - 1,
        "t reached": float(run.t),
        "T_b": float(run.verdict["T_b"]) if run.blowup else float("nan"),
        "verdict": run.verdict["reason"],
        "seconds": time.perf_counter() - t0,
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "results" / "reproduce"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    opts = {"executor": "serial", "progress": False}

    runs = [(0.5, 0.7)] if args.quick else [(0.5, 0.7), (0.05, 0.6)]
    points = [
        {"delta0": d0, "t_end": te, "halve_on": h, "safeguard": s, "max_iter": 20000}
        for d0, te in runs
        for h, s in VARIANTS
    ]
    # I_max (not stated in the paper): where the exit flag, and so the first halving, comes
    points += [
        {"delta0": 0.5, "t_end": 0.7, "halve_on": "max_iterations", "safeguard": "floor", "max_iter": k}
        for k in I_MAX_PROBE
    ]
    t0 = time.perf_counter()
    gk1 = run_sweep(gk1_variant, points, out / "cache" / "paper_variants", desc="paper_variants", **opts)
    gk1 = gk1.drop(columns=["cached"])
    gk1.to_csv(out / "paper_variants.csv", index=False)
    record_csv(out / "paper_variants.csv")
    write_markdown(out / "paper_variants.md",
        "# Halving rule and SQP safeguard: the adaptive g1 runs of gk1_records (issue 18)\n\n"
        "alg:MR_JKO_ver2 as written (dt0 = 0.01 carried, eps_t = 5e-6), the paper's SQP (beta = 1000, "
        "log Fisher, I_max = 20000, eps = 1e-10), g1 = exp(-2 v^2), exact T = 0.5.  Defaults: "
        "halve_on = any_failure, safeguard = floor (the first row of each delta0).\n\n"
        + gk1.to_markdown(index=False, floatfmt=".4g")
        + f"\n\nWall time {time.perf_counter() - t0:.1f} s (OPENBLAS_NUM_THREADS=1; cached points count 0).\n"
    )
    cases = [("gamma3_lambda4", 61)]
    if not args.quick:
        cases += [("gamma3_lambda4", 121)] + [(f"gamma1p5_{c}", n) for c in ("before", "after") for n in (41, 61)]
    cpoints = [{"case": c, "n": n, "rule": r} for c, n in cases for r in ("projections", "quadrant")]
    t0 = time.perf_counter()
    cache = out / "cache" / "paper_variants_conc"
    conc = run_sweep(concentration_variant, cpoints, cache, desc="concentration", **opts)
    conc = conc.drop(columns=["cached"])
    conc.to_csv(out / "paper_variants_concentration.csv", index=False)
    record_csv(out / "paper_variants_concentration.csv")
    write_markdown(out / "paper_variants_concentration.md",
        "# Concentration set: projections (default) against the paper's quadrant set (issue 18)\n\n"
        "inhom_gamma3 lambda = 4 at 61 x 61 to t = 2 (quick form) and 121 x 121 to t = 4 (shipped scene); "
        "inhom_gamma1p5 before (lambda = 10) and after (lambda = 5) at 41 x 41 and 61 x 61 to t = 0.6 with the "
        "quick form's density stop sigma_v < 0.05.  Uniform v-spacing: 0.1333 (gamma = 3, 61), 0.06667 (121), "
        "0.25 (gamma = 3/2, 41), 0.1667 (61).  quadrant: "
        "alg:SPMCSL-JKO step 4 (f* on x > 0, v > 0); an empty set gives the uniform grid.\n\n"
        + conc.to_markdown(index=False, floatfmt=".4g")
        + f"\n\nWall time {time.perf_counter() - t0:.1f} s (OPENBLAS_NUM_THREADS=1; cached points count 0).\n"
    )


if __name__ == "__main__":
    main()
