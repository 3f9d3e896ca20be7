"""One judge for every collision solver: the certificate of a returned point.

Each method has its own stopping rule and tolerance ``tol`` (the conic solver's gap, the
SQP's :math:`\\zeta` test, Newton's residual target).  When its rule says it has stopped at
a solution, the method hands the point to :func:`certify`, which decides the status by
the same three checks for every method:

1. the point and its objective are finite (an infinite objective means a flux through
   an emptied cell, :math:`s_k = 0`, :math:`m_k \\ne 0`, or a log-Fisher term at f = 0):
   ``NUMERICAL_ERROR``;
2. the scaled KKT residual (:meth:`CollisionProblem.kkt_residual`) is at most ``kkt_tol``,
   else ``NOT_CERTIFIED``;
3. with ``check_convexity``, the reduced Hessian is positive definite there (second-order
   test, :meth:`CollisionProblem.is_local_minimiser`), else ``NONCONVEX``.

A method that did not stop at a solution (iteration or time limit, solver failure,
reduced accuracy, the linearised energy) passes its own status as ``claimed``; it is kept,
and the residual and objective are still evaluated for the result.

A new method calls it once on its final, feasible point::

    cert = certify(problem, f, m, kkt_tol=kkt_tol, check_convexity=check_convexity)
    return CollisionResult.from_certificate(problem, f, m, cert, "mine", iterations, seconds, info)
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jko_cvx._numbers import real_array
from jko_cvx.collision._checks import check_bool, check_unit
from jko_cvx.collision.problem import CollisionProblem, KKTResidual
from jko_cvx.collision.result import CollisionResult, Status

__all__ = ["Certificate", "certify", "certify_rescaled", "certify_validated"]

_JUDGED = (Status.CONVERGED, Status.NOT_CERTIFIED, Status.NONCONVEX)  # the certificate's outcomes, judged again


@dataclass(frozen=True)
class Certificate:
    """What :func:`certify` found at a point (per slice for a batch).

    Attributes
    ----------
    status : Status or ndarray of Status
        The certified status (see :func:`certify`).
    residual : float or ndarray
        The total scaled KKT residual, the number compared with ``kkt_tol``.
    objective : float or ndarray
        :math:`J(f, m)` at the point (``inf`` outside the domain).
    kkt : KKTResidual or None
        The residual's components (None when the caller passed only ``residual``).

    Examples
    --------
    >>> import numpy as np
    >>> from jko_cvx import CollisionProblem, Grid, PowerKernel, certify, solve_collision
    >>> grid = Grid.uniform(-2.0, 2.0, 41)
    >>> prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt=0.01, beta=10.0)
    >>> res = solve_collision(prob, method="newton")
    >>> cert = certify(prob, res.f, res.m, kkt_tol=1e-6)
    >>> cert.status.name, bool(cert.residual < 1e-6), bool(cert.residual == cert.kkt.total)
    ('CONVERGED', True, True)
    """

    status: Status | NDArray
    residual: float | NDArray[np.float64]
    objective: float | NDArray[np.float64]
    kkt: KKTResidual | None = None


def certify(
    problem: CollisionProblem,
    f: ArrayLike,
    m: ArrayLike,
    *,
    kkt_tol: float,
    check_convexity: bool = True,
    claimed: Status | NDArray | None = None,
    kkt: KKTResidual | None = None,
    residual: float | NDArray | None = None,
    second_order: bool | NDArray[np.bool_] | None = None,
) -> Certificate:
    """Certify the point ``(f, m)`` a solver returned for ``problem``.

    Parameters
    ----------
    problem : CollisionProblem
        Unbatched, or batched with ``f`` of shape ``(B, N)``.
    f, m : array_like
        The returned point (feasible: the solver has projected it).
    kkt_tol : float
        Certification threshold on the scaled KKT residual, in (0, 1).
    check_convexity : bool, default True
        Run the second-order test on points that pass the residual test.
    claimed : Status or array of Status, optional
        The method's own verdict (per slice for a batch).  ``None`` or ``CONVERGED``
        means "stopped at a solution by its own rule" and is judged here; any other
        status is kept as it is.
    kkt : KKTResidual, optional
        The residual at ``(f, m)`` when the caller has it already.
    residual : float or ndarray, optional
        Only its total (``kkt.total``), when the caller has that already.
    second_order : bool or array of bool, optional
        The second-order test's outcome when the caller has it already (Newton gets it
        from its last Cholesky factorisation); computed here where needed otherwise.

    ``kkt``, ``residual`` and ``second_order`` are taken as given: pass them only as the
    solver computed them at this very point, or not at all (the certificate then evaluates
    them).  A negative entry of ``f`` counts through the residual's positivity part, relative
    to max f: values at the level of rounding pass, larger ones fail the residual test.

    Returns
    -------
    Certificate
        ``status`` is ``CONVERGED``, ``NOT_CERTIFIED``, ``NONCONVEX``, ``NUMERICAL_ERROR``
        or the ``claimed`` failure status.

    Examples
    --------
    A solver's answer is certified; the feasible point ``(f_star, 0)`` (no collision at all) is not:

    >>> import numpy as np
    >>> from jko_cvx import CollisionProblem, Grid, PowerKernel, certify, solve_collision
    >>> grid = Grid.uniform(-2.0, 2.0, 41)
    >>> prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt=0.01, beta=10.0)
    >>> res = solve_collision(prob, method="sqp")
    >>> certify(prob, res.f, res.m, kkt_tol=1e-6).status.name
    'CONVERGED'
    >>> cert = certify(prob, prob.f_star, np.zeros(grid.n - 1), kkt_tol=1e-6)
    >>> cert.status.name, bool(cert.residual > 1e-3)
    ('NOT_CERTIFIED', True)
    """
    kkt_tol = check_unit("kkt_tol", kkt_tol)
    check_convexity = check_bool("check_convexity", check_convexity)
    f = real_array("f", f)
    m = real_array("m", m)
    shape = problem.f_star.shape
    if f.shape != shape:
        raise ValueError(f"f must have shape {shape} (the problem's f_star), got {f.shape}")
    if m.shape != (*shape[:-1], shape[-1] - 1):
        raise ValueError(f"m must have shape {(*shape[:-1], shape[-1] - 1)} (one flux per cell edge), got {m.shape}")
    rows = shape[:-1]
    claimed = _given("claimed", claimed, rows, lambda c: isinstance(c, Status), "a Status")
    second_order = _given("second_order", second_order, rows, lambda o: isinstance(o, bool | np.bool_), "a bool")
    if residual is not None:
        try:
            total = np.asarray(residual, dtype=float) if not isinstance(residual, bool) else np.array(-1.0)
        except (TypeError, ValueError):
            total = np.array(-1.0)
        if total.shape not in ((), rows) or np.any(total < 0):  # NaN passes: a residual that could not be evaluated
            raise ValueError(f"residual must be a non-negative number (one per slice for a batch), got {residual!r}")
    if kkt is not None and not isinstance(kkt, KKTResidual):
        raise TypeError(f"kkt must be a KKTResidual (problem.kkt_residual(f, m)), got {type(kkt).__name__}")
    return certify_validated(problem, f, m, kkt_tol, check_convexity, claimed, kkt, residual, second_order)


def _given(name: str, value, rows: tuple[int, ...], ok, what: str):
    """A caller's per-point value (``claimed``, ``second_order``): None, one value, or one per slice of a batch
    (None there: not given for that slice)."""
    if value is None:
        return None
    arr = np.asarray(value, dtype=object)
    if arr.shape not in ((), rows) or not all(v is None or ok(v) for v in arr.ravel().tolist()):
        raise TypeError(f"{name} must be {what} or one per slice of a batch {rows}, got {value!r}")
    return value


def certify_validated(
    problem: CollisionProblem,
    f: NDArray[np.float64],
    m: NDArray[np.float64],
    kkt_tol: float,
    check_convexity: bool,
    claimed: Status | NDArray | None = None,
    kkt: KKTResidual | None = None,
    residual: float | NDArray | None = None,
    second_order: bool | NDArray[np.bool_] | None = None,
    objective: float | NDArray | None = None,
) -> Certificate:
    """:func:`certify` for arguments a solver has already checked (float arrays, ``kkt_tol`` in (0, 1)).

    The same certificate, without checking (and copying) the arguments again: a solver's
    final step, once per call.  ``f`` and ``m`` are only read.  ``objective``: the value of
    ``problem.objective(f, m)`` when the solver has it already (bit for bit).
    """
    if residual is None or objective is None:
        with np.errstate(all="ignore"):
            if residual is None:
                kkt = problem.kkt_residual(f, m) if kkt is None else kkt
                residual = kkt.total
            if objective is None:
                objective = problem.objective(f, m)
    if f.ndim == 1:
        finite = bool(np.isfinite(f).all() and np.isfinite(m).all() and np.isfinite(objective))
        status = _judge(
            problem, f, m, float(residual), objective, kkt_tol, check_convexity, claimed, second_order, None, finite
        )
        return Certificate(status, float(residual), float(objective), kkt)
    rows = f.shape[0]
    total = np.array(_per_row(residual, rows), dtype=float)  # a copy: the certificate's own
    objective = np.asarray(objective, dtype=float)
    claims = None if claimed is None else _per_row(np.asarray(claimed, dtype=object), rows)
    booleans = isinstance(second_order, np.ndarray) and second_order.dtype == bool  # the solver's outcomes
    orders = _per_row(second_order if booleans else np.asarray(second_order, dtype=object), rows)
    # the rows _judge would call CONVERGED, decided for the whole batch at once (the same tests, in the
    # same order of precedence); _judge decides every other row
    finite = np.isfinite(f).all(axis=-1) & np.isfinite(m).all(axis=-1) & np.isfinite(objective)
    clean = finite & (total <= kkt_tol)  # NaN: False (a comparison, no warning)
    if claims is not None:
        clean &= np.fromiter((c is None or c is Status.CONVERGED for c in claims), dtype=bool, count=rows)
    if check_convexity:
        clean &= orders if booleans else np.fromiter((o is not None and bool(o) for o in orders), bool, rows)
    status = np.empty(rows, dtype=object)
    status[clean] = Status.CONVERGED
    for i in np.flatnonzero(~clean).tolist():
        claim = None if claims is None else claims[i]
        status[i] = _judge(
            problem, f[i], m[i], total[i], objective[i], kkt_tol, check_convexity, claim, orders[i], i, bool(finite[i])
        )
    return Certificate(status, total, objective, kkt)


def certify_rescaled(
    problem: CollisionProblem, scaled: CollisionResult, c: float, *, kkt_tol: float, check_convexity: bool
) -> CollisionResult:
    """The answer ``scaled`` to ``problem.in_units_of_max()`` (unit ``c``), scaled back and certified against
    ``problem`` itself (:meth:`~jko_cvx.collision.CollisionProblem.in_units_of_max`).

    A failure status the solver claimed (iteration or time limit, solver error, ...) is kept; a
    certificate's outcome is judged again on the original problem.  ``info`` gains ``scaled_by = c``.
    """
    t0 = time.perf_counter()
    f, m = scaled.f * c, scaled.m * c
    claimed = None if scaled.status in _JUDGED else scaled.status
    cert = certify(problem, f, m, kkt_tol=kkt_tol, check_convexity=check_convexity, claimed=claimed)
    info = {**scaled.info, "scaled_by": c}
    if "kkt" in info:
        info["kkt"] = cert.kkt  # the residual's components on this problem, not the scaled one's
    seconds = scaled.seconds + time.perf_counter() - t0
    return CollisionResult.from_certificate(problem, f, m, cert, scaled.method, scaled.iterations, seconds, info)


def _per_row(value, rows: int):
    """``value`` with one entry per row: itself where it has that shape (np.broadcast_to costs ~8 us)."""
    return value if np.shape(value) == (rows,) else np.broadcast_to(value, (rows,))


def _judge(
    problem: CollisionProblem,
    f: NDArray,
    m: NDArray,
    residual: float,
    objective: float,
    kkt_tol: float,
    check_convexity: bool,
    claimed: Status | None,
    second_order: bool | None,
    row: int | None = None,
    finite: bool | None = None,
) -> Status:
    """The status of one point (row ``row`` of a batched problem); see :func:`certify`.

    ``finite``: whether f, m and the objective are all finite, when the caller has it.
    """
    if claimed is not None and claimed is not Status.CONVERGED:
        return claimed
    if finite is None:
        finite = bool(np.all(np.isfinite(f)) and np.all(np.isfinite(m)) and np.isfinite(objective))
    if not finite:
        return Status.NUMERICAL_ERROR
    if not residual <= kkt_tol:
        return Status.NOT_CERTIFIED
    if check_convexity:
        if second_order is None:
            sub = problem.with_f_star(problem.f_star[row]) if problem.batched else problem
            second_order = sub.is_local_minimiser(f, m)
        if not second_order:
            return Status.NONCONVEX
    return Status.CONVERGED
