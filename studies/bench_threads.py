"""Benchmark of BLAS threading for batched Newton: default environment, OPENBLAS_NUM_THREADS=1, the package's control.

Batch: 32 slices of the ``inhom_gamma3_lambda4`` datum (``eqn:f0``, a = b = 6, c = 1.5,
d = 2, L_x = L_v = 4, N_x = 32) on the refined v-grid the engine starts from (one-bump
map, delta0 = 0.02, delta = 0.5), log Fisher beta = 1000, dt = 0.02, strength 2, momentum
conserved, tol = 1e-8; gamma = 3 and 3/2, N_v = 121, 241, 481.  Each configuration runs in
its own process (BLAS reads its environment at start-up), one after the other, so the
medians are taken under the same machine conditions:

* ``default env``: what the package did before issue 15 (BLAS left at its default of
  one thread per core, the dense per-slice Cholesky, no slice threads):
  ``JKO_CVX_BLAS_THREADS=0 JKO_CVX_THREADS=1 JKO_CVX_NEWTON_LINALG=dense``;
* ``OPENBLAS_NUM_THREADS=1``: the same with one BLAS thread;
* ``control, dense``: the package's thread control (:mod:`jko_cvx.threads`: one BLAS
  thread, the slices in two threads, as the package's default was when the shipped results
  were measured) with the dense Cholesky;
* ``control, structured``: thread control as above and :mod:`jko_cvx.collision._structured`
  (the package's default but for the two slice threads).

Every configuration is measured without and with another busy process (``python -c
'while True: pass'``, started for the busy rows and stopped after them).  The machine may
be shared: the 1-minute load average before and after each configuration is recorded.
Times are wall-clock medians over ``--repeats`` solves after one warm-up, and the CPU time
of the process (all its threads) for the same solves.

Run: ``python studies/bench_threads.py [--repeats 3] [--sizes 121 241 481]``.  Writes
``studies/results/bench_threads.csv`` and ``.md`` and prints the tables.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx.environment import record_csv, write_markdown

RESULTS = Path(__file__).parent / "results"
SCENE = Path(__file__).parent / "scenes" / "inhom_gamma3_lambda4.toml"
_JKO = ("JKO_CVX_BLAS_THREADS", "JKO_CVX_THREADS", "JKO_CVX_NEWTON_LINALG", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")
CONFIGS = {
    "default env": {"JKO_CVX_BLAS_THREADS": "0", "JKO_CVX_THREADS": "1", "JKO_CVX_NEWTON_LINALG": "dense"},
    "OPENBLAS_NUM_THREADS=1": {
        "OPENBLAS_NUM_THREADS": "1",
        "JKO_CVX_BLAS_THREADS": "0",
        "JKO_CVX_THREADS": "1",
        "JKO_CVX_NEWTON_LINALG": "dense",
    },
    "control, dense": {"JKO_CVX_THREADS": "2", "JKO_CVX_NEWTON_LINALG": "dense"},
    "control, structured": {"JKO_CVX_THREADS": "2"},
}


def inhom_batch(n_v: int, gamma: float, slices: int = 32, dt: float = 0.02):
    """The benchmark batch (see the module docstring) as a batched CollisionProblem."""

    from jko_cvx import CollisionProblem, PowerKernel
    from jko_cvx.mesh.maps import OneBumpMap
    from jko_cvx.mesh.remapping import remap
    from jko_cvx.scene.model import load_scene

    scene = load_scene(SCENE).replace({"x.n": slices, "v.n": n_v})
    vgrid, xgrid = scene.vgrid(), scene.xgrid()
    f = scene.initial_density(xgrid, vgrid)
    spec = scene.refine.v
    grid = OneBumpMap.from_density(vgrid, f.max(axis=0), spec.delta0, spec.delta).grid(n_v)
    f = np.maximum(remap(vgrid, f, grid, axis=-1, conserve_momentum=True), 1e-300)
    return CollisionProblem(grid, PowerKernel(gamma), f, dt, 2.0, 1000.0, "log", conserve_momentum=True)


def time_solves(problem, repeats: int, tol: float = 1e-8) -> dict:
    """Median wall and CPU seconds of ``repeats`` batched Newton solves (after one warm-up)."""
    from jko_cvx import solve_collision

    res = solve_collision(problem, "newton", tol=tol)
    walls, cpus = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        res = solve_collision(problem, "newton", tol=tol)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    kkt = np.atleast_1d(res.kkt_residual)
    return {
        "median_wall_s": statistics.median(walls),
        "median_cpu_s": statistics.median(cpus),
        "newton_iterations": int(np.sum(res.iterations)),
        "certified": int(np.sum(kkt <= tol)),
        "slices": int(kkt.size),
        "max_kkt": float(kkt.max()),
    }


def blas_setting() -> str:
    """BLAS threads as the libraries report them inside the package's limit, and the slice threads."""
    from threadpoolctl import threadpool_info

    from jko_cvx.threads import blas_limits, slice_workers

    with blas_limits():
        counts = sorted({lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"})
    return f"BLAS threads {counts}, slice threads {slice_workers()}"


def child(args: argparse.Namespace) -> None:
    rows = []
    for gamma in args.gammas:
        for n in args.sizes:
            load0 = os.getloadavg()[0]
            row = time_solves(inhom_batch(n, gamma), args.repeats)
            rows.append({"gamma": gamma, "N_v": n, **row, "load_before": load0, "load_after": os.getloadavg()[0]})
    print(json.dumps({"setting": blas_setting(), "rows": rows}))


def run_config(name: str, args: argparse.Namespace) -> tuple[str, list[dict]]:
    env = {k: v for k, v in os.environ.items() if k not in _JKO}
    env.update(CONFIGS[name])
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[1])
    cmd = [sys.executable, __file__, "--child", "--repeats", str(args.repeats), "--sizes", *map(str, args.sizes)]
    cmd += ["--gammas", *map(str, args.gammas)]
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
    data = json.loads(out.strip().splitlines()[-1])
    return data["setting"], data["rows"]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--sizes", type=int, nargs="+", default=[121, 241, 481])
    ap.add_argument("--gammas", type=float, nargs="+", default=[3.0, 1.5])
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, default=RESULTS / "bench_threads.csv")
    args = ap.parse_args(argv)
    if args.child:
        child(args)
        return
    rows = []
    for busy in (False, True):
        spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"]) if busy else None
        try:
            time.sleep(1.0 if busy else 0.0)
            for name in CONFIGS:
                setting, res = run_config(name, args)
                rows += [{"busy": busy, "config": name, "threads": setting, **r} for r in res]
                print(f"busy={busy} {name}: done ({setting})", flush=True)
        finally:
            if spinner is not None:
                spinner.kill()
                spinner.wait()
    df = pd.DataFrame(rows)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out, index=False)
    record_csv(args.out)
    text = report(df)
    write_markdown(args.out.with_suffix(".md"), text)
    print(text)


def report(df: pd.DataFrame) -> str:
    """Markdown: wall medians side by side, ratios to the default environment, the full table."""
    parts = [
        "# Batched Newton and BLAS threads (32 slices, inhom_gamma3_lambda4 datum, dt = 0.02, tol = 1e-8)\n",
        f"Machine: {os.cpu_count()} cores, shared (1-minute load averages in the CSV); "
        f"measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.\n",
    ]
    for busy, sub in df.groupby("busy"):
        wide = sub.pivot_table(index=["gamma", "N_v"], columns="config", values="median_wall_s")[list(CONFIGS)]
        ratio = wide.div(wide["default env"], axis=0)
        ratio.columns = [f"{c} / default" for c in ratio.columns]
        head = "With" if busy else "Without"
        parts.append(f"\n## {head} another busy process: median wall seconds per batched solve\n")
        table = pd.concat([wide, ratio.iloc[:, 1:]], axis=1).reset_index()
        parts.append(table.to_markdown(index=False, floatfmt=".3g"))
        parts.append("\n")
    cols = ["busy", "config", "gamma", "N_v", "median_wall_s", "median_cpu_s", "newton_iterations", "certified"]
    cols += ["slices", "max_kkt", "load_before", "load_after", "threads"]
    parts.append("\n## All rows\n\n" + df[cols].to_markdown(index=False, floatfmt=".3g") + "\n")
    return "\n".join(parts)


if __name__ == "__main__":
    main()
