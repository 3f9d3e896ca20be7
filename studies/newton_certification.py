"""Certification rate of Newton against the nonlinear reference (IPOPT) on held-out random families.

Three families of one collision step each, drawn from seeds used nowhere else:

* ``broad``: gamma ~ U(0.5, 5), dt log-uniform in [1e-4, 1], beta log-uniform in [1, 1e4] or
  inf (one in three), both Fisher forms, grids with spacing ratios max h / min h up to 50,
  N in [41, 161];
* ``large_dt``: no Fisher term, gamma ~ U(3.5, 3.7), dt chosen for an explicit CFL number
  log-uniform in [20, 300];
* ``two_bumps``: non-uniform grids, two Gaussian bumps, gamma ~ U(3, 4.5), dt ~ U(0.1, 0.5),
  beta = inf.

Each problem is solved by :func:`~jko_cvx.collision.newton.solve_newton` and
:func:`~jko_cvx.collision.nlp.solve_nlp` at their defaults (Newton certifies at KKT 1e-10,
IPOPT at 1e-6).  Both returned points are then judged by one yardstick,
:func:`~jko_cvx.collision.certify.certify` at the engine's acceptance threshold
(:data:`~jko_cvx.engine.loop.ACCEPT_KKT`, columns ``*_cert``) and at 1e-10 (``*_cert10``):
the solvers' own statuses use different tolerances.
Rows are appended to ``studies/results/newton_certification.csv`` with the date, the code
commit, the label, the seed set and the BLAS thread setting; run it once per code version::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python studies/newton_certification.py LABEL [PER_FAMILY] [SEEDS]

``SEEDS``: ``development`` (default; the families the solver was tuned on), ``held_out``
(other seeds of the same families, drawn once a change is made, to measure it) or ``review``:
six families an independent review drew to probe the claim (seed 515000, N in [20, 250],
gamma ~ U(0.5, 5), dt log-uniform in [1e-4, 1], beta log-uniform in [1, 1e4] or inf, scales
of f* from 1e-3 to 1e3): ``offcentre`` (one to three asymmetric bumps off v = 0), ``vacuum``
(tails down to 1e-30 of the peak), ``nonuniform`` (spacing ratios 10-50: random, clustered or
one jump), ``bigcfl`` (no Fisher term, explicit CFL numbers 10-1000), ``special_gamma``
(gamma at 1, 2 or 3, shifted by 0, 1e-6, 1e-3 or 0.05) and ``extreme_dt`` (dt in
[1e-4, 5e-4] or [0.4, 1]); ``review_b`` to ``review_f``: the same generators under other seeds
(``REVIEW_SEED_SETS``; ``review_e`` and ``review_f`` drawn after Newton's trust-region stage was built, to
measure it).
"""

from __future__ import annotations

import csv
import datetime
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status
from jko_cvx.collision import solve_newton
from jko_cvx.collision.certify import certify
from jko_cvx.collision.nlp import solve_nlp
from jko_cvx.engine.loop import ACCEPT_KKT
from jko_cvx.testing import random_density

OUT = Path(__file__).parent / "results" / "newton_certification.csv"
SEEDS = {"broad": 9101, "large_dt": 9202, "two_bumps": 9303}
HELD_OUT_SEEDS = {"broad": 9404, "large_dt": 9505, "two_bumps": 9606}
TITLE = (
    "# Newton against IPOPT: certification on random families\n\n"
    "One collision step per problem, solved by Newton and by IPOPT (`method='nlp'`) at their defaults; "
    "`studies/newton_certification.py`, one section per run, rows in `newton_certification.csv`.\n\n"
)


def _grid(rng: np.random.Generator, n: int, ratio: float, half_width: float = 2.0) -> Grid:
    """Grid on [-half_width, half_width] whose spacings span the ratio max/min = ``ratio``."""
    steps = ratio ** rng.uniform(0.0, 1.0, n - 1)
    steps[rng.integers(n - 1)], steps[rng.integers(n - 1)] = 1.0, ratio  # both ends of the range
    pts = np.concatenate([[0.0], np.cumsum(steps)])
    return Grid(-half_width + 2 * half_width * pts / pts[-1])


def _two_bumps(rng: np.random.Generator, grid: Grid) -> np.ndarray:
    v = grid.points
    a, b = rng.uniform(-1.2, -0.2), rng.uniform(0.2, 1.2)
    return rng.uniform(0.3, 1.0) * np.exp(-rng.uniform(2, 15) * (v - a) ** 2) + rng.uniform(0.3, 1.0) * np.exp(
        -rng.uniform(2, 15) * (v - b) ** 2
    )


def problems(family: str, count: int, seeds: dict[str, int] = SEEDS) -> list[tuple[CollisionProblem, dict]]:
    """The first ``count`` problems of ``family`` with their parameters."""
    rng = np.random.default_rng(seeds[family])
    out = []
    for _ in range(count):
        n = int(rng.integers(41, 162))
        if family == "broad":
            gamma = float(rng.uniform(0.5, 5.0))
            grid = _grid(rng, n, float(rng.uniform(1.0, 50.0)))
            dt = float(10 ** rng.uniform(-4, 0))
            beta = np.inf if rng.uniform() < 1 / 3 else float(10 ** rng.uniform(0, 4))
            fisher = str(rng.choice(["perspective", "log"]))
            f = random_density(rng, grid)
        elif family == "large_dt":
            gamma = float(rng.uniform(3.5, 3.7))
            grid = _grid(rng, n, float(rng.uniform(1.0, 3.0)))
            f = random_density(rng, grid)
            probe = CollisionProblem(grid, PowerKernel(gamma), f, 1.0)
            cfl = float(10 ** rng.uniform(np.log10(20), np.log10(300)))
            dt = cfl / probe.cfl()
            beta, fisher = np.inf, None
        else:
            gamma = float(rng.uniform(3.0, 4.5))
            grid = _grid(rng, n, float(rng.uniform(1.0, 10.0)))
            f = _two_bumps(rng, grid)
            dt = float(rng.uniform(0.1, 0.5))
            beta, fisher = np.inf, None
        P = CollisionProblem(grid, PowerKernel(gamma), f, dt, beta=beta, fisher=fisher)
        out.append((P, {"n": n, "gamma": gamma, "dt": dt, "beta": beta, "cfl": P.cfl()}))
    return out


REVIEW_SEED = 515000
REVIEW_SEED_SETS = {
    "review": REVIEW_SEED, "review_b": 616161, "review_c": 727272, "review_d": 838383, "review_e": 949494,
    "review_f": 105105,
}  # fmt: skip
"""The review's generators under four seeds: ``review`` (the review's draw), ``review_b`` (drawn at a later stop to
measure a change, Newton alone; one of its steps is now a test), ``review_c`` (drawn after the filled start was
built; one of its steps is now a test of ``max_iter``) and ``review_d`` (drawn after that, used for nothing else)."""
REVIEW_FAMILIES = ("offcentre", "vacuum", "nonuniform", "bigcfl", "special_gamma", "extreme_dt")


def _review_grid(rng: np.random.Generator, n: int, ratio: float, half_width: float) -> Grid:
    """A grid on [-half_width, half_width] with spacing ratio ``ratio``: random spacings, a smooth cluster
    (fine about a random centre) or one jump between a fine and a coarse block, one in three each."""
    kind = rng.integers(3)
    if ratio <= 1.0001 or (kind == 0 and ratio < 1.5):
        return Grid.uniform(-half_width, half_width, n)
    if kind == 0:
        return _grid(rng, n, ratio, half_width)
    if kind == 1:
        x = np.linspace(0, 1, n - 1)
        c, w = rng.uniform(0.1, 0.9), rng.uniform(0.03, 0.3)
        steps = 1 + (ratio - 1) * (1 - np.exp(-(((x - c) / w) ** 2)))
        steps[np.argmin(steps)], steps[np.argmax(steps)] = 1.0, ratio
    else:
        steps = np.ones(n - 1)
        k = int(rng.integers(3, n - 4))
        if rng.uniform() < 0.5:
            steps[:k] = ratio
        else:
            steps[k:] = ratio
    pts = np.concatenate([[0.0], np.cumsum(steps)])
    return Grid(-half_width + 2 * half_width * pts / pts[-1])


def _review_bumps(rng: np.random.Generator, v: np.ndarray, half_width: float) -> np.ndarray:
    """One to three bumps off v = 0, each with other widths on its two sides."""
    f = np.zeros_like(v)
    for _ in range(int(rng.integers(1, 4))):
        c, a = rng.uniform(-0.8 * half_width, 0.8 * half_width), 10 ** rng.uniform(-0.3, 1.5)
        aa = np.where(v < c, a, a * 10 ** rng.uniform(-1, 1))
        f += rng.uniform(0.05, 3.0) * np.exp(-aa * (v - c) ** 2)
    return f


def review_problem(family: str, i: int, seed: int | None = None) -> tuple[CollisionProblem, dict]:
    """Problem ``i`` of the review's ``family`` (see the module docstring) with its parameters; ``seed`` defaults to
    ``REVIEW_SEED``."""
    rng = np.random.default_rng([REVIEW_SEED if seed is None else seed, REVIEW_FAMILIES.index(family), i])
    n, L = int(rng.integers(20, 251)), float(rng.uniform(1.5, 3.0))
    gamma, dt = float(rng.uniform(0.5, 5.0)), float(10 ** rng.uniform(-4, 0))
    if rng.uniform() < 0.25:
        beta, fisher = np.inf, None
    else:
        beta, fisher = float(10 ** rng.uniform(0, 4)), str(rng.choice(["perspective", "log"]))
    if family == "offcentre":
        grid = _review_grid(rng, n, float(10 ** rng.uniform(0, 1)), L)
        f = _review_bumps(rng, grid.points, L)
        f = np.maximum(f, 10 ** rng.uniform(-12, -3) * f.max())
    elif family == "vacuum":
        grid = _review_grid(rng, n, float(10 ** rng.uniform(0, 1)), L)
        v, c = grid.points, rng.uniform(-0.5, 0.5) * L
        floor = 10 ** rng.uniform(-30, -8)
        a = -np.log(floor) / (L - abs(c)) ** 2 * rng.uniform(1.0, 3.0)  # at the floor well before the ends
        f = np.exp(-a * (v - c) ** 2)
        if rng.uniform() < 0.5:
            f = f + rng.uniform(0.1, 1) * np.exp(-a * rng.uniform(0.5, 4) * (v - c - rng.uniform(-0.5, 0.5)) ** 2)
        f = np.maximum(f, floor)
    elif family == "nonuniform":
        grid = _review_grid(rng, n, float(rng.uniform(10, 50)), L)
        f = _review_bumps(rng, grid.points, L)
        f = np.maximum(f, 10 ** rng.uniform(-8, -2) * f.max())
    elif family == "bigcfl":
        grid = _review_grid(rng, n, float(10 ** rng.uniform(0, np.log10(20))), L)
        f = _review_bumps(rng, grid.points, L)
        f = np.maximum(f, 10 ** rng.uniform(-6, -1) * f.max())
        beta, fisher = np.inf, None
        f = f * 10 ** rng.uniform(-3, 3)
        dt = float(10 ** rng.uniform(1, 3)) / CollisionProblem(grid, PowerKernel(gamma), f, 1.0).cfl()
    elif family == "special_gamma":
        gamma = float(rng.choice([1.0, 2.0, 3.0])) + float(rng.choice([0.0, 1e-6, -1e-6, 1e-3, -1e-3, 0.05, -0.05]))
        grid = _review_grid(rng, n, float(10 ** rng.uniform(0, np.log10(50))), L)
        f = _review_bumps(rng, grid.points, L)
        f = np.maximum(f, 10 ** rng.uniform(-10, -2) * f.max())
    elif family == "extreme_dt":
        dt = float(10 ** rng.uniform(-4, -3.3)) if rng.uniform() < 0.5 else float(10 ** rng.uniform(-0.4, 0))
        grid = _review_grid(rng, n, float(10 ** rng.uniform(0, np.log10(50))), L)
        f = _review_bumps(rng, grid.points, L)
        f = np.maximum(f, 10 ** rng.uniform(-10, -2) * f.max())
    else:
        raise ValueError(f"family must be one of {REVIEW_FAMILIES}, got {family!r}")
    if family != "bigcfl":
        f = f * 10 ** rng.uniform(-3, 3)
    P = CollisionProblem(grid, PowerKernel(gamma), f, dt, beta=beta, fisher=fisher)
    return P, {"n": n, "gamma": gamma, "dt": dt, "beta": beta, "cfl": P.cfl()}


def study_args(count: int, seed_set: str) -> tuple[str, int, str]:
    """``LABEL [PER_FAMILY] [SEEDS]`` from the command line, with the study's defaults for the last two."""
    label = sys.argv[1] if len(sys.argv) > 1 else "current"
    count = int(sys.argv[2]) if len(sys.argv) > 2 else count
    seed_set = sys.argv[3] if len(sys.argv) > 3 else seed_set
    if seed_set not in ("development", "held_out", *REVIEW_SEED_SETS):
        raise SystemExit(f"SEEDS must be one of {('development', 'held_out', *REVIEW_SEED_SETS)}, got {seed_set!r}")
    return label, count, seed_set


def main() -> None:
    label, count, seed_set = study_args(20, "development")
    seeds = {"development": SEEDS, "held_out": HELD_OUT_SEEDS}.get(seed_set)
    families = tuple(SEEDS) if seeds is not None else REVIEW_FAMILIES

    def family_problems(family: str) -> list[tuple[CollisionProblem, dict]]:
        if seeds is None:
            return [review_problem(family, i, REVIEW_SEED_SETS[seed_set]) for i in range(count)]
        return problems(family, count, seeds)

    commit = subprocess.run(
        ["git", "-C", str(Path(__file__).parent), "describe", "--always", "--dirty"], capture_output=True, text=True
    ).stdout.strip()
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    rows = []
    for family in families:
        for i, (P, par) in enumerate(family_problems(family)):
            t = time.perf_counter()
            rn = solve_newton(P)
            tn = time.perf_counter() - t
            t = time.perf_counter()
            rc = solve_nlp(P)
            tc = time.perf_counter() - t
            gap = float(P.objective(rn.f, rn.m) - P.objective(rc.f, rc.m))
            judged = {
                f"{name}_cert{suffix}": certify(P, r.f, r.m, kkt_tol=tol).status.name
                for name, r in (("newton", rn), ("nlp", rc))
                for suffix, tol in (("", ACCEPT_KKT), ("10", 1e-10))
            }
            rows.append(
                {
                    "date": date, "commit": commit, "label": label, "threads": threads, "family": family, "index": i,
                    **{k: f"{v:.4g}" for k, v in par.items()},
                    "newton": rn.status.name, "newton_kkt": f"{rn.kkt_residual:.2e}", "newton_iter": rn.iterations,
                    "newton_s": f"{tn:.3f}", "nlp": rc.status.name, "nlp_kkt": f"{rc.kkt_residual:.2e}",
                    "nlp_s": f"{tc:.3f}", "objective_gap": f"{gap:.2e}", "seeds": seed_set, **judged,
                }
            )  # fmt: skip
    _append(rows)
    conv = Status.CONVERGED.name
    lines = [
        f"{label} ({commit}, seeds {seed_set}, {date} UTC, OPENBLAS_NUM_THREADS={threads})",
        "",
        "Statuses: each solver's own (Newton at KKT 1e-10, IPOPT at 1e-6); certified: the returned point judged by "
        f"certify at the engine's acceptance threshold {ACCEPT_KKT:g} (and at 1e-10).",
        "",
        "| family | problems | nlp CONVERGED | Newton CONVERGED | nlp certified | Newton certified | Newton certified "
        "where nlp is | same at 1e-10 | both NONCONVEX |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for family in families:
        fam = [r for r in rows if r["family"] == family]
        ref = [r for r in fam if r["nlp_cert"] == conv]
        ref10 = [r for r in fam if r["nlp_cert10"] == conv]
        lines.append(
            f"| {family} | {len(fam)} | {sum(r['nlp'] == conv for r in fam)} | {sum(r['newton'] == conv for r in fam)} "
            f"| {len(ref)} | {sum(r['newton_cert'] == conv for r in fam)} "
            f"| {sum(r['newton_cert'] == conv for r in ref)} / {len(ref)} "
            f"| {sum(r['newton_cert10'] == conv for r in ref10)} / {len(ref10)} "
            f"| {sum(r['nlp'] == r['newton'] == Status.NONCONVEX.name for r in fam)} |"
        )
    missed = [r for r in rows if r["nlp_cert"] == conv and r["newton_cert"] != conv]
    keys = ("family", "index", "gamma", "dt", "cfl", "beta", "newton", "newton_kkt", "nlp_kkt")
    lines += ["", *(f"missed: { {k: r[k] for k in keys} }" for r in missed)] if missed else []
    text = "\n".join(lines) + "\n"
    print(text)
    with (OUT.with_suffix(".md")).open("a") as fh:
        fh.write((TITLE if fh.tell() == 0 else "\n") + "## " + text)


def _append(rows: list[dict], out: Path = OUT) -> None:
    """Append ``rows`` to ``out``, rewriting it with the union of the columns where they differ."""
    old: list[dict] = []
    fields = list(rows[0])
    if out.exists():
        with out.open(newline="") as fh:
            reader = csv.DictReader(fh)
            old = list(reader)
            fields = list(dict.fromkeys([*(reader.fieldnames or []), *fields]))
    with out.open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields, restval="")
        writer.writeheader()
        writer.writerows([*old, *rows])


if __name__ == "__main__":
    main()
