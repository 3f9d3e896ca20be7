"""Newton's fixed per-call cost: this tree against a baseline commit, in one process, bit for bit.

The baseline package is exported from git (``git archive BASE jko_cvx``) into a temporary
folder and imported as ``jko_cvx_base`` (its absolute imports renamed), so both versions run
side by side in one process.  Two parts:

1. **Equality** (``--check``): a family of problems -- gamma 1, 1.5, 2, 3 (and 4 with
   beta = inf at a large step, which goes through the retry cascade and the barrier);
   N 21-481; both Fisher forms; beta 1, 10, 1000, inf; single problems and batches; warm
   starts; ``conserve_momentum`` -- is solved by both versions, and every returned f, m,
   objective, KKT residual, mass error, status, iteration count and ``info`` entry must be
   bitwise the same.  Any difference is printed and the script exits with status 1.
2. **Timing**: the step of ``studies/bench_collision.py`` (gamma = 1, f* = exp(-2 v^2) on
   [-2, 2], dt = 0.01), N = 61-481, perspective and log Fisher, beta = 10 and 1000, through
   ``solve_collision``: the baseline's Newton, this tree's Newton and this tree's SQP,
   interleaved in every round; CPU time (``time.process_time``, which the shared machine's
   load affects least), median over rounds of ``--inner`` solves.  Writes
   ``studies/results/newton_single_call.{csv,md}`` with the environment.

Run with one BLAS thread::

    OPENBLAS_NUM_THREADS=1 python studies/newton_single_call.py --base 90f3581 --check
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

import numpy as np
import pandas as pd

import jko_cvx
from jko_cvx.environment import git_state, record_csv, write_markdown
from jko_cvx.threads import thread_environment

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "studies" / "results"


def tree_label() -> str:
    """This checkout's commit for a benchmark's report: 12 digits, ``(modified)`` where the package differs."""
    commit, dirty = git_state()
    return f"{(commit or 'unknown')[:12]}{' (modified)' if dirty else ''}"


def import_baseline(commit: str, folder: Path):
    """The package at ``commit``, imported as ``jko_cvx_base`` from ``folder``."""
    data = subprocess.run(["git", "archive", commit, "jko_cvx"], cwd=ROOT, capture_output=True, check=True).stdout
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(folder, filter="data")
    pkg = folder / "jko_cvx_base"
    (folder / "jko_cvx").rename(pkg)
    for path in pkg.rglob("*.py"):
        path.write_text(re.sub(r"\bjko_cvx\b", "jko_cvx_base", path.read_text()))
    sys.path.insert(0, str(folder))
    return importlib.import_module("jko_cvx_base")


def _f_star(grid_points: np.ndarray, kind: str, batch: int, rng: np.random.Generator) -> np.ndarray:
    v = grid_points
    if kind == "gauss":
        rows = [np.exp(-2 * v**2)]
    elif kind == "two_bumps":
        rows = [0.9 * np.exp(-12.5 * (v - 0.4) ** 2) + 0.3 * np.exp(-1.5 * (v + 0.3) ** 2)]
    else:  # "random": shifted, scaled Gaussians with a small floor
        rows = []
    while len(rows) < batch:
        rows.append(rng.uniform(0.5, 2) * np.exp(-rng.uniform(1, 8) * (v - rng.uniform(-0.4, 0.4)) ** 2) + 1e-6)
    return np.stack(rows) if batch > 1 else rows[0]


def family(rng: np.random.Generator) -> list[dict]:
    """The problems of the equality check (keyword arguments for :func:`_problem` and the solver)."""
    cases = []
    for gamma in (1.0, 1.5, 2.0, 3.0):
        for n in (21, 61, 121, 241, 481):
            for fisher, beta in (("perspective", 10.0), ("log", 1000.0), ("perspective", 1.0), ("log", np.inf)):
                cases.append(dict(gamma=gamma, n=n, fisher=fisher, beta=beta, dt=0.01, kind="gauss", batch=1))
        for dt in (0.05, 0.3):
            cases.append(dict(gamma=gamma, n=61, fisher="log", beta=10.0, dt=dt, kind="two_bumps", batch=1))
        cases.append(dict(gamma=gamma, n=61, fisher="perspective", beta=10.0, dt=0.01, kind="random", batch=5))
        cases.append(dict(gamma=gamma, n=41, fisher="log", beta=1000.0, dt=0.02, kind="random", batch=12))
        cases.append(dict(gamma=gamma, n=61, fisher="log", beta=10.0, dt=0.01, kind="gauss", batch=1, momentum=True))
        cases.append(dict(gamma=gamma, n=61, fisher="perspective", beta=10.0, dt=0.01, kind="random", batch=4,
                          momentum=True))  # fmt: skip
        cases.append(dict(gamma=gamma, n=61, fisher="perspective", beta=10.0, dt=0.01, kind="gauss", batch=1,
                          warm=True))  # fmt: skip
        cases.append(dict(gamma=gamma, n=41, fisher="log", beta=30.0, dt=0.01, kind="random", batch=6, warm=True))
        cases.append(dict(gamma=gamma, n=61, fisher="perspective", beta=10.0, dt=0.01, kind="gauss", batch=1,
                          options=dict(start="zero", tol=1e-8)))  # fmt: skip
    # the retry cascade and the barrier (issue 34's failing step), and a non-convex step
    cases.append(dict(gamma=4.0, n=121, fisher="perspective", beta=np.inf, dt=0.03, kind="two_bumps", batch=1))
    cases.append(dict(gamma=3.6, n=61, fisher="perspective", beta=np.inf, dt=0.5, kind="random", batch=3))
    cases.append(dict(gamma=3.0, n=61, fisher="perspective", beta=np.inf, dt=2.0, kind="two_bumps", batch=1))
    cases.append(dict(gamma=1.0, n=121, fisher="perspective", beta=30.0, dt=0.01, kind="gauss", batch=1,
                      span=3.0))  # fmt: skip
    return cases


def _problem(pkg, case: dict, rng_seed: int):
    span = case.get("span", 2.0)
    grid = pkg.Grid.uniform(-span, span, case["n"])
    f = _f_star(grid.points, case["kind"], case["batch"], np.random.default_rng(rng_seed))
    return pkg.CollisionProblem(grid, pkg.PowerKernel(case["gamma"]), f, case["dt"], beta=case["beta"],
                                fisher=case["fisher"], conserve_momentum=case.get("momentum", False))  # fmt: skip


def _same(a, b) -> bool:
    """Bitwise equality of two results' fields (NaN equal to NaN)."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if hasattr(a, "name") and hasattr(b, "name"):  # Status of either package
        return a.name == b.name
    a_arr, b_arr = np.asarray(a), np.asarray(b)
    if a_arr.dtype == object or b_arr.dtype == object:
        pairs = zip(a_arr.ravel(), b_arr.ravel(), strict=True)
        return a_arr.shape == b_arr.shape and all(_same(x, y) for x, y in pairs)
    if a_arr.shape != b_arr.shape or a_arr.dtype != b_arr.dtype:
        return False
    if a_arr.dtype.kind == "f":
        return a_arr.tobytes() == b_arr.tobytes()
    return bool(np.array_equal(a_arr, b_arr))


FIELDS = ("f", "m", "status", "iterations", "objective", "kkt_residual", "mass_error", "info")


def check(base) -> list[str]:
    """Solve the family with both versions; the differing fields, as lines."""
    bad = []
    for i, case in enumerate(family(np.random.default_rng(0))):
        results = []
        for pkg in (base, jko_cvx):
            P = _problem(pkg, case, i)
            options = dict(case.get("options", {}))
            if case.get("warm"):
                first = pkg.solve_collision(P, method="newton")
                options["m0"] = first.m * 0.9
            results.append(pkg.solve_collision(P, method="newton", **options))
        a, b = results
        diff = [name for name in FIELDS if not _same(getattr(a, name), getattr(b, name))]
        if case["n"] <= 121 and case["batch"] == 1 and case["kind"] == "gauss" and len(case) == 7:
            # the SQP shares the edge-term derivatives (jko_cvx.collision.terms) with Newton
            sqp = [pkg.solve_collision(_problem(pkg, case, i), method="sqp", max_iter=2000) for pkg in (base, jko_cvx)]
            diff += [f"sqp.{name}" for name in FIELDS[:-1] if not _same(getattr(sqp[0], name), getattr(sqp[1], name))]
        statuses = np.ravel(a.status)
        names = sorted({s.name for s in statuses})
        label = f"case {i}: {case} -> {names}, iterations {np.ravel(a.iterations).tolist()}"
        print(("DIFFERS " + str(diff) + " " if diff else "same    ") + label, flush=True)
        if diff:
            bad.append(f"{label}: {diff}")
    return bad


def timing(base, sizes: list[int], rounds: int, inner: int) -> pd.DataFrame:
    rows = []
    for n in sizes:
        for fisher, beta in (("perspective", 10.0), ("log", 10.0), ("perspective", 1000.0), ("log", 1000.0)):
            case = dict(gamma=1.0, n=n, fisher=fisher, beta=beta, dt=0.01, kind="gauss", batch=1)
            Pb, Pn = _problem(base, case, 0), _problem(jko_cvx, case, 0)
            fns = {
                "base_newton": lambda Pb=Pb: base.solve_collision(Pb, method="newton"),
                "newton": lambda Pn=Pn: jko_cvx.solve_collision(Pn, method="newton"),
                "sqp": lambda Pn=Pn: jko_cvx.solve_collision(Pn, method="sqp"),
            }
            if n == 121 and fisher == "perspective" and beta == 10.0:  # the conic / Newton target
                fns["conic"] = lambda Pn=Pn: jko_cvx.solve_collision(Pn, method="conic")
            last = {k: fn() for k, fn in fns.items()}  # warm-up (conic's compile)
            # ~10 ms of solves per round and method; a method slower than 0.2 s per solve runs 3 rounds
            first = {}
            for k, fn in fns.items():
                t0 = time.process_time()
                fn()
                first[k] = time.process_time() - t0
            reps = {k: max(1, min(inner, round(0.01 / max(t, 1e-6)))) for k, t in first.items()}
            times = {k: [] for k in fns}
            for r in range(rounds):
                for k, fn in fns.items():
                    if first[k] > 0.2 and r >= 3:
                        continue
                    t0 = time.process_time()
                    for _ in range(reps[k]):
                        fn()
                    times[k].append((time.process_time() - t0) / reps[k])
            med = {k: statistics.median(v) for k, v in times.items()}
            row = {"N": n, "fisher": fisher, "beta": beta}
            row.update({f"{k}_ms": 1e3 * v for k, v in med.items()})
            row["newton/base"] = med["newton"] / med["base_newton"]
            row["sqp/newton"] = med["sqp"] / med["newton"]
            row["sqp/base_newton"] = med["sqp"] / med["base_newton"]
            if "conic" in med:
                row["conic/newton"] = med["conic"] / med["newton"]
                row["conic/base_newton"] = med["conic"] / med["base_newton"]
            row["newton_it"] = last["newton"].iterations
            row["sqp_it"] = last["sqp"].iterations
            rows.append(row)
            print(row, flush=True)
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--base", required=True, help="the baseline commit")
    ap.add_argument("--check", action="store_true", help="the bitwise equality check")
    ap.add_argument("--no-timing", dest="timing", action="store_false")
    ap.add_argument("--sizes", type=int, nargs="+", default=[61, 121, 241, 481])
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--inner", type=int, default=10)
    ap.add_argument("--no-write", dest="write", action="store_false", help="print only")
    args = ap.parse_args(argv)
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    dirty = subprocess.run(["git", "status", "--porcelain", "jko_cvx"], cwd=ROOT, capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory() as tmp:
        base = import_baseline(args.base, Path(tmp))
        bad = check(base) if args.check else []
        if args.timing:
            df = timing(base, args.sizes, args.rounds, args.inner)
            if args.write:
                RESULTS.mkdir(exist_ok=True)
                csv = RESULTS / "newton_single_call.csv"
                df.to_csv(csv, index=False)
                record_csv(csv)
                text = (
                    "# Newton's single solve: baseline against this tree, side by side\n\n"
                    f"Baseline {args.base}, tree at {head.strip()}"
                    + (" (with uncommitted changes to jko_cvx)" if dirty.strip() else "")
                    + ".  "
                    "The step of `studies/bench_collision.py` (gamma = 1, f* = exp(-2 v^2) on [-2, 2], "
                    "dt = 0.01, default tolerances) through `solve_collision`; CPU time "
                    f"(`time.process_time`), median over {args.rounds} rounds (3 for a solver slower than "
                    f"0.2 s) of up to {args.inner} solves (about 10 ms), the solvers interleaved in every "
                    "round; conic at N = 121 with the perspective form and beta = 10 only.  "
                    f"Threads: {thread_environment()}; load average {os.getloadavg()[0]:.1f} at the start.  "
                    + ("Every result of the equality family is bitwise the baseline's.\n\n" if args.check and not bad
                       else "\n\n")
                    + df.to_markdown(index=False, floatfmt=".3g")
                    + "\n"
                )  # fmt: skip
                write_markdown(RESULTS / "newton_single_call.md", text)
    if bad:
        print(f"{len(bad)} case(s) differ:\n" + "\n".join(bad))
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
