"""Newton's retry cascade: a baseline commit against this tree on the review families, side by side.

Every step of one seed set of ``studies/newton_certification.py`` (six families of 100 steps) is solved by
Newton at its defaults with the baseline (exported with ``git archive`` and imported as ``jko_cvx_base``, as in
``studies/newton_single_call.py``) and with this tree, interleaved step by step in one process (the order of the
two alternating), CPU time by ``time.process_time``.  Both answers are judged by this tree's ``certify`` at the
engine's acceptance threshold.  The steps fall into groups: certified by both (where the answers must be the
same bit for bit if the change touched only uncertified slices), by this tree only, by the baseline only, and by
neither (those pay every stage of the cascade).

Run::

    OPENBLAS_NUM_THREADS=1 python studies/bench_newton_cascade.py --base f5d75b0 [--seeds review_b]

Writes ``studies/results/bench_newton_cascade.{csv,md}`` (rows appended per run) with the environment.
"""

from __future__ import annotations

import argparse
import datetime
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
from newton_certification import REVIEW_FAMILIES, REVIEW_SEED_SETS, review_problem
from newton_single_call import import_baseline, tree_label

from jko_cvx import Status, solve_collision
from jko_cvx.collision.certify import certify
from jko_cvx.engine.loop import ACCEPT_KKT
from jko_cvx.environment import environment_line, record_csv
from jko_cvx.threads import thread_environment

RESULTS = Path(__file__).parent / "results"
GROUPS = ("both", "tree only", "base only", "neither")


def _base_problem(base, P):
    """The same problem built by the baseline package (same grid points, kernel, datum and parameters)."""
    return base.CollisionProblem(
        base.Grid(P.grid.points), base.PowerKernel(P.kernel.gamma), P.f_star, P.dt, P.strength, P.beta, P.fisher,
        P.conserve_momentum,
    )


def _solve(solve, problem):
    t = time.process_time()
    res = solve(problem, method="newton")
    return res, time.process_time() - t


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="baseline commit")
    ap.add_argument("--seeds", default="review_b", choices=sorted(REVIEW_SEED_SETS))
    ap.add_argument("--per-family", type=int, default=100)
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        base = import_baseline(args.base, Path(tmp))
        k = 0
        for family in REVIEW_FAMILIES:
            for i in range(args.per_family):
                P, par = review_problem(family, i, REVIEW_SEED_SETS[args.seeds])
                Pb = _base_problem(base, P)
                order = ("base", "tree") if k % 2 == 0 else ("tree", "base")
                k += 1
                out = {}
                for side in order:
                    out[side] = _solve(base.solve_collision, Pb) if side == "base" else _solve(solve_collision, P)
                (rb, tb), (rt, tt) = out["base"], out["tree"]
                cb = certify(P, rb.f, rb.m, kkt_tol=ACCEPT_KKT).status is Status.CONVERGED
                ct = certify(P, rt.f, rt.m, kkt_tol=ACCEPT_KKT).status is Status.CONVERGED
                rows.append(
                    {
                        "family": family, "index": i, "gamma": par["gamma"], "cfl": par["cfl"],
                        "group": GROUPS[0] if cb and ct else GROUPS[1] if ct else GROUPS[2] if cb else GROUPS[3],
                        "base_s": tb, "tree_s": tt, "base_iter": int(rb.iterations), "tree_iter": int(rt.iterations),
                        "base_status": rb.status.name, "tree_status": rt.status.name,
                        "same_bits": bool(np.array_equal(rb.f, rt.f) and np.array_equal(rb.m, rt.m)),
                        "trust_region": bool(rt.info.get("trust_region", False)),
                    }
                )  # fmt: skip
    df = pd.DataFrame(rows)
    now = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    df.insert(0, "seeds", args.seeds)
    df.insert(0, "tree", tree_label())
    df.insert(0, "base", args.base)
    df.insert(0, "date", now)
    csv_path = RESULTS / "bench_newton_cascade.csv"
    old = pd.read_csv(csv_path) if csv_path.exists() else None
    (df if old is None else pd.concat([old, df], ignore_index=True)).to_csv(csv_path, index=False)
    record_csv(csv_path)
    summary = (
        df.groupby("group", sort=False)
        .agg(
            steps=("index", "size"),
            base_cpu_s=("base_s", "sum"),
            tree_cpu_s=("tree_s", "sum"),
            median_step_ratio=("tree_s", lambda s: float(np.median(s / df.loc[s.index, "base_s"]))),
            same_bits=("same_bits", "sum"),
            trust_region=("trust_region", "sum"),
        )
        .reindex([g for g in GROUPS if g in set(df.group)])
    )
    summary.insert(3, "tree/base", summary.tree_cpu_s / summary.base_cpu_s)
    section = (
        f"## Seeds {args.seeds}: baseline {args.base}, tree {tree_label()}; {now} UTC\n\n"
        f"{environment_line()}\n\n"
        f"Threads: {thread_environment()}.  {len(df)} steps, CPU time per group (sums, and the median of the per-step "
        "ratios), `same_bits`: steps whose f and m are equal bit for bit between the versions; `trust_region`: "
        "steps whose returned point comes from the trust-region stage.\n\n"
        + summary.to_markdown(floatfmt=".3g")
        + "\n"
    )
    md = RESULTS / "bench_newton_cascade.md"
    head = (
        "# Newton's retry cascade: baseline against this tree on the review families\n\n"
        "`OPENBLAS_NUM_THREADS=1 python studies/bench_newton_cascade.py --base COMMIT --seeds SEEDS`: every step of "
        "the seed set solved by both versions at Newton's defaults, interleaved in one process; certified: "
        f"`certify` at {ACCEPT_KKT:g} on each returned point.  Sections are appended per run, each with its "
        "environment.\n\n"
    )
    text = md.read_text() if md.exists() else head
    md.write_text(text.rstrip("\n") + "\n\n" + section if md.exists() else head + section)
    print(section)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
