"""Do the references certify where another solver does?  Conic and IPOPT on held-out random families.

A reference that fails where another solver certifies is a gap in verification (``jko-cvx verify``
would call such a step unverified).  This study solves each problem with the conic reference
(:func:`~jko_cvx.collision.conic.solve_conic`, where the problem is conic-representable: the
perspective Fisher form or none), the nonlinear reference (:func:`~jko_cvx.collision.nlp.solve_nlp`,
IPOPT), Newton and the paper's SQP, all at their defaults, and judges every returned point by one
yardstick, :func:`~jko_cvx.collision.certify.certify` at the references' own certification
threshold, KKT 1e-6 (their default ``kkt_tol``: the one ``jko-cvx verify`` holds a reference to;
columns ``*_cert``), and at the engine's acceptance threshold
(:data:`~jko_cvx.engine.loop.ACCEPT_KKT`, columns ``*_cert8``, shown, not counted).  A problem counts
against a reference when some other solver's point is certified and the reference's is not (a NONCONVEX
step -- a stationary point that is not a minimiser, or a solver's own report that the step's reduced
Hessian is indefinite -- is a correct answer where no solver finds a certified minimiser).

Families (the first three are ``studies/newton_certification.py``'s, on its held-out seeds):

* ``broad``, ``large_dt``, ``two_bumps``: see that study;
* ``small_dt_graded``: around a step on which the conic reference once returned SOLVER_ERROR
  (N = 80, gamma = 2.85, dt = 1.3e-4, beta = 13.5, spacing ratio 26.5): N = 80,
  gamma ~ U(2.7, 3.0), dt log-uniform in [5e-5, 5e-4], beta log-uniform in [5, 40], spacing
  ratio ~ U(20, 35), the perspective form, densities floored at 1e-8 to 5e-2 of their maximum;
* ``large_dt_no_fisher``: around a step on which it once returned INACCURATE (dt = 0.39,
  beta = inf): dt ~ U(0.3, 0.5), no Fisher term, gamma ~ U(0.5, 5), N in [26, 121], spacing
  ratios up to 50.

Rows are appended to ``studies/results/reference_certification.csv`` with the date, the code
commit, the seed set and the BLAS thread setting, and a section to the Markdown report::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python studies/reference_certification.py LABEL [PER_FAMILY] [SEEDS]

``SEEDS``: ``held_out`` (default) or ``development``.
"""

from __future__ import annotations

import datetime
import os
import time
from pathlib import Path

import numpy as np

from jko_cvx import CollisionProblem, PowerKernel, Status
from jko_cvx.collision import solve_conic, solve_newton, solve_nlp, solve_sqp
from jko_cvx.collision.certify import certify
from jko_cvx.engine.loop import ACCEPT_KKT
from jko_cvx.environment import record_csv
from jko_cvx.testing import random_density
from studies.newton_certification import HELD_OUT_SEEDS, SEEDS, _append, _grid, problems, study_args
from studies.newton_single_call import tree_label

OUT = Path(__file__).parent / "results" / "reference_certification.csv"
NEW_SEEDS = {"small_dt_graded": 9707, "large_dt_no_fisher": 9808}
NEW_HELD_OUT_SEEDS = {"small_dt_graded": 9909, "large_dt_no_fisher": 10010}
SOLVERS = {"conic": solve_conic, "nlp": solve_nlp, "newton": solve_newton, "sqp": solve_sqp}
REFERENCES = ("conic", "nlp")
REFERENCE_KKT = 1e-6
"""The references' default ``kkt_tol``: the threshold every point is judged at."""
TITLE = (
    "# The references against every solver: certification on held-out random families\n\n"
    "One collision step per problem, solved by the conic reference (where the problem is conic-representable), "
    "IPOPT (`method='nlp'`), Newton and the paper's SQP at their defaults; every returned point judged by "
    f"`certify` at the references' threshold {REFERENCE_KKT:g}.  `studies/reference_certification.py`, "
    "one section per run, rows in `reference_certification.csv`.\n\n"
)


def targeted(family: str, count: int, seed: int) -> list[tuple[CollisionProblem, dict]]:
    """The first ``count`` problems of a family drawn around a reference's former failure."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        if family == "small_dt_graded":
            n, gamma = 80, float(rng.uniform(2.7, 3.0))
            grid = _grid(rng, n, float(rng.uniform(20.0, 35.0)))
            f = random_density(rng, grid, floor=float(10 ** rng.uniform(-8, np.log10(0.05))))
            dt = float(10 ** rng.uniform(np.log10(5e-5), np.log10(5e-4)))
            beta, fisher = float(10 ** rng.uniform(np.log10(5), np.log10(40))), "perspective"
        elif family == "large_dt_no_fisher":
            n, gamma = int(rng.integers(26, 122)), float(rng.uniform(0.5, 5.0))
            grid = _grid(rng, n, float(rng.uniform(1.0, 50.0)))
            f = random_density(rng, grid)
            dt, beta, fisher = float(rng.uniform(0.3, 0.5)), np.inf, None
        else:
            raise ValueError(f"unknown family {family!r}")
        P = CollisionProblem(grid, PowerKernel(gamma), f, dt, beta=beta, fisher=fisher)
        out.append((P, {"n": n, "gamma": gamma, "dt": dt, "beta": beta, "cfl": P.cfl()}))
    return out


def run(count: int, seed_set: str) -> list[dict]:
    old, new = (HELD_OUT_SEEDS, NEW_HELD_OUT_SEEDS) if seed_set == "held_out" else (SEEDS, NEW_SEEDS)
    cases = {fam: problems(fam, count, old) for fam in old}
    cases |= {fam: targeted(fam, count, seed) for fam, seed in new.items()}
    rows = []
    for family, items in cases.items():
        for i, (P, par) in enumerate(items):
            row = {"family": family, "index": i, "fisher": P.fisher or "none"}
            row |= {k: f"{v:.4g}" for k, v in par.items()}
            for name, solve in SOLVERS.items():
                if name == "conic" and P.fisher == "log":
                    row |= {name: "n/a", f"{name}_cert": "n/a", f"{name}_cert8": "n/a"}
                    row |= {f"{name}_kkt": "", f"{name}_s": ""}
                    continue
                t = time.perf_counter()
                r = solve(P)
                row[f"{name}_s"] = f"{time.perf_counter() - t:.3f}"
                cert = certify(P, r.f, r.m, kkt_tol=REFERENCE_KKT)
                row |= {
                    name: r.status.name, f"{name}_cert": cert.status.name, f"{name}_kkt": f"{cert.residual:.2e}",
                    f"{name}_cert8": certify(P, r.f, r.m, kkt_tol=ACCEPT_KKT).status.name,
                }
            rows.append(row)
            print(family, i, {k: row[k] for k in ("gamma", "dt", "beta", *(f"{s}_cert" for s in SOLVERS))}, flush=True)
    return rows


def certified(row: dict, name: str) -> bool:
    """The solver's answer is right: its point certified, or NONCONVEX (its point a stationary non-minimiser, or its
    own report that the step's reduced Hessian is indefinite) where no solver's point is certified a minimiser."""
    conv, nonconvex = Status.CONVERGED.name, Status.NONCONVEX.name
    if row[f"{name}_cert"] == conv:
        return True
    said = nonconvex in (row[f"{name}_cert"], row[name])
    return said and not any(row[f"{s}_cert"] == conv for s in SOLVERS)


def summary(rows: list[dict], heading: str) -> str:
    lines = [
        heading,
        "",
        f"Accepted: certified at KKT {REFERENCE_KKT:g}, or NONCONVEX (a stationary point that is not a minimiser, or "
        "the solver's own report of an indefinite reduced Hessian) where no solver's point is certified a minimiser.  "
        "'missed' counts problems where another solver is accepted and the reference is not.",
        "",
        "| family | problems | conic posable | conic accepted | conic missed | nlp accepted | nlp missed "
        "| Newton accepted | SQP accepted | conic median s | nlp median s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for family in dict.fromkeys(r["family"] for r in rows):
        fam = [r for r in rows if r["family"] == family]
        posable = [r for r in fam if r["conic"] != "n/a"]

        def missed(ref: str, pool: list[dict]) -> int:
            return sum(not certified(r, ref) and any(certified(r, s) for s in SOLVERS if s != ref) for r in pool)

        def median_s(name: str, pool: list[dict]) -> str:
            return f"{np.median([float(r[f'{name}_s']) for r in pool]):.3g}" if pool else "-"

        lines.append(
            f"| {family} | {len(fam)} | {len(posable)} | {sum(certified(r, 'conic') for r in posable)} "
            f"| {missed('conic', posable)} | {sum(certified(r, 'nlp') for r in fam)} | {missed('nlp', fam)} "
            f"| {sum(certified(r, 'newton') for r in fam)} | {sum(certified(r, 'sqp') for r in fam)} "
            f"| {median_s('conic', posable)} | {median_s('nlp', fam)} |"
        )
    gaps = [
        r for r in rows
        for ref in REFERENCES
        if r[ref] != "n/a" and not certified(r, ref) and any(certified(r, s) for s in SOLVERS if s != ref)
    ]  # fmt: skip
    keys = ("family", "index", "gamma", "dt", "cfl", "beta", "fisher", *(f"{s}_cert" for s in SOLVERS), "conic_kkt")
    lines += ["", *(f"missed: { {k: r[k] for k in keys} }" for r in gaps)] if gaps else ["", "No reference missed."]
    return "\n".join(lines) + "\n"


def main() -> None:
    label, count, seed_set = study_args(12, "held_out")
    tree = tree_label()
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    rows = run(count, seed_set)
    meta = {"date": date, "commit": tree, "label": label, "threads": threads, "seeds": seed_set}
    _append([meta | r for r in rows], OUT)
    record_csv(OUT)
    text = summary(rows, f"{label} ({tree}, seeds {seed_set}, {date} UTC, OPENBLAS_NUM_THREADS={threads})")
    print(text)
    with OUT.with_suffix(".md").open("a") as fh:
        fh.write((TITLE if fh.tell() == 0 else "\n") + "## " + text)


if __name__ == "__main__":
    main()
