"""The discrete collision step: one Fisher-regularised JKO step in velocity.

This module is the single truth that every solver and every test is judged by.

Discrete problem (``eqn:non-uniform JKO`` with ``eqn:linear_constraint``)
------------------------------------------------------------------------
Unknowns: densities :math:`f_j` at the N grid points and fluxes
:math:`m_k = m_{k+1/2}` at the N-1 interior half points (zero flux through the
ends).  With :math:`s_k = f_k + f_{k+1}` and :math:`\\Delta v_k = v_{k+1} - v_k`,

.. math::

    J(f, m) = \\sum_k \\Big[\\frac{2 m_k^2}{s_k}
              + \\frac{c}{\\Delta v_k^2}\\,\\psi(f_k, f_{k+1})\\Big]\\Delta v_k
              + \\Delta t\\,\\sigma\\, f^\\top K f,
    \\qquad c = \\Delta t^2/\\beta^2,

subject to :math:`h \\odot (f - f^*) + D m = 0` (``eqn:linear_constraint`` times
:math:`h_j`; summing the rows shows that every feasible point has the mass of
:math:`f^*`).  :math:`K_{il} = W(v_i - v_l) h_i h_l` and :math:`\\sigma` is the
collision strength (see :mod:`jko_cvx.kernels`).  The Fisher term :math:`\\psi` is

* ``"log"`` (the paper's): :math:`(\\log y - \\log x)^2 (x + y)/2`;
* ``"perspective"``: :math:`(y - x)^2 / ((x + y)/2)`, a rotated second-order cone,
  exactly representable in CVXPY; same continuum limit :math:`|\\nabla \\log f|^2 f`;
* none (:math:`\\beta = \\infty`).

KKT residual
------------
Stationarity with a multiplier :math:`\\phi` (a potential, one value per grid
point) reads

.. math::

    r^f_j = \\frac{\\partial_{f_j} J}{h_j} + \\phi_j = 0, \\qquad
    r^m_k = \\partial_{m_k} J + \\phi_k - \\phi_{k+1} = 0 .

:meth:`CollisionProblem.kkt_residual` chooses :math:`\\phi` by weighted least
squares with weights :math:`w_j = f_j / \\max f` and :math:`\\omega_k = s_k / (2\\max f)`
(the scale-free, complementarity-like weighting an interior-point method
controls: vacuum cells, where the potential is undetermined, carry no weight),
and reports

* ``stationarity`` = :math:`\\max(\\max_j w_j|r^f_j|, \\max_k \\omega_k |r^m_k|)` divided by
  the potential scale :math:`\\max_j w_j \\sum_{\\text{terms}} |\\partial_{f_j}J_{\\text{term}}|/h_j`;
* ``feasibility`` = :math:`\\|h\\odot(f-f^*) + Dm\\|_1 / \\|h \\odot f^*\\|_1` (relative mass units);
  with ``conserve_momentum`` also the relative momentum change
  (:meth:`CollisionProblem.momentum_change`), and the stationarity has one more
  multiplier :math:`u` (:math:`r^m_k` gains :math:`u\\,\\Delta v_k`);
* ``positivity`` = :math:`\\max(0, -\\min_j f_j) / \\max_j f_j`;
* ``total`` = the largest of the three.  A solution is *certified* when
  ``total <= kkt_tol``.

Momentum
--------
Multiplying the constraint by :math:`v_j` and summing gives
:math:`\\sum_j v_j h_j (f_j - f^*_j) = \\sum_k m_k \\Delta v_k`: the paper's step changes the
slice momentum by the discretisation error (measured 2e-6 to 1e-5 relative per step on the
agreement family), which the continuous operator keeps at zero.  For a point-symmetric
datum the changes cancel between the slices at x and -x, but only as long as the solver
keeps the symmetry: on ``inhom_gamma3_lambda4`` rounding-level asymmetry at the x = 0
slice grows by 30-1000x per step once the bumps meet (a nearly flat direction of the
step), and the total momentum drifts to 3e-9 whatever the solver tolerance (6e-10 at
tol = 1e-11).  ``conserve_momentum=True`` adds :math:`\\sum_k m_k \\Delta v_k = 0` (one
linear constraint, one more multiplier) and the drift is 1.4e-15 over the same run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from jko_cvx._numbers import real_array, real_scalar
from jko_cvx.collision._linalg import divergence, divergence_adjoint, solve_sym_tridiagonal
from jko_cvx.collision.terms import (
    FISHER_TERMS,
    band_coefficients,
    reduced_bands,
    wasserstein_derivatives,
    wasserstein_value,
)
from jko_cvx.grid import Grid
from jko_cvx.kernels import EnergyOperator, PowerKernel
from jko_cvx.mesh.moments import restore_moments

__all__ = ["LOG_FORM_METHODS", "MOMENTUM_METHODS", "CollisionProblem", "FisherForm", "KKTResidual", "methods_text"]

FisherForm = Literal["log", "perspective"]
_FISHER_FORMS = ("log", "perspective")
LOG_FORM_METHODS = ("newton", "sqp", "nlp")
"""The methods that pose ``fisher="log"`` (conic cannot: the log form is not conic-representable)."""
MOMENTUM_METHODS = ("newton", "conic", "nlp")
"""The methods with the momentum constraint ``conserve_momentum=True`` (the paper's SQP has none)."""


def methods_text(methods: tuple[str, ...], quote: str = '"') -> str:
    """``"newton", "sqp" or "nlp"``: the alternatives an error message names."""
    names = [f"{quote}{m}{quote}" for m in methods]
    return ", ".join(names[:-1]) + f" or {names[-1]}" if len(names) > 1 else names[0]


@dataclass(frozen=True)
class KKTResidual:
    """Components of the scaled KKT residual (see module docstring).

    For a batched problem each field is an array with one entry per slice.

    Examples
    --------
    >>> import numpy as np
    >>> from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
    >>> grid = Grid.uniform(-2.0, 2.0, 41)
    >>> prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt=0.01, beta=10.0)
    >>> res = solve_collision(prob, method="newton")
    >>> kkt = prob.kkt_residual(res.f, res.m)
    >>> bool(kkt.total < 1e-8), kkt.multiplier.shape  # one multiplier per grid point
    (True, (41,))
    >>> bool(kkt.total == max(kkt.stationarity, kkt.feasibility, kkt.positivity))
    True
    """

    stationarity: NDArray[np.float64] | float
    feasibility: NDArray[np.float64] | float
    positivity: NDArray[np.float64] | float
    multiplier: NDArray[np.float64]

    @property
    def total(self) -> NDArray[np.float64] | float:
        """The largest component: the number a solution is certified by."""
        return np.maximum(np.maximum(self.stationarity, self.feasibility), self.positivity)


@dataclass(frozen=True)
class TermParts:
    """Objective, gradient or Hessian split by term (Wasserstein, Fisher, energy)."""

    wasserstein: object
    fisher: object
    energy: object


def _check_positive_finite(name: str, value: object, allow_inf: bool = False) -> float:
    x = real_scalar(name, value)
    if np.isnan(x) or x <= 0 or (np.isinf(x) and not allow_inf):
        rng = "(0, inf]" if allow_inf else "(0, inf)"
        raise ValueError(f"{name} must lie in {rng}, got {value!r}")
    return x


def add_pentadiagonal(dense: NDArray[np.float64], diag: NDArray, off1: NDArray, off2: NDArray) -> NDArray[np.float64]:
    """``dense`` (broadcast over the bands' batch axes) plus a symmetric pentadiagonal matrix."""
    n1 = dense.shape[-1]
    H = np.empty((*diag.shape[:-1], n1, n1))
    H[...] = dense
    flat = H.reshape(*diag.shape[:-1], n1 * n1)  # a view: strided diagonals, no fancy indexing
    flat[..., :: n1 + 1] += diag
    flat[..., 1 :: n1 + 1] += off1
    flat[..., n1 :: n1 + 1] += off1
    flat[..., 2 : n1 * (n1 - 2) : n1 + 1] += off2
    flat[..., 2 * n1 :: n1 + 1] += off2
    return H


class CollisionProblem:
    """One collision step: minimise :math:`J(f, m)` subject to the continuity constraint.

    Parameters
    ----------
    grid : Grid
        Velocity grid (non-uniform allowed).
    kernel : PowerKernel
        Interaction kernel :math:`W(v) = |v|^\\gamma/\\gamma`.
    f_star : array_like, shape (N,) or (B, N)
        The density before the collision step (:math:`f^{n+1/2}`): finite, non-negative,
        with positive mass.  A 2-D array is a batch of B independent problems on the
        same grid (one row per x-slice).  ``fisher="log"`` needs ``f_star > 0``.
    dt : float
        Time step :math:`\\Delta t > 0`.
    strength : float, default 1.0
        Collision strength :math:`\\sigma > 0` (:math:`\\lambda/2` for ``eqn: gke``,
        1 for ``eqn: gke_hom``).
    beta : float, default inf
        Fisher weight :math:`\\beta \\in (0, \\infty]`; the regulariser is
        :math:`\\beta^{-2}\\Delta t^2 \\int |\\nabla\\log f|^2 f`.  ``inf`` means no regulariser.
    fisher : {"perspective", "log"} or None, default "perspective"
        Discretisation of the Fisher information; ignored (set to None) when ``beta`` is inf.
    conserve_momentum : bool, default False
        Add the linear constraint :math:`\\sum_k m_k \\Delta v_k = 0`, i.e.
        :math:`\\sum_j v_j h_j (f_j - f^*_j) = 0`: the step then conserves the slice's
        momentum exactly, as the continuous collision operator does (``prop:properties``).
        The paper's discrete step (False) conserves it only up to the discretisation
        error, so momentum is conserved in a run only through the symmetry of the datum,
        which the solver's rounding breaks (see the module docstring).

    Examples
    --------
    One step from :math:`f^* = e^{-2v^2}` with the Fisher term, solved by the conic reference
    and by Newton; both reach the same minimiser:

    >>> import numpy as np
    >>> from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
    >>> grid = Grid.uniform(-2.0, 2.0, 41)
    >>> prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt=0.01, beta=10.0)
    >>> prob.n, prob.batched, prob.fisher
    (41, False, 'perspective')
    >>> ref = solve_collision(prob, method="conic")
    >>> new = solve_collision(prob, method="newton")
    >>> ref.status.name, new.status.name
    ('CONVERGED', 'CONVERGED')
    >>> bool(np.abs(ref.f - new.f).max() < 1e-5), bool(abs(ref.objective - new.objective) < 1e-8)
    (True, True)
    >>> bool(prob.objective(new.f, new.m) < prob.objective(prob.f_star, np.zeros(grid.n - 1)))
    True
    """

    def __init__(
        self,
        grid: Grid,
        kernel: PowerKernel,
        f_star: ArrayLike,
        dt: float,
        strength: float = 1.0,
        beta: float = np.inf,
        fisher: FisherForm | None = "perspective",
        conserve_momentum: bool = False,
    ) -> None:
        if not isinstance(grid, Grid):
            raise TypeError(f"grid must be a jko_cvx.Grid, got {type(grid).__name__}")
        if not isinstance(kernel, PowerKernel):
            raise TypeError(f"kernel must be a jko_cvx.PowerKernel, got {type(kernel).__name__}")
        self.grid = grid
        self.kernel = kernel
        self.dt = _check_positive_finite("dt", dt)
        self.strength = _check_positive_finite("strength", strength)
        self.beta = _check_positive_finite("beta", beta, allow_inf=True)
        if fisher is not None and fisher not in _FISHER_FORMS:
            raise ValueError(f"fisher must be one of {_FISHER_FORMS} or None, got {fisher!r}")
        if np.isinf(self.beta) or fisher is None:
            self.beta, fisher = np.inf, None
        self.fisher: FisherForm | None = fisher
        if not isinstance(conserve_momentum, (bool, np.bool_)):
            raise TypeError(f"conserve_momentum must be True or False, got {conserve_momentum!r}")
        self.conserve_momentum = bool(conserve_momentum)
        self.f_star = self._validate_density(f_star)
        self.f_star.flags.writeable = False
        with np.errstate(over="ignore"):
            self.mass = self.f_star @ grid.h
        if not np.all(np.isfinite(self.mass)):
            raise ValueError("f_star's mass sum(h * f_star) overflows the floating-point range: rescale f_star")
        if np.any(self.mass <= 0):
            raise ValueError("f_star must have positive mass (it is zero)")
        if fisher == "log" and np.any(self.f_star <= 0):
            raise ValueError('f_star must be strictly positive for fisher="log" (log f is undefined at 0)')
        # Coefficients of the edge terms, in NumPy arithmetic (no Python OverflowError):
        # each must be a finite float, else the arguments are out of range.
        with np.errstate(all="ignore"):
            self.c_fisher = 0.0 if fisher is None else float((np.float64(self.dt) / self.beta) ** 2)
            self.wass_coef = 2.0 * grid.dv
            self.fisher_coef = self.c_fisher / grid.dv
            self.energy_coef = float(np.float64(self.dt) * self.strength)
        self.wass_coef.flags.writeable = False  # constants of the problem, as f_star
        self.fisher_coef.flags.writeable = False
        if not np.all(np.isfinite(self.fisher_coef)):
            raise ValueError(
                f"beta = {beta!r} and dt = {dt!r} give the Fisher weight (dt/beta)^2 / dv = inf: "
                "beta must be larger (or dt smaller), within the floating-point range"
            )
        if not np.isfinite(self.energy_coef):
            raise ValueError(f"dt * strength = {dt!r} * {strength!r} overflows: dt must be smaller")
        self.energy: EnergyOperator = kernel.energy_operator(grid)

    # ------------------------------------------------------------------ basics
    def _validate_density(self, f_star: ArrayLike) -> NDArray[np.float64]:
        f = real_array("f_star", f_star)
        if f.ndim not in (1, 2) or f.shape[-1] != self.grid.n:
            raise ValueError(
                f"f_star must have shape ({self.grid.n},) or (B, {self.grid.n}) to match the grid, got {f.shape}"
            )
        if f.ndim == 2 and f.shape[0] == 0:
            raise ValueError(f"f_star as a batch must have at least one row, got shape {f.shape}")
        if not np.all(np.isfinite(f)):
            raise ValueError("f_star must be finite (found NaN or inf)")
        if np.any(f < 0):
            raise ValueError(f"f_star must be non-negative, min(f_star) = {f.min()!r}")
        return f

    @property
    def n(self) -> int:
        """Number of velocity grid points N."""
        return self.grid.n

    @property
    def batched(self) -> bool:
        """True when ``f_star`` holds several independent problems (one per row)."""
        return self.f_star.ndim == 2

    @property
    def batch_size(self) -> int:
        """Number of independent problems (1 unless batched)."""
        return self.f_star.shape[0] if self.batched else 1

    def slice(self, i: int) -> CollisionProblem:
        """The i-th problem of a batch as an unbatched problem (same grid, kernel, dt)."""
        if not self.batched:
            raise ValueError("slice() needs a batched problem")
        return self.with_f_star(self.f_star[i])

    def with_f_star(self, f_star: ArrayLike) -> CollisionProblem:
        """Same grid, kernel, dt, strength and regulariser with a new ``f_star``."""
        return CollisionProblem(
            self.grid, self.kernel, f_star, self.dt, self.strength, self.beta, self.fisher, self.conserve_momentum
        )

    def in_units_of_max(self) -> tuple[CollisionProblem, float]:
        """The same step with densities of order one, and the unit: ``(scaled, c)``, :math:`c = \\max f^*`.

        Every term of :math:`J` but the energy is 1-homogeneous in :math:`(f, m)` (the kinetic
        term :math:`2 m^2 / s`, both Fisher forms) and the energy is 2-homogeneous, so the
        minimiser of the step for :math:`(f^*, \\text{strength})` is :math:`c` times the minimiser
        for :math:`(f^*/c, c\\,\\text{strength})`; ``scaled`` is that problem.  ``c = 1`` (and
        ``scaled`` this problem) where max f* is not a finite positive number or is 1, or where the
        scaled strength is not a finite positive number.  Unbatched problems only.
        """
        if self.batched:
            raise ValueError("in_units_of_max() needs an unbatched problem (use slice(i))")
        c = float(np.max(self.f_star))
        if not (np.isfinite(c) and c > 0) or c == 1.0:
            return self, 1.0
        try:
            scaled = CollisionProblem(self.grid, self.kernel, self.f_star / c, self.dt, self.strength * c, self.beta,
                                      self.fisher, self.conserve_momentum)  # fmt: skip
        except ValueError:  # the scaled strength leaves the float range (strength 1e300, max f* 1e10)
            return self, 1.0
        return scaled, c

    def rows(self, index: ArrayLike | slice) -> CollisionProblem:
        """The batch of rows ``f_star[index]`` (an unbatched problem counts as one row).

        The rows were validated with this problem, so nothing is checked again: this is
        the cheap form of :meth:`with_f_star` that the batched solvers use on the slices
        still iterating.  The result is always batched.
        """
        sub = object.__new__(type(self))  # copy.copy's shallow copy, without its reduce protocol
        sub.__dict__.update(self.__dict__)
        f = self.f_star if self.batched else self.f_star[None]
        sub.f_star = f[index]
        sub.f_star.flags.writeable = False
        sub.mass = np.atleast_1d(self.mass)[index]
        return sub

    def with_dt(self, dt: float) -> CollisionProblem:
        """Same problem with a new time step."""
        return CollisionProblem(
            self.grid, self.kernel, self.f_star, dt, self.strength, self.beta, self.fisher, self.conserve_momentum
        )

    def __repr__(self) -> str:
        b = f", batch={self.batch_size}" if self.batched else ""
        c = ", conserve_momentum=True" if self.conserve_momentum else ""
        return (
            f"CollisionProblem(N={self.n}, gamma={self.kernel.gamma:g}, dt={self.dt:g}, "
            f"strength={self.strength:g}, beta={self.beta:g}, fisher={self.fisher!r}{c}{b})"
        )

    # ------------------------------------------------------------ constraint
    def constraint_matrix(self) -> sp.csr_matrix:
        """Sparse ``A`` (N x (2N-1)) of :math:`A u = b`, ``u = [f, m]``: ``A = [diag(h), D]``."""
        n = self.n
        D = sp.diags([np.ones(n - 1), -np.ones(n - 1)], [0, -1], shape=(n, n - 1))
        return sp.hstack([sp.diags(self.grid.h), D]).tocsr()

    def constraint_rhs(self) -> NDArray[np.float64]:
        """``b = h * f_star``."""
        return self.f_star * self.grid.h

    def constraint_residual(self, f: ArrayLike, m: ArrayLike) -> NDArray[np.float64]:
        """:math:`h\\odot(f - f^*) + D m` (mass units, one entry per grid point)."""
        return self.grid.h * (np.asarray(f) - self.f_star) + divergence(m)

    def momentum_change(self, f: ArrayLike) -> NDArray[np.float64] | float:
        """Relative momentum change :math:`|\\sum_j v_j h_j (f_j - f^*_j)| / \\sum_j |v_j| h_j f^*_j`."""
        v, h = self.grid.points, self.grid.h
        num = np.abs((np.asarray(f, dtype=float) - self.f_star) @ (v * h))
        return num / np.maximum(self.f_star @ (np.abs(v) * h), np.finfo(float).tiny)

    def flux_from_density(self, f: ArrayLike) -> NDArray[np.float64]:
        """The unique flux with :math:`h\\odot(f-f^*) + Dm = 0` for an ``f`` of the right mass.

        :math:`m_k = -\\sum_{j \\le k} h_j (f_j - f^*_j)`.
        """
        dm = self.grid.h * (np.asarray(f, dtype=float) - self.f_star)
        return -np.cumsum(dm, axis=-1)[..., :-1]

    def density_from_flux(self, m: ArrayLike) -> NDArray[np.float64]:
        """:math:`f = f^* - (Dm)/h`: the density that makes ``m`` feasible."""
        return self.f_star - divergence(m) / self.grid.h

    def on_momentum_plane(self, m: ArrayLike) -> NDArray[np.float64]:
        """Euclidean projection of fluxes onto :math:`\\sum_k m_k \\Delta v_k = 0` (identity without
        ``conserve_momentum``): the flux of a density with the momentum of ``f_star``."""
        m = np.asarray(m, dtype=float)
        if not self.conserve_momentum:
            return m
        a = self.grid.dv
        return m - np.multiply.outer((m @ a) / (a @ a), a)

    def project_feasible(self, f: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Clip ``f`` at 0, rescale it to the mass of ``f_star`` and rebuild ``m``.

        Used on solver outputs (conic solvers return entries around -1e-13 and satisfy
        the constraint only to their tolerance).  The result conserves mass (and, with
        ``conserve_momentum``, momentum: see :func:`jko_cvx.mesh.moments.restore_moments`)
        to machine precision.  A flux through an emptied edge (:math:`f_k = f_{k+1} = 0`)
        is set to 0: the cumulative sum leaves rounding noise there (1e-17), which
        would cost an infinite Wasserstein term; what it removes from the constraint
        shows in the KKT residual's feasibility part, never in the mass.
        """
        f = np.maximum(np.asarray(f, dtype=float), 0.0)
        if self.conserve_momentum:
            momentum = self.f_star @ (self.grid.points * self.grid.h)
            f, _ = restore_moments(f, self.grid.h, self.grid.points, self.mass, momentum)
        else:
            f, _ = restore_moments(f, self.grid.h, self.grid.points, self.mass)
        m = self.flux_from_density(f)
        return f, np.where(f[..., :-1] + f[..., 1:] > 0, m, 0.0)

    def initial_point(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The feasible starting point ``(f_star, 0)``."""
        return self.f_star.copy(order="K"), np.zeros((*self.f_star.shape[:-1], self.n - 1))

    # ------------------------------------------------------------ objective
    def _edges(self, f: NDArray[np.float64]) -> tuple[NDArray, NDArray, NDArray]:
        x, y = f[..., :-1], f[..., 1:]
        return x, y, x + y

    def objective_parts(self, f: ArrayLike, m: ArrayLike) -> TermParts:
        """The three terms of :math:`J`: Wasserstein, Fisher and energy (``dt*strength*f'Kf``)."""
        f = np.asarray(f, dtype=float)
        m = np.asarray(m, dtype=float)
        x, y, s = self._edges(f)
        with np.errstate(divide="ignore", invalid="ignore"):
            # Phi(0, 0) = 0, Phi(0, m != 0) = inf (Benamou-Brenier convention).
            q = np.where(s > 0, wasserstein_value(m, np.where(s > 0, s, 1.0)), np.where(m == 0, 0.0, np.inf))
            wass = q @ self.wass_coef
            if self.fisher is None:
                fis = np.zeros_like(wass)
            else:
                fis = FISHER_TERMS[self.fisher].guarded_value(x, y, s) @ self.fisher_coef
        en = self.energy_coef * self.energy.quadratic(f)
        return TermParts(wass, fis, en)

    def objective(self, f: ArrayLike, m: ArrayLike) -> NDArray[np.float64] | float:
        """:math:`J(f, m)` (``inf`` outside the domain of the Wasserstein or Fisher term)."""
        p = self.objective_parts(f, m)
        return p.wasserstein + p.fisher + p.energy

    def gradient_parts(self, f: ArrayLike, m: ArrayLike) -> TermParts:
        """Gradient of each term as ``(grad_f, grad_m)`` pairs; energy has ``grad_m = 0``."""
        f = np.asarray(f, dtype=float)
        m = np.asarray(m, dtype=float)
        x, y, s = self._edges(f)
        zf = np.zeros_like(f)
        vac = s <= 0  # vacuum edge (f_k = f_{k+1} = 0): take the zero subgradient
        with np.errstate(divide="ignore", invalid="ignore"):
            s_safe = np.where(vac, 1.0, s)
            wd = wasserstein_derivatives(np.where(vac, 0.0, m), s_safe, self.wass_coef)
            gfw = zf.copy()
            gfw[..., :-1] += wd.g_s
            gfw[..., 1:] += wd.g_s
            gff = zf.copy()
            if self.fisher is not None:
                x0, y0 = np.where(vac, 0.0, x), np.where(vac, 0.0, y)  # zero subgradient on vacuum edges
                gx, gy = FISHER_TERMS[self.fisher].gradient(x0, y0, s_safe, self.fisher_coef)
                gff[..., :-1] += gx
                gff[..., 1:] += gy
        gfe = 2 * self.energy_coef * self.energy.matvec(f)
        return TermParts((gfw, wd.g_m), (gff, np.zeros_like(m)), (gfe, np.zeros_like(m)))

    def gradient(self, f: ArrayLike, m: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """:math:`(\\nabla_f J, \\nabla_m J)`."""
        p = self.gradient_parts(f, m)
        return p.wasserstein[0] + p.fisher[0] + p.energy[0], p.wasserstein[1]

    def edge_hessian(self, f: ArrayLike, m: ArrayLike) -> dict[str, NDArray[np.float64]]:
        """Hessian of the edge terms (Wasserstein + Fisher) per edge k (:mod:`~jko_cvx.collision.terms`).

        Returns the entries ``xx, yy, xy`` (w.r.t. :math:`f_k, f_{k+1}`), ``xm, ym``
        (mixed with :math:`m_k`) and ``mm``; each has shape ``(..., N-1)``.
        """
        f = np.asarray(f, dtype=float)
        m = np.asarray(m, dtype=float)
        x, y, s = self._edges(f)
        with np.errstate(divide="ignore", invalid="ignore"):
            wd = wasserstein_derivatives(m, s, self.wass_coef)
            xx, yy, xy = wd.h_ss.copy(), wd.h_ss.copy(), wd.h_ss.copy()
            if self.fisher is not None:
                hx, hy, hxy = FISHER_TERMS[self.fisher].hessian(x, y, s, self.fisher_coef)
                xx += hx
                yy += hy
                xy += hxy
        return {"xx": xx, "yy": yy, "xy": xy, "xm": wd.h_sm, "ym": wd.h_sm, "mm": wd.h_mm}

    def hessian(self, f: ArrayLike, m: ArrayLike) -> NDArray[np.float64]:
        """Dense Hessian of :math:`J` w.r.t. ``u = [f, m]`` (unbatched; for tests and small N)."""
        if np.ndim(f) != 1:
            raise ValueError("hessian() takes a single (unbatched) point")
        n = self.n
        e = self.edge_hessian(f, m)
        H = np.zeros((2 * n - 1, 2 * n - 1))
        k = np.arange(n - 1)
        np.add.at(H, (k, k), e["xx"])
        np.add.at(H, (k + 1, k + 1), e["yy"])
        H[k, k + 1] += e["xy"]
        H[k + 1, k] += e["xy"]
        H[k, n + k] += e["xm"]
        H[n + k, k] += e["xm"]
        H[k + 1, n + k] += e["ym"]
        H[n + k, k + 1] += e["ym"]
        H[n + k, n + k] += e["mm"]
        H[:n, :n] += 2 * self.energy_coef * self.energy.dense()
        return H

    def null_space_basis(self) -> sp.csr_matrix:
        """Sparse Z ((2N-1) x (N-1)) with ``A Z = 0``: a feasible direction is ``(-D p / h, p)``."""
        n = self.n
        D = sp.diags([np.ones(n - 1), -np.ones(n - 1)], [0, -1], shape=(n, n - 1))
        return sp.vstack([-sp.diags(1 / self.grid.h) @ D, sp.eye(n - 1)]).tocsr()

    def edge_hessian_bands(self, f: ArrayLike, m: ArrayLike) -> tuple[NDArray, NDArray, NDArray]:
        """Bands of :math:`Z^\\top \\nabla^2 (J - \\text{energy}) Z`: diagonal, 1st and 2nd off-diagonal.

        See :func:`~jko_cvx.collision.terms.reduced_bands`.
        """
        e = self.edge_hessian(f, m)
        return reduced_bands(self.grid, e["xx"], e["yy"], e["xy"], e["xm"], e["mm"])

    def reduced_hessian(self, f: ArrayLike, m: ArrayLike) -> NDArray[np.float64]:
        """Hessian of J on the constraint null space, :math:`Z^\\top \\nabla^2 J Z` (dense, (N-1)^2, batched).

        The step problem is locally convex iff this is positive definite; its loss of
        definiteness is the discrete sign of concentration (the energy's concave part
        outweighs the Wasserstein and Fisher curvature).  Formed from the pentadiagonal
        edge part and the constant energy block ``2 dt strength T'KT``.
        """
        f = np.asarray(f, dtype=float)
        with np.errstate(all="ignore"):  # vacuum edges give inf (frozen fluxes)
            bands = self.edge_hessian_bands(f, m)
            return add_pentadiagonal(2 * self.energy_coef * self.energy.flux_block(), *bands)

    def _scaled_reduced_hessian(self, f: ArrayLike, m: ArrayLike) -> NDArray[np.float64] | None:
        Hr = self.reduced_hessian(f, m)
        d = np.diag(Hr)
        # A flux through a vacuum edge (s_k = 0) has infinite curvature: it is frozen at
        # 0 and drops out of the test (principal submatrix of the other fluxes).
        keep = d < np.inf
        Hr, d = Hr[np.ix_(keep, keep)], d[keep]
        if not (np.all(np.isfinite(Hr)) and np.all(d > 0)):
            return None
        scale = 1 / np.sqrt(d)
        Hs = Hr * scale[:, None] * scale[None, :]
        if self.conserve_momentum and Hs.shape[0] > 1:
            # Second-order conditions hold on the tangent space of the constraints: with
            # the momentum constraint a'm = 0 that is a-perp (for gamma = 2 the energy's
            # concave part lies exactly along a and drops out).  In the scaled variables
            # y = D^1/2 m the normal is D^-1/2 a; Z = the last columns of its Householder
            # reflector, an orthonormal basis of the tangent space.
            normal = self.grid.dv[keep] * scale
            u = normal / np.linalg.norm(normal)
            u[0] += 1.0 if u[0] >= 0 else -1.0
            Q = np.eye(u.size) - np.outer(u, u) * (2 / (u @ u))
            Z = Q[:, 1:]
            Hs = Z.T @ Hs @ Z
        return Hs

    def convexity_margin(self, f: ArrayLike, m: ArrayLike) -> float:
        """Smallest eigenvalue of the Jacobi-scaled reduced Hessian (unit diagonal).

        Negative means that ``(f, m)`` is not a local minimiser: the step problem has
        lost convexity there.  Jacobi scaling makes the number scale-free and keeps it
        finite when near-vacuum cells put entries of 1e90 in the Hessian.  ``-inf`` when
        the Hessian is not finite or has a non-positive diagonal entry.  With
        ``conserve_momentum`` it is the Hessian on the constraint's tangent space.
        """
        Hs = self._scaled_reduced_hessian(f, m)
        return -np.inf if Hs is None else float(np.linalg.eigvalsh(Hs)[0])

    def is_local_minimiser(self, f: ArrayLike, m: ArrayLike, tol: float = 1e-9) -> bool:
        """Second-order test: :meth:`convexity_margin` ``>= -tol``, decided by one Cholesky factorisation.

        With ``conserve_momentum`` the test is on the momentum constraint's tangent space.
        """
        Hs = self._scaled_reduced_hessian(f, m)
        if Hs is None:
            return False
        try:
            np.linalg.cholesky(Hs + tol * np.eye(Hs.shape[0]))
        except np.linalg.LinAlgError:
            return False
        return True

    # ------------------------------------------------------------ KKT residual
    def kkt_residual(self, f: ArrayLike, m: ArrayLike, parts: TermParts | None = None) -> KKTResidual:
        """Scaled KKT residual of ``(f, m)``; see the module docstring for the definition.

        ``parts`` may pass :meth:`gradient_parts` at ``(f, m)`` when the caller has it already.
        """
        f = np.asarray(f, dtype=float)
        m = np.asarray(m, dtype=float)
        h = band_coefficients(self.grid, 2 if f.ndim == 2 else 1)[0]  # a (1, n) row for a batch: no broadcast
        if parts is None:
            parts = self.gradient_parts(f, m)
        gf = parts.wasserstein[0] + parts.fisher[0] + parts.energy[0]
        gm = parts.wasserstein[1]
        fpos = np.maximum(f, 0.0)
        fmax = fpos.max(axis=-1, keepdims=True)
        fmax = np.where(fmax > 0, fmax, 1.0)
        w = fpos / fmax
        om = (fpos[..., :-1] + fpos[..., 1:]) / (2 * fmax)
        with np.errstate(invalid="ignore", over="ignore"):
            a = np.where(w > 0, gf / h, 0.0)
            gmw = np.where(om > 0, gm, 0.0)
            # Weighted least squares for phi: (W^2 + G' O^2 G) phi = -W^2 a - G' O^2 gm.
            w2, o2 = w**2, om**2
            diag = w2.copy()
            diag[..., :-1] += o2
            diag[..., 1:] += o2
            eps = 1e-30 * diag.max(axis=-1, keepdims=True)
            diag = diag + eps
            # G = D^T, so G' v = D v = divergence(v).
            rhs = -w2 * a - divergence(o2 * gmw) - eps * a
            phi = solve_sym_tridiagonal(diag, -o2, rhs)
            rf = a + phi
            rm = gmw + divergence_adjoint(phi)
            if self.conserve_momentum:
                # One more multiplier u for sum_k m_k dv_k = 0: r^m gains u*dv.  For fixed u
                # the optimal phi is phi0 - u z (z = T^-1 D(O^2 dv)); then u minimises the
                # same weighted norm, a scalar least-squares problem.
                dv = self.grid.dv
                z = solve_sym_tridiagonal(diag, -o2, np.broadcast_to(divergence(o2 * dv), diag.shape).copy())
                zf, zm = -z, dv - divergence_adjoint(z)
                den = np.sum(w2 * zf * zf, axis=-1) + np.sum(o2 * zm * zm, axis=-1)
                num = np.sum(w2 * rf * zf, axis=-1) + np.sum(o2 * rm * zm, axis=-1)
                u = -np.divide(num, den, out=np.zeros_like(np.asarray(den)), where=den > 0)
                u = np.asarray(u)[..., None]
                phi, rf, rm = phi - u * z, rf + u * zf, rm + u * zm
            stat_num = np.maximum((w * np.abs(rf)).max(axis=-1), (om * np.abs(rm)).max(axis=-1))
            scale_f = sum(np.abs(p[0]) for p in (parts.wasserstein, parts.fisher, parts.energy)) / h
            scale = np.maximum(np.where(w > 0, w * scale_f, 0.0).max(axis=-1), (om * np.abs(gmw)).max(axis=-1))
            scale = np.where(scale > 0, scale, np.finfo(float).tiny)
            stationarity = stat_num / scale
            stationarity = np.where(np.isfinite(stationarity), stationarity, np.inf)
        feas = np.abs(h * (f - self.f_star) + divergence(m)).sum(axis=-1) / (self.f_star * h).sum(axis=-1)
        if self.conserve_momentum:
            feas = np.maximum(feas, self.momentum_change(f))
        positivity = np.maximum(0.0, -f.min(axis=-1)) / fmax[..., 0]
        if f.ndim == 1:
            return KKTResidual(float(stationarity), float(feas), float(positivity), phi)
        return KKTResidual(stationarity, feas, positivity, phi)

    def explicit_velocity(self) -> NDArray[np.float64]:
        """Velocity of the explicit step at the half points, :math:`-\\sigma\\,\\Delta(W * f^*)/\\Delta v`."""
        psi = self.strength * self.energy.matvec(self.f_star) / self.grid.h
        return -np.diff(psi, axis=-1) / self.grid.dv

    def cfl(self) -> float:
        """Explicit CFL number :math:`\\Delta t \\max|a| / \\min \\Delta v` of the collision velocity field.

        The paper's SQP starts with an explicit-Euler step (its Hessian has no f-m
        coupling); above CFL ~ 1 that step empties low-density cells and the
        positivity safeguard stalls it.  The conic reference has no such limit.
        """
        return float(self.dt * np.abs(self.explicit_velocity()).max() / self.grid.dv.min())

    def mass_error(self, f: ArrayLike) -> NDArray[np.float64] | float:
        """Relative mass error :math:`|\\sum h f - \\sum h f^*| / \\sum h f^*`."""
        return np.abs(np.asarray(f) @ self.grid.h - self.mass) / self.mass
