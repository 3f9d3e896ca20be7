"""Benchmark of ``jko-cvx verify``: its cost against the scene's own run, and the conic reference against N.

Part 1 (verify overhead).  Each scene is run three ways side by side in one process, in each of
``--rounds`` rounds (medians reported, and the range of the ratio with workers): ``simulate``
(the scene's own run) and ``verify`` (the same run, with every step's slices re-solved by the
reference) with the reference solves in this process (``workers=1``: ``verify_1_s``, ``ratio_1``)
and in ``usable_cores()`` worker processes (the default: ``verify_s``, ``ratio``); the ratio of
the wall times to the run's is the overhead, and the two verifications' tables must be equal but
for the solve times.  A one-step verification before them compiles the reference's model (which
forked workers inherit), so neither timing pays for it.  Scenes:

* ``tab_bu_g1`` (homogeneous gamma = 1) at N = 121, perspective Fisher with beta = 30, 10
  steps, Newton against conic;
* ``tab_bu_g1`` as shipped (log Fisher, beta = 6000), 10 steps, Newton against nlp;
* ``inhom_gamma3_lambda4`` at 41 x 41 as shipped (log Fisher, beta = 1000), 2 steps, Newton
  against nlp on every slice;
* ``inhom_gamma3_lambda4`` at 41 x 41 with the perspective form at beta = 30 (the form conic
  poses), Newton against conic, then against nlp; the same at 61 x 61 over 5 steps (the issue's
  target: verify at most 10x the run's time against conic).

Part 2 (the conic solve against N at gamma = 3): f* = exp(-2 v^2) on [-2, 2], dt = 0.01,
perspective Fisher beta = 10, median over ``--repeats`` solves of a warm model cache (the DPP
compile excluded, as in a run), the default truncated split, ``"eigen"`` and ``"diagonal"``; the fitted
growth exponent from N = 121 to the largest N.

Run: ``OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 python studies/bench_verify.py``
(about 3 minutes on 2 shared cores).  Writes ``studies/results/bench_verify.csv`` (part 1),
``bench_verify_conic.csv`` (part 2) and ``bench_verify.md`` (both, with the date, the code
commit and the thread setting).
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.verify import TIMES, verify
from jko_cvx.scene import shipped_scene
from jko_cvx.studies.sweep import code_provenance
from jko_cvx.threads import thread_environment, usable_cores

RESULTS = Path(__file__).parent / "results"


def scenes() -> list[tuple[str, object, str]]:
    g1 = shipped_scene("tab_bu_g1").replace({"t_end": 0.1})
    g3 = shipped_scene("inhom_gamma3_lambda4").replace({"v.n": 41, "x.n": 41, "t_end": 0.1})
    g61 = shipped_scene("inhom_gamma3_lambda4").replace({"v.n": 61, "x.n": 61, "t_end": 0.25})
    persp = {"collision.fisher": "perspective", "collision.beta": 30.0}
    return [
        ("tab_bu_g1 N=121 perspective beta=30", g1.replace(persp), "conic"),
        ("tab_bu_g1 N=121 log beta=6000", g1, "nlp"),
        ("inhom_gamma3_lambda4 41x41 log beta=1000", g3, "nlp"),
        ("inhom_gamma3_lambda4 41x41 perspective beta=30", g3.replace(persp), "conic"),
        ("inhom_gamma3_lambda4 41x41 perspective beta=30", g3.replace(persp), "nlp"),
        ("inhom_gamma3_lambda4 61x61 perspective beta=30 (5 steps)", g61.replace(persp), "conic"),
        ("inhom_gamma3_lambda4 61x61 perspective beta=30 (5 steps)", g61.replace(persp), "nlp"),
    ]


def overhead(rounds: int) -> pd.DataFrame:
    rows = []
    for label, scene, reference in scenes():
        verify(scene.replace({"t_end": scene.time.dt}), reference, workers=1)  # compile the reference's model
        own, wall_1, wall = [], [], []
        for _ in range(rounds):  # the three timings side by side in every round; medians over the rounds
            t0 = time.perf_counter()
            run = simulate(scene)
            own.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            serial = verify(scene, reference, workers=1)
            wall_1.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            ver = verify(scene, reference)  # the default: the reference solves of a step in usable_cores() processes
            wall.append(time.perf_counter() - t0)
            t = ver.table
            keep = [c for c in t.columns if c not in TIMES]
            assert serial.table[keep].equals(t[keep]), "the workers changed the table"
        ratios = np.array(wall) / np.array(own)
        rows.append({
            "scene": label, "method": scene.collision.method, "reference": reference, "steps": run.steps,
            "run_s": float(np.median(own)), "verify_1_s": float(np.median(wall_1)),
            "ratio_1": float(np.median(np.array(wall_1) / np.array(own))), "workers": usable_cores(),
            "verify_s": float(np.median(wall)), "ratio": float(np.median(ratios)),
            "ratio_min": float(ratios.min()), "ratio_max": float(ratios.max()), "slice_solves": len(t),
            "ref_median_s": float(t["seconds_ref"].median()) if len(t) else float("nan"),
            "outcomes": ", ".join(f"{n} {k}" for k, n in t["outcome"].value_counts().items()) if len(t) else "none",
            "max_df": float(t["df"].max()) if len(t) else float("nan"),
            "verdict": ver.verdict,
        })  # fmt: skip
        print(rows[-1])
    return pd.DataFrame(rows)


def conic_growth(sizes: list[int], repeats: int) -> pd.DataFrame:
    rows = []
    for split in ("truncated", "eigen", "diagonal"):
        for n in sizes:
            g = Grid.uniform(-2.0, 2.0, n)
            prob = CollisionProblem(g, PowerKernel(3.0), np.exp(-2 * g.points**2), 0.01, beta=10.0)
            solve_collision(prob, method="conic", dc_split=split)  # compile the model once (a run's cache)
            times, res = [], None
            for _ in range(repeats):
                t0 = time.perf_counter()
                res = solve_collision(prob, method="conic", dc_split=split)
                times.append(time.perf_counter() - t0)
            rows.append({"dc_split": split, "N": n, "median_s": statistics.median(times), "status": res.status.name,
                         "kkt_residual": float(res.kkt_residual), "passes": res.info.get("passes")})  # fmt: skip
            print(rows[-1])
    return pd.DataFrame(rows)


def _exponent(df: pd.DataFrame, split: str) -> float:
    d = df[(df.dc_split == split) & (df.N >= 121)]
    return float(np.polyfit(np.log(d.N), np.log(d.median_s), 1)[0]) if len(d) >= 2 else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[61, 121, 241, 481])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3, help="rounds of the verify-against-run timings (medians)")
    args = ap.parse_args()
    code = code_provenance(verify)
    load0 = os.getloadavg()[0]
    ov = overhead(args.rounds)
    cg = conic_growth(args.sizes, args.repeats)
    RESULTS.mkdir(exist_ok=True)
    ov.to_csv(RESULTS / "bench_verify.csv", index=False)
    cg.to_csv(RESULTS / "bench_verify_conic.csv", index=False)
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    md = [
        "# `jko-cvx verify`: overhead and the conic reference against N (`studies/bench_verify.py`)",
        "",
        f"Finished {stamp} on this 2-core machine; code git {str(code['git_commit'])[:12]} (jko_cvx modified: "
        f"{code['jko_cvx_modified']}); threads: {thread_environment()}; 1-minute load {load0:.2f} before, "
        f"{os.getloadavg()[0]:.2f} after.",
        "",
        f"## Verify against the scene's own run (wall seconds, side by side in each of {args.rounds} rounds; "
        "medians, and the range of the ratio with workers)",
        "",
        ov.drop(columns=["verdict"]).to_markdown(index=False, floatfmt=".3g"),
        "",
        *[f"- {r.scene}: {r.verdict}" for r in ov.itertuples()],
        "",
        f"## One conic solve at gamma = 3 (median of {args.repeats}, model compiled beforehand)",
        "",
        cg.to_markdown(index=False, floatfmt=".3g"),
        "",
        f"Growth exponent N = 121 .. {max(args.sizes)}: truncated split (the default) "
        f"{_exponent(cg, 'truncated'):.2f}, eigen split {_exponent(cg, 'eigen'):.2f}, diagonal split "
        f"{_exponent(cg, 'diagonal'):.2f} (target: at most 1.5).",
        "",
    ]
    (RESULTS / "bench_verify.md").write_text("\n".join(md))
    print("\n".join(md))


if __name__ == "__main__":
    main()
