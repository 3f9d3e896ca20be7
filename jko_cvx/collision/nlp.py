"""The nonlinear reference: the collision step posed in CVXPY's nonlinear mode, solved by IPOPT.

The conic reference (:mod:`jko_cvx.collision.conic`) covers only the perspective Fisher
form and splits the energy into convex and concave parts.  Here the step is posed as it
stands -- either Fisher form, the full quadratic energy -- as one smooth, non-convex
program, solved with ``problem.solve(nlp=True)`` ("disciplined nonlinear programming",
cvxpy.org/tutorial/dnlp) by IPOPT, a primal-dual interior-point method with the exact
Hessian of the Lagrangian (formed by CVXPY's differentiation engine):

.. math::

    \\min_{f \\ge 0,\\ m}\\ \\frac{1}{\\varsigma}\\Big[\\sum_k \\frac{2\\Delta v_k\\, m_k^2}{s_k}
        + \\sum_k \\frac{c}{\\Delta v_k}\\,\\psi(f_k, f_{k+1})
        + \\Delta t\\,\\sigma\\, f^\\top K f\\Big]
    \\quad\\text{s.t.}\\quad h\\odot(f - f^*) + D m = 0
    \\ \\big(\\text{and } \\textstyle\\sum_k m_k \\Delta v_k = 0 \\text{ with } ``conserve\\_momentum``\\big),

with :math:`s_k = f_k + f_{k+1}` and :math:`\\psi` the log form
:math:`\\tfrac12(\\log f_{k+1} - \\log f_k)^2 s_k` (``eqn:non-uniform JKO``) or the
perspective form :math:`2 (f_{k+1} - f_k)^2 / s_k`: exactly :math:`J` of
:class:`~jko_cvx.collision.problem.CollisionProblem`.  :math:`\\varsigma` is the
Wasserstein cost of the explicit step's flux: it makes the objective's gradient O(1)
whatever ``dt`` and ``beta`` (without it IPOPT's absolute dual tolerance is loose by the
factor :math:`1/\\varsigma \\sim 10^5`: measured f error 1.7e-6 against 5e-12 at
N = 81, beta = 100).  The variables are :math:`f/F` and :math:`m/F` with :math:`F = \\max f^*`:
IPOPT's absolute constants (the start is moved ``bound_push`` = 1e-2 away from the bound
:math:`f \\ge 0`) are then relative to the slice, which matters for near-vacuum slices
(:math:`\\max f^* \\sim 10^{-10}`) that would otherwise be moved 1e8-fold.

IPOPT starts from the explicit step (the first step of the paper's SQP, damped to keep
:math:`f \\ge f^*/2`), the same start as Newton's.  All data enter as CVXPY Parameters, so
the model -- and CVXPY's compiled derivative oracles -- are built once per (N, Fisher
form, momentum constraint); every solve still re-runs CVXPY's reduction chain
(canonicalisation), reported apart as ``canonicalize_seconds``.

The result is judged like every other method's (:meth:`CollisionProblem.kkt_residual`
after the projection onto the constraint, then the second-order test); IPOPT's own
outcome is mapped onto :class:`Status` by :data:`IPOPT_STATUS`.  Needs ``cyipopt``
(``pip install "jko_cvx[nlp]"``).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from jko_cvx.collision._linalg import divergence
from jko_cvx.collision.certify import certify
from jko_cvx.collision.options import Options, Spec, option
from jko_cvx.collision.problem import CollisionProblem, KKTResidual
from jko_cvx.collision.result import CollisionResult, Status
from jko_cvx.collision.sqp import explicit_step

__all__ = ["INSTALL_HINT", "IPOPT_STATUS", "NlpModel", "NlpOptions", "nlp_available", "solve_nlp"]

#: IPOPT's return codes (``ApplicationReturnStatus``) onto :class:`Status`.  A
#: ``CONVERGED`` entry is only a candidate: the point must still pass the KKT and
#: second-order tests (:func:`~jko_cvx.collision.certify.certify`).
IPOPT_STATUS: dict[int, Status] = {
    0: Status.CONVERGED,  # Solve_Succeeded
    1: Status.INACCURATE,  # Solved_To_Acceptable_Level (the acceptable_* options)
    2: Status.INFEASIBLE,  # Infeasible_Problem_Detected
    3: Status.NOT_CERTIFIED,  # Search_Direction_Becomes_Too_Small: stopped without convergence
    4: Status.INFEASIBLE,  # Diverging_Iterates (unbounded)
    5: Status.SOLVER_ERROR,  # User_Requested_Stop
    6: Status.SOLVER_ERROR,  # Feasible_Point_Found: square problems only, never ours
    -1: Status.MAX_ITERATIONS,  # Maximum_Iterations_Exceeded
    -2: Status.NUMERICAL_ERROR,  # Restoration_Failed
    -3: Status.NUMERICAL_ERROR,  # Error_In_Step_Computation
    -4: Status.TIME_LIMIT,  # Maximum_CpuTime_Exceeded (option max_cpu_time)
    -5: Status.TIME_LIMIT,  # Maximum_WallTime_Exceeded (option max_wall_time)
    -10: Status.SOLVER_ERROR,  # Not_Enough_Degrees_Of_Freedom
    -11: Status.SOLVER_ERROR,  # Invalid_Problem_Definition
    -12: Status.SOLVER_ERROR,  # Invalid_Option
    -13: Status.NUMERICAL_ERROR,  # Invalid_Number_Detected (NaN or inf from the model)
    -100: Status.SOLVER_ERROR,  # Unrecoverable_Exception
    -101: Status.SOLVER_ERROR,  # NonIpopt_Exception_Thrown
    -102: Status.SOLVER_ERROR,  # Insufficient_Memory
    -199: Status.SOLVER_ERROR,  # Internal_Error
}

#: What to install when IPOPT is missing (also named by the verify reference).
INSTALL_HINT = 'method="nlp" needs IPOPT through cyipopt: pip install "jko_cvx[nlp]" (or pip install cyipopt-wheels)'
# Options this module sets itself (through tol and max_iter) or that would break it.
_RESERVED = {"tol": "tol", "max_iter": "max_iter", "print_level": "verbose", "hessian_approximation": None}
_FRACTION_TO_BOUNDARY = 0.5  # the explicit start keeps f >= f*/2, as Newton's does


def nlp_available() -> bool:
    """True when CVXPY can reach IPOPT (``cyipopt`` importable)."""
    from cvxpy.reductions.solvers.defines import INSTALLED_SOLVERS

    return "IPOPT" in INSTALLED_SOLVERS


@dataclass
class NlpModel:
    """A parameterised CVXPY model of the collision step in nonlinear mode, with its IPOPT oracles."""

    problem: Any  # cp.Problem
    params: dict[str, Any]
    f: Any
    m: Any
    cache: dict[str, Any] = field(default_factory=dict)  # CVXPY's NLP solver cache (the oracles)
    build_seconds: float = 0.0
    iterations: int = 0


_MODEL_CACHE: dict[tuple, NlpModel] = {}


def _build_model(n: int, fisher: str | None, momentum: bool) -> NlpModel:
    """The CVXPY problem for this structure; every number enters through a Parameter."""
    import cvxpy as cp

    p = {
        "f_star": cp.Parameter(n, name="f_star"),
        "h": cp.Parameter(n, nonneg=True, name="h"),
        "wass": cp.Parameter(n - 1, nonneg=True, name="wass"),
        "K": cp.Parameter((n, n), name="K"),
    }
    f = cp.Variable(n, nonneg=True, name="f")
    m = cp.Variable(n - 1, name="m")
    s = f[:-1] + f[1:]
    D = sp.diags([np.ones(n - 1), -np.ones(n - 1)], [0, -1], shape=(n, n - 1)).tocsc()
    # One division per edge: the Wasserstein numerator (and the perspective Fisher one) over s.
    num = cp.multiply(p["wass"], cp.square(m))
    fisher_term = 0
    if fisher is not None:
        p["fisher"] = cp.Parameter(n - 1, nonneg=True, name="fisher")
        if fisher == "perspective":
            num = num + cp.multiply(p["fisher"], cp.square(f[1:] - f[:-1]))
        else:
            logf = cp.log(f)
            fisher_term = cp.sum(cp.multiply(p["fisher"], cp.multiply(cp.square(logf[1:] - logf[:-1]), s)))
    # The full energy f'Kf, no convex-concave split (K is indefinite for gamma > 2).
    obj = cp.sum(num / s) + fisher_term + cp.sum(cp.multiply(f, p["K"] @ f))
    cons = [cp.multiply(p["h"], f - p["f_star"]) + D @ m == 0]
    if momentum:  # sum_k m_k dv_k = 0 (CollisionProblem.conserve_momentum)
        p["dv"] = cp.Parameter(n - 1, nonneg=True, name="dv")
        cons.append(p["dv"] @ m == 0)
    prob = cp.Problem(cp.Minimize(obj), cons)
    if not prob.is_dnlp():  # pragma: no cover - a modelling error, not a data error
        raise RuntimeError("collision NLP model is not DNLP")
    return NlpModel(prob, p, f, m)


def _get_model(n: int, fisher: str | None, momentum: bool) -> tuple[NlpModel, bool]:
    """The cached model for this structure, and whether this call built it."""
    key = (n, fisher, momentum)
    model = _MODEL_CACHE.get(key)
    if model is not None:
        return model, False
    model = _build_model(n, fisher, momentum)
    _MODEL_CACHE[key] = model
    return model, True


def _start(problem: CollisionProblem) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """The explicit step ``(f0, m0)`` (damped to keep f >= f*/2) and its Wasserstein cost.

    The explicit step is the paper's SQP's first step from ``(f*, 0)``, one tridiagonal
    solve (:func:`~jko_cvx.collision.sqp.explicit_step`).  Where it is not finite
    (vacuum edges) the start is ``(f*, 0)``.  The cost :math:`\\varsigma` scales the
    objective (module docstring).
    """
    f_star = problem.f_star
    pf, pm = explicit_step(problem)
    if not (np.all(np.isfinite(pm)) and np.all(np.isfinite(pf))):
        pm, pf = np.zeros(problem.n - 1), np.zeros(problem.n)
    neg = pf < 0
    alpha = min(1.0, _FRACTION_TO_BOUNDARY * float(np.min(-f_star[neg] / pf[neg]))) if np.any(neg) else 1.0
    m0 = alpha * pm
    f0 = f_star - divergence(m0) / problem.grid.h
    s = f_star[:-1] + f_star[1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        cost = float(np.sum(np.where(s > 0, problem.wass_coef * pm**2 / s, 0.0)))
    if not (np.isfinite(cost) and cost > 0):  # no explicit flux: the cost of moving dt * mass once
        cost = (problem.dt * float(problem.mass)) ** 2 * float(problem.grid.dv.sum()) / float(f_star.max())
    return f0, m0, cost


def _fill(model: NlpModel, problem: CollisionProblem, scale: float, unit: float) -> None:
    """Set the Parameters for this problem in the model's units (module docstring).

    The model's variables are :math:`f/F` and :math:`m/F` (``unit`` :math:`F = \\max f^*`);
    the edge terms are 1-homogeneous and the energy 2-homogeneous in :math:`(f, m)`, so
    only the coefficients change; every one is divided by ``scale`` :math:`\\varsigma`.
    """
    prm = model.params
    prm["f_star"].value = problem.f_star / unit
    prm["h"].value = problem.grid.h
    prm["wass"].value = problem.wass_coef * (unit / scale)
    prm["K"].value = (problem.energy_coef * unit**2 / scale) * problem.energy.dense()
    if problem.fisher == "log":
        prm["fisher"].value = 0.5 * problem.fisher_coef * (unit / scale)
    elif problem.fisher == "perspective":
        prm["fisher"].value = 2.0 * problem.fisher_coef * (unit / scale)
    if problem.conserve_momentum:
        prm["dv"].value = problem.grid.dv / problem.grid.dv.max()


class _IterationCounter:
    """IPOPT's intermediate callback: records the iteration count (CVXPY does not report it)."""

    def __init__(self, model: NlpModel) -> None:
        self.model = model

    def __call__(self, alg_mod: int, iter_count: int, *args: Any) -> bool:
        self.model.iterations = int(iter_count)
        return True


def _exact_auxiliaries(canon: Any, own: set[int]) -> None:
    """Start CVXPY's auxiliary variables at their defining values.

    The DNLP canonicalisation replaces ``log(f)`` and ``x / s`` by ``log(t)``, ``x / z``
    with new variables ``t == f``, ``z == s``, started at ``max(value, 1e-3)``: an
    absolute clip, inconsistent with the start wherever a density is below 1e-3 (in units
    of max f*) and IPOPT's ``bound_push`` (default 1e-2, see :func:`_run_ipopt`) is set
    below that.  The defining constraints come innermost first, so one pass sets them all.
    """
    import cvxpy as cp

    for con in canon.constraints:
        var = con.args[0]
        if isinstance(con, cp.constraints.Equality) and isinstance(var, cp.Variable) and var.id not in own:
            val = con.args[1].value
            if val is not None and np.all(np.isfinite(val)):
                var.value = np.maximum(val, 0.0) if var.is_nonneg() else val


def _run_ipopt(model: NlpModel, f0: NDArray, m0: NDArray, options: dict[str, Any], verbose: bool) -> dict[str, Any]:
    """One IPOPT solve of the filled model from ``(f0, m0)``.

    CVXPY's ``solve(nlp=True)`` path, unrolled (``nlp_solving_chain.solve_nlp``, cvxpy 1.9:
    the same reductions for a minimisation, then IPOPT) to keep IPOPT's own return code
    (CVXPY folds several codes into one status), to start the auxiliary variables exactly
    and to time canonicalisation, oracle build and the IPOPT solve apart.
    """
    from cvxpy.reductions.cvx_attr2constr import CvxAttr2Constr
    from cvxpy.reductions.dnlp2smooth.dnlp2smooth import Dnlp2Smooth
    from cvxpy.reductions.solvers.defines import SOLVER_MAP_NLP
    from cvxpy.reductions.solvers.nlp_solvers.nlp_solver import Oracles

    model.f.value, model.m.value = f0, m0
    t0 = time.perf_counter()
    solver = SOLVER_MAP_NLP["IPOPT"]
    canon = model.problem
    for reduction in (CvxAttr2Constr(reduce_bounds=not solver.BOUNDED_VARIABLES), Dnlp2Smooth()):
        canon, _ = reduction.apply(canon)
    _exact_auxiliaries(canon, {model.f.id, model.m.id})
    data, inv = solver.apply(canon)
    # IPOPT moves a start closer than bound_push to a lower bound (here every bound is
    # x >= 0) to bound_push; CVXPY evaluates the first derivatives at the unmoved start,
    # which is 0/0 at vacuum edges.  Move it here, so both see the same point.
    lower = np.isfinite(data["lb"]) & ~np.isfinite(data["ub"])
    push = float(options.get("bound_push", 1e-2)) * np.maximum(1.0, np.abs(data["lb"][lower]))
    data["x0"][lower] = np.maximum(data["x0"][lower], data["lb"][lower] + push)
    t1 = time.perf_counter()
    build = 0.0
    if "oracles" not in model.cache:  # CVXPY's compiled derivative oracles, once per model
        oracles = Oracles(data["_bounds"].new_problem, verbose=verbose, use_hessian=True)
        oracles.intermediate = _IterationCounter(model)
        model.cache["oracles"] = oracles
        build = time.perf_counter() - t1
        model.build_seconds += build
    model.iterations = 0
    t2 = time.perf_counter()
    sol = solver.solve_via_data(data, False, verbose, solver_opts=dict(options), solver_cache=model.cache)
    t3 = time.perf_counter()
    offsets = inv.var_offsets  # f and m keep their ids through the reductions
    x = np.asarray(sol.get("x", np.full(inv.x_length, np.nan)), dtype=float)
    n = model.f.size
    return {
        "code": int(sol["status"]),
        "message": sol.get("status_msg", b"").decode() if isinstance(sol.get("status_msg"), bytes) else "",
        "f": x[offsets[model.f.id] : offsets[model.f.id] + n].copy(),
        "m": x[offsets[model.m.id] : offsets[model.m.id] + n - 1].copy(),
        "iterations": model.iterations,
        "canonicalize_seconds": t1 - t0,
        "build_seconds": build,
        "solver_seconds": t3 - t2,
    }


def _final_point(
    problem: CollisionProblem, f_raw: NDArray, m_raw: NDArray, claimed: Status
) -> tuple[NDArray, NDArray, Status, KKTResidual]:
    """IPOPT's point made feasible (IPOPT meets linear constraints only to its tolerance), with its residual.

    Two feasible points are built from IPOPT's ``(f, m)`` and the one with the smaller KKT
    residual is kept:

    - f projected (:meth:`CollisionProblem.project_feasible`: clipped, moments restored)
      and m rebuilt from it, :math:`m_k = -\\sum_{j\\le k} h_j (f_j - f^*_j)`.  When the
      step barely moves the slice (a floor-level or near-equilibrium slice), that sum
      cancels: m keeps only IPOPT's relative accuracy times :math:`|f|/|f - f^*|`
      (measured: m off by 3.5e-8 relative and a KKT residual of 1.6e-8 at a point within
      5e-16 of Newton's, whose residual is 1e-14);
    - m kept (with ``conserve_momentum``, projected onto :math:`\\sum_k m_k \\Delta v_k = 0`)
      and f rebuilt from it, :math:`f = f^* - Dm/h`, the flux variables Newton works in;
      used only when that f is positive.

    A non-finite point is replaced by ``f*`` and reported ``NUMERICAL_ERROR``.
    """
    if not np.all(np.isfinite(f_raw)):
        f_raw = problem.f_star
        if claimed in (Status.CONVERGED, Status.INACCURATE):
            claimed = Status.NUMERICAL_ERROR
    f, m = problem.project_feasible(f_raw)
    kkt = problem.kkt_residual(f, m)
    m_raw = np.asarray(m_raw, dtype=float)
    if m_raw.shape == m.shape and np.all(np.isfinite(m_raw)):
        m_raw = problem.on_momentum_plane(m_raw)
        f_m = problem.density_from_flux(m_raw)
        if f_m.min() > 0:
            kkt_m = problem.kkt_residual(f_m, m_raw)
            if kkt_m.total < kkt.total:
                return f_m, m_raw, claimed, kkt_m
    return f, m, claimed, kkt


def solve_nlp(
    problem: CollisionProblem,
    *,
    tol: float = 1e-9,
    max_iter: int = 500,
    kkt_tol: float = 1e-6,
    solver_options: dict[str, Any] | None = None,
    check_convexity: bool = True,
    verbose: bool = False,
) -> CollisionResult:
    """Solve the collision step with CVXPY's nonlinear mode and IPOPT (an independent reference).

    Parameters
    ----------
    problem : CollisionProblem
        An unbatched problem, either Fisher form (or none), with or without the momentum
        constraint.  :func:`~jko_cvx.collision.solve.solve_collision` solves a batch slice
        by slice.
    tol : float, default 1e-9
        IPOPT's ``tol`` (its scaled NLP error; the objective is scaled to O(1), see the
        module docstring).
    max_iter : int, default 500
        IPOPT's ``max_iter`` (status ``MAX_ITERATIONS`` beyond).
    kkt_tol : float, default 1e-6
        A point IPOPT reports solved is ``CONVERGED`` only if the scaled KKT residual of
        the projected point is at most this, else ``NOT_CERTIFIED``.
    solver_options : dict, optional
        Further IPOPT options (e.g. ``acceptable_tol``, ``max_cpu_time``, ``mu_strategy``).
        Each is checked against IPOPT before any work is done; ``tol``, ``max_iter`` and
        ``print_level`` go through the arguments above.
    check_convexity : bool, default True
        Second-order test at a certified point (``NONCONVEX`` when it fails).
    verbose : bool, default False
        IPOPT's iteration log (print_level 5).

    Returns
    -------
    CollisionResult
        ``iterations`` are IPOPT's.  ``info`` holds ``ipopt_status`` (IPOPT's return code,
        mapped by :data:`IPOPT_STATUS`), ``ipopt_message``, ``build_seconds`` (model and
        derivative oracles built by this call; 0 when cached), ``model_build_seconds``
        (the cached model's), ``canonicalize_seconds`` (CVXPY's reduction chain, every
        solve), ``solver_seconds`` (IPOPT) and ``scale`` (:math:`\\varsigma`).
        ``seconds`` excludes ``build_seconds``.
    """
    opts = _check_nlp_args(problem, tol, max_iter, kkt_tol, solver_options, check_convexity, verbose)
    t_start = time.perf_counter()
    t0 = time.perf_counter()
    model, built_now = _get_model(problem.n, problem.fisher, problem.conserve_momentum)
    time_model = time.perf_counter() - t0
    if built_now:
        model.build_seconds = time_model
    f0, m0, scale = _start(problem)
    unit = float(problem.f_star.max())
    _fill(model, problem, scale, unit)
    from cvxpy.error import SolverError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # CVXPY's DNLP notices; the status reports the outcome
            run = _run_ipopt(model, f0 / unit, m0 / unit, opts.ipopt(), opts.verbose)
        status = IPOPT_STATUS.get(run["code"], Status.SOLVER_ERROR)
    except (SolverError, ValueError, ArithmeticError) as exc:  # the external solver failed: reported, not raised
        run = {"code": None, "message": f"{type(exc).__name__}: {exc}", "f": problem.f_star / unit, "iterations": 0}
        run.update(canonicalize_seconds=0.0, build_seconds=0.0, solver_seconds=0.0)
        status = Status.SOLVER_ERROR
    build = (time_model if built_now else 0.0) + run["build_seconds"]  # model, then oracles (first solve)
    f, m, claimed, kkt = _final_point(
        problem, unit * run["f"], unit * run.get("m", np.full(problem.n - 1, np.nan)), status
    )
    cert = certify(problem, f, m, kkt_tol=opts.kkt_tol, check_convexity=opts.check_convexity, claimed=claimed, kkt=kkt)
    return CollisionResult.from_certificate(
        problem,
        f,
        m,
        cert,
        "nlp",
        run["iterations"],
        time.perf_counter() - t_start - build,
        {
            "ipopt_status": run["code"],
            "ipopt_message": run["message"],
            "built_now": built_now,
            "build_seconds": build,
            "model_build_seconds": model.build_seconds,
            "canonicalize_seconds": run["canonicalize_seconds"],
            "solver_seconds": run["solver_seconds"],
            "scale": scale,
            "kkt": kkt,
        },
    )


def _check_solver_options(label: str, solver_options: Any) -> dict[str, Any]:
    """Further IPOPT options, each a plain int, float or str accepted by IPOPT; errors name the option."""
    if not isinstance(solver_options, dict):
        raise TypeError(f"{label} must be a dict of IPOPT options, got {type(solver_options).__name__}")
    out: dict[str, Any] = {}
    for key, val in solver_options.items():
        if not isinstance(key, str):
            raise TypeError(f"{label} keys must be IPOPT option names (str), got {key!r}")
        if key in _RESERVED:
            use = _RESERVED[key]
            hint = f"pass {use}= to solve_nlp" if use else "the method needs IPOPT's exact Hessian"
            raise ValueError(f"{label}[{key!r}] is set by method='nlp' itself; {hint}")
        if isinstance(val, (bool, np.bool_)) or not isinstance(val, (int, float, str, np.integer, np.floating)):
            raise TypeError(
                f"{label}[{key!r}] must be an int, float or str (IPOPT's yes/no options are strings), got {val!r}"
            )
        out[key] = val.item() if isinstance(val, (np.integer, np.floating)) else val
    _check_ipopt_options(out)
    return out


_UNIT = Spec("float", lo=0.0, hi=1.0, lo_open=True, hi_open=True)


@dataclass(frozen=True)
class NlpOptions(Options):
    """The options of :func:`solve_nlp`, checked once on construction (see its docstring for each).

    Fields are checked in this order; ``solver_options`` are checked by IPOPT itself, so
    constructing options with them needs ``cyipopt``.
    """

    tol: float = option(1e-9, _UNIT)
    kkt_tol: float = option(1e-6, _UNIT)
    max_iter: int = option(500, Spec("int", lo=1))
    check_convexity: bool = option(True, Spec("bool"))
    verbose: bool = option(False, Spec("bool"))
    # IPOPT's, on the scene allow-list as a table checked against the scene's IPOPT allow-list
    solver_options: dict[str, Any] | None = option(None, Spec("table", check_with=_check_solver_options))

    def ipopt(self) -> dict[str, Any]:
        """The options handed to IPOPT: ``tol``, ``max_iter``, the print level, no banner, then ``solver_options``."""
        opts: dict[str, Any] = {"tol": self.tol, "max_iter": self.max_iter, "print_level": 5 if self.verbose else 0}
        opts["sb"] = "yes"  # no IPOPT banner
        opts.update(self.solver_options or {})
        return opts


def _check_nlp_args(
    problem: CollisionProblem,
    tol: float,
    max_iter: int,
    kkt_tol: float,
    solver_options: dict[str, Any] | None,
    check_convexity: bool,
    verbose: bool,
) -> NlpOptions:
    """Validate the arguments (before any work)."""
    if not nlp_available():
        raise ImportError(INSTALL_HINT)
    if not isinstance(problem, CollisionProblem):
        raise TypeError(f"problem must be a CollisionProblem, got {type(problem).__name__}")
    if problem.batched:
        raise ValueError("method='nlp' solves one problem at a time; pass problem.slice(i) or use solve_collision")
    return NlpOptions(tol=tol, kkt_tol=kkt_tol, max_iter=max_iter, check_convexity=check_convexity, verbose=verbose,
                      solver_options=solver_options)  # fmt: skip


def _check_ipopt_options(options: dict[str, Any]) -> None:
    """Let IPOPT itself accept or reject each option (name, type, range) on a one-variable problem."""
    import cyipopt

    class _Dummy:
        def objective(self, x: NDArray) -> float:
            return 0.0

        def gradient(self, x: NDArray) -> NDArray:
            return np.zeros(1)

    probe = cyipopt.Problem(n=1, m=0, problem_obj=_Dummy(), lb=[0.0], ub=[1.0])
    for key, val in options.items():
        try:
            probe.add_option(key, val)
        except TypeError:
            raise ValueError(
                f"solver_options[{key!r}] = {val!r} is rejected by IPOPT: an unknown option, a value of the wrong "
                "type (IPOPT distinguishes integers from reals) or out of range; IPOPT printed the reason above"
            ) from None
