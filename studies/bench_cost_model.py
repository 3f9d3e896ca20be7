"""Newton's collision solve against a LAPACK cost model: iterations times one banded factorisation and solve.

The step of ``studies/bench_collision.py`` -- f* = exp(-2 v^2) on a uniform grid of [-2, 2],
dt = 0.01, strength 1, perspective Fisher term with beta = 10 -- for the power kernels
gamma = 1 and gamma = 3, N = 61, 121, 241 (``--sizes``), solved by ``solve_collision(problem,
"newton")`` at its defaults:

1. **single**: one unbatched problem, with the NumPy iteration and with ``compiled=True`` (numba;
   ``compiled_used`` records that every slice took the compiled path);
2. **batched**: the problem as a batch of B = 32 and B = 121 slices (``--batches``), either B
   identical copies (``same``) or the shifted and scaled Gaussians of ``bench_collision.py``'s
   batch (``perturbed``), with the NumPy iteration and with ``compiled=True`` (one compiled loop over
   the slices); time and iterations per slice;
3. **the cost model**: the LAPACK calls one Newton direction makes, replayed through
   ``scipy.linalg.lapack`` on the very matrices and right-hand sides the solver passed them
   (recorded during one single solve by a proxy of the ``lapack`` module of the collision
   modules, not by editing them): gamma = 1 one ``dpbtrf`` of the pentadiagonal reduced
   Hessian (size N - 1) and one ``dpbtrs``; gamma = 3 one ``dpbtrf`` of G (the pentadiagonal
   part, its positive-definiteness test) and one ``dgbsv`` (kl = ku = 4) of the interleaved
   system of ``Semiseparable3`` (size 2 (N - 1), three right-hand sides).  Per call: the
   calls as the package makes them, wrapper overhead included (a ``dgbsv`` that overwrites its
   matrix gets a fresh copy before each call, whose time is measured alone and subtracted);
   chained: the same systems as one block-diagonal band matrix of B blocks, one call per
   routine (as ``jko_cvx.collision._linalg``'s ``*_batch`` helpers chain them), per slice.
   The model is iterations x per-call time (single solves) and iterations per slice x chained
   time per slice (batches; the ratio against the per-call model is given too);
4. **ratios** time / model per gamma, N and path, and the solver's own time inside LAPACK
   (every LAPACK call of a solve timed through the proxy, ``dptsv`` of the KKT residual and
   the explicit start included) as a share of that solve (wall clock, medians over solves).

Timing: CPU time (``time.process_time``), median over ``--rounds`` rounds of about 10 ms of
repetitions each, every path and model call of one (gamma, N) interleaved in each round.
Then, at N = 121 (``--profile-n``), a profile: wall-clock timers wrapped around the solver's
phases (module attributes replaced for the run and restored) for the single solves (gamma =
1 and 3, NumPy and compiled) and the perturbed batch of 121 slices, and cProfile's top functions
for the compiled single solves and the gamma = 3 NumPy one.

Run with one BLAS thread::

    OPENBLAS_NUM_THREADS=1 python studies/bench_cost_model.py

Writes ``studies/results/bench_cost_model.csv`` (the table) and ``bench_cost_model.md`` (the
table, the model's calls, the profiles, the environment and thread setting).
"""

from __future__ import annotations

import argparse
import cProfile
import datetime
import io
import os
import pstats
import shlex
import statistics
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.linalg import lapack as _scipy_lapack

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.collision import _compiled, _linalg, _structured, newton, sqp
from jko_cvx.collision.problem import CollisionProblem as _ProblemClass
from jko_cvx.environment import git_state, record_csv, write_markdown
from jko_cvx.threads import thread_environment

RESULTS = Path(__file__).resolve().parent / "results"
LAPACK_MODULES = (newton, _linalg, _structured, sqp)  # the collision modules that call scipy's lapack
MODEL_ROUTINES = ("dpbtrf", "dpbtrs", "dgbsv")  # the calls of one Newton direction (gamma = 1 and 3)
LAPACK_LISTED = (*MODEL_ROUTINES, "dptsv")  # the routines a profile lists (dptsv: the KKT residual, the start)
ROUND_S = 0.01  # CPU seconds of repetitions per callable and round


# --------------------------------------------------------------------------- problems
def step_problem(gamma: float, n: int, slices: int = 0, kind: str = "same") -> CollisionProblem:
    """The benchmark step; ``slices`` > 0 makes a batch of identical (``same``) or perturbed slices."""
    grid = Grid.uniform(-2.0, 2.0, n)
    f0 = np.exp(-2 * grid.points**2)
    if slices == 0:
        f = f0
    elif kind == "same":
        f = np.tile(f0, (slices, 1))
    else:  # bench_collision.py's batch: shifted and scaled Gaussians
        rng = np.random.default_rng(0)
        f = np.stack(
            [rng.uniform(0.5, 2) * np.exp(-2 * (grid.points - rng.uniform(-0.3, 0.3)) ** 2) for _ in range(slices)]
        )
    return CollisionProblem(grid, PowerKernel(gamma), f, 0.01, beta=10.0, fisher="perspective")


# --------------------------------------------------------------------------- LAPACK proxy
class LapackProxy:
    """Stands in for ``scipy.linalg.lapack`` in the collision modules: times every call, records some.

    ``seconds[name]`` and ``calls[name]`` accumulate per routine; ``columns[name]`` the band
    columns passed (the chained calls' size); with ``capture`` on, the arguments of the
    routines of :data:`MODEL_ROUTINES` are copied (layout kept) into ``captured``.
    """

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.columns: dict[str, int] = defaultdict(int)
        self.capture = False
        self.captured: list[tuple[str, tuple, dict]] = []
        self._cache: dict[str, Callable] = {}

    def __getattr__(self, name: str) -> Callable:
        if name.startswith("_"):
            raise AttributeError(name)
        cached = self._cache.get(name)
        if cached is not None:
            return cached
        real = getattr(_scipy_lapack, name)

        def timed(*args, **kwargs):
            if self.capture and name in MODEL_ROUTINES:
                copies = tuple(np.array(a, order="K", copy=True) if isinstance(a, np.ndarray) else a for a in args)
                self.captured.append((name, copies, dict(kwargs)))
            t0 = time.perf_counter()
            out = real(*args, **kwargs)
            self.seconds[name] += time.perf_counter() - t0
            self.calls[name] += 1
            band = args[2] if name == "dgbsv" else args[0]
            self.columns[name] += int(np.shape(band)[-1])
            return out

        self._cache[name] = timed
        return timed

    def reset(self) -> None:
        self.seconds.clear()
        self.calls.clear()
        self.columns.clear()
        self.captured.clear()


@contextmanager
def patched(pairs: list[tuple[object, str, object]]):
    """Set ``owner.name = value`` for each triple inside the block; restore the originals after."""
    saved = [(owner, name, owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name))
             for owner, name, _ in pairs]  # fmt: skip
    try:
        for owner, name, value in pairs:
            setattr(owner, name, value)
        yield
    finally:
        for owner, name, value in reversed(saved):
            setattr(owner, name, value)


@contextmanager
def lapack_proxy(proxy: LapackProxy):
    """The collision modules call ``proxy`` for ``lapack`` inside the block."""
    with patched([(mod, "lapack", proxy) for mod in LAPACK_MODULES]):
        yield proxy


# --------------------------------------------------------------------------- timing
def cpu_per_call(fn: Callable[[], object], reps: int) -> float:
    """CPU seconds per call of ``reps`` consecutive calls."""
    c0 = time.process_time()
    for _ in range(reps):
        fn()
    return (time.process_time() - c0) / reps


def interleaved(fns: dict[str, Callable[[], object]], rounds: int) -> dict[str, float]:
    """Median CPU seconds per call of each callable: ``rounds`` rounds, all callables in each, ~10 ms each."""
    for fn in fns.values():  # warm-up
        fn()
    first = {k: max(cpu_per_call(fn, 1), 1e-7) for k, fn in fns.items()}
    reps = {k: max(1, min(20000, round(ROUND_S / t))) for k, t in first.items()}
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(rounds):
        for k, fn in fns.items():
            times[k].append(cpu_per_call(fn, reps[k]))
    return {k: statistics.median(v) for k, v in times.items()}


# --------------------------------------------------------------------------- the cost model
def direction_sets(captured: list[tuple[str, tuple, dict]]) -> list[list[tuple[str, tuple, dict]]]:
    """The recorded calls grouped per Newton direction: each group starts at a ``dpbtrf``."""
    sets: list[list] = []
    for call in captured:
        if call[0] == "dpbtrf" or not sets:
            sets.append([])
        sets[-1].append(call)
    return sets


class Replay:
    """One direction's LAPACK calls, replayed as the solver made them (a fresh matrix where it is overwritten)."""

    def __init__(self, calls: list[tuple[str, tuple, dict]]) -> None:
        self.items = []
        for name, args, kwargs in calls:
            fn = getattr(_scipy_lapack, name)
            refresh = None
            if kwargs.get("overwrite_ab"):
                pos = 2 if name == "dgbsv" else 0
                src = args[pos]
                buf = np.array(src, order="K", copy=True)
                args = (*args[:pos], buf, *args[pos + 1 :])
                refresh = (buf, src)
            self.items.append((name, fn, args, kwargs, refresh))
        self.refreshes = [r for *_, r in self.items if r is not None]

    def routine(self, name: str) -> list[tuple]:
        """The calls of routine ``name``: (function, args, kwargs, refresh or None)."""
        return [(fn, args, kwargs, refresh) for n, fn, args, kwargs, refresh in self.items if n == name]

    def check(self) -> None:
        for name, fn, args, kwargs, refresh in self.items:
            if refresh is not None:
                np.copyto(*refresh)
            if fn(*args, **kwargs)[-1] != 0:
                raise RuntimeError(f"replayed {name} did not succeed")


def _runner(items: list[tuple]) -> Callable[[], None]:
    """Call every recorded call of ``items`` once (a refreshed matrix where the call overwrites it)."""

    def run() -> None:
        for fn, args, kwargs, refresh in items:
            if refresh is not None:
                np.copyto(*refresh)
            fn(*args, **kwargs)

    return run


def _refresher(pairs: list[tuple[np.ndarray, np.ndarray]]) -> Callable[[], None]:
    """The refreshes of a :func:`_runner` alone (their time is subtracted)."""

    def run() -> None:
        for buf, src in pairs:
            np.copyto(buf, src)

    return run


class Chained:
    """The direction systems of ``sets`` (cycled) as one block-diagonal band matrix of ``slices`` blocks.

    One call per routine: ``dpbtrf`` (overwriting a refreshed copy, as
    ``pentadiagonal_cholesky_batch``), then ``dpbtrs`` with the chained factors (gamma = 1, as
    ``pentadiagonal_solve_batch``) or ``dgbsv`` (overwriting a refreshed copy, as
    ``banded_lu_solve_batch``).
    """

    def __init__(self, sets: list[list[tuple[str, tuple, dict]]], slices: int) -> None:
        picks = [sets[b % len(sets)] for b in range(slices)]
        by_name = [{name: args for name, args, _ in s} for s in picks]
        self.refreshes = []
        self.calls = []
        ab = np.asfortranarray(np.concatenate([d["dpbtrf"][0] for d in by_name], axis=1))
        buf = ab.copy(order="F")
        self.refreshes.append((buf, ab))
        self.calls.append(("dpbtrf", lambda buf=buf: _scipy_lapack.dpbtrf(buf, lower=1, overwrite_ab=1)))
        if "dpbtrs" in by_name[0]:
            c = np.asfortranarray(np.concatenate([d["dpbtrs"][0] for d in by_name], axis=1))
            rhs = np.ascontiguousarray(np.concatenate([d["dpbtrs"][1] for d in by_name], axis=0))
            self.calls.append(("dpbtrs", lambda c=c, rhs=rhs: _scipy_lapack.dpbtrs(c, rhs, lower=1)))
        if "dgbsv" in by_name[0]:
            kl, ku = by_name[0]["dgbsv"][:2]
            ab_lu = np.asfortranarray(np.concatenate([d["dgbsv"][2] for d in by_name], axis=1))
            rhs = np.asfortranarray(np.concatenate([d["dgbsv"][3] for d in by_name], axis=0))
            buf_lu = ab_lu.copy(order="F")
            self.refreshes.append((buf_lu, ab_lu))
            self.calls.append(("dgbsv", lambda b=buf_lu, r=rhs: _scipy_lapack.dgbsv(kl, ku, b, r, overwrite_ab=1)))

    def run(self) -> None:
        for buf, src in self.refreshes:
            np.copyto(buf, src)
        for _, call in self.calls:
            call()

    def refresh(self) -> None:
        for buf, src in self.refreshes:
            np.copyto(buf, src)

    def check(self) -> None:
        self.refresh()
        for name, call in self.calls:
            if call()[-1] != 0:
                raise RuntimeError(f"chained {name} did not succeed")


# --------------------------------------------------------------------------- measurements
def paths(gamma: float, n: int, batches: list[int]) -> dict[str, tuple[CollisionProblem, dict]]:
    """The solves of one (gamma, N): label -> (problem, options)."""
    out = {"single": (step_problem(gamma, n), {})}
    out["single compiled"] = (out["single"][0], {"compiled": True})
    for b in batches:
        for kind in ("same", "perturbed"):
            out[f"batch {b} {kind}"] = (step_problem(gamma, n, b, kind), {})
            out[f"batch {b} {kind} compiled"] = (out[f"batch {b} {kind}"][0], {"compiled": True})
    return out


def instrumented(problem: CollisionProblem, opts: dict, repeats: int) -> tuple[object, float, float, float]:
    """One instrumented solve's result, and over ``repeats`` solves the medians of the wall seconds in LAPACK
    (every routine), of the solve's wall seconds, and of the slice-directions (the band columns of the
    direction's factorisation, in blocks); per solve, so that a solve the shared machine interrupted does not
    count."""
    factor = "dgbsv" if problem.kernel.gamma == 3.0 else "dpbtrf"
    block = (2 if factor == "dgbsv" else 1) * (problem.n - 1)
    proxy = LapackProxy()
    lap, wall, units = [], [], []
    with lapack_proxy(proxy):
        for _ in range(repeats):
            proxy.reset()
            t0 = time.perf_counter()
            res = solve_collision(problem, "newton", **opts)
            wall.append(time.perf_counter() - t0)
            lap.append(sum(proxy.seconds.values()))
            units.append(proxy.columns[factor] / block)
    return res, statistics.median(lap), statistics.median(wall), statistics.median(units)


def measure(gamma: float, n: int, batches: list[int], rounds: int) -> tuple[list[dict], dict]:
    """The rows of one (gamma, N) and the model's per-routine call times."""
    cases = paths(gamma, n, batches)
    # the model's systems: recorded during one single solve
    proxy = LapackProxy()
    proxy.capture = True
    with lapack_proxy(proxy):
        solve_collision(cases["single"][0], "newton")
    sets = direction_sets(proxy.captured)
    replays = [Replay(s) for s in sets]
    for r in replays:
        r.check()
    chains = {b: Chained(sets, b) for b in batches}
    for c in chains.values():
        c.check()
    routines = [name for name, _, _ in sets[0]]

    fns: dict[str, Callable[[], object]] = {}
    for label, (prob, opts) in cases.items():
        fns[label] = lambda p=prob, o=opts: solve_collision(p, "newton", **o)
    for name in routines:
        fns[f"call {name}"] = _runner([item for r in replays for item in r.routine(name)])
    fns["call refresh"] = _refresher([pair for r in replays for pair in r.refreshes])
    for b, c in chains.items():
        fns[f"chain {b}"] = c.run
        fns[f"chain {b} refresh"] = c.refresh
    med = interleaved(fns, rounds)
    nsets = len(replays)
    call_s = {name: med[f"call {name}"] / nsets for name in routines}
    refresh_s = med["call refresh"] / nsets
    per_call = sum(call_s.values()) - refresh_s  # one direction through scipy, the copies of overwritten input out
    chain_s = {b: (med[f"chain {b}"] - med[f"chain {b} refresh"]) / b for b in batches}

    rows = []
    for label, (prob, opts) in cases.items():
        slices = prob.batch_size
        res, lapack_s, wall, units = instrumented(prob, opts, 9 if slices == 1 else 3)
        statuses = np.atleast_1d(np.asarray(res.status, dtype=object))
        its = float(np.mean(res.iterations))
        directions = units / slices
        t = med[label] / slices
        row = {
            "gamma": gamma, "N": n, "path": label, "slices": slices,
            "time_us": 1e6 * t, "iterations": its, "directions": directions,
            "converged": sum(s.name == "CONVERGED" for s in statuses),
            "compiled_used": bool(np.all(res.info["compiled"])),
            "lapack_in_solve_us": 1e6 * lapack_s / slices, "lapack_share": lapack_s / wall,
            "model_call_us": 1e6 * per_call,
        }  # fmt: skip
        for name in routines:
            row[f"{name}_call_us"] = 1e6 * call_s[name]
        row["refresh_us"] = 1e6 * refresh_s
        if slices == 1:
            row["model_chain_us"] = np.nan
            row["model_us"] = its * 1e6 * per_call
        else:
            row["model_chain_us"] = 1e6 * chain_s[slices]
            row["model_us"] = its * 1e6 * chain_s[slices]
        row["time/model"] = row["time_us"] / row["model_us"]
        row["time/model_call"] = row["time_us"] / (its * 1e6 * per_call)
        rows.append(row)
        print({k: (round(v, 3) if isinstance(v, float) else v) for k, v in row.items()}, flush=True)
    return rows, {"sets": nsets, "call_us": {k: 1e6 * v for k, v in call_s.items()}, "refresh_us": 1e6 * refresh_s}


# --------------------------------------------------------------------------- profile
PHASES = [
    # (owner, attribute, label, within)
    (newton, "_compiled_single", "newton._compiled_single", "solve"),
    (_compiled, "iterate", "_compiled.iterate (numba)", "_compiled_single"),
    (newton, "_attempt", "newton._attempt", "solve"),
    (newton, "_start", "newton._start", "_attempt"),
    (newton, "_iterate", "newton._iterate", "_attempt"),
    (newton, "_fused", "newton._fused (gradient, bands)", "_iterate"),
    (newton, "_direction", "newton._direction", "_iterate"),
    (newton, "_structured_direction", "newton._structured_direction", "_direction"),
    (newton, "dense_kernel_direction", "_structured.dense_kernel_direction", "_direction"),
    (_structured.Semiseparable3, "_solve_chunk", "Semiseparable3._solve_chunk", "dense_kernel_direction"),
    (_structured, "banded_lu_solve_batch", "_linalg.banded_lu_solve_batch", "_solve_chunk"),
    (_structured, "pentadiagonal_cholesky_batch", "_linalg.pentadiagonal_cholesky_batch (in _structured)",
     "_solve_chunk"),
    (newton, "pentadiagonal_cholesky_batch", "_linalg.pentadiagonal_cholesky_batch (in newton)",
     "_structured_direction"),
    (newton, "pentadiagonal_solve_batch", "_linalg.pentadiagonal_solve_batch", "_structured_direction"),
    (newton, "_residual_test", "newton._residual_test", "_iterate"),
    (_ProblemClass, "kkt_residual", "CollisionProblem.kkt_residual", "_residual_test / _finalise"),
    (newton, "_step", "newton._step", "_iterate"),
    (newton, "_line_search", "newton._line_search", "_step"),
    (newton, "_retire", "newton._retire", "_iterate"),
    (newton, "_finalise", "newton._finalise", "_attempt / _compiled_single"),
    (newton, "certify_validated", "certify_validated", "_finalise"),
]  # fmt: skip


def phase_profile(problem: CollisionProblem, opts: dict, repeats: int) -> pd.DataFrame:
    """Wall time per solve in each phase (inclusive), in LAPACK by routine, and the total: medians over solves."""
    acc: dict[str, float] = defaultdict(float)
    count: dict[str, int] = defaultdict(int)

    def wrap(orig: Callable, label: str) -> Callable:
        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return orig(*args, **kwargs)
            finally:
                acc[label] += time.perf_counter() - t0
                count[label] += 1

        return timed

    pairs = []
    for owner, name, label, _ in PHASES:
        orig = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
        pairs.append((owner, name, wrap(orig, label)))
    proxy = LapackProxy()
    solve_collision(problem, "newton", **opts)  # warm-up
    gamma3 = problem.kernel.gamma == 3.0
    block = (2 if gamma3 else 1) * (problem.n - 1)
    per_solve: dict[str, list[float]] = defaultdict(list)  # seconds per solve, by phase
    calls: dict[str, list[int]] = defaultdict(list)
    with patched(pairs), lapack_proxy(proxy):
        for _ in range(repeats):
            acc.clear()
            count.clear()
            proxy.reset()
            t0 = time.perf_counter()
            solve_collision(problem, "newton", **opts)
            per_solve["total"].append(time.perf_counter() - t0)
            for _, _, label, _ in PHASES:
                per_solve[label].append(acc[label])
                calls[label].append(count[label])
            for name in LAPACK_LISTED:
                per_solve[f"LAPACK {name}"].append(proxy.seconds[name])
                calls[f"LAPACK {name}"].append(proxy.calls[name])
            per_solve["LAPACK, all routines"].append(sum(proxy.seconds.values()))
            calls["LAPACK, all routines"].append(sum(proxy.calls.values()))
            # slice-directions: the band columns the direction's factorisation saw, in blocks
            per_solve["units"].append(proxy.columns["dgbsv" if gamma3 else "dpbtrf"] / block)
    med = {k: statistics.median(v) for k, v in per_solve.items()}
    total = med["total"]
    rows = [{"phase": "solve_collision (total)", "within": "", "us_per_solve": 1e6 * total,
             "calls_per_solve": 1.0, "share": 1.0}]  # fmt: skip
    labels = [(label, within) for _, _, label, within in PHASES]
    labels += [(f"LAPACK {name}", "(proxy)") for name in LAPACK_LISTED]
    labels.append(("LAPACK, all routines", "(proxy)"))
    for label, within in labels:
        if max(calls[label]):
            rows.append({"phase": label, "within": within, "us_per_solve": 1e6 * med[label],
                         "calls_per_solve": statistics.median(calls[label]), "share": med[label] / total})  # fmt: skip
    units = med["units"]
    out = pd.DataFrame(rows)
    out["us_per_slice_direction"] = out["us_per_solve"] / units if units else np.nan
    return out


def c_profile(problem: CollisionProblem, opts: dict, repeats: int, top: int) -> str:
    """cProfile's top ``top`` functions by own time over ``repeats`` solves, as text."""
    solve_collision(problem, "newton", **opts)
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(repeats):
        solve_collision(problem, "newton", **opts)
    prof.disable()
    out = io.StringIO()
    stats = pstats.Stats(prof, stream=out).strip_dirs().sort_stats("tottime")
    stats.print_stats(top)
    lines = out.getvalue().splitlines()
    first = next(i for i, line in enumerate(lines) if "function calls" in line)
    return f"{repeats} solves under cProfile\n" + "\n".join(lines[first:]).rstrip()


# --------------------------------------------------------------------------- report
def _table(df: pd.DataFrame, floatfmt: str = ".3g") -> str:
    return df.to_markdown(index=False, floatfmt=floatfmt)


def targets_section(df: pd.DataFrame, n: int = 121) -> str:
    """The targets at N = ``n``: a single solve within 5x and a batched slice within 2x of the model, per gamma
    and path (NumPy iteration, compiled), from the rows of this run."""
    rows = []
    for (gamma, path), r in df[df.N == n].set_index(["gamma", "path"]).iterrows():
        target = 5.0 if r["slices"] == 1 else 2.0
        rows.append({"gamma": gamma, "path": path, "time/model": r["time/model"], "target": target,
                     "met": bool(r["time/model"] <= target), "compiled_used": r["compiled_used"]})  # fmt: skip
    if not rows:
        return f"## The targets at N = {n}\n\nN = {n} was not measured in this run."
    return (f"## The targets at N = {n}: a single solve within 5x, a batched slice within 2x of the model\n\n"
            + _table(pd.DataFrame(rows)))  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[61, 121, 241])
    ap.add_argument("--gammas", type=float, nargs="+", default=[1.0, 3.0])
    ap.add_argument("--batches", type=int, nargs="+", default=[32, 121])
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--profile-n", type=int, default=121)
    ap.add_argument("--out", type=Path, default=RESULTS / "bench_cost_model.csv")
    args = ap.parse_args(argv)
    commit, dirty = git_state()
    load0 = os.getloadavg()[0]
    wall0 = time.perf_counter()
    for gamma in (1.0, 3.0):  # numba: load (or compile) outside the timings
        solve_collision(step_problem(gamma, 61), "newton", compiled=True)
        solve_collision(step_problem(gamma, 61, 8, "perturbed"), "newton", compiled=True)
    rows, calls = [], []
    for gamma in args.gammas:
        for n in args.sizes:
            r, c = measure(gamma, n, args.batches, args.rounds)
            rows += r
            per_routine = {f"{k}_us": v for k, v in c["call_us"].items()}
            calls.append({"gamma": gamma, "N": n, "systems": c["sets"], **per_routine, "refresh_us": c["refresh_us"]})
    df = pd.DataFrame(rows)
    calls_df = pd.DataFrame(calls)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out, index=False)
    record_csv(args.out)

    pn = args.profile_n
    profiles = []
    for title, gamma, slices, opts, reps in (
        ("gamma = 1, single, compiled=True", 1.0, 0, {"compiled": True}, 400),
        ("gamma = 1, single, NumPy iteration", 1.0, 0, {}, 200),
        ("gamma = 3, single", 3.0, 0, {}, 100),
        ("gamma = 3, single, compiled=True", 3.0, 0, {"compiled": True}, 400),
        ("gamma = 1, batch of 121 perturbed slices (per batched solve)", 1.0, 121, {}, 10),
        ("gamma = 3, batch of 121 perturbed slices (per batched solve)", 3.0, 121, {}, 5),
    ):
        prob = step_problem(gamma, pn, slices, "perturbed")
        profiles.append((f"{title}, {reps} solves", phase_profile(prob, opts, reps)))
    cprofiles = [
        ("gamma = 1, single, compiled=True", c_profile(step_problem(1.0, pn), {"compiled": True}, 400, 15)),
        ("gamma = 3, single", c_profile(step_problem(3.0, pn), {}, 100, 15)),
        ("gamma = 3, single, compiled=True", c_profile(step_problem(3.0, pn), {"compiled": True}, 400, 15)),
    ]
    load1 = os.getloadavg()[0]
    runtime = time.perf_counter() - wall0

    show = ["gamma", "N", "path", "slices", "time_us", "iterations", "directions", "model_call_us", "model_chain_us",
            "model_us", "time/model", "time/model_call", "lapack_in_solve_us", "lapack_share", "converged"]  # fmt: skip
    cmd = shlex.join(["python", "studies/bench_cost_model.py", *(argv if argv is not None else sys.argv[1:])])
    parts = [
        "# Newton's collision solve against the LAPACK cost model (`studies/bench_cost_model.py`)\n\n"
        f"`OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')} {cmd}`, finished "
        f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC on this {os.cpu_count()}-core machine; tree "
        f"{(commit or 'unknown')[:12]}{' (jko_cvx modified)' if dirty else ''}; threads: {thread_environment()}; "
        f"1-minute load {load0:.2f} before, {load1:.2f} after; {runtime:.0f} s in all.\n\n"
        "The step of `bench_collision.py` (f* = exp(-2 v^2) on [-2, 2], dt = 0.01, strength 1, perspective Fisher, "
        "beta = 10), Newton at its defaults (tol 1e-10).  `time_us`: CPU time per solve (single) or per slice "
        f"(batch), median of {args.rounds} interleaved rounds of about 10 ms.  `iterations`: Newton iterations per "
        "slice (mean over a batch); `directions`: Newton directions (LAPACK factorisations) per slice, counted "
        "through the proxy (one more than the iterations: the last direction is computed at the converged point, "
        "where the residual test stops).  `model_call_us`: one direction's LAPACK calls (gamma = 1 dpbtrf + "
        "dpbtrs on N - 1; gamma = 3 dpbtrf of G on N - 1 + dgbsv kl = ku = 4 on 2 (N - 1) with 3 right-hand "
        "sides) through scipy.linalg.lapack, replayed on the systems the solver passed; `model_chain_us`: per "
        "slice of one chained call per routine over as many blocks as the batch has slices.  `model_us` = "
        "iterations x model_call_us (single) or x model_chain_us (batch); `time/model` their ratio, "
        "`time/model_call` the ratio against the per-call model for every row.  `lapack_in_solve_us`: the "
        "solver's own time inside LAPACK per slice (every routine, dptsv included; wall clock, median over 9 "
        "instrumented solves, 3 for a batch), `lapack_share` that time over the instrumented solve's wall time "
        "(median).",
        "## Time against the model\n\n" + _table(df[show]),
        targets_section(df),
        "## The model's LAPACK calls (us per call through scipy, median)\n\n"
        "`systems`: the directions recorded in one single solve (all replayed, the time per system); "
        "`refresh_us`: the copy of a matrix that dgbsv overwrites (subtracted in `model_call_us`).\n\n"
        + _table(calls_df),
    ]
    for title, prof in profiles:
        parts.append(f"## Phases, N = {pn}, {title}: wall us per solve, median over "
                     "the solves (inclusive; `within` names the caller)\n\n"
                     "`us_per_slice_direction`: per solve over the slice-directions of the solve (slices x Newton "
                     "directions, counted through the LAPACK proxy; none on the compiled path).\n\n"
                     + _table(prof, ".4g"))  # fmt: skip
    for title, text in cprofiles:
        parts.append(f"## cProfile, N = {pn}, {title} (top 15 by own time)\n\n```\n{text}\n```")
    text = "\n\n".join(parts) + "\n"
    write_markdown(args.out.with_suffix(".md"), text)
    print(text)
    print(f"wrote {args.out} and {args.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
