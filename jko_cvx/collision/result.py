"""Solver results and statuses (modelled on diffrax's RESULTS and scipy's OptimizeResult)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["CollisionResult", "Status"]


class Status(enum.Enum):
    """Outcome of a collision solve; the value is the human-readable message.

    Examples
    --------
    >>> from jko_cvx import Status
    >>> Status.CONVERGED.success, Status.MAX_ITERATIONS.success
    (True, False)
    >>> [s.name for s in Status if s.success]
    ['CONVERGED', 'LINEARIZED']
    >>> Status.NOT_CERTIFIED.value
    'the solver stopped but the KKT residual is above tolerance'
    """

    CONVERGED = "converged: KKT residual within tolerance"
    LINEARIZED = (
        "solved the linearised-energy (semi-implicit) problem; its KKT residual against the full "
        "problem is reported but not certified"
    )
    INACCURATE = "the solver reports reduced accuracy (e.g. CVXPY OPTIMAL_INACCURATE); not certified"
    NOT_CERTIFIED = "the solver stopped but the KKT residual is above tolerance"
    MAX_ITERATIONS = "iteration limit reached before convergence (the paper's exit flag e_f = 1)"
    TIME_LIMIT = "time limit reached before convergence"
    NONCONVEX = "loss of convexity: the reduced Hessian is not positive definite"
    NUMERICAL_ERROR = "numerical breakdown (non-finite values or a failed factorisation)"
    INFEASIBLE = "the solver reports the problem infeasible or unbounded"
    SOLVER_ERROR = "the external solver failed"

    @property
    def success(self) -> bool:
        """True for the statuses that deliver what was asked for."""
        return self in (Status.CONVERGED, Status.LINEARIZED)


@dataclass
class CollisionResult:
    """Result of one collision solve (or a batch of them).

    Attributes
    ----------
    f : ndarray, shape (N,) or (B, N)
        Density after the collision step, :math:`f^{n+1}`; feasible and mass-conserving.
    m : ndarray, shape (N-1,) or (B, N-1)
        Fluxes at the half points.
    status : Status or ndarray of Status
        Outcome; ``status.value`` is the message.  One per slice for a batch.
    method : str
        ``"conic"``, ``"sqp"`` or ``"newton"``.
    iterations : int or ndarray
        Iterations (SQP/Newton) or interior-point iterations summed over conic solves.
    objective : float or ndarray
        :math:`J(f, m)` of the returned point.
    kkt_residual : float or ndarray
        Total scaled KKT residual (see :meth:`CollisionProblem.kkt_residual`).
    mass_error : float or ndarray
        Relative mass error against ``f_star``.
    seconds : float
        Wall time of the solve (CVXPY compile time excluded; see ``info``).
    info : dict
        Method-specific details (e.g. conic ``passes``, ``solver_status``, ``compile_seconds``;
        SQP ``exit_flag`` and ``zeta``).

    Examples
    --------
    A batch of two slices (one row of ``f_star`` each), one status per slice:

    >>> import numpy as np
    >>> from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
    >>> grid = Grid.uniform(-2.0, 2.0, 41)
    >>> g = np.exp(-2 * grid.points**2)
    >>> prob = CollisionProblem(grid, PowerKernel(1.0), np.stack([g, 0.5 * g]), dt=0.01, beta=10.0)
    >>> res = solve_collision(prob, method="newton")
    >>> res.method, res.f.shape, res.m.shape
    ('newton', (2, 41), (2, 40))
    >>> [s.name for s in res.status], bool(np.all(res.kkt_residual < 1e-8))
    (['CONVERGED', 'CONVERGED'], True)
    >>> bool(np.all(np.abs(res.mass_error) < 1e-12))  # the step conserves mass
    True
    """

    f: NDArray[np.float64]
    m: NDArray[np.float64]
    status: Any
    method: str
    iterations: Any
    objective: Any
    kkt_residual: Any
    mass_error: Any
    seconds: float
    info: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def from_point(
        cls,
        problem: Any,
        f: NDArray,
        m: NDArray,
        status: Status,
        method: str,
        iterations: int,
        kkt_residual: float,
        seconds: float,
        info: dict[str, Any] | None = None,
    ) -> CollisionResult:
        """A single-problem result at ``(f, m)``: the objective and mass error are evaluated here."""
        return cls(
            f=f,
            m=m,
            status=status,
            method=method,
            iterations=iterations,
            objective=float(problem.objective(f, m)),
            kkt_residual=float(kkt_residual),
            mass_error=float(problem.mass_error(f)),
            seconds=seconds,
            info=info or {},
        )

    @classmethod
    def from_certificate(
        cls,
        problem: Any,
        f: NDArray,
        m: NDArray,
        certificate: Any,
        method: str,
        iterations: Any,
        seconds: float,
        info: dict[str, Any] | None = None,
    ) -> CollisionResult:
        """A result at ``(f, m)`` from a :class:`~jko_cvx.collision.certify.Certificate` (single or batched)."""
        batched = np.ndim(f) == 2
        return cls(
            f=f,
            m=m,
            status=certificate.status,
            method=method,
            iterations=iterations,
            objective=certificate.objective if batched else float(certificate.objective),
            kkt_residual=certificate.residual if batched else float(certificate.residual),
            mass_error=problem.mass_error(f) if batched else float(problem.mass_error(f)),
            seconds=seconds,
            info=info or {},
        )

    @property
    def success(self) -> bool | NDArray[np.bool_]:
        """True when the status is a success (per slice for a batch)."""
        if isinstance(self.status, Status):
            return self.status.success
        return np.array([s.success for s in np.ravel(self.status)]).reshape(np.shape(self.status))

    @property
    def message(self) -> str | list[str]:
        """Human-readable status message(s); a solver's ``info["hint"]`` (the likely cause of a failure) follows."""
        if isinstance(self.status, Status):
            return self.status.value + (f"; {self.info['hint']}" if self.info.get("hint") else "")
        return [s.value for s in np.ravel(self.status)]

    def __repr__(self) -> str:
        if isinstance(self.status, Status):
            return (
                f"CollisionResult(method={self.method!r}, status={self.status.name}, "
                f"iterations={self.iterations}, objective={self.objective:.12g}, "
                f"kkt_residual={self.kkt_residual:.2e}, mass_error={self.mass_error:.1e}, "
                f"seconds={self.seconds:.4f})"
            )
        ok = int(np.sum(self.success))
        return f"CollisionResult(method={self.method!r}, batch={len(self.status)}, success={ok}/{len(self.status)})"
