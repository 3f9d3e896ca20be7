"""Benchmark of the issue-15 targets: batched Newton cost against N_v, and whole time steps at 481 and 1025.

Part 1 (batched Newton): the batch of ``studies/bench_threads.py`` (32 slices of the
``inhom_gamma3_lambda4`` datum on its refined v-grid, log Fisher beta = 1000, dt = 0.02,
strength 2, tol = 1e-8), gamma = 3 and 3/2, N_v = 121, 241, 481, 1025, in the default
environment (the package's defaults: :mod:`jko_cvx.threads` thread control and the
structured solves of :mod:`jko_cvx.collision._structured`), side by side with the dense
Cholesky (``JKO_CVX_NEWTON_LINALG=dense``, same process, same thread control; up to
N_v = 481).  Medians of ``--repeats`` solves after a warm-up, wall and process CPU
seconds; the cost exponent p of time ~ N_v^p from 121 to 481 (target: p <= 1.5, every
slice certified: KKT residual <= 1e-8).

Part 2 (time steps): the ``inhom_gamma3_lambda4`` scene (``sec:sp_inhom_gamma_3``, gamma = 3,
lambda = 4, dt = 0.05) with N_x = N_v = 481 and 1025, ``--steps`` steps each (target:
at most 2 s per 481 x 481 step on 2 cores), and the 481 x 481 step with the dense
Cholesky for comparison.  Per step: wall and CPU seconds (the run's total over the
steps, including the initial refinement) and the split into collision, transport and
refinement.

The machine may be shared: the 1-minute load average is recorded with every row.  Run:
``python studies/bench_scale.py [--repeats 3] [--steps 2] [--gammas 3 1.5] [--tag T]``; writes
``studies/results/bench_scale{T}_newton.csv``, ``bench_scale{T}_step.csv`` and ``bench_scale{T}.md``
(the shipped gamma = 4 rows, exact low-rank solves: ``--gammas 4 --no-steps --tag _gamma4``).
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from pathlib import Path

import numpy as np
import pandas as pd
from bench_threads import SCENE, inhom_batch, time_solves

from jko_cvx.collision._structured import LINALG_ENV
from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.scene.model import load_scene
from jko_cvx.studies.sweep import code_identity
from jko_cvx.threads import thread_environment

RESULTS = Path(__file__).parent / "results"


def _with_linalg(mode: str):
    """Set ``JKO_CVX_NEWTON_LINALG`` (read at every Newton direction) and return the previous value."""
    old = os.environ.get(LINALG_ENV)
    os.environ[LINALG_ENV] = mode
    return old


def _restore(old: str | None) -> None:
    if old is None:
        os.environ.pop(LINALG_ENV, None)
    else:
        os.environ[LINALG_ENV] = old


def newton_rows(sizes: list[int], dense_max: int, repeats: int, gammas: tuple[float, ...] = (3.0, 1.5)) -> list[dict]:
    rows = []
    for gamma in gammas:
        for n in sizes:
            problem = inhom_batch(n, gamma)
            for mode in ("auto", "dense"):
                if mode == "dense" and n > dense_max:
                    continue
                old = _with_linalg(mode)
                try:
                    load0 = os.getloadavg()[0]
                    row = time_solves(problem, repeats)
                finally:
                    _restore(old)
                linalg = "structured (default)" if mode == "auto" else "dense Cholesky"
                rows.append({"gamma": gamma, "N_v": n, "linalg": linalg, **row, "load": load0})
    return rows


def step_rows(cases: list[tuple[int, str]], steps: int) -> list[dict]:
    """Time steps of the scene at N_x = N_v = n; records the process's peak resident memory so far.

    The scene-size limit (:mod:`jko_cvx.scene.limits`) estimates 32 B N^2 bytes per slice for
    batched dense Newton Hessians (32 GiB at 1025 x 1025), which the structured and threaded
    directions no longer form; it is raised here to 64 GiB and the measured peak is reported.
    """
    base = load_scene(SCENE)
    rows = []
    os.environ.setdefault("JKO_CVX_MAX_GIB", "64")
    for n, mode in cases:
        scene = base.replace(
            {"x.n": n, "v.n": n, "t_end": steps * base.time.dt, "output.every": 10**6, "output.checkpoint_every": 10**6}
        )
        old = _with_linalg(mode)
        try:
            load0 = os.getloadavg()[0]
            c0, t0 = time.process_time(), time.perf_counter()
            run = simulate(scene)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        finally:
            _restore(old)
        k = max(len(run.diagnostics) - 1, 1)
        rows.append(
            {
                "N_x = N_v": n,
                "linalg": "structured (default)" if mode == "auto" else "dense Cholesky",
                "steps": k,
                "wall_per_step_s": wall / k,
                "cpu_per_step_s": cpu / k,
                "collision_s": run.seconds["collision"] / k,
                "transport_s": run.seconds["transport"] / k,
                "refine_s": run.seconds["refine"] / k,
                "newton_iterations_max": int(run.diagnostics["iterations"].iloc[1:].max()),
                "failed_slices": int(run.diagnostics["failed"].sum()),
                "verdict": run.verdict["reason"],
                "load": load0,
                "load_after": os.getloadavg()[0],
                "peak_rss_gib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20,
            }
        )
        print(rows[-1], flush=True)
    return rows


def exponents(newton: pd.DataFrame) -> pd.DataFrame:
    """Cost exponent p (time ~ N_v^p) from N_v = 121 to 481: two-point and least squares over 121..481."""
    out = []
    for (gamma, linalg), sub in newton.groupby(["gamma", "linalg"]):
        sub = sub.set_index("N_v")
        if not {121, 481} <= set(sub.index):
            continue
        fit = sub.loc[[n for n in sub.index if 121 <= n <= 481]]
        for what in ("median_wall_s", "median_cpu_s"):
            two = np.log(sub.loc[481, what] / sub.loc[121, what]) / np.log(481 / 121)
            lsq = np.polyfit(np.log(fit.index.to_numpy(float)), np.log(fit[what].to_numpy()), 1)[0]
            out.append({"gamma": gamma, "linalg": linalg, "time": what, "p (121 -> 481)": two, "p (fit)": lsq})
    return pd.DataFrame(out)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--steps", type=int, default=2)
    ap.add_argument("--sizes", type=int, nargs="+", default=[121, 241, 481, 1025])
    ap.add_argument("--dense-max", type=int, default=481, help="largest N_v run with the dense Cholesky")
    ap.add_argument("--no-steps", dest="time_steps", action="store_false", help="skip part 2")
    ap.add_argument("--gammas", type=float, nargs="+", default=[3.0, 1.5], help="kernels of part 1")
    ap.add_argument("--tag", default="", help="suffix of the output files (bench_scale{tag}_newton.csv, ...)")
    args = ap.parse_args(argv)
    if args.tag and not args.tag.replace("_", "").isalnum():
        ap.error(f"--tag must be letters, digits and underscores, got {args.tag!r}")
    setting = f"threads: {thread_environment()}; code {code_identity(main)['package_sha256'][:12]}"
    newton = pd.DataFrame(newton_rows(args.sizes, args.dense_max, args.repeats, tuple(args.gammas)))
    RESULTS.mkdir(parents=True, exist_ok=True)
    newton.to_csv(RESULTS / f"bench_scale{args.tag}_newton.csv", index=False)
    record_csv(RESULTS / f"bench_scale{args.tag}_newton.csv")
    print(newton.to_markdown(index=False, floatfmt=".3g"), flush=True)
    fits = exponents(newton)
    steps = pd.DataFrame()
    if args.time_steps:
        steps = pd.DataFrame(step_rows([(481, "auto"), (1025, "auto"), (481, "dense")], args.steps))
        steps.to_csv(RESULTS / f"bench_scale{args.tag}_step.csv", index=False)
        record_csv(RESULTS / f"bench_scale{args.tag}_step.csv")
    text = report(newton, fits, steps, setting)
    write_markdown(RESULTS / f"bench_scale{args.tag}.md", text)
    print(text)


def report(newton: pd.DataFrame, fits: pd.DataFrame, steps: pd.DataFrame, setting: str) -> str:
    wide = newton.pivot_table(index=["gamma", "N_v"], columns="linalg", values=["median_wall_s", "median_cpu_s"])
    wide.columns = [f"{lin} {what.replace('median_', '')}" for what, lin in wide.columns]
    parts = [
        "# Scale targets (issue 15)\n",
        f"{setting}; {os.cpu_count()} cores shared with other users (load averages in the CSVs); "
        f"measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.\n",
        "\n## Batched Newton, 32 slices (median seconds per solve)\n",
        wide.reset_index().to_markdown(index=False, floatfmt=".3g"),
        "\n\n## Cost exponent p, time ~ N_v^p, N_v = 121 to 481 (target p <= 1.5)\n",
        fits.to_markdown(index=False, floatfmt=".2f"),
        "\n\n## Every row\n",
        newton.to_markdown(index=False, floatfmt=".3g"),
    ]
    if len(steps):
        parts += ["\n\n## inhom_gamma3_lambda4 time steps (target: <= 2 s per 481 x 481 step)\n"]
        parts += [steps.to_markdown(index=False, floatfmt=".3g")]
    return "\n".join(parts) + "\n"


if __name__ == "__main__":
    main()
