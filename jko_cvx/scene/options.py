"""Solver options a scene may set: an allow-list per collision method and per conic solver.

A scene is data that may come from anyone, and ``collision.options`` reaches the solver.
Only options whose values are numbers, enumerations or booleans pass: tolerances,
iteration and time limits, the algorithm variants and ``verbose``.  Nothing that names a
file or a callable does (SCS's ``write_data_filename`` / ``log_csv_filename``, a
``callback``, a warm start ``m0``), and every value is checked here, before the run starts.
The per-method allow-list is derived from the methods' options dataclasses (each field's
:class:`~jko_cvx.collision.options.Spec`: its type, range, choices, and whether a scene may
set it), so it accepts what the solver accepts.

``collision.options.solver_options`` (method ``"conic"``) is checked against the allow-list
of the chosen CVXPY solver: Clarabel, SCS, OSQP and ECOS tolerances, iteration and time
limits and ``verbose``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jko_cvx.collision.options import Spec, scene_specs
from jko_cvx.collision.solve import OPTIONS
from jko_cvx.scene.schema import Rule, SceneError, check_known, require_table

__all__ = ["METHOD_OPTIONS", "RUN_KKT", "SOLVER_OPTIONS", "parse_options", "rule_of"]

RUN_KKT: dict[str, float] = {"newton": 1e-8, "nlp": 1e-8, "conic": 1e-6, "sqp": 1e-6}
"""Per method: the KKT threshold at which a run certifies its collision steps (the engine accepts a step
when every slice is certified at it; :class:`jko_cvx.engine.loop.Stepper`).  Newton and IPOPT reach
1e-8 at about the cost of 1e-6; the conic method's inner solves pin f to about ``sqrt(tol)`` and its residual
stops near 1e-8 to 1e-7; the paper's SQP keeps its own default, its failures being its exit flag.  A
scene's ``collision.options.kkt_tol`` sets another; a looser one (the paper's SQP has no KKT test of its
own) is honoured and the run's summary says so, since "certified" then means less.  A loose ``tol`` does
not loosen it: Newton certifies at the smaller of its ``tol`` and this threshold."""

_TOL = Rule("float", lo=0.0, hi=1.0, lo_open=True, hi_open=True)
_COUNT = Rule("int", lo=1)
_BOOL = Rule("bool")
_SECONDS = Rule("float", lo=0.0, lo_open=True)
_POSITIVE = Rule("float", lo=0.0, lo_open=True)  # IPOPT's tolerances may exceed 1


def rule_of(spec: Spec) -> Rule:
    """The scene :class:`Rule` of a collision option's :class:`~jko_cvx.collision.options.Spec`."""
    if not spec.scene:
        raise ValueError(f"a {spec.kind} option is not set by scenes")
    return Rule(spec.kind, lo=spec.lo, hi=spec.hi, lo_open=spec.lo_open, hi_open=spec.hi_open, choices=spec.choices)


METHOD_OPTIONS: dict[str, dict[str, Rule]] = {
    method: {name: rule_of(spec) for name, spec in scene_specs(cls).items()} for method, cls in OPTIONS.items()
}
"""Per method: the options a scene may pass and the values each accepts, derived from the method's
options dataclass (:data:`jko_cvx.collision.solve.OPTIONS`): its fields marked for scenes, with their
ranges and choices."""

SOLVER_OPTIONS: dict[str, dict[str, Rule]] = {
    "CLARABEL": {
        **{
            name: _TOL
            for name in (
                "tol_gap_abs",
                "tol_gap_rel",
                "tol_feas",
                "tol_infeas_abs",
                "tol_infeas_rel",
                "tol_ktratio",
                "reduced_tol_gap_abs",
                "reduced_tol_gap_rel",
                "reduced_tol_feas",
                "reduced_tol_infeas_abs",
                "reduced_tol_infeas_rel",
                "reduced_tol_ktratio",
            )
        },
        "max_iter": _COUNT,
        "time_limit": _SECONDS,
        "verbose": _BOOL,
    },
    "SCS": {
        "eps_abs": _TOL,
        "eps_rel": _TOL,
        "eps_infeas": _TOL,
        "max_iters": _COUNT,
        "time_limit_secs": _SECONDS,
        "verbose": _BOOL,
    },
    "OSQP": {
        "eps_abs": _TOL,
        "eps_rel": _TOL,
        "eps_prim_inf": _TOL,
        "eps_dual_inf": _TOL,
        "max_iter": _COUNT,
        "time_limit": _SECONDS,
        "verbose": _BOOL,
    },
    "IPOPT": {  # method "nlp": limits and termination tolerances only
        "max_cpu_time": _SECONDS,
        "max_wall_time": _SECONDS,
        "acceptable_tol": _POSITIVE,
        "acceptable_iter": Rule("int", lo=0),
        "constr_viol_tol": _POSITIVE,
        "dual_inf_tol": _POSITIVE,
        "compl_inf_tol": _POSITIVE,
    },
    "ECOS": {
        "abstol": _TOL,
        "reltol": _TOL,
        "feastol": _TOL,
        "max_iters": _COUNT,
        "verbose": _BOOL,
    },
}
"""Per CVXPY solver: the ``solver_options`` a scene may pass (no option that writes files)."""

_FILE_HINT = "options that write files or run code are never accepted from a scene"


def parse_options(method: str, options: Any, where: str = "collision.options") -> dict[str, Any]:
    """Check ``collision.options`` for ``method`` against :data:`METHOD_OPTIONS`; return a plain dict.

    The options must also be keyword options of the installed solver function: an option on
    the allow-list that this version's solver lacks (``time_limit`` before it exists) is
    refused here rather than at the first step.
    """
    options = require_table(options, where)
    allowed = METHOD_OPTIONS[method]
    _refuse_unknown(options, allowed, where, f"method {method!r}")
    out: dict[str, Any] = {}
    for name, val in options.items():
        if name == "solver_options":
            continue
        out[name] = allowed[name].parse(val, f"{where}.{name}")
    if "solver_options" in options:
        solver = "IPOPT" if method == "nlp" else out.get("solver", "CLARABEL")
        sub = require_table(options["solver_options"], f"{where}.solver_options")
        _refuse_unknown(sub, SOLVER_OPTIONS[solver], f"{where}.solver_options", f"solver {solver!r}")
        out["solver_options"] = {
            name: SOLVER_OPTIONS[solver][name].parse(val, f"{where}.solver_options.{name}") for name, val in sub.items()
        }
    _check_supported(method, out, where)
    return out


def _refuse_unknown(options: Mapping[str, Any], allowed: Mapping[str, Rule], where: str, what: str) -> None:
    try:
        check_known(options, allowed, where)
    except SceneError as exc:
        raise SceneError(f"{exc} (the allow-list for {what}; {_FILE_HINT})") from None


def _check_supported(method: str, options: Mapping[str, Any], where: str) -> None:
    """Options on the allow-list must exist in this version's solver (its keyword-only parameters)."""
    import inspect

    from jko_cvx.collision.solve import METHODS

    params = inspect.signature(METHODS[method]).parameters
    known = {p.name for p in params.values() if p.kind is p.KEYWORD_ONLY}
    if method == "conic" and "solver" in options:
        from jko_cvx.collision import conic_solvers

        if options["solver"] not in conic_solvers():
            raise SceneError(f"{where}.solver = {options['solver']!r} is not installed; installed: {conic_solvers()}")
    if method == "newton" and options.get("compiled"):
        from jko_cvx.collision.newton import NewtonOptions

        try:  # the options' own check: compiled = true needs numba
            NewtonOptions(compiled=True)
        except ImportError as exc:
            raise SceneError(f"{where}.compiled = true: {exc}") from None
    missing = sorted(set(options) - known)
    if missing:
        raise SceneError(
            f"{where}.{missing[0]} is not an option of method {method!r} in this version; it accepts {sorted(known)}"
        )
