"""The conic reference: the collision step posed in CVXPY, solved by Clarabel (or SCS, ...).

Units: every step is solved in units of its largest density
(:meth:`~jko_cvx.collision.CollisionProblem.in_units_of_max`: :math:`f^*/c` with the strength
times :math:`c`, :math:`c = \\max f^*`, the same minimiser scaled by :math:`1/c`) and the answer,
scaled back, is certified against the problem itself
(:func:`~jko_cvx.collision.certify.certify_rescaled`).  Clarabel's tolerances are partly
absolute: posed at its own scale, a low-mass x-slice of the paper's gamma = 3 scene
(``inhom_gamma3_lambda4``, perspective form, beta = 30, 61 x 61, first step) was not certified on
42 of the 61 slices, those with max f* from 1e-10 to 0.15 (25 MAX_ITERATIONS and 16 SOLVER_ERROR at
KKT 1.6e-4 to 0.78, one NOT_CERTIFIED at 1.3e-6), and the run under ``method = "conic"`` stopped at
its first step; in units of max f* all 61 are certified.

Limits (measured): on slices whose low-density cells carry the residual (concentrating slices,
explicit CFL 9 to 13, tails at 1e-10 of the peak; a low-mass slice with tails at 4e-8) the answer
is within 6e-10 to 1.3e-7 of Newton's certified one in f but the KKT residual stalls at 2.2e-6 to
1.4e-5 in every form and unit and at both inner tolerances; a tiny step (dt ~ 1e-4) on a graded
grid with rough data stalled at 6.8e-4.  Such steps are NOT_CERTIFIED or INACCURATE, never
CONVERGED; Newton certifies them, and IPOPT (``method = "nlp"``) the graded-grid one.

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

Edge units (:func:`_solve_forms`; a fallback, or the first attempt where the smallest
:math:`s^*_k` lies between 1e-11 and 1e-6 of the largest, a run's density floor): a step that
does not settle in f units is solved again with each edge whose
:math:`s^*_k = f^*_k + f^*_{k+1}` is below :math:`\\epsilon_e \\max s^*`
(:math:`\\epsilon_e` = ``_EDGE_REF`` = 1e-3) in units of :math:`a_k = s^*_k / (\\epsilon_e \\max s^*)`
in both cones (the variable :math:`s_k/a_k`, the raw cone's :math:`(f_{k+1} - f_k)/a_k`; the
centred cone's entry keeps its units), the objective weights multiplied back, and every flux
in units of :math:`b_k = \\min(\\mu, s^*_k)` instead of :math:`\\mu` (:math:`m_k = b_k \\hat m_k`):
on a near-vacuum x-slice (the density floor 1e-10 over half the grid next to cells of 0.03)
the unscaled entries of those cones sit below the solver's absolute feasibility tolerance, and
the inner solves end inaccurate.  The minimiser is the same; only the solver's view of it
changes.

The energy enters through the difference-of-convex split of :mod:`jko_cvx.kernels`
(restricted to mass-free directions, exact on the feasible set): the convex part
:math:`\\|P_+\\delta\\|^2` stays quadratic and the concave part is linearised inside
:math:`\\ell` (convex-concave procedure): first at the explicit step (computed from f* alone),
then at the previous pass's answer.  Every fixed point is a KKT point of the full problem; the
loop also stops at the first pass whose answer the certificate accepts.  All data enter as
CVXPY Parameters (the model is DPP), so the model is compiled once per (N, Fisher on/off,
rank of :math:`P_+`, solver) and re-solved thereafter.

Every solve starts cold (``warm_start=False``: CVXPY would otherwise hand the solver the
previous solve's iterate or workspace, so the answer would depend on what was solved
before), and the whole solve is bounded in time (``time_limit``).  The solve is split
into phases: options checked once (:class:`ConicOptions`), the model built or fetched
(:func:`_build_model`), its parameters filled (:func:`_fill`), the convex-concave loop
(:func:`_dc_loop`, raw solver statuses mapped by one table), and the certificate
(:func:`~jko_cvx.collision.certify.certify`).  CVXPY is imported on first use.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from jko_cvx.collision._checks import check_options_dict
from jko_cvx.collision.certify import Certificate, certify, certify_rescaled
from jko_cvx.collision.options import Options, Spec, option
from jko_cvx.collision.problem import LOG_FORM_METHODS, CollisionProblem, methods_text
from jko_cvx.collision.refine import refine_once
from jko_cvx.collision.result import CollisionResult, Status
from jko_cvx.collision.sqp import explicit_step

__all__ = ["ConicModel", "ConicOptions", "clear_model_cache", "conic_solvers", "model_cache_size", "solve_conic"]

_ENERGY_MODES = ("dc", "linearized")
_FISHER_CONES = ("auto", "centred", "raw")
_DC_SPLITS = ("eigen", "diagonal", "truncated")
# "truncated": eigenvalues of the convex part below this fraction of the largest go to the
# diagonal majorant (their largest times |h delta|^2) instead of the dense block.  1e-4 (rank
# 14 at gamma = 3) slowed the convex-concave loop where the energy is strong (strength 50,
# dt = 0.05: 50 passes, not settled, against eigen's 30); 1e-5 (rank 26) takes eigen's passes.
_TRUNCATE_BELOW = 1e-5
# "auto" centres the Fisher cone when the step is this small against the data.
_CENTRE_BELOW = 1e-4
# Default bound on one conic solve, all convex-concave passes together (seconds).  SCS
# inside the loop had no bound at all: one call ran for more than 15 minutes.
_TIME_LIMIT = 120.0
# Cones whose s* = f*_k + f*_{k+1} is below this fraction of the largest are written in units
# of their own s* (_edge_scales): on near-vacuum x-slices (floor 1e-10 next to O(1) cells) the
# unscaled cone entries sat below Clarabel's absolute feasibility tolerance (0/18 certified;
# 18/18 in edge units, the 64 others unchanged; 1e-2 and 1e-4 measured the same).
_EDGE_REF = 1e-3
# A step whose smallest edge sum s* lies in this range relative to the largest (a run's density
# floor under a populated slice) is tried in edge units first: its f-unit cones sit below the
# solver's feasibility tolerance.  Measured on inhom_gamma3_lambda4 (perspective, beta = 30):
# 41 x 41 after one step, the raw form in edge units settled on 15 of 15 such slices, the f units
# failed in both forms on 1 and in the first form on 8; 61 x 61 over five steps (the reference
# in units of max f*), 75 of 140 such slices failed in both forms in f units, and verifying the
# run took 9.3 s against 17.9 s.  Below the range the edge units' coefficients fail more often
# (Gaussians over floors of 1e-12 to 5e-12 of the peak, gamma 1 and 2: both forms failed, the f
# units settled; tails that fall to 1e-70 of the peak, as in an initial datum: the centred f-unit
# form settles where the edge units fail), and above it the f units settle.
_EDGE_FIRST = (1e-11, 1e-6)
# A step that no cone form or units settle at the method's tol is tried again at this gap tolerance
# (feasibility stays floored at 1e-8, _solver_settings): on inhom_gamma3_lambda4 at 61 x 61
# (perspective, beta = 30, t = 0.3) the inner solves' accuracy stalled the loop's KKT residual at
# 2.2e-6 to 5e-6 on 3 slices (NOT_CERTIFIED after every attempt) and the run stopped; at 1e-12 the
# first attempt certified each in 2 to 3 passes.  Not the default: 1e-12 ends more solves
# AlmostSolved (INACCURATE).
_RETRY_TOL = 1e-12
_RETRY_FROM = 1e-10
"""The default ``tol``: the retry (and the largest move of the refinement) starts from it."""


def _cvxpy():
    """CVXPY, imported on first use (``import jko_cvx`` must not pay for it)."""
    import cvxpy

    return cvxpy


def conic_solvers() -> list[str]:
    """Installed CVXPY solvers that accept second-order cones (Clarabel first).

    The ``solver`` option of ``solve_collision(..., method="conic")`` is one of these.

    Examples
    --------
    >>> from jko_cvx import conic_solvers
    >>> conic_solvers()[0]  # Clarabel is a dependency of the package
    'CLARABEL'
    """
    cp = _cvxpy()
    from cvxpy.reductions.solvers.defines import INSTALLED_CONIC_SOLVERS, SOLVER_MAP_CONIC

    out = []
    for name in INSTALLED_CONIC_SOLVERS:
        solver = SOLVER_MAP_CONIC.get(name)
        if solver is not None and cp.SOC in solver.SUPPORTED_CONSTRAINTS:
            out.append(name)
    return sorted(out, key=lambda s: (s != "CLARABEL", s))


def _solver_settings(solver: str, tol: float, seconds: float) -> dict[str, Any]:
    """Map one relative tolerance and a time budget onto the named solver's settings.

    Clarabel's primal residual stalls near 1e-10 on these models (O(1) densities sit in
    the cone offsets next to O(dt) unknowns), which turns tight feasibility tolerances
    into AlmostSolved.  Feasibility is restored exactly by the projection onto the
    constraint afterwards, so only the gap tolerance follows ``tol`` below 1e-8.
    """
    if solver == "CLARABEL":
        feas = max(tol, 1e-8)
        return {
            "tol_gap_abs": tol,
            "tol_gap_rel": tol,
            "tol_feas": feas,
            "tol_ktratio": min(1e-6, feas),
            "time_limit": seconds,
        }
    if solver == "SCS":
        return {"eps_abs": tol, "eps_rel": tol, "time_limit_secs": seconds}
    if solver == "ECOS":
        return {"abstol": tol, "reltol": tol, "feastol": tol}
    if solver == "MOSEK":
        return {
            "mosek_params": {
                "MSK_DPAR_INTPNT_CO_TOL_REL_GAP": tol,
                "MSK_DPAR_INTPNT_CO_TOL_PFEAS": tol,
                "MSK_DPAR_OPTIMIZER_MAX_TIME": seconds,
            }
        }
    return {}


def _check_solver(label: str, solver: Any) -> str:
    """``solver`` if it names an installed conic solver in CVXPY's upper case, else ``ValueError``."""
    if not isinstance(solver, str) or solver.upper() not in conic_solvers():
        raise ValueError(f"{label} must be one of the installed conic solvers {conic_solvers()}, got {solver!r}")
    if solver != solver.upper():
        raise ValueError(f"solver names are upper case as in CVXPY, e.g. {solver.upper()!r}; got {solver!r}")
    return solver


def _check_solver_options(label: str, options: Any) -> dict[str, Any]:
    """A dict of keyword options for the solver (None gives ``{}``), none of which writes a file."""
    return _no_file_options(check_options_dict(label, options))


_UNIT = Spec("float", lo=0.0, hi=1.0, lo_open=True, hi_open=True)
_SECONDS = "be a finite number of seconds > 0"


@dataclass(frozen=True)
class ConicOptions(Options):
    """The options of :func:`solve_conic`, checked once on construction (see its docstring for each).

    Fields are checked in this order.  ``solver`` accepts any installed conic solver; a scene
    may name only the ``choices`` of its spec.  ``dc_tol=None`` is resolved from ``tol``
    (``min(1e-2, 10 * sqrt(tol))``).  Problem-dependent checks: :meth:`checked`.
    """

    solver: str = option("CLARABEL", Spec("str", choices=("CLARABEL", "SCS", "ECOS"), check_with=_check_solver))
    tol: float = option(1e-10, _UNIT)
    time_limit: float = option(_TIME_LIMIT, Spec("float", lo=0.0, lo_open=True, text=_SECONDS))
    energy: str = option("dc", Spec("str", choices=_ENERGY_MODES))
    dc_split: str = option("truncated", Spec("str", choices=_DC_SPLITS))
    fisher_cone: str = option("auto", Spec("str", choices=_FISHER_CONES))
    max_passes: int = option(50, Spec("int", lo=1))
    dc_tol: float | None = option(None, _UNIT)
    kkt_tol: float = option(1e-6, _UNIT)
    solver_options: dict[str, Any] | None = option(None, Spec("table", check_with=_check_solver_options))
    check_convexity: bool = option(True, Spec("bool"))
    verbose: bool = option(False, Spec("bool"))
    # Judge OPTIMAL_INACCURATE by the certificate: fixed-grid runs at gamma = 2.5 and 3 then
    # certify 320 of 320 steps, against 308 (and 317-319 at tol 1e-9 / 1e-8, with 50-100x
    # larger residuals; the conic-defaults study).  Not on the scene allow-list.
    accept_inaccurate: bool = option(True, Spec("bool", scene=False))

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.dc_tol is None:  # the solver resolves f to about sqrt(tol): a tighter threshold chases noise
            object.__setattr__(self, "dc_tol", min(1e-2, 10 * self.tol**0.5))
        if self.solver_options is None:
            object.__setattr__(self, "solver_options", {})
        if self.solver == "CLARABEL" and self.solver_options:
            import clarabel

            # the settings object's fields, and the two keys CVXPY's interface takes itself
            known = {k for k in dir(clarabel.DefaultSettings()) if not k.startswith("_")}
            from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import CLARABEL

            known |= {"use_quad_obj", getattr(CLARABEL, "ACCEPT_UNKNOWN", "use_quad_obj")}
            unknown = sorted(set(self.solver_options) - known)
            if unknown:
                raise TypeError(
                    f"solver_options {unknown} are not settings of CLARABEL; its settings: {sorted(known)}"
                )

    @classmethod
    def checked(cls, problem: CollisionProblem, **options: Any) -> ConicOptions:
        """Options validated against ``problem``; a ``ValueError``/``TypeError`` names the bad one."""
        if problem.batched:
            raise ValueError("method='conic' solves one problem at a time; pass problem.slice(i)")
        if problem.fisher == "log":
            raise ValueError(
                f'fisher="log" is not conic-representable: use method={methods_text(LOG_FORM_METHODS)} '
                'for the log form (nlp: the independent CVXPY + IPOPT reference), or fisher="perspective" '
                'with method="conic"'
            )
        return cls(**options)


def _no_file_options(options: dict[str, Any]) -> dict[str, Any]:
    """``options`` unless one of them names a file the solver would write (``ValueError`` naming it).

    A collision step writes nothing: SCS's ``write_data_filename`` / ``log_csv_filename``,
    MOSEK's ``save_file``, Gurobi's ``LogFile`` and the like (any key containing "file")
    are refused.  Scenes pass a stricter allow-list (:mod:`jko_cvx.scene.options`).
    """
    bad = sorted(k for k in options if "file" in k.lower())
    if bad:
        raise ValueError(f"solver_options {bad} would make the solver write files; the collision step writes none")
    return options


@dataclass
class ConicModel:
    """A compiled, parameterised CVXPY model of the collision step."""

    problem: Any  # cvxpy.Problem
    params: dict[str, Any]  # name -> cvxpy.Parameter
    delta: Any  # cvxpy.Variable
    m_hat: Any  # cvxpy.Variable
    compile_seconds: float


_MODEL_CACHE: dict[tuple, ConicModel] = {}


def clear_model_cache() -> None:
    """Forget every compiled model (the next solve of each structure compiles again)."""
    _MODEL_CACHE.clear()


def model_cache_size() -> int:
    """Number of compiled models held (one per N, Fisher form, split and solver)."""
    return len(_MODEL_CACHE)


def _build_model(
    n: int,
    with_fisher: bool,
    centred: bool,
    r_plus: int,
    diagonal: bool,
    solver: str,
    momentum: bool = False,
    weighted: bool = False,
    edge_units: bool = False,
) -> tuple[ConicModel, bool]:
    """The cached model for this structure, and whether it was compiled by this call.

    ``edge_units``: the cones and fluxes in the units of each edge (module docstring), else in
    f units and the flux scale mu throughout.
    """
    key = (n, with_fisher, centred, r_plus, diagonal, solver, momentum, weighted, edge_units)
    model = _MODEL_CACHE.get(key)
    if model is not None:
        return model, False
    cp = _cvxpy()
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
    D = sp.diags([np.ones(n - 1), -np.ones(n - 1)], [0, -1], shape=(n, n - 1)).tocsc()
    if edge_units:  # (_edge_scales): s = (f_k + f_{k+1})/a_k, m = b_k m_hat_k (f units)
        p["s0"] = cp.Parameter(n - 1, nonneg=True, name="s0")  # s*/a
        p["mu_a"] = cp.Parameter(n - 1, nonneg=True, name="mu_a")  # mu/a
        p["b"] = cp.Parameter(n - 1, nonneg=True, name="b")  # b/mu
        s = p["s0"] + cp.multiply(p["mu_a"], delta[:-1] + delta[1:])
        flux = D @ cp.multiply(p["b"], m_hat)
    else:
        s = f[:-1] + f[1:]
        flux = D @ m_hat
    cons = [
        cp.SOC(s + t_hat, cp.vstack([s - t_hat, 2 * m_hat]), axis=0),
        cp.multiply(p["h"], delta) + flux == 0,
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
        elif edge_units:  # (f_{k+1} - f_k)/a_k
            p["d0"] = cp.Parameter(n - 1, name="d0")  # d*/a
            e = p["d0"] + cp.multiply(p["mu_a"], delta[1:] - delta[:-1])
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
    if weighted:  # the truncated split's majorant of the dropped eigenvalues: |w * delta|^2
        p["weights"] = cp.Parameter(n, nonneg=True, name="weights")
        obj = obj + cp.sum_squares(cp.multiply(p["weights"], delta))
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

    The explicit step (:func:`~jko_cvx.collision.sqp.explicit_step`, one tridiagonal
    solve) includes the Fisher-driven flux, which dominates for rough data.  It is capped
    at a quarter of the mass, the largest flux a feasible point can carry.
    """
    f = problem.f_star
    # NumPy scalars throughout: data at the edge of the floating-point range give inf or 0
    # here (caught by _fill), never a Python OverflowError or ZeroDivisionError.
    with np.errstate(all="ignore"):
        _, pm = explicit_step(problem)
        mu = np.abs(pm).max() if np.all(np.isfinite(pm)) else np.float64(np.nan)
        if not np.isfinite(mu) or mu <= 0:
            mu, pm = np.float64(problem.dt) * problem.mass, np.zeros(problem.n - 1)
        # No feasible flux exceeds the mass (|m_k| = |sum_{j<=k} h_j (f_j - f*_j)| <= M); for
        # large dt the explicit step overshoots the implicit one by orders of magnitude.
        cap = 0.25 * np.float64(problem.mass)
        if mu > cap:
            pm, mu = pm * (cap / mu), cap
        s = f[:-1] + f[1:]
        cost = np.sum(np.where(s > 0, problem.wass_coef * pm**2 / np.where(s > 0, s, 1.0), 0.0))
        if not np.isfinite(cost) or cost <= 0:
            cost = mu**2 * problem.grid.dv.sum() / np.maximum(f.max(), 1e-300)
    return float(mu), float(cost)


def _edge_scales(problem: CollisionProblem, mu: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(a, b): the units of s (cone entries) and of the flux m on each edge.

    a = 1 (f units, as before) where s* is at least ``_EDGE_REF`` of its largest, s* in
    units of that threshold below it (floored at 1e-12 against underflow; 1 where s* = 0);
    b = min(mu, s*), at least 1e-12 mu: the flux through a near-vacuum edge is of the order of its mass.
    """
    s_star = problem.f_star[:-1] + problem.f_star[1:]
    a = np.minimum(1.0, s_star / (_EDGE_REF * s_star.max()))
    a = np.where(s_star > 0, np.maximum(a, 1e-12), 1.0)
    b = np.where(s_star > 0, np.minimum(mu, np.maximum(s_star, 1e-12 * mu)), mu)  # b^2 must not underflow
    return a, b


@dataclass
class _Filled:
    """A model with its parameters filled for one problem, and what the loop needs."""

    model: ConicModel
    compiled_now: bool
    mu: float
    varsigma: float
    grad_star: NDArray[np.float64]  # linear part at f* (energy, plus Fisher for the centred cone)
    concave: Callable[[NDArray], NDArray] | None  # gradient of the linearised concave part, or None
    fisher_cone: str | None


def _fill(problem: CollisionProblem, opts: ConicOptions, fisher_cone: str, edge_units: bool = False) -> _Filled | None:
    """Fetch the model and fill its parameters; None where the data's scale gives non-finite values."""
    split = problem.energy.split()
    linearized = opts.energy == "linearized"
    rho = split.rho if opts.dc_split == "diagonal" else 0.0  # convex part: exact, or rho*|delta|^2
    diagonal = opts.dc_split == "diagonal" and rho > 0 and not linearized
    P_top, rho_tail = split.P_plus, 0.0
    if opts.dc_split == "truncated" and not linearized:  # convex part: leading block + diagonal majorant
        P_top, rho_tail = split.truncated(problem.grid.h, _TRUNCATE_BELOW)
    weighted = rho_tail > 0
    r_plus = 0 if (linearized or diagonal) else P_top.shape[0]
    has_concave = not linearized and (split.P_minus.shape[0] > 0 or diagonal or weighted)
    mu, varsigma = (np.float64(x) for x in _flux_scale(problem))
    with_fisher = problem.fisher is not None
    centred = with_fisher and fisher_cone == "centred"
    ec, fs = problem.energy_coef, problem.f_star
    values: dict[str, Any] = {"f_star": fs, "h": problem.grid.h, "mu": float(mu)}
    with np.errstate(all="ignore"):
        s_star, d_star = fs[:-1] + fs[1:], fs[1:] - fs[:-1]
        if edge_units:
            a, b = _edge_scales(problem, float(mu))
            values.update(s0=s_star / a, mu_a=mu / a, b=b / mu)
            values["wass"] = problem.wass_coef * b**2 / (a * varsigma)
            if problem.conserve_momentum:
                values["dv"] = problem.grid.dv * b / (problem.grid.dv * b).max()
            if with_fisher and not centred:
                values["d0"] = d_star / a
            if with_fisher:  # centred: e in units of mu; raw: of a
                values["fisher"] = 2 * problem.fisher_coef * (mu**2 if centred else a**2) / (a * varsigma)
        else:
            values["wass"] = problem.wass_coef * mu**2 / varsigma
            if problem.conserve_momentum:
                values["dv"] = problem.grid.dv / problem.grid.dv.max()
            if with_fisher:
                values["fisher"] = 2 * problem.fisher_coef * (mu**2 if centred else 1.0) / varsigma
        if centred:
            values["ratio"] = np.divide(d_star, s_star, out=np.zeros_like(s_star), where=s_star > 0)
        if r_plus:
            values["P_plus"] = np.sqrt(ec / varsigma) * mu * P_top
        if weighted:
            values["weights"] = np.sqrt(ec * rho_tail / varsigma) * mu * problem.grid.h
        if diagonal:
            values["rho"] = ec * rho * mu**2 / varsigma
        # Linear part at f*: the energy gradient and the Fisher gradient (see the centred cone).
        parts = problem.gradient_parts(*problem.initial_point())
        grad_star = parts.energy[0] + parts.fisher[0] if centred else parts.energy[0]
        scales = np.array([mu, varsigma, mu * mu / varsigma])
        finite = np.all(np.isfinite(scales)) and np.all(scales > 0) and np.all(np.isfinite(grad_star * mu / varsigma))
    if not (finite and all(np.all(np.isfinite(v)) for v in values.values())):
        return None  # f* at the edge of the floating-point range (e.g. of order 1e-320): no O(1) scaling
    model, compiled_now = _build_model(
        problem.n, with_fisher, centred, r_plus, diagonal, opts.solver, problem.conserve_momentum, weighted, edge_units
    )
    for name, value in values.items():
        model.params[name].value = value

    def concave(d: NDArray[np.float64]) -> NDArray[np.float64]:
        """Gradient (in f units) of the concave part -d'(K_c)d at mu*d, K_c = rho I - K~ or K~_-."""
        x = mu * d
        if diagonal:
            kt = split.P_plus.T @ (split.P_plus @ x) - split.concave_matvec(x)
            return -2 * ec * (rho * x - kt)
        if weighted:  # K_c = P_top'P_top + rho_tail H^2 - K~ (PSD on mass-free directions)
            kt = split.P_plus.T @ (split.P_plus @ x) - split.concave_matvec(x)
            cx = P_top.T @ (P_top @ x) + rho_tail * problem.grid.h**2 * x
            return -2 * ec * (cx - kt)
        return -2 * ec * split.concave_matvec(x)

    cone = ("centred" if centred else "raw") if with_fisher else None
    return _Filled(model, compiled_now, mu, varsigma, grad_star, concave if has_concave else None, cone)


@dataclass
class _Loop:
    """Outcome of the convex-concave loop."""

    delta: NDArray[np.float64]
    claimed: Status
    raw_status: str | None = None
    passes: int = 0
    ipm_iterations: int = 0
    solver_seconds: float = 0.0
    last_move: float = np.inf
    certificate: Certificate | None = None  # where the certificate stopped the loop: the result's


def _raw_to_status(raw: str) -> Status | None:
    """CVXPY's status of one pass as a package status; None where the loop goes on."""
    cp = _cvxpy()
    table = {
        cp.OPTIMAL: None,
        cp.OPTIMAL_INACCURATE: None,  # judged after the loop (accept_inaccurate)
        cp.INFEASIBLE: Status.INFEASIBLE,
        cp.UNBOUNDED: Status.INFEASIBLE,
        cp.INFEASIBLE_INACCURATE: Status.INFEASIBLE,
        cp.UNBOUNDED_INACCURATE: Status.INFEASIBLE,
        cp.USER_LIMIT: Status.TIME_LIMIT,  # Clarabel MaxTime or MaxIterations (told apart by the clock)
    }
    return table.get(raw, Status.SOLVER_ERROR)


def _linearise_first_at(problem: CollisionProblem, mu: float) -> NDArray[np.float64]:
    """Where the first pass linearises the concave part: the explicit step, in units of mu (0 where not finite).

    The explicit step is computed from f* alone (the first step of the paper's SQP), so the
    reference stays independent of any solver's answer.  Linearised there, the first pass's
    error in the energy's gradient is of the size of the implicit step's departure from the
    explicit one, O(dt^2), where at f* it is O(dt).
    """
    with np.errstate(all="ignore"):
        pf, _ = explicit_step(problem)
        start = pf / mu
    return start if np.all(np.isfinite(start)) else np.zeros(problem.n)


def _dc_loop(problem: CollisionProblem, filled: _Filled, opts: ConicOptions, t_start: float) -> _Loop:
    """Convex-concave passes: one conic solve each, until the answer is certified or at a fixed point.

    The first pass linearises the concave part at the explicit step (:func:`_linearise_first_at`),
    every later one at the previous pass's answer.  The loop stops where the certificate accepts
    the pass's answer (projected onto the constraint, as :func:`_finish` does), or where the
    answer moves less than ``dc_tol`` (a fixed point: a KKT point of the full problem) and its
    KKT residual no longer falls:
    measured on ``inhom_gamma3_lambda4`` at 61 x 61 (perspective, beta = 30, five steps of
    verification), 471 passes for 336 solves against 813 linearised first at f* and run to the
    fixed point, every answer within 1.6e-7 of Newton's.
    """
    cp = _cvxpy()
    model, mu, varsigma = filled.model, filled.mu, filled.varsigma
    t_start += model.compile_seconds if filled.compiled_now else 0.0  # compiling is not solving
    loop = _Loop(np.zeros(problem.n), Status.MAX_ITERATIONS)
    at = None if filled.concave is None else _linearise_first_at(problem, mu)
    residual = np.inf  # the previous pass's KKT residual
    while loop.passes < opts.max_passes:
        left = opts.time_limit - (time.perf_counter() - t_start)
        if left <= 0:
            loop.claimed = Status.TIME_LIMIT
            break
        with np.errstate(over="ignore", invalid="ignore"):
            lin = (filled.grad_star if at is None else filled.grad_star + filled.concave(at)) * mu / varsigma
        if not np.all(np.isfinite(lin)):  # an energy at the edge of the float range (strength * max f* ~ 1e300)
            loop.claimed = Status.NUMERICAL_ERROR
            break
        model.params["lin"].value = lin
        settings = {**_solver_settings(opts.solver, opts.tol, left), **opts.solver_options}
        try:
            with warnings.catch_warnings():
                # CVXPY warns "Solution may be inaccurate"; the status says it (INACCURATE).
                warnings.filterwarnings("ignore", message="Solution may be inaccurate")
                model.problem.solve(solver=opts.solver, verbose=opts.verbose, warm_start=False, **settings)
        except cp.error.SolverError:
            loop.claimed, loop.raw_status = Status.SOLVER_ERROR, "SolverError"
            break
        except TypeError as exc:
            if not opts.solver_options:
                raise
            # the solver's own refusal of a key (only CLARABEL's settings are known beforehand)
            keys = sorted(opts.solver_options)
            raise TypeError(f"solver_options {keys} for solver {opts.solver!r}: {exc}") from None
        loop.passes += 1
        loop.raw_status = model.problem.status
        stats = model.problem.solver_stats
        loop.ipm_iterations += int(getattr(stats, "num_iters", 0) or 0)
        loop.solver_seconds += float(getattr(stats, "solve_time", 0.0) or 0.0)
        failed = _raw_to_status(loop.raw_status)
        if failed is Status.TIME_LIMIT and time.perf_counter() - t_start < opts.time_limit:
            failed = Status.MAX_ITERATIONS  # the solver's own iteration limit (CVXPY USER_LIMIT)
        if failed is None and model.delta.value is None:
            failed = Status.SOLVER_ERROR
        if failed is not None:
            loop.claimed = failed
            break
        new = np.asarray(model.delta.value, dtype=float)
        if not np.all(np.isfinite(new)):
            loop.claimed = Status.NUMERICAL_ERROR
            break
        loop.last_move = float(np.abs(new - (loop.delta if at is None else at)).max())
        loop.delta = new
        if at is None:
            loop.claimed = Status.CONVERGED
            break
        cert = _certificate(problem, filled, new, opts)
        if cert.status is Status.CONVERGED:
            loop.certificate, loop.claimed = cert, Status.CONVERGED
            break
        # A fixed point to dc_tol ends the loop unless the residual is still falling: a large step
        # converges slowly, and its moves drop below dc_tol passes before the certificate accepts
        if loop.last_move <= opts.dc_tol and not cert.residual < residual:
            loop.claimed = Status.CONVERGED
            break
        residual, at = cert.residual, new
    return loop


def _projected(problem: CollisionProblem, filled: _Filled, delta: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """The loop's point ``f* + mu delta`` projected onto the constraint, ``(f, m)``."""
    with np.errstate(all="ignore"):
        return problem.project_feasible(problem.f_star + filled.mu * delta)


def _certificate(
    problem: CollisionProblem, filled: _Filled, delta: NDArray[np.float64], opts: ConicOptions
) -> Certificate:
    """The certificate of a pass's answer (``CONVERGED``: a KKT point of the full problem to ``kkt_tol``)."""
    f, m = _projected(problem, filled, delta)
    return certify(problem, f, m, kkt_tol=opts.kkt_tol, check_convexity=opts.check_convexity)


def _finish(
    problem: CollisionProblem, filled: _Filled | None, loop: _Loop, opts: ConicOptions, t_start: float
) -> CollisionResult:
    """Project the loop's point onto the constraint and certify it."""
    usable = filled is not None and loop.claimed not in (Status.SOLVER_ERROR, Status.NUMERICAL_ERROR)
    if usable:
        f, m = _projected(problem, filled, loop.delta)
    else:
        with np.errstate(all="ignore"):
            f, m = problem.project_feasible(problem.f_star.copy())
    claimed = loop.claimed
    inaccurate = claimed is Status.CONVERGED and loop.raw_status == _cvxpy().OPTIMAL_INACCURATE
    if inaccurate and not opts.accept_inaccurate:
        claimed = Status.INACCURATE
    elif claimed is Status.CONVERGED and opts.energy == "linearized":
        claimed = Status.LINEARIZED
    if loop.certificate is not None and claimed is Status.CONVERGED:  # the loop's own, of this very point
        cert = loop.certificate
    else:
        cert = certify(problem, f, m, kkt_tol=opts.kkt_tol, check_convexity=opts.check_convexity, claimed=claimed)
    if inaccurate and cert.status is Status.NOT_CERTIFIED:
        cert = replace(cert, status=Status.INACCURATE)  # the solver said so, and the certificate agrees
    compile_s = filled.model.compile_seconds if filled is not None else 0.0
    info = {
        "compiled_now": filled is not None and filled.compiled_now,
        "fisher_cone": None if filled is None else filled.fisher_cone,
        "passes": loop.passes,
        "solver": opts.solver,
        "solver_status": loop.raw_status,
        "last_move": loop.last_move,
        "compile_seconds": compile_s,
        "solver_seconds": loop.solver_seconds,
        "kkt": cert.kkt,
    }
    seconds = time.perf_counter() - t_start - (compile_s if info["compiled_now"] else 0.0)
    return CollisionResult.from_certificate(problem, f, m, cert, "conic", loop.ipm_iterations, seconds, info)


def _solve_form(
    problem: CollisionProblem, opts: ConicOptions, fisher_cone: str, edge_units: bool = False
) -> CollisionResult:
    """One conic solve with the Fisher cone in the given form (in edge units where asked)."""
    t_start = time.perf_counter()
    filled = _fill(problem, opts, fisher_cone, edge_units)
    if filled is None:
        return _finish(problem, None, _Loop(np.zeros(problem.n), Status.NUMERICAL_ERROR), opts, t_start)
    loop = _dc_loop(problem, filled, opts, t_start)
    res = _finish(problem, filled, loop, opts, t_start)
    if edge_units:
        res.info["edge_units"] = True
    return res


_SETTLED = (Status.CONVERGED, Status.NONCONVEX, Status.LINEARIZED, Status.TIME_LIMIT)
_RANK = {Status.CONVERGED: 0, Status.LINEARIZED: 0, Status.NONCONVEX: 1}


def _solve_forms(problem: CollisionProblem, opts: ConicOptions, forms: list[str]) -> CollisionResult:
    """The Fisher cone forms in order, in f units, then (where none settles) in edge units; edge units first at a floor.

    Neither cone form wins everywhere (measured); the edge units (module docstring) rescue the
    near-vacuum slices whose cones sit below the solver's tolerance, but on data whose tails
    fall to 1e-12 of the peak or below their coefficients may make an otherwise settled solve
    fail, so they come last, except where the smallest edge sum lies in ``_EDGE_FIRST`` (a
    run's density floor under a populated slice), where they come first and the f units after
    them.  The first attempt is returned where it settles (CONVERGED, NONCONVEX, LINEARIZED,
    TIME_LIMIT); otherwise the attempts go on until one is CONVERGED, NONCONVEX or LINEARIZED
    or the time is spent, and the best of them is returned (CONVERGED or LINEARIZED, then
    NONCONVEX, then the smallest KKT residual).  The time limit covers every attempt but not
    the models' compilation (a worker process compiles its own, so the budget does not depend
    on which process solves the step).  Where no attempt settles at ``tol``, the same attempts run
    again at :data:`_RETRY_TOL` (``info["tol"]`` records it on an answer from them; Clarabel only,
    from the default ``tol`` down, and not where ``solver_options`` set the gap tolerance); where
    none settles then either, the best answer is refined (:func:`_refined`).
    ``info["fallback_from"]`` names the first of two forms where another attempt ran,
    ``info["edge_units"]`` is True where the answer comes from the edge units, ``info["attempts"]``
    counts the attempts.
    """
    t_start = time.perf_counter()
    tried: list[CollisionResult] = []
    units = (True, False) if _near_vacuum(problem) else (False, True)
    # the retry at a tighter gap tolerance is Clarabel's, from the default tolerance down: a tol the caller
    # loosened (or a first-order solver) is answered at that tol
    retry = (opts.solver == "CLARABEL" and _RETRY_TOL < opts.tol <= _RETRY_FROM
             and not any(k.startswith("tol_gap") for k in opts.solver_options))  # fmt: skip
    best = None
    for tol in [opts.tol, _RETRY_TOL] if retry else [opts.tol]:
        for edge_units, form in [(edge_units, form) for edge_units in units for form in forms]:
            compiled = sum(r.info.get("compile_seconds", 0.0) for r in tried if r.info.get("compiled_now"))
            left = opts.time_limit - (time.perf_counter() - t_start - compiled)
            if tried and left <= 0:
                break
            res = _solve_form(problem, replace(opts, time_limit=left, tol=tol) if tried else opts, form, edge_units)
            if tol != opts.tol:
                res.info["tol"] = tol
            tried.append(res)
            if len(tried) == 1 and res.status in _SETTLED:
                res.info["attempts"] = 1
                return res
            if res.status in _RANK or res.status is Status.TIME_LIMIT:
                break
        best = min(tried, key=lambda r: (_RANK.get(r.status, 2), r.kkt_residual))
        if best.status in _RANK or any(r.status is Status.TIME_LIMIT for r in tried):
            break
    refine_s = 0.0
    if best is not None and best.status not in _RANK and not any(r.status is Status.TIME_LIMIT for r in tried):
        # no round settled: the best answer, refined where one correction certifies it
        refined = _refined(problem, best, opts)
        if refined is not None:
            refine_s, best = refined.seconds - best.seconds, refined
    assert best is not None
    if len(tried) > 1:
        if len(forms) > 1:
            best.info["fallback_from"] = forms[0]
        best.seconds = sum(r.seconds for r in tried) + refine_s
    best.info["attempts"] = len(tried)
    return best


def _refined(problem: CollisionProblem, res: CollisionResult, opts: ConicOptions) -> CollisionResult | None:
    """``res`` after one Newton correction where that certifies it (:func:`~jko_cvx.collision.refine.refine_once`).

    Only a correction within the method's accuracy in f, ``sqrt(tol)`` (at most ``sqrt(1e-10)``), is
    taken: the refinement certifies an answer the inner solves pinned but could not drive below
    ``kkt_tol``, and moves it by less than the conic answer's own error.  The correction uses the
    problem's gradient and reduced Hessian (the certificate's, and Newton's), so a refined answer is
    independent of the Newton solver only to that bound (``info["refined_by"]``), a tenth of the
    verification's tolerance.  Not with the linearised energy, nor where the caller asked reduced
    accuracy to be reported (``accept_inaccurate=False`` and an inaccurate last solve).
    """
    if res.status in (Status.SOLVER_ERROR, Status.NUMERICAL_ERROR, Status.TIME_LIMIT) or opts.energy == "linearized":
        return None  # no point to refine, or the linearised energy's answer is not the full problem's
    almost = res.info.get("solver_status") == _cvxpy().OPTIMAL_INACCURATE
    if not opts.accept_inaccurate and (res.status is Status.INACCURATE or almost):
        return None  # the caller asked for reduced accuracy to be reported as such
    t0 = time.perf_counter()
    max_move = float(np.sqrt(min(opts.tol, _RETRY_FROM)))  # a loosened tol does not widen the move
    out = refine_once(problem, res.f, res.m, max_move=max_move, kkt_tol=opts.kkt_tol,
                      check_convexity=opts.check_convexity)  # fmt: skip
    if out is None:
        return None
    f, m, cert, move = out
    info = {**res.info, "refined_by": move, "refined_from": res.status.name, "kkt": cert.kkt}
    seconds = res.seconds + time.perf_counter() - t0
    return CollisionResult.from_certificate(problem, f, m, cert, "conic", res.iterations, seconds, info)


def _near_vacuum(problem: CollisionProblem) -> bool:
    """Whether the smallest edge sum s* = f*_k + f*_k+1 lies in ``_EDGE_FIRST`` relative to the largest."""
    s = problem.f_star[:-1] + problem.f_star[1:]
    top = float(s.max())
    if not (np.isfinite(top) and top > 0):
        return False
    rel = float(s.min()) / top
    return _EDGE_FIRST[0] <= rel <= _EDGE_FIRST[1]


def solve_conic(
    problem: CollisionProblem,
    *,
    solver: str = "CLARABEL",
    tol: float = 1e-10,
    energy: str = "dc",
    dc_split: str = "truncated",
    fisher_cone: str = "auto",
    max_passes: int = 50,
    dc_tol: float | None = None,
    kkt_tol: float = 1e-6,
    solver_options: dict[str, Any] | None = None,
    check_convexity: bool = True,
    verbose: bool = False,
    time_limit: float = _TIME_LIMIT,
    accept_inaccurate: bool = True,
) -> CollisionResult:
    """Solve the collision step with CVXPY (the conic reference).

    Parameters
    ----------
    problem : CollisionProblem
        The (unbatched) problem.  ``fisher="log"`` is not conic-representable.
    solver : str, default "CLARABEL"
        Any installed CVXPY solver that accepts second-order cones (:func:`conic_solvers`).
    tol : float, default 1e-10
        This method's own stopping tolerance: the relative gap (and feasibility, floored
        at 1e-8 for Clarabel) passed to the solver.  The objective is flat in f, so f is
        accurate to roughly ``sqrt(tol)`` (DESIGN.md).
    energy : {"dc", "linearized"}, default "dc"
        ``"dc"``: convex-concave loop, one conic solve per pass, until the iterate moves
        less than ``dc_tol`` -- a KKT point of the full problem.  ``"linearized"``: one
        solve with the energy linearised at ``f_star`` (semi-implicit); status ``LINEARIZED``.
    dc_split : {"truncated", "eigen", "diagonal"}, default "truncated"
        Convex part of the difference-of-convex split on mass-free directions: the
        eigenvalues above 1e-5 of the largest exactly and a diagonal majorant of the rest
        (:meth:`~jko_cvx.kernels.EnergySplit.truncated`; rank 26 for gamma = 3 at N = 121 to
        961, about the passes of ``"eigen"``: one solve at gamma = 3 grows like N^1.05 from
        N = 121 to 481 against N^1.7, 7x faster at N = 121 and 18x at 481, and its model
        compiles in 0.6 s at N = 481 against 41 s; the same statuses on 72 of 72 steps of
        gamma = 2.5, 3 and 4 at N = 41 and 121, f within 6.7e-6 where both converge), the
        exact positive part :math:`\\tilde K_+` (fewest passes, a dense block of rank about N
        in every solve: the interior-point factorisations cost O(N^3)), or the majorant
        :math:`\\lambda_{max}(\\tilde K_+)\\|\\delta\\|^2` (cheap solves, many passes); all the
        same for :math:`\\gamma \\le 2`, where :math:`\\tilde K_+ = 0`.  The split is computed once per
        grid and gamma (:meth:`~jko_cvx.PowerKernel.energy_operator`).
    fisher_cone : {"auto", "centred", "raw"}, default "auto"
        Form of the perspective-Fisher cone (module docstring).  ``"auto"`` tries the
        centred form first when the explicit flux is below 1e-4 of max f* and the raw one
        otherwise, and falls back to the other when the first is not certified (``info``
        then has ``fallback_from``): raw is better conditioned on rough data, centred on
        smooth data with a strong Fisher term (beta = 1: KKT 3e-9 against 1.5e-6).  A step
        that neither form settles (nor the given form) is solved again in edge units (module
        docstring; ``info["edge_units"]`` is True where the answer comes from them); a step at a
        density floor (the smallest edge sum between 1e-11 and 1e-6 of the largest) is tried in
        edge units first, then in f units.
    max_passes : int, default 50
        Limit on convex-concave passes (status ``MAX_ITERATIONS`` when reached).
    dc_tol : float, optional
        Fixed-point threshold of the loop: the largest change of :math:`(f - f^*)/\\mu` between
        the linearisation point and the pass's answer (:math:`\\mu` = explicit flux).  Default
        ``min(1e-2, 10 * sqrt(tol))``: the solver resolves f only to about ``sqrt(tol)``.  The loop
        stops first at a pass the certificate (``kkt_tol``) accepts, and at a fixed point only once
        the KKT residual stops falling: a large step converges slowly, and its moves fell below
        the threshold passes before a pass was certified (measured on the random families of the
        Newton certification study, the steps conic can pose: stopped at the threshold, 7 of 45
        held-out and 12 of 44 development steps ended NOT_CERTIFIED at KKT 1.2e-6 to 5.4e-6,
        explicit CFL 26 to 8643; going on while the residual falls, every step that IPOPT
        certifies is certified and the others are NONCONVEX, as IPOPT's are).
    kkt_tol : float, default 1e-6
        Certification threshold (the same for every method,
        :func:`~jko_cvx.collision.certify.certify`): a settled loop is ``CONVERGED`` only
        if the scaled KKT residual of the full problem is at most this, else ``NOT_CERTIFIED``;
        the loop also stops at the first pass it certifies.
    solver_options : dict, optional
        Extra keyword arguments for the solver (override ``tol`` and the time limit).
    check_convexity : bool, default True
        Second-order test at a certified point (``NONCONVEX`` where it fails).
    verbose : bool
        Passed to CVXPY.
    time_limit : float, default 120
        Wall-clock bound (s) on the whole solve: each pass gets the time left (Clarabel
        ``time_limit``, SCS ``time_limit_secs``, MOSEK's max time); status ``TIME_LIMIT``.
    accept_inaccurate : bool, default True
        A last solve reported ``OPTIMAL_INACCURATE`` (Clarabel AlmostSolved) is judged by
        the certificate like any other (``INACCURATE`` only where it fails; ``False``:
        always).  Measured (the conic-defaults study): such points at gamma =
        2.5 and 3 have KKT 6e-10 to 3e-9 and pass the second-order test.

    Returns
    -------
    CollisionResult
        ``info``: ``passes``, ``solver_status`` (CVXPY's, last pass), ``compile_seconds``,
        ``solver_seconds``, ``attempts`` (cone forms and units tried).  Every solve starts cold:
        the answer does not depend on earlier solves.
    """
    options = {k: v for k, v in locals().items() if k != "problem"}
    opts = ConicOptions.checked(problem, **options)
    # Clarabel's tolerances are partly absolute: posed at a low-mass slice's own scale the cone entries sit below
    # them (module docstring), so every step is solved in units of its largest density and certified unscaled
    scaled, c = problem.in_units_of_max()
    if opts.fisher_cone == "auto" and problem.fisher is not None:
        mu, _ = _flux_scale(scaled)
        first = "centred" if mu < _CENTRE_BELOW else "raw"
        res = _solve_forms(scaled, opts, [first, "raw" if first == "centred" else "centred"])
    else:
        res = _solve_forms(scaled, opts, [opts.fisher_cone])
    if c == 1.0:
        return res
    return certify_rescaled(problem, res, c, kkt_tol=opts.kkt_tol, check_convexity=opts.check_convexity)
