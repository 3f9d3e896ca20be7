"""A positivity-preserving, second-order finite-volume peer for the homogeneous equation.

Solves :math:`f_t = \\sigma\\,\\partial_v((W' * f) f)` (``eqn: gke_hom`` with strength
:math:`\\sigma`) on :math:`[a, b]` with no-flux ends, independently of the JKO machinery, as a
comparison baseline (``jko-cvx study work_precision_peer``).  The scheme follows Carrillo,
Chertock and Huang, "A finite-volume method for nonlinear nonlocal equations with a gradient
flow structure", Commun. Comput. Phys. 17 (2015) 233-258, section 2 (one dimension):

* unknowns: cell averages :math:`\\bar f_j` on N uniform cells of width :math:`\\Delta v`;
* semi-discrete form :math:`\\bar f_j' = -(F_{j+1/2} - F_{j-1/2})/\\Delta v`, with the upwind
  flux :math:`F_{j+1/2} = u^+_{j+1/2} f^E_j + u^-_{j+1/2} f^W_{j+1}` (their eq. (2.4)),
  :math:`F_{1/2} = F_{N+1/2} = 0`;
* :math:`f^{E,W}_j = \\bar f_j \\pm \\tfrac{\\Delta v}{2} s_j`: piecewise-linear (MUSCL)
  reconstruction with the generalised minmod slope
  :math:`s_j = \\operatorname{minmod}(\\theta \\tfrac{\\bar f_{j+1} - \\bar f_j}{\\Delta v},
  \\tfrac{\\bar f_{j+1} - \\bar f_{j-1}}{2\\Delta v}, \\theta \\tfrac{\\bar f_j - \\bar f_{j-1}}{\\Delta v})`,
  :math:`\\theta \\in [1, 2]` (their eq. (2.6)); the end cells take zero slope.  The edge
  values are non-negative whenever the averages are;
* velocity :math:`u_{j+1/2} = -\\sigma\\,(W' * f)(v_{j+1/2})`, with :math:`W' * f` integrated
  exactly against the piecewise-constant density:
  :math:`\\int_{v_{i-1/2}}^{v_{i+1/2}} W'(x - w)\\,dw = W(x - v_{i-1/2}) - W(x - v_{i+1/2})`.
  (CCH take centred differences of the potential :math:`\\xi = \\sigma W * f`; for
  piecewise-constant f the two agree up to :math:`O(\\Delta v^2)`, and the exact edge
  quadrature also serves singular :math:`W'`.)  For :math:`\\gamma = 1`,
  :math:`W' * f = 2F - M` (prefix sums, O(N)); for :math:`\\gamma = 2`,
  :math:`W' * f = M v - \\int w f` (O(N)); otherwise a precomputed dense (N-1) x N matrix;
* time: the three-stage, third-order SSP Runge-Kutta method (Shu-Osher), a convex
  combination of forward Euler steps.

Positivity (CCH Theorem 2.2): each forward Euler stage keeps :math:`\\bar f \\ge 0` when
:math:`\\Delta t \\max_j |u_{j+1/2}| \\le \\Delta v / 2`.  The step is
:math:`\\Delta t = \\mathrm{cfl}\\,\\Delta v / \\max |u|` with ``cfl <= 1/2``; the velocity of
the later stages is re-checked, and a stage that would break the bound retries the step
with the step size it allows.  Mass is conserved to rounding (the fluxes telescope).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from numbers import Integral

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jko_cvx._numbers import is_real
from jko_cvx.kernels import PowerKernel

__all__ = ["Cells", "FiniteVolumeRun", "evolve_finite_volume"]

_POSITIVITY_CFL = 0.5  # Delta t max|u| <= Delta v / 2 keeps every Euler stage non-negative


@dataclass(frozen=True)
class Cells:
    """N uniform cells on ``[lo, hi]``: edges :math:`v_{j+1/2}`, centres, width :math:`\\Delta v`."""

    lo: float
    hi: float
    n: int

    def __post_init__(self) -> None:
        if not (np.isfinite(self.lo) and np.isfinite(self.hi) and self.lo < self.hi):
            raise ValueError(f"lo and hi must be finite with lo < hi, got lo={self.lo!r}, hi={self.hi!r}")
        if isinstance(self.n, bool) or int(self.n) != self.n or self.n < 3:
            raise ValueError(f"n must be an integer >= 3, got {self.n!r}")
        object.__setattr__(self, "n", int(self.n))

    @property
    def dv(self) -> float:
        return (self.hi - self.lo) / self.n

    @property
    def edges(self) -> NDArray[np.float64]:
        """The N + 1 cell edges, ends included."""
        return np.linspace(self.lo, self.hi, self.n + 1)

    @property
    def centres(self) -> NDArray[np.float64]:
        return self.lo + (np.arange(self.n) + 0.5) * self.dv

    def averages(self, cdf: Callable[[NDArray[np.float64]], NDArray[np.float64]]) -> NDArray[np.float64]:
        """Exact cell averages of a density given by its cumulative distribution ``cdf``."""
        return np.diff(cdf(self.edges)) / self.dv

    def mass(self, f: ArrayLike) -> float:
        return float(np.sum(f) * self.dv)


@dataclass
class FiniteVolumeRun:
    """Output of :func:`evolve_finite_volume`.

    Attributes
    ----------
    cells : Cells
    f : ndarray, shape (N,)
        Cell averages at ``t_end``.
    times : ndarray, shape (steps + 1,)
        The time levels reached (0 first, ``t_end`` last).
    steps : int
        Accepted SSP-RK3 steps.
    rejected : int
        Steps retried because a later stage broke the positivity bound.
    seconds : float
        Wall time of the loop.
    """

    cells: Cells
    f: NDArray[np.float64]
    times: NDArray[np.float64]
    steps: int
    rejected: int
    seconds: float


class _Velocity:
    """:math:`u_{j+1/2} = -\\sigma (W' * f)(v_{j+1/2})` at the N - 1 interior edges, exact for piecewise-constant f."""

    def __init__(self, cells: Cells, kernel: PowerKernel, strength: float) -> None:
        self.cells, self.gamma, self.strength = cells, kernel.gamma, strength
        e = cells.edges
        self.inner = e[1:-1]
        self.matrix = None
        if self.gamma not in (1.0, 2.0):
            x = self.inner[:, None]
            self.matrix = kernel(x - e[None, :-1]) - kernel(x - e[None, 1:])  # (N-1, N)

    def __call__(self, f: NDArray[np.float64]) -> NDArray[np.float64]:
        dv = self.cells.dv
        if self.gamma == 1.0:  # W' = sign: W' * f = F - (M - F)
            F = np.cumsum(f)[:-1] * dv
            conv = 2 * F - np.sum(f) * dv
        elif self.gamma == 2.0:  # W' = w: W' * f = M x - int w f
            c = self.cells.centres
            conv = np.sum(f) * dv * self.inner - np.sum(f * c) * dv
        else:
            conv = self.matrix @ f
        return -self.strength * conv


def _edge_values(f: NDArray[np.float64], theta: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """MUSCL edge values (east, west) with the generalised minmod slope; end cells flat."""
    d = np.diff(f)  # f_{j+1} - f_j
    a, b, c = theta * d[1:], 0.5 * (d[1:] + d[:-1]), theta * d[:-1]
    same = (np.sign(a) == np.sign(b)) & (np.sign(b) == np.sign(c))
    half = np.zeros_like(f)
    half[1:-1] = np.where(same, np.sign(b) * np.minimum(np.minimum(np.abs(a), np.abs(b)), np.abs(c)), 0.0) / 2
    return f + half, f - half


def _rhs(f: NDArray[np.float64], u: NDArray[np.float64], theta: float, dv: float) -> NDArray[np.float64]:
    """:math:`-(F_{j+1/2} - F_{j-1/2})/\\Delta v` with the upwind flux and zero flux at the ends."""
    east, west = _edge_values(f, theta)
    flux = np.zeros(f.size + 1)
    flux[1:-1] = np.maximum(u, 0.0) * east[:-1] + np.minimum(u, 0.0) * west[1:]
    return -np.diff(flux) / dv


def _ssp_rk3(
    f: NDArray[np.float64], dt: float, velocity: _Velocity, theta: float, dv: float
) -> NDArray[np.float64] | float:
    """One SSP-RK3 step; returns the new averages, or the largest safe dt when a stage breaks the bound."""
    bound = _POSITIVITY_CFL * dv
    u = velocity(f)
    f1 = f + dt * _rhs(f, u, theta, dv)
    u1 = velocity(f1)
    if dt * np.abs(u1).max() > bound:
        return 0.9 * bound / np.abs(u1).max()
    f2 = 0.75 * f + 0.25 * (f1 + dt * _rhs(f1, u1, theta, dv))
    u2 = velocity(f2)
    if dt * np.abs(u2).max() > bound:
        return 0.9 * bound / np.abs(u2).max()
    return f / 3 + (2 / 3) * (f2 + dt * _rhs(f2, u2, theta, dv))


def evolve_finite_volume(
    cells: Cells,
    kernel: PowerKernel,
    f0: ArrayLike,
    t_end: float,
    *,
    strength: float = 1.0,
    cfl: float = 0.4,
    theta: float = 2.0,
    max_steps: int = 10_000_000,
) -> FiniteVolumeRun:
    """Advance the cell averages ``f0`` to ``t_end`` (see the module docstring for the scheme).

    Parameters
    ----------
    cells : Cells
        Uniform cells on the velocity interval (no-flux ends).
    kernel : PowerKernel
        :math:`W(v) = |v|^\\gamma/\\gamma`.
    f0 : array_like, shape (N,)
        Initial cell averages, finite and non-negative (e.g. ``cells.averages(f0.cdf)``).
    t_end : float
        Final time, finite and > 0; the last step is shortened to reach it exactly.
    strength : float, default 1.0
        :math:`\\sigma > 0`.
    cfl : float, default 0.4
        :math:`\\Delta t = \\mathrm{cfl}\\,\\Delta v / \\max|u|`; in (0, 1/2] (the positivity bound).
    theta : float, default 2.0
        Minmod parameter in [1, 2] (1: most dissipative, 2: least).
    max_steps : int
        Safety bound on the number of steps (a ValueError past it: the velocity grows without
        bound only at blow-up, which the peer does not continue through).
    """
    if not isinstance(cells, Cells):
        raise TypeError(f"cells must be a jko_cvx.finite_volume.Cells, got {type(cells).__name__}")
    if not isinstance(kernel, PowerKernel):
        raise TypeError(f"kernel must be a jko_cvx.PowerKernel, got {type(kernel).__name__}")
    f = np.array(f0, dtype=float)
    if f.shape != (cells.n,):
        raise ValueError(f"f0 must have shape ({cells.n},) (one average per cell), got {f.shape}")
    if not np.all(np.isfinite(f)) or f.min() < 0:
        raise ValueError("f0 must be finite and non-negative")
    for name, val, ok, rng in (
        ("t_end", t_end, lambda x: np.isfinite(x) and x > 0, "a finite number > 0"),
        ("strength", strength, lambda x: np.isfinite(x) and x > 0, "a finite number > 0"),
        ("cfl", cfl, lambda x: 0 < x <= _POSITIVITY_CFL, f"in (0, {_POSITIVITY_CFL}]"),
        ("theta", theta, lambda x: 1 <= x <= 2, "in [1, 2]"),
    ):
        if not is_real(val) or not ok(val):
            raise ValueError(f"{name} must be {rng}, got {val!r}")
    if isinstance(max_steps, (bool, np.bool_)) or not isinstance(max_steps, Integral) or max_steps < 1:
        raise ValueError(f"max_steps must be an integer >= 1, got {max_steps!r}")
    velocity = _Velocity(cells, kernel, float(strength))
    dv = cells.dv
    t, times, rejected = 0.0, [0.0], 0
    t0 = time.perf_counter()
    while t < t_end * (1 - 1e-14):
        if len(times) > max_steps:
            raise ValueError(f"more than max_steps = {max_steps} steps before t_end = {t_end!r} (blow-up?)")
        speed = float(np.abs(velocity(f)).max())
        dt = min(t_end - t, cfl * dv / speed if speed > 0 else t_end - t)
        while True:
            out = _ssp_rk3(f, dt, velocity, theta, dv)
            if isinstance(out, np.ndarray):
                break
            dt, rejected = out, rejected + 1
        f = out
        t = t + dt if t + dt < t_end * (1 - 1e-14) else float(t_end)
        times.append(t)
    return FiniteVolumeRun(cells, f, np.array(times), len(times) - 1, rejected, time.perf_counter() - t0)
