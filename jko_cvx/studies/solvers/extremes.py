"""Stability at the extremes: a library of hard collision steps and the outcome matrix.

:func:`extreme_cases` builds named hard problems (tiny and huge dt, vacuum tails down to
1e-30, exact vacuum (compact support), lambda up to 310, grid spacing ratios up to 1e4, the step right before blow-up,
gamma from 1 to 3, N from 21 to 961, beta from 0.1 to infinity).  :func:`extremes_matrix`
runs every solver on every case and classifies each outcome:

* ``certified``: the status says success, the KKT residual recomputed here is at most
  ``kkt_tol``, the point passes the second-order test, mass is exact to 1e-10, f >= 0,
  and f agrees (max-norm, relative ``agree_tol``) with every other certified solution of
  the same case;
* ``certified (other local min)``: as above, but another solver found a different
  certified local minimiser (the step is non-convex for large dt; ``objective_gap`` says
  which is lower);
* ``flagged``: the status says failure (with its message);
* ``silently wrong``: the status says success but one of the checks fails.  Zero for the
  package's solvers is the requirement.

For the conic solvers the raw CVXPY status is kept too (``raw_status``), for nlp IPOPT's
return code (``ipopt 0`` is IPOPT's success): a third-party "optimal" that the package's
certification turned into a failure is counted in ``third_party_caught``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.collision import CollisionProblem, conic_solvers, solve_collision
from jko_cvx.collision.nlp import nlp_available
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.grid import Grid
from jko_cvx.kernels import PowerKernel

__all__ = ["ExtremeCase", "default_solvers", "extreme_cases", "extremes", "extremes_matrix"]


@dataclass(frozen=True)
class ExtremeCase:
    """A named hard problem, built lazily (some builders run a short simulation)."""

    name: str
    build: Callable[[], CollisionProblem]
    heavy: bool = False  # excluded from the quick subset


def _gauss(grid: Grid, rate: float = 2.0) -> np.ndarray:
    return np.exp(-rate * grid.points**2)


def _before_blowup() -> CollisionProblem:
    """The paper's first test's step at t = 0.49 (T = 0.5; the default scene at beta = 1000, where no blow-up rule
    fires before t = 0.5): its refined grid and density, posed with the perspective Fisher term and no momentum
    constraint so that every solver can take it."""
    from jko_cvx.scene.model import default_scene
    from jko_cvx.studies.compare import problem_from_scene

    p = problem_from_scene(default_scene().replace({"collision.beta": 1000.0}), 0.49)
    return CollisionProblem(p.grid, p.kernel, p.f_star, p.dt, p.strength, p.beta, "perspective")


def _ratio_grid(ratio: float, n: int = 121) -> Grid:
    # x = L sinh(k s)/sinh(k): spacing ratio (end/centre) = cosh(k)
    k = float(np.arccosh(ratio))
    s = np.linspace(-1, 1, n)
    return Grid(2 * np.sinh(k * s) / np.sinh(k))


def extreme_cases() -> list[ExtremeCase]:
    """The library of hard collision steps (``heavy`` ones only in the full study)."""
    G = Grid.uniform(-2.0, 2.0, 121)
    G4 = Grid.uniform(-4.0, 4.0, 121)
    r3, r4 = _ratio_grid(1e3), _ratio_grid(1e4)
    wide = Grid.uniform(-7.0, 7.0, 201)

    def case(name, grid, gamma, f, dt, beta=10.0, strength=1.0, heavy=False):
        return ExtremeCase(name, lambda: CollisionProblem(grid, PowerKernel(gamma), f, dt, strength, beta), heavy)

    return [
        case("dt=1e-6, gamma=1", G, 1.0, _gauss(G), 1e-6),
        case("dt=1e-6, gamma=3", G, 3.0, _gauss(G), 1e-6),
        case("dt=1, gamma=1.5", G, 1.5, _gauss(G), 1.0),
        case("dt=3, gamma=2", G, 2.0, _gauss(G), 3.0),
        case("dt=10, gamma=3", G, 3.0, _gauss(G), 10.0),
        case("vacuum tails 1e-30, beta=10", G4, 1.0, np.exp(-4.3 * G4.points**2), 0.01),
        case("vacuum tails 1e-30, beta=inf", G4, 1.0, np.exp(-4.3 * G4.points**2), 0.01, np.inf),
        # exact zeros (compact support): vacuum edges, which no interior iterate of Newton/SQP can start from
        case("vacuum edges (compact support), gamma=2", G, 2.0, np.maximum(1 - G.points**2, 0.0), 0.01),
        case("lambda=310 (strength 155), gamma=2", wide, 2.0, np.exp(-(wide.points**2)), 0.001, 10.0, 155.0),
        case("lambda=310, gamma=2, dt=0.01", wide, 2.0, np.exp(-(wide.points**2)), 0.01, 10.0, 155.0),
        case("spacing ratio 1e3, gamma=1", r3, 1.0, np.exp(-50 * r3.points**2) + 1e-3, 1e-3),
        case("spacing ratio 1e3, gamma=3", r3, 3.0, np.exp(-50 * r3.points**2) + 1e-3, 1e-3),
        case("spacing ratio 1e4, gamma=1", r4, 1.0, np.exp(-50 * r4.points**2) + 1e-3, 1e-3),
        case("spacing ratio 1e4, gamma=3", r4, 3.0, np.exp(-50 * r4.points**2) + 1e-3, 1e-3),
        ExtremeCase("right before blow-up (g1, t = 0.49)", _before_blowup),
        case("gamma=1", G, 1.0, _gauss(G), 0.01),
        case("gamma=1.5", G, 1.5, _gauss(G), 0.01),
        case("gamma=2", G, 2.0, _gauss(G), 0.01),
        case("gamma=3", G, 3.0, _gauss(G), 0.01),
        case("N=21", Grid.uniform(-2.0, 2.0, 21), 1.0, _gauss(Grid.uniform(-2.0, 2.0, 21)), 0.01),
        case(
            "N=961, gamma=1", Grid.uniform(-2.0, 2.0, 961), 1.0, _gauss(Grid.uniform(-2.0, 2.0, 961)), 0.01, heavy=True
        ),
        case("beta=0.1", G, 1.0, _gauss(G), 0.01, 0.1),
        case("beta=1", G, 1.0, _gauss(G), 0.01, 1.0),
        case("beta=inf", G, 1.0, _gauss(G), 0.01, np.inf),
    ]


def default_solvers() -> dict[str, tuple[str, dict]]:
    """The package's solvers, every installed conic solver and nlp (IPOPT) when installed."""
    out = {
        "newton": ("newton", {}),
        "newton:tol=1e-8": ("newton", {"tol": 1e-8}),  # the tolerance the study engine runs at
        "sqp:banded": ("sqp", {"max_iter": 20000}),
        # each iteration is one OSQP solve (up to 0.4 s where ADMM struggles, lambda = 310): I_max = 50
        "sqp:osqp": ("sqp", {"qp": "osqp", "max_iter": 50}),
    }
    for solver in conic_solvers():
        opts: dict = {"solver": solver}
        if solver == "SCS":  # first-order: bound its work (it otherwise runs for minutes on gamma = 3)
            opts.update(tol=1e-6, solver_options={"max_iters": 5000})
        out[f"conic:{solver}"] = ("conic", opts)
    if nlp_available():  # bounded like the other external solvers: IPOPT's CPU-time limit
        out["nlp"] = ("nlp", {"solver_options": {"max_cpu_time": 60.0}})
    return out


def extremes_matrix(
    cases: list[ExtremeCase] | None = None,
    solvers: dict[str, tuple[str, dict]] | None = None,
    kkt_tol: float = 1e-6,
    agree_tol: float = 1e-3,
    quick: bool = False,
    progress: bool = False,
) -> pd.DataFrame:
    """Run every solver on every case; one row per (case, solver) with the classified outcome.

    Parameters
    ----------
    cases : list of ExtremeCase, optional
        Default :func:`extreme_cases` (without the ``heavy`` ones when ``quick``).
    solvers : dict, optional
        Label -> (method, options); default :func:`default_solvers`.
    kkt_tol : float, default 1e-6
        Certification threshold on the recomputed KKT residual.
    agree_tol : float, default 1e-3
        Cross-check: certified solutions of one case agree in max-norm to
        ``agree_tol * max f``.
    quick : bool, default False
        Skip the heavy cases.
    progress : bool, default False
        A tqdm bar over the cases.
    """
    cases = extreme_cases() if cases is None else cases
    if quick:
        cases = [c for c in cases if not c.heavy]
    solvers = default_solvers() if solvers is None else solvers
    rows = []
    from tqdm.auto import tqdm

    for case in tqdm(cases, desc="extremes", disable=not progress):
        prob = case.build()
        results = {}
        for label, (method, opts) in solvers.items():
            t0 = time.perf_counter()
            try:
                res = solve_collision(prob, method, **opts)
                err = None
            except Exception as exc:  # a solver crash is a flagged failure, recorded with its message
                res, err = None, f"{type(exc).__name__}: {exc}"
            results[label] = (res, err, time.perf_counter() - t0)
        checks = {label: _checks(prob, res, kkt_tol) for label, (res, _e, _s) in results.items() if res is not None}
        certified = {label: results[label][0] for label, c in checks.items() if results[label][0].success and c == ""}
        fmax = max((float(r.f.max()) for r in certified.values()), default=1.0)
        for label, (res, err, seconds) in results.items():
            row: dict[str, Any] = {"case": case.name, "solver": label, "seconds": seconds}
            if res is None:
                row.update(status="EXCEPTION", outcome="flagged", kkt=np.nan, message=err, raw_status="")
                rows.append(row)
                continue
            kkt = float(prob.kkt_residual(res.f, res.m).total)
            raw = _raw_status(label, res)
            message = ""
            if not res.success:
                outcome, message = "flagged", res.message
            elif checks[label]:
                outcome, message = "silently wrong", checks[label]
            else:
                other = {
                    o: r for o, r in certified.items() if o != label and np.abs(res.f - r.f).max() > agree_tol * fmax
                }
                if not other:
                    outcome = "certified"
                else:
                    # two certified local minimisers: the step is non-convex, both answers are honest
                    best = min(r.objective for r in other.values())
                    outcome = "certified (other local min)"
                    message = f"differs from {', '.join(other)}; objective {res.objective - best:+.3g} vs theirs"
            row.update(
                status=res.status.name,
                outcome=outcome,
                kkt=kkt,
                message=message,
                raw_status=raw,
                third_party_caught=bool(raw in ("optimal", "optimal_inaccurate", "ipopt 0") and not res.success),
            )
            rows.append(row)
    return pd.DataFrame(rows)


def _raw_status(label: str, res) -> str:
    """The external solver's own verdict: CVXPY's status for conic, IPOPT's return code for nlp."""
    if label.startswith("conic"):
        return str(res.info.get("solver_status", ""))
    if label.startswith("nlp"):
        code = res.info.get("ipopt_status")
        return "" if code is None else f"ipopt {code}"
    return ""


def _checks(prob: CollisionProblem, res, kkt_tol: float) -> str:
    """Why a returned solution is not certifiable ("" when it is), checked here whatever the status says."""
    why = []
    if not np.all(np.isfinite(res.f)):
        why.append("non-finite f")
    else:
        kkt = float(prob.kkt_residual(res.f, res.m).total)
        if not kkt <= kkt_tol:
            why.append(f"KKT residual {kkt:.1e} > {kkt_tol:g}")
        if res.f.min() < 0:
            why.append(f"negative f ({res.f.min():.1e})")
        if not float(prob.mass_error(res.f)) <= 1e-10:
            why.append("mass not conserved")
        if not why and not prob.is_local_minimiser(res.f, res.m):
            why.append("not a local minimiser (second-order test)")
    return "; ".join(why)


_PACKAGE = ("newton", "newton:tol=1e-8", "sqp:banded", "sqp:osqp") + (("nlp",) if nlp_available() else ())


def extremes(out: Path, quick: bool = False, **_sweep_opts: Any) -> pd.DataFrame:
    """The full matrix as a study: writes ``extremes.{csv,md}`` (outcome matrix, counts, failures)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    df = extremes_matrix(quick=quick, progress=True)
    df.to_csv(out / "extremes.csv", index=False)
    record_csv(out / "extremes.csv")
    matrix = df.pivot(index="case", columns="solver", values="outcome").reindex(df.case.unique())
    short = {
        "certified": "ok",
        "certified (other local min)": "ok (local)",
        "flagged": "FLAGGED",
        "silently wrong": "SILENTLY WRONG",
    }
    status = df.pivot(index="case", columns="solver", values="status").reindex(df.case.unique())
    cell = matrix.map(lambda o: short.get(o, o)) + " (" + status + ")"
    counts = df.groupby(["solver", "outcome"]).size().unstack(fill_value=0)
    counts["third-party optimal caught"] = df.groupby("solver").third_party_caught.sum().astype(int)
    counts["package solver"] = [s in _PACKAGE for s in counts.index]
    not_ok = df[df.outcome.isin(["flagged", "silently wrong", "certified (other local min)"])]
    wrong_package = int(((df.outcome == "silently wrong") & df.solver.isin(_PACKAGE)).sum())
    text = (
        "# Stability at the extremes\n\n"
        f"Every solver on every hard case.  Silently wrong outcomes of the package's solvers: **{wrong_package}**.\n"
        "A third-party solver's success is re-certified by the KKT residual (`third_party_caught`: raw\n"
        "status optimal, turned into a failure by the package).\n\n"
        "## Outcome matrix (outcome and status)\n\n"
        + cell.reset_index().to_markdown(index=False)
        + "\n\n## Counts\n\n"
        + counts.reset_index().to_markdown(index=False)
        + "\n\n## Every outcome that is not a plain certified solve\n\n"
        + not_ok[["case", "solver", "status", "outcome", "raw_status", "kkt", "message"]].to_markdown(
            index=False, floatfmt=".2g"
        )
        + "\n"
    )
    write_markdown(out / "extremes.md", text)
    return df
