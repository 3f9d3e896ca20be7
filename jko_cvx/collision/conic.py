"""The conic reference: the collision step posed in CVXPY, solved by Clarabel (or SCS, ...).

Model (in scaled variables :math:`\\delta = (f - f^*)/\\mu`, :math:`\\hat m = m/\\mu`,
:math:`\\hat t = t/\\mu^2`, with :math:`\\mu` the size of the explicit-Euler flux, so that
every variable is O(1) whatever ``dt``):

.. math::

    \\min\\ \\frac{1}{\\varsigma}\\Big[\\sum_k 2\\Delta v_k \\mu^2 \\hat t_k
        + \\sum_k \\frac{2c\\mu^2}{\\Delta v_k} q_k
        + \\mu^2 \\|P_+\\delta\\|^2 + \\mu\\, \\ell^\\top \\delta\\Big]

    \\text{s.t.}\\quad \\hat m_k^2 \\le s_k \\hat t_k,\\quad
    (\\delta_{k+1}-\\delta_k - r_k(\\delta_k+\\delta_{k+1}))^2 \\le s_k q_k
    \\quad(\\text{rotated cones, one vectorised SOC each}),

    h\\odot\\delta + D\\hat m = 0,\\qquad f = f^* + \\mu\\delta \\ge 0,

with :math:`s_k = f_k + f_{k+1}` and :math:`r_k = (f^*_{k+1}-f^*_k)/(f^*_{k+1}+f^*_k)`.
This is the *centred* Fisher cone (``fisher_cone="centred"``): the perspective is
1-homogeneous, so its tangent plane at :math:`f^*` passes through 0 and
:math:`d^2/s = (d - r s)^2/s + 2 r d - r^2 s`; the cone variable stays O(1) however
small the step, and the linear remainder (the Fisher gradient at :math:`f^*`) sits in
:math:`\\ell` with the energy gradient.  The *raw* cone :math:`(f_{k+1}-f_k)^2 \\le s_k q_k`
is better conditioned for larger steps on rough data; ``"auto"`` picks by step size.

The energy enters through the difference-of-convex split of :mod:`jko_cvx.kernels`
(restricted to mass-free directions, exact on the feasible set): the convex part
:math:`\\|P_+\\delta\\|^2` stays quadratic and the concave part is linearised at the
current iterate inside :math:`\\ell` (convex-concave procedure).  Every fixed point is a
KKT point of the full problem.  All data enter as CVXPY Parameters (the model is DPP), so the model is compiled
once per (N, Fisher on/off, rank of :math:`P_+`, solver) and re-solved thereafter.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Any

import cvxpy as cp
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .problem import CollisionProblem
from .result import CollisionResult, Status

__all__ = ["ConicModel", "conic_solvers", "solve_conic"]

_ENERGY_MODES = ("dc", "linearized")


def conic_solvers() -> list[str]:
    """Installed CVXPY solvers that accept second-order cones (Clarabel first)."""
    from cvxpy.reductions.solvers.defines import INSTALLED_CONIC_SOLVERS, SOLVER_MAP_CONIC

    out = []
    for name in INSTALLED_CONIC_SOLVERS:
        solver = SOLVER_MAP_CONIC.get(name)
        if solver is not None and cp.SOC in solver.SUPPORTED_CONSTRAINTS:
            out.append(name)
    return sorted(out, key=lambda s: (s != "CLARABEL", s))


def _tolerance_options(solver: str, tol: float) -> dict[str, Any]:
    """Map one relative tolerance onto the named solver's settings.

    Clarabel's primal residual stalls near 1e-10 on these models (O(1) densities sit in
    the cone offsets next to O(dt) unknowns), which turns tight feasibility tolerances
    into AlmostSolved.  Feasibility is restored exactly by the projection onto the
    constraint afterwards, so only the gap tolerance follows ``tol`` below 1e-8.
    """
    if solver == "CLARABEL":
        feas = max(tol, 1e-8)
        return {"tol_gap_abs": tol, "tol_gap_rel": tol, "tol_feas": feas, "tol_ktratio": min(1e-6, feas)}
    if solver == "SCS":
        return {"eps_abs": tol, "eps_rel": tol}
    if solver == "ECOS":
        return {"abstol": tol, "reltol": tol, "feastol": tol}
    if solver == "MOSEK":
        return {"mosek_params": {"MSK_DPAR_INTPNT_CO_TOL_REL_GAP": tol, "MSK_DPAR_INTPNT_CO_TOL_PFEAS": tol}}
    return {}


@dataclass
class ConicModel:
    """A compiled, parameterised CVXPY model of the collision step."""

    problem: cp.Problem
    params: dict[str, cp.Parameter]
    delta: cp.Variable
    m_hat: cp.Variable
    compile_seconds: float


_MODEL_CACHE: dict[tuple, ConicModel] = {}
_FISHER_CONES = ("auto", "centred", "raw")
# "auto" centres the Fisher cone when the step is this small against the data.
_CENTRE_BELOW = 1e-4


def _build_model(
    n: int, with_fisher: bool, centred: bool, r_plus: int, diagonal: bool, solver: str, momentum: bool = False
) -> tuple[ConicModel, bool]:
    """The cached model for this structure, and whether it was compiled by this call."""
    key = (n, with_fisher, centred, r_plus, diagonal, solver, momentum)
    model = _MODEL_CACHE.get(key)
    if model is not None:
        return model, False
    p = {
        "f_star": cp.Parameter(n, name="f_star"),
        "h": cp.Parameter(n, nonneg=True, name="h"),
        "mu": cp.Parameter(nonneg=True, name="mu"),
        "wass": cp.Parameter(n - 1, nonneg=True, name="wass"),
        "lin": cp.Parameter(n, name="lin"),
    }
    delta = cp.Variable(n, name="delta")
    m_hat = cp.Variable(n - 1, name="m_hat")
    t_hat = cp.Variable(n - 1, name="t_hat")
    f = p["f_star"] + p["mu"] * delta
    s = f[:-1] + f[1:]
    D = sp.diags([np.ones(n - 1), -np.ones(n - 1)], [0, -1], shape=(n, n - 1)).tocsc()
    cons = [
        cp.SOC(s + t_hat, cp.vstack([s - t_hat, 2 * m_hat]), axis=0),
        cp.multiply(p["h"], delta) + D @ m_hat == 0,
        f >= 0,
    ]
    if momentum:  # sum_k m_k dv_k = 0: the step conserves momentum (CollisionProblem.conserve_momentum)
        p["dv"] = cp.Parameter(n - 1, nonneg=True, name="dv")
        cons.append(p["dv"] @ m_hat == 0)
    obj = p["wass"] @ t_hat + p["lin"] @ delta
    if with_fisher:
        p["fisher"] = cp.Parameter(n - 1, nonneg=True, name="fisher")
        q = cp.Variable(n - 1, name="q")
        if centred:
            # d^2/s = (d - r s)^2/s + (2 r d - r^2 s) with r = d*/s*: d - r s = mu (d_hat - r s_hat)
            # vanishes at f*, so the cone variable is O(1) however small the step; the
            # linear remainder (the Fisher gradient at f*) joins "lin".
            p["ratio"] = cp.Parameter(n - 1, name="ratio")
            e = (delta[1:] - delta[:-1]) - cp.multiply(p["ratio"], delta[1:] + delta[:-1])
        else:
            e = f[1:] - f[:-1]
        cons.append(cp.SOC(s + q, cp.vstack([s - q, 2 * e]), axis=0))
        obj = obj + p["fisher"] @ q
    if diagonal:
        p["rho"] = cp.Parameter(nonneg=True, name="rho")
        obj = obj + p["rho"] * cp.sum_squares(delta)
    elif r_plus > 0:
        # y = P_+ delta as a constraint keeps the parameter linear in the data (cheap DPP).
        p["P_plus"] = cp.Parameter((r_plus, n), name="P_plus")
        y = cp.Variable(r_plus, name="y")
        cons.append(y == p["P_plus"] @ delta)
        obj = obj + cp.sum_squares(y)
    prob = cp.Problem(cp.Minimize(obj), cons)
    assert prob.is_dpp(), "collision model must be DPP"
    # Compile once with placeholder values; later solves only refill the parameters.
    for par in p.values():
        par.value = np.ones(par.shape) if par.shape else 1.0
    t0 = time.perf_counter()
    prob.get_problem_data(solver, enforce_dpp=True)
    model = ConicModel(prob, p, delta, m_hat, time.perf_counter() - t0)
    _MODEL_CACHE[key] = model
    return model, True


def _flux_scale(problem: CollisionProblem) -> tuple[float, float]:
    """(mu, varsigma): size of the explicit step's flux and of its Wasserstein cost.

    The explicit step is the first SQP step from ``(f*, 0)`` (one tridiagonal solve):
    it includes the Fisher-driven flux, which dominates for rough data.  It is capped
    at a quarter of the mass, the largest flux a feasible point can carry.
    """
    from .sqp import _qp_step_banded

    f, m = problem.initial_point()
    gf, gm = problem.gradient(f, m)
    with np.errstate(all="ignore"):
        _, pm = _qp_step_banded(problem, f, m, gf, gm)
    mu = float(np.abs(pm).max()) if np.all(np.isfinite(pm)) else np.nan
    if not np.isfinite(mu) or mu <= 0:
        mu, pm = problem.dt * float(problem.mass), np.zeros_like(m)
    # No feasible flux exceeds the mass (|m_k| = |sum_{j<=k} h_j (f_j - f*_j)| <= M); for
    # large dt the explicit step overshoots the implicit one by orders of magnitude.
    cap = 0.25 * float(problem.mass)
    if mu > cap:
        pm, mu = pm * (cap / mu), cap
    s = f[:-1] + f[1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        cost = float(np.sum(np.where(s > 0, problem.wass_coef * pm**2 / s, 0.0)))
    if not np.isfinite(cost) or cost <= 0:
        cost = mu**2 * float(problem.grid.dv.sum()) / max(float(f.max()), 1e-300)
    return mu, cost


def solve_conic(
    problem: CollisionProblem,
    *,
    solver: str = "CLARABEL",
    tol: float = 1e-10,
    energy: str = "dc",
    dc_split: str = "eigen",
    fisher_cone: str = "auto",
    max_passes: int = 50,
    dc_tol: float | None = None,
    kkt_tol: float = 1e-6,
    solver_options: dict[str, Any] | None = None,
    check_convexity: bool = True,
    verbose: bool = False,
) -> CollisionResult:
    """Solve the collision step with CVXPY (the conic reference).

    Parameters
    ----------
    problem : CollisionProblem
        The (unbatched) problem.  ``fisher="log"`` is not conic-representable.
    solver : str, default "CLARABEL"
        Any installed CVXPY solver that accepts second-order cones (:func:`conic_solvers`).
    tol : float, default 1e-10
        Relative tolerance passed to the solver (gap and feasibility).  The objective
        is flat in f, so f is accurate to roughly ``sqrt(tol)`` (DESIGN.md).
    energy : {"dc", "linearized"}, default "dc"
        ``"dc"``: convex-concave loop, one conic solve per pass, until the iterate moves
        less than ``dc_tol`` (relative to the flux scale) -- a KKT point of the full
        problem.  ``"linearized"``: one solve with the energy linearised at ``f_star``
        (semi-implicit scheme); status ``LINEARIZED``.
    dc_split : {"eigen", "diagonal"}, default "eigen"
        Convex part of the difference-of-convex split on mass-free directions.
        ``"eigen"``: the exact positive part :math:`\\tilde K_+` kept as a quadratic
        (fewest passes, but a dense N x N block in every conic solve).
        ``"diagonal"``: the majorant :math:`\\rho\\|\\delta\\|^2`, :math:`\\rho = \\lambda_{max}(\\tilde K_+)`,
        with :math:`\\rho I - \\tilde K` linearised (cheap solves).  Both coincide for
        :math:`\\gamma \\le 2`, where :math:`\\tilde K_+ = 0`.
    fisher_cone : {"auto", "centred", "raw"}, default "auto"
        Form of the perspective-Fisher cone.  ``"raw"``: :math:`(f_{k+1}-f_k)^2 \\le s_k q_k`.
        ``"centred"``: the same term rewritten about :math:`f^*` (see the module
        docstring), whose cone variable stays O(1) however small the step.  ``"auto"``
        tries the centred form first when the explicit flux is below 1e-4 of max f* (tiny
        steps, where the raw cone loses the step in rounding) and the raw form otherwise,
        and falls back to the other form when the first is not certified (``info`` then
        has ``fallback_from``).  Measured: raw is better conditioned on rough data, centred
        on smooth data with a strong Fisher term (beta = 1: KKT 3e-9 against 1.5e-6).
    max_passes : int, default 50
        Limit on convex-concave passes (status ``MAX_ITERATIONS`` when reached).
    dc_tol : float, optional
        Stopping threshold of the convex-concave loop: the largest change of
        :math:`(f - f^*)/\\mu` between passes (:math:`\\mu` = size of the explicit-Euler
        flux).  Default ``10 * sqrt(tol)``: the solver resolves f only to about
        ``sqrt(tol)``, so a tighter threshold chases noise.
    kkt_tol : float, default 1e-6
        A converged loop is reported ``CONVERGED`` only if the scaled KKT residual of the
        full problem is at most this; otherwise ``NOT_CERTIFIED``.
    solver_options : dict, optional
        Extra keyword arguments for the solver (override ``tol``).
    check_convexity : bool, default True
        Second-order test at a certified point: if the reduced Hessian is not positive
        definite the point is a KKT point but not a minimiser, reported ``NONCONVEX``.
    verbose : bool
        Passed to CVXPY.

    Returns
    -------
    CollisionResult
        ``info`` holds ``passes``, ``solver_status`` (CVXPY's, last pass),
        ``compile_seconds`` and ``solver_seconds``.
    """
    if dc_tol is None:
        dc_tol = min(1e-2, 10 * float(tol) ** 0.5) if isinstance(tol, (int, float)) and tol > 0 else 1e-4
    _check_conic_args(problem, solver, tol, energy, max_passes, dc_tol, kkt_tol)
    if fisher_cone not in _FISHER_CONES:
        raise ValueError(f"fisher_cone must be one of {_FISHER_CONES}, got {fisher_cone!r}")
    if dc_split not in ("diagonal", "eigen"):
        raise ValueError(f"dc_split must be 'diagonal' or 'eigen', got {dc_split!r}")
    opts = {
        "solver": solver,
        "tol": tol,
        "energy": energy,
        "dc_split": dc_split,
        "max_passes": max_passes,
        "dc_tol": dc_tol,
        "kkt_tol": kkt_tol,
        "solver_options": solver_options,
        "check_convexity": check_convexity,
        "verbose": verbose,
    }
    if fisher_cone == "auto" and problem.fisher is not None:
        # Neither cone form wins everywhere (measured): try the one the step size favours,
        # fall back to the other when the first is not certified, keep the better result.
        mu, _ = _flux_scale(problem)
        first = "centred" if mu < _CENTRE_BELOW * float(problem.f_star.max()) else "raw"
        res = solve_conic(problem, fisher_cone=first, **opts)
        if res.status in (Status.CONVERGED, Status.NONCONVEX, Status.LINEARIZED):
            return res
        other = solve_conic(problem, fisher_cone="raw" if first == "centred" else "centred", **opts)
        rank = {Status.CONVERGED: 0, Status.NONCONVEX: 1}
        best = min((res, other), key=lambda r: (rank.get(r.status, 2), r.kkt_residual))
        best.info["fallback_from"] = first
        best.seconds = res.seconds + other.seconds
        return best
    t_start = time.perf_counter()
    n = problem.n
    split = problem.energy.split()
    linearized = energy == "linearized"
    # Convex part of the split: exact (P_+ quadratic) or a diagonal majorant rho*|delta|^2.
    rho = split.rho if dc_split == "diagonal" else 0.0
    diagonal = dc_split == "diagonal" and rho > 0 and not linearized
    r_plus = 0 if (linearized or diagonal) else split.P_plus.shape[0]
    has_concave = not linearized and (split.P_minus.shape[0] > 0 or diagonal)
    mu, varsigma = _flux_scale(problem)
    with_fisher = problem.fisher is not None
    centred = with_fisher and fisher_cone == "centred"
    model, compiled_now = _build_model(n, with_fisher, centred, r_plus, diagonal, solver, problem.conserve_momentum)
    ec = problem.energy_coef
    prm = model.params
    prm["f_star"].value = problem.f_star
    prm["h"].value = problem.grid.h
    prm["mu"].value = mu
    if problem.conserve_momentum:
        prm["dv"].value = problem.grid.dv / problem.grid.dv.max()
    prm["wass"].value = problem.wass_coef * mu**2 / varsigma
    fs = problem.f_star
    if centred:
        s_star, d_star = fs[:-1] + fs[1:], fs[1:] - fs[:-1]
        prm["ratio"].value = np.divide(d_star, s_star, out=np.zeros_like(s_star), where=s_star > 0)
    if with_fisher:
        prm["fisher"].value = 2 * problem.fisher_coef * (mu**2 if centred else 1.0) / varsigma
    if r_plus:
        prm["P_plus"].value = np.sqrt(ec / varsigma) * mu * split.P_plus
    if diagonal:
        prm["rho"].value = ec * rho * mu**2 / varsigma
    # Linear part at f*: the energy gradient and the Fisher gradient (see the centred cone).
    parts = problem.gradient_parts(*problem.initial_point())
    grad_star = parts.energy[0] + parts.fisher[0] if centred else parts.energy[0]
    opts = _tolerance_options(solver, tol)
    opts.update(solver_options or {})

    def concave_gradient(d: NDArray[np.float64]) -> NDArray[np.float64]:
        """Gradient (in f units) of the concave part -d'(K_c)d at mu*d, K_c = rho I - K~ or K~_-."""
        x = mu * d
        if diagonal:
            kt = split.P_plus.T @ (split.P_plus @ x) - split.concave_matvec(x)
            return -2 * ec * (rho * x - kt)
        return -2 * ec * split.concave_matvec(x)

    delta = np.zeros(n)
    passes, ipm_iters, solver_seconds = 0, 0, 0.0
    status = Status.MAX_ITERATIONS
    raw_status: str | None = None
    moved = np.inf
    while passes < max_passes:
        lin = grad_star + concave_gradient(delta) if has_concave else grad_star
        prm["lin"].value = lin * mu / varsigma
        try:
            with warnings.catch_warnings():
                # CVXPY warns "Solution may be inaccurate"; the status says it (INACCURATE).
                warnings.filterwarnings("ignore", message="Solution may be inaccurate")
                model.problem.solve(solver=solver, verbose=verbose, **opts)
        except cp.error.SolverError:
            status, raw_status = Status.SOLVER_ERROR, "SolverError"
            break
        passes += 1
        raw_status = model.problem.status
        stats = model.problem.solver_stats
        ipm_iters += int(getattr(stats, "num_iters", 0) or 0)
        solver_seconds += float(getattr(stats, "solve_time", 0.0) or 0.0)
        if raw_status in (cp.INFEASIBLE, cp.UNBOUNDED, cp.INFEASIBLE_INACCURATE, cp.UNBOUNDED_INACCURATE):
            status = Status.INFEASIBLE
            break
        if raw_status not in (cp.OPTIMAL, cp.OPTIMAL_INACCURATE) or model.delta.value is None:
            status = Status.SOLVER_ERROR
            break
        new = np.asarray(model.delta.value, dtype=float)
        if not np.all(np.isfinite(new)):
            status = Status.NUMERICAL_ERROR
            break
        moved = float(np.abs(new - delta).max())
        delta = new
        if not has_concave or moved <= dc_tol:
            status = Status.CONVERGED
            break

    if model.m_hat.value is not None and status not in (Status.SOLVER_ERROR, Status.NUMERICAL_ERROR):
        f_raw = problem.f_star + mu * delta
    else:
        f_raw = problem.f_star.copy()
    f, m = problem.project_feasible(f_raw)
    kkt = problem.kkt_residual(f, m)
    if status is Status.CONVERGED:
        if raw_status == cp.OPTIMAL_INACCURATE:
            status = Status.INACCURATE
        elif linearized:
            status = Status.LINEARIZED
        elif not kkt.total <= kkt_tol:
            status = Status.NOT_CERTIFIED
        elif check_convexity and not problem.is_local_minimiser(f, m):
            status = Status.NONCONVEX
    return CollisionResult.from_point(
        problem,
        f,
        m,
        status,
        "conic",
        ipm_iters,
        kkt.total,
        time.perf_counter() - t_start - (model.compile_seconds if compiled_now else 0.0),
        {
            "compiled_now": compiled_now,
            "fisher_cone": "centred" if centred else ("raw" if with_fisher else None),
            "passes": passes,
            "solver": solver,
            "solver_status": raw_status,
            "last_move": moved,
            "compile_seconds": model.compile_seconds,
            "solver_seconds": solver_seconds,
            "kkt": kkt,
        },
    )


def _check_conic_args(
    problem: CollisionProblem, solver: str, tol: float, energy: str, max_passes: int, dc_tol: float, kkt_tol: float
) -> None:
    if problem.batched:
        raise ValueError("method='conic' solves one problem at a time; pass problem.slice(i)")
    if problem.fisher == "log":
        raise ValueError(
            'fisher="log" is not conic-representable; use fisher="perspective" for method="conic" '
            '(or method="sqp"/"newton" for the log form)'
        )
    if not isinstance(solver, str) or solver.upper() not in conic_solvers():
        raise ValueError(f"solver must be one of the installed conic solvers {conic_solvers()}, got {solver!r}")
    if solver != solver.upper():
        raise ValueError(f"solver names are upper case as in CVXPY, e.g. {solver.upper()!r}; got {solver!r}")
    if energy not in _ENERGY_MODES:
        raise ValueError(f"energy must be one of {_ENERGY_MODES}, got {energy!r}")
    for name, val in (("tol", tol), ("dc_tol", dc_tol), ("kkt_tol", kkt_tol)):
        if not (isinstance(val, (int, float)) and np.isfinite(val) and 0 < val < 1):
            raise ValueError(f"{name} must lie in (0, 1), got {val!r}")
    if not (isinstance(max_passes, (int, np.integer)) and max_passes >= 1):
        raise ValueError(f"max_passes must be an integer >= 1, got {max_passes!r}")
