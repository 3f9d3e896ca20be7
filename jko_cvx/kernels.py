"""Interaction kernels and the discrete interaction energy.

The collision operator of the granular kinetic equation (``eqn: gke``) is the
Wasserstein gradient flow of

.. math::  E(f) = \\frac{\\sigma}{2} \\iint W(v - w) f(v) f(w)\\,dv\\,dw,
           \\qquad W(v) = |v|^\\gamma / \\gamma,

where :math:`\\sigma` is the collision ``strength`` (:math:`\\lambda/2` in ``eqn: gke``,
1 in ``eqn: gke_hom``).  On a grid with cell widths :math:`h` the energy is
:math:`E(f) = \\tfrac{\\sigma}{2} f^\\top K f` with :math:`K_{il} = W(v_i - v_l) h_i h_l`
(the paper's :math:`E` in ``eqn:non-uniform JKO`` is :math:`f^\\top K f`, i.e. twice
ours, which is why the JKO objective carries :math:`\\Delta t\\, f^\\top K f`).

Why the energy is not convex: for :math:`0 < \\gamma \\le 2` the kernel
:math:`|v|^\\gamma` is conditionally negative definite, so :math:`\\delta^\\top K \\delta \\le 0`
for every mass-free direction (:math:`h \\cdot \\delta = 0`).  Every feasible point of
the JKO step has the mass of :math:`f^*`, so only the restriction of :math:`K` to
mass-free directions matters; :meth:`EnergyOperator.split` returns it as a
difference of positive semidefinite parts :math:`\\tilde K = \\tilde K_+ - \\tilde K_-`
(``tilde K_+`` vanishes for :math:`\\gamma \\le 2`).  For :math:`\\gamma = 2`,
:math:`K = (a h^\\top + h a^\\top)/2 - b b^\\top` with :math:`a = h v^2`, :math:`b = h v`,
an exact rank-3 form that is used instead of a dense matrix.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jko_cvx._numbers import real_scalar
from jko_cvx.grid import Grid

__all__ = [
    "DenseEnergy",
    "EnergyOperator",
    "EnergySplit",
    "LowRankEnergy",
    "PowerKernel",
    "clear_operator_cache",
    "operator_cache_info",
]

# Largest even integer gamma whose flux block is used in the factored form (beyond it the
# expansion in powers of v cancels too much to be worth checking).
_MAX_EVEN_POWER = 8
# Relative size below which eigenvalues of the projected energy count as zero.
_EIG_REL_TOL = 1e-12


@dataclass(frozen=True)
class FluxBlock:
    """Structure of the energy block :math:`T^\\top K T` seen by the fluxes.

    ``kind`` is ``"diagonal"`` (:math:`\\gamma = 1`: :math:`W'' = 2\\delta`, so the block is
    :math:`-2\\operatorname{diag}(\\Delta v)`), ``"rank1"`` (:math:`\\gamma = 2`: the block is
    :math:`-\\Delta v \\Delta v^\\top`), ``"lowrank"`` (even integer :math:`\\gamma \\ge 4`: the
    block is ``basis @ coef @ basis.T``, see :func:`even_power_flux_factors`) or ``"dense"``.
    ``diag``, ``u``, ``basis`` and ``coef``, and ``dense`` hold the data of each kind (block =
    ``diag(diag)``, ``-u u'``, ``basis coef basis'`` or ``dense``).
    """

    kind: str
    diag: NDArray[np.float64] | None = None
    u: NDArray[np.float64] | None = None
    dense: NDArray[np.float64] | None = None
    basis: NDArray[np.float64] | None = None
    coef: NDArray[np.float64] | None = None


def even_power_flux_factors(points: NDArray[np.float64], gamma: int) -> tuple[NDArray, NDArray]:
    """Exact low-rank factors of the flux block for :math:`W(v) = v^\\gamma/\\gamma`, even integer :math:`\\gamma`.

    The flux block is the mixed second difference :math:`E_{kl} = \\Delta_k \\Delta_l W(v_k - v_l)`
    (:meth:`EnergyOperator.flux_block`).  Expanding
    :math:`(a - b)^\\gamma/\\gamma = \\sum_p \\binom{\\gamma}{p} a^p (-b)^{\\gamma - p}/\\gamma`, the
    differences remove the terms in one variable only (p = 0 and p = gamma), so

    .. math::  E = U C U^\\top, \\qquad U_{kp} = v_{k+1}^p - v_k^p,\\quad
               C_{pq} = [p + q = \\gamma]\\,\\binom{\\gamma}{p} (-1)^{q}/\\gamma,

    p, q = 1, ..., gamma - 1: rank gamma - 1, an anti-diagonal (so invertible) C.  For gamma = 2 this is
    :math:`-\\Delta v \\Delta v^\\top`; the first column of U is :math:`\\Delta v`, the momentum
    constraint's normal.  Returns ``(U, C)``.
    """
    v = np.asarray(points, dtype=float)
    powers = np.arange(1, gamma)
    U = np.diff(v[:, None] ** powers, axis=0)
    C = np.zeros((gamma - 1, gamma - 1))
    for i, p in enumerate(powers):
        C[i, gamma - 2 - i] = math.comb(gamma, int(p)) * (-1) ** (gamma - int(p)) / gamma
    return U, C


@dataclass(frozen=True)
class EnergySplit:
    """Difference-of-convex split of the energy on mass-free directions.

    ``delta @ K @ delta == |P_plus @ delta|^2 - |P_minus @ delta|^2`` for every
    ``delta`` with ``h @ delta == 0``.

    Attributes
    ----------
    P_plus : ndarray, shape (r_plus, N)
        Factor of the convex part (``r_plus == 0`` for conditionally negative
        definite kernels, i.e. ``gamma <= 2``).
    P_minus : ndarray, shape (r_minus, N)
        Factor of the concave part.
    """

    P_plus: NDArray[np.float64]
    P_minus: NDArray[np.float64]

    @functools.cached_property
    def rho(self) -> float:
        """Largest eigenvalue of the convex part, :math:`\\lambda_{max}(\\tilde K_+)` (0 if none; computed once)."""
        if self.P_plus.shape[0] == 0:
            return 0.0
        return float(np.linalg.eigvalsh(self.P_plus @ self.P_plus.T).max())

    def truncated(self, h: NDArray[np.float64], below: float) -> tuple[NDArray[np.float64], float]:
        """The convex part's leading factor and a diagonal majorant of the rest: ``(P_top, rho_tail)``.

        With :math:`\\tilde K_+ = H V \\Lambda V^\\top H` (``H = diag(h)``, the eigenpairs of the
        centred kernel, :meth:`DenseEnergy.split`), ``P_top`` keeps the rows with
        :math:`\\lambda_i > \\text{below}\\cdot\\lambda_{max}` and ``rho_tail`` is the largest dropped
        :math:`\\lambda_i` (0 if none), so that

        .. math::  C = P_{top}^\\top P_{top} + \\rho_{tail} H^2 \\succeq \\tilde K_+,\\qquad
                   \\delta^\\top (C - \\tilde K_+)\\delta = \\sum_{i \\notin top} (\\rho_{tail} - \\lambda_i)
                   (v_i^\\top H\\delta)^2 + \\rho_{tail} |(I - VV^\\top) H\\delta|^2 \\ge 0:

        a convex part of rank ``len(P_top)`` plus a diagonal, and ``C - K~`` is convex on mass-free
        directions.  ``h`` is the grid's cell widths (the rows are :math:`\\sqrt{\\lambda_i} v_i^\\top H`).
        """
        if self.P_plus.shape[0] == 0:
            return self.P_plus, 0.0
        lam = np.sum((self.P_plus / h) ** 2, axis=1)
        keep = lam > below * lam.max()
        return self.P_plus[keep], float(lam[~keep].max()) if not keep.all() else 0.0

    def concave_matvec(self, delta: NDArray[np.float64]) -> NDArray[np.float64]:
        """:math:`\\tilde K_- \\delta` (last axis)."""
        return (delta @ self.P_minus.T) @ self.P_minus


def _even_power(gamma: float | None) -> bool:
    """gamma an even integer in [4, _MAX_EVEN_POWER] (gamma = 2 has its own exact operator)."""
    return gamma is not None and float(gamma).is_integer() and 4 <= gamma <= _MAX_EVEN_POWER and gamma % 2 == 0


class EnergyOperator:
    """The matrix :math:`K_{il} = W(v_i - v_l) h_i h_l` in whatever form is cheapest."""

    grid: Grid

    def matvec(self, f: ArrayLike) -> NDArray[np.float64]:
        """:math:`K f` along the last axis (works on a batch of rows)."""
        raise NotImplementedError

    def quadratic(self, f: ArrayLike) -> NDArray[np.float64] | float:
        """:math:`f^\\top K f` along the last axis."""
        f = np.asarray(f, dtype=float)
        return np.einsum("...i,...i->...", f, self.matvec(f))

    def dense(self) -> NDArray[np.float64]:
        """The dense N x N matrix K (for tests and small problems)."""
        raise NotImplementedError

    def split(self) -> EnergySplit:
        """DC split of K restricted to mass-free directions (cached)."""
        raise NotImplementedError

    def flux_structure(self) -> FluxBlock:
        """:meth:`flux_block` in its cheapest exact form (cached): diagonal, rank one, low rank or dense."""
        cached = getattr(self, "_flux_structure", None)
        if cached is None:
            if isinstance(self, LowRankEnergy):
                # T'h = 0 and T'(h v) = dv, so T'KT = -(dv)(dv)^T exactly.
                cached = FluxBlock("rank1", u=self.grid.dv.copy())
            elif getattr(self, "gamma", None) == 1.0:
                # W = |v|: the mixed second difference of |v_i - v_j| vanishes off the
                # diagonal (W'' = 2 delta) and equals -2 dv_k on it.
                cached = FluxBlock("diagonal", diag=-2 * self.grid.dv)
            elif _even_power(getattr(self, "gamma", None)):
                cached = self._even_power_structure()
            else:
                E = self.flux_block()
                d = np.diag(E).copy()
                # each entry combines four kernel values: rounding ~ 8 eps max|W|
                W = self.dense() / np.outer(self.grid.h, self.grid.h)
                if np.abs(E - np.diag(d)).max() <= 8 * np.finfo(float).eps * np.abs(W).max():
                    cached = FluxBlock("diagonal", diag=d)
                else:
                    cached = FluxBlock("dense", dense=E)
            self._flux_structure = cached
        return cached

    def _even_power_structure(self) -> FluxBlock:
        """The ``"lowrank"`` block of an even integer gamma >= 4, where it reproduces :meth:`flux_block`.

        The factors are exact in exact arithmetic; they are used only where they agree with
        the dense block to rounding (each dense entry combines four kernel values, each
        factored entry gamma - 1 products), else the block stays ``"dense"`` (very wide
        grids, where the expansion cancels).
        """
        E = self.flux_block()
        U, C = even_power_flux_factors(self.grid.points, int(self.gamma))
        W = self.dense() / np.outer(self.grid.h, self.grid.h)
        size = np.abs(U).max(axis=0)
        tol = 8 * np.finfo(float).eps * (np.abs(W).max() + (self.gamma - 1) * (size @ np.abs(C) @ size))
        if np.abs(U @ C @ U.T - E).max() <= tol:
            return FluxBlock("lowrank", basis=U, coef=C)
        return FluxBlock("dense", dense=E)

    def flux_block(self) -> NDArray[np.float64]:
        """:math:`T^\\top K T` with :math:`T = -\\operatorname{diag}(1/h) D` (cached): K seen by the fluxes.

        The energy's contribution to the reduced Hessian of the collision step, in the
        flux variables (see :mod:`jko_cvx.collision.newton`); (N-1) x (N-1), dense.
        """
        cached = getattr(self, "_flux_block", None)
        if cached is None:
            h = self.grid.h
            A = self.dense()
            a, b = -1 / h[:-1], 1 / h[1:]
            cached = (
                np.outer(a, a) * A[:-1, :-1]
                + np.outer(a, b) * A[:-1, 1:]
                + np.outer(b, a) * A[1:, :-1]
                + np.outer(b, b) * A[1:, 1:]
            )
            cached.flags.writeable = False
            self._flux_block = cached
        return cached


class DenseEnergy(EnergyOperator):
    """Dense K for a general power kernel."""

    def __init__(self, grid: Grid, kernel: PowerKernel) -> None:
        self.grid = grid
        self.gamma = kernel.gamma
        v = grid.points
        self.K = kernel(v[:, None] - v[None, :]) * np.outer(grid.h, grid.h)
        self.K.flags.writeable = False
        self._split: EnergySplit | None = None

    def matvec(self, f: ArrayLike) -> NDArray[np.float64]:
        return np.asarray(f, dtype=float) @ self.K  # K is symmetric

    def dense(self) -> NDArray[np.float64]:
        return self.K

    def split(self) -> EnergySplit:
        if self._split is None:
            # Split the unweighted kernel matrix W (O(1) entries) on {sum g = 0}, g = h*delta,
            # then scale by h: the same split as that of K on {h.delta = 0}, but computed
            # without the h_i h_l factors that span six decades on refined grids.
            h = self.grid.h
            W = self.K / np.outer(h, h)
            Wc = W - W.mean(axis=0, keepdims=True)
            Wc = Wc - Wc.mean(axis=1, keepdims=True)
            lam, V = np.linalg.eigh((Wc + Wc.T) / 2)
            cut = _EIG_REL_TOL * max(np.abs(lam).max(), np.finfo(float).tiny)
            pos, neg = lam > cut, lam < -cut
            P_plus = (np.sqrt(lam[pos])[:, None] * V[:, pos].T) * h
            P_minus = (np.sqrt(-lam[neg])[:, None] * V[:, neg].T) * h
            self._split = EnergySplit(P_plus, P_minus)
        return self._split


class LowRankEnergy(EnergyOperator):
    """Exact rank-3 form of K for :math:`\\gamma = 2`: :math:`K = (a h^T + h a^T)/2 - b b^T`."""

    def __init__(self, grid: Grid) -> None:
        self.grid = grid
        v, h = grid.points, grid.h
        self.a = h * v**2
        self.b = h * v
        self.h = h
        self._split: EnergySplit | None = None

    def matvec(self, f: ArrayLike) -> NDArray[np.float64]:
        f = np.asarray(f, dtype=float)
        fa = (f @ self.a)[..., None]
        fh = (f @ self.h)[..., None]
        fb = (f @ self.b)[..., None]
        return 0.5 * (self.a * fh + self.h * fa) - self.b * fb

    def quadratic(self, f: ArrayLike) -> NDArray[np.float64] | float:
        f = np.asarray(f, dtype=float)
        return (f @ self.a) * (f @ self.h) - (f @ self.b) ** 2

    def dense(self) -> NDArray[np.float64]:
        return 0.5 * (np.outer(self.a, self.h) + np.outer(self.h, self.a)) - np.outer(self.b, self.b)

    def split(self) -> EnergySplit:
        if self._split is None:
            # On h-orthogonal directions the a h^T terms vanish: K~ = -(Q b)(Q b)^T.
            h = self.h
            qb = self.b - (self.b @ h) / (h @ h) * h
            self._split = EnergySplit(np.zeros((0, h.size)), qb[None, :])
        return self._split


@dataclass(frozen=True)
class PowerKernel:
    """Power-law interaction kernel :math:`W(v) = |v|^\\gamma / \\gamma` (``kernel`` in the paper).

    Parameters
    ----------
    gamma : float
        Exponent, ``gamma > 0``.  The paper uses 1, 3/2, 2 and 3:
        :math:`\\gamma < 2` blows up in finite time, :math:`\\gamma \\ge 2` in infinite time
        (homogeneous case).

    Examples
    --------
    >>> import numpy as np
    >>> from jko_cvx import Grid, PowerKernel
    >>> W = PowerKernel(2.0)
    >>> W([-1.0, 0.0, 2.0]), W.derivative([-1.0, 0.0, 2.0])
    (array([0.5, 0. , 2. ]), array([-1.,  0.,  2.]))
    >>> W.is_low_rank  # gamma = 2: the energy matrix is exactly rank 3
    True
    >>> grid = Grid.uniform(-1.0, 1.0, 5)
    >>> PowerKernel(1.0).potential(grid, np.ones(grid.n))  # exact here: (W * 1)(v) = 1 + v^2 on [-1, 1]
    array([2.  , 1.25, 1.  , 1.25, 2.  ])
    """

    gamma: float

    def __post_init__(self) -> None:
        g = real_scalar("gamma", self.gamma)
        if not np.isfinite(g) or g <= 0:
            raise ValueError(f"gamma must be a finite number > 0, got {self.gamma!r}")
        object.__setattr__(self, "gamma", g)

    def __call__(self, v: ArrayLike) -> NDArray[np.float64]:
        """:math:`W(v) = |v|^\\gamma/\\gamma`."""
        return np.abs(np.asarray(v, dtype=float)) ** self.gamma / self.gamma

    def derivative(self, v: ArrayLike) -> NDArray[np.float64]:
        """:math:`W'(v) = \\operatorname{sign}(v) |v|^{\\gamma-1}` (0 at v = 0)."""
        v = np.asarray(v, dtype=float)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = np.sign(v) * np.abs(v) ** (self.gamma - 1)
        return np.where(v == 0, 0.0, out)

    @property
    def is_low_rank(self) -> bool:
        """True for :math:`\\gamma = 2`, whose energy matrix has the exact rank-3 form."""
        return self.gamma == 2.0

    def energy_operator(self, grid: Grid) -> EnergyOperator:
        """The energy matrix on ``grid``, shared by every grid with the same points and kernel with the same gamma.

        Operators live in a bounded least-recently-used cache (:func:`operator_cache_info`), so K,
        its DC split (:meth:`EnergyOperator.split`) and the flux block are computed once per
        (points, gamma) however many grid objects, problems and slices share them.
        """
        return _cached_operator(self, grid)

    def potential(self, grid: Grid, f: ArrayLike) -> NDArray[np.float64]:
        """Discrete potential :math:`(W * f)(v_j) = \\sum_l W(v_j - v_l) f_l h_l`."""
        return self.energy_operator(grid).matvec(f) / grid.h


# Operators keyed on what they are computed from: the kernel's gamma and the grid's type, points
# and cell widths (h follows from the points; both are keyed so a wrong hit would need both equal).
# Strength, dt and the Fisher term scale or sit beside the operator, never enter it.  The engine
# builds a new Grid object every step and a verification re-poses every slice, so a cache per
# grid object recomputed K and the eigendecomposition once per step.
_OPERATOR_CACHE_BYTES = 256 * 2**20
"""Memory bound of the operator cache (estimated bytes, :func:`operator_cache_info`)."""
_OPERATORS: OrderedDict[tuple, tuple[EnergyOperator, int]] = OrderedDict()
_OPERATORS_LOCK = threading.Lock()  # slices are solved on threads


def _operator_bytes(n: int) -> int:
    """Upper estimate of one operator's memory at N points: K, the split's factors and the flux block."""
    return 3 * 8 * n * n


def _cached_operator(kernel: PowerKernel, grid: Grid) -> EnergyOperator:
    """The cached operator of ``kernel`` on ``grid`` (built, and older ones evicted, on a miss)."""
    key = (float(kernel.gamma), type(grid), grid.points.tobytes(), grid.h.tobytes())
    with _OPERATORS_LOCK:
        hit = _OPERATORS.get(key)
        if hit is not None:
            _OPERATORS.move_to_end(key)
            return hit[0]
    op = LowRankEnergy(grid) if kernel.is_low_rank else DenseEnergy(grid, kernel)
    size = _operator_bytes(grid.n)
    with _OPERATORS_LOCK:
        hit = _OPERATORS.get(key)  # another thread may have built it meanwhile: keep one
        if hit is not None:
            return hit[0]
        _OPERATORS[key] = (op, size)
        total = sum(s for _, s in _OPERATORS.values())
        while total > _OPERATOR_CACHE_BYTES and len(_OPERATORS) > 1:
            _, (_, s) = _OPERATORS.popitem(last=False)
            total -= s
    return op


def clear_operator_cache() -> None:
    """Forget every cached energy operator (the next :meth:`PowerKernel.energy_operator` builds anew)."""
    with _OPERATORS_LOCK:
        _OPERATORS.clear()


def operator_cache_info() -> dict[str, int]:
    """The operator cache: ``entries``, estimated ``bytes`` held and the bound ``max_bytes``.

    Each operator is counted at :math:`3 \\cdot 8 N^2` bytes (K, the factors of its split and the
    flux block, whether computed yet or not); the least recently used ones are evicted while the
    total exceeds ``max_bytes`` (256 MiB: about 46 grids of 481 points, two of 2000), except the
    newest, which is kept whatever its size.
    """
    with _OPERATORS_LOCK:
        return {
            "entries": len(_OPERATORS),
            "bytes": sum(s for _, s in _OPERATORS.values()),
            "max_bytes": _OPERATOR_CACHE_BYTES,
        }
