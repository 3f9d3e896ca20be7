"""One-dimensional non-uniform grids (the velocity grid of the paper's JKO step).

The paper (``\\subsubsection{Non-uniform velocity discretization}``) places the
density at grid points :math:`v_1 < \\dots < v_N` and the flux at the half points.
With :math:`\\Delta v_j = v_j - v_{j-1}` and :math:`h_j = (\\Delta v_j + \\Delta v_{j+1})/2`
in the interior, the end cells are :math:`h_1 = \\Delta v_2 / 2` and
:math:`h_N = \\Delta v_N / 2`: the grid points include the end points :math:`\\pm L`
of the domain, so :math:`\\sum_j h_j = v_N - v_1` and the quadrature
:math:`\\int g \\approx \\sum_j g(v_j) h_j` is the trapezoidal rule.  This is the
single quadrature used everywhere in the package (collision mass, the
mass-rescaling formulas ``eqn:semi_update`` and ``eqn:mass_conserv_v``, and the
diagnostics); DESIGN.md asks for one consistent choice and this is it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jko_cvx._numbers import is_real, real_array, real_scalar

__all__ = ["Grid", "PeriodicGrid"]



MAX_POINTS = 10_000_000
"""The most points a grid may have (80 MB of coordinates; a collision step on it is far beyond reach)."""


def _check_count(name: str, n: object, minimum: int = 3) -> int:
    """``n`` as an int in ``[minimum, MAX_POINTS]`` (an integral float such as 5.0 passes), else ``ValueError``
    naming it (``True`` is not a count)."""
    if isinstance(n, bool) or not (is_real(n) and float(n).is_integer() and minimum <= n <= MAX_POINTS):
        raise ValueError(f"{name} must be an integer in [{minimum}, {MAX_POINTS}], got {n!r}")
    return int(n)


@dataclass(frozen=True, eq=False)
class Grid:
    """A frozen, strictly increasing 1-D grid with trapezoidal cell widths.

    Parameters
    ----------
    points : array_like, shape (N,)
        Finite, strictly increasing grid points, ``N >= 3``.

    Attributes
    ----------
    points : ndarray, shape (N,)
        The grid points :math:`v_j` (read-only copy).
    dv : ndarray, shape (N-1,)
        Spacings :math:`\\Delta v_{j+1/2} = v_{j+1} - v_j` between neighbours.
    h : ndarray, shape (N,)
        Cell widths :math:`h_j` (trapezoidal weights), ``h.sum() == points[-1] - points[0]``.

    Examples
    --------
    >>> import numpy as np
    >>> from jko_cvx import Grid
    >>> g = Grid.uniform(-2.0, 2.0, 5)
    >>> g.h
    array([0.5, 1. , 1. , 1. , 0.5])
    >>> float(g.mass(g.points**2)), float(g.moment(np.ones(5), 2))  # trapezoidal: 2 (4/2 + 1) = 6
    (6.0, 6.0)
    >>> Grid([-1.0, -0.1, 0.0, 0.1, 1.0]).dv  # non-uniform: finer near the origin
    array([0.9, 0.1, 0.1, 0.9])
    """

    points: NDArray[np.float64]
    dv: NDArray[np.float64] = field(init=False, repr=False)
    h: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        pts = real_array("points", self.points)
        if pts.ndim != 1:
            raise ValueError(f"points must be one-dimensional, got shape {pts.shape}")
        if pts.size < 3:
            raise ValueError(f"points must hold at least 3 grid points, got {pts.size}")
        if not np.all(np.isfinite(pts)):
            raise ValueError("points must be finite (no NaN or inf)")
        dv = np.diff(pts)
        if not np.all(dv > 0):
            bad = int(np.argmin(dv))
            raise ValueError(
                "points must be strictly increasing; "
                f"points[{bad + 1}] = {pts[bad + 1]!r} <= points[{bad}] = {pts[bad]!r}"
            )
        h = np.empty_like(pts)
        h[0] = dv[0] / 2
        h[-1] = dv[-1] / 2
        h[1:-1] = (dv[:-1] + dv[1:]) / 2
        for arr in (pts, dv, h):
            arr.flags.writeable = False
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "dv", dv)
        object.__setattr__(self, "h", h)

    @classmethod
    def uniform(cls, a: float, b: float, n: int) -> Grid:
        """Uniform grid of ``n`` points on ``[a, b]`` (end points included).

        Raises
        ------
        ValueError
            If ``a >= b``, either end is not finite, or ``n < 3``.
        """
        if not (is_real(a) and is_real(b) and np.isfinite(a) and np.isfinite(b)):
            raise ValueError(f"a and b must be finite, got a={a!r}, b={b!r}")
        if not a < b:
            raise ValueError(f"a must be smaller than b, got a={a!r}, b={b!r}")
        return cls(np.linspace(a, b, _check_count("n", n)))

    @property
    def n(self) -> int:
        """Number of grid points N."""
        return int(self.points.size)

    @property
    def length(self) -> float:
        """Length of the domain, ``points[-1] - points[0]``."""
        return float(self.points[-1] - self.points[0])

    @property
    def spacing_ratio(self) -> float:
        """Largest over smallest spacing, ``max(dv) / min(dv)`` (1 for a uniform grid)."""
        return float(self.dv.max() / self.dv.min())

    def integrate(self, values: ArrayLike, axis: int = -1) -> NDArray[np.float64] | float:
        """Trapezoidal integral :math:`\\sum_j g_j h_j` along ``axis``."""
        vals = np.asarray(values, dtype=float)
        if vals.shape[axis] != self.n:
            raise ValueError(f"values must have length {self.n} along axis {axis}, got shape {vals.shape}")
        return np.moveaxis(vals, axis, -1) @ self.h

    def mass(self, f: ArrayLike) -> NDArray[np.float64] | float:
        """Discrete mass :math:`\\sum_j f_j h_j` (last axis)."""
        return self.integrate(f)

    def moment(self, f: ArrayLike, order: int) -> NDArray[np.float64] | float:
        """Discrete moment :math:`\\sum_j v_j^k f_j h_j` (last axis)."""
        return self.integrate(np.asarray(f, dtype=float) * self.points**order)

    def __repr__(self) -> str:
        return (
            f"Grid(n={self.n}, [{self.points[0]:.6g}, {self.points[-1]:.6g}], "
            f"min dv={self.dv.min():.3g}, max dv={self.dv.max():.3g})"
        )


@dataclass(frozen=True, eq=False)
class PeriodicGrid:
    """A strictly increasing grid on a periodic interval ``[x0, x0 + period)``.

    Cell widths wrap around: :math:`h_i = (x_{i+1} - x_{i-1})/2` with
    :math:`x_N = x_0 + P` and :math:`x_{-1} = x_{N-1} - P`, so ``h.sum() == period``: the
    trapezoidal rule of a periodic function (the quadrature of ``eqn:semi_update``).

    Examples
    --------
    >>> from jko_cvx import PeriodicGrid
    >>> x = PeriodicGrid.uniform(1.0, 4)  # four cell-centred points on [-1, 1)
    >>> x.points, x.h
    (array([-0.75, -0.25,  0.25,  0.75]), array([0.5, 0.5, 0.5, 0.5]))
    >>> PeriodicGrid([-0.9, 0.0, 0.5], period=2.0).h  # non-uniform: the first and last widths wrap around
    array([0.75, 0.7 , 0.55])
    """

    points: NDArray[np.float64]
    period: float
    h: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        pts = real_array("points", self.points)
        if pts.ndim != 1 or pts.size < 3:
            raise ValueError(f"points must be one-dimensional with at least 3 entries, got shape {pts.shape}")
        if not np.all(np.isfinite(pts)) or not np.all(np.diff(pts) > 0):
            raise ValueError("points must be finite and strictly increasing")
        P = real_scalar("period", self.period)
        if not (np.isfinite(P) and pts[-1] - pts[0] < P):
            raise ValueError(
                f"period must be finite and exceed points[-1] - points[0] = {pts[-1] - pts[0]!r}, got {P!r}"
            )
        ext = np.concatenate([[pts[-1] - P], pts, [pts[0] + P]])
        h = (ext[2:] - ext[:-2]) / 2
        for arr in (pts, h):
            arr.flags.writeable = False
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "period", P)
        object.__setattr__(self, "h", h)

    @classmethod
    def uniform(cls, half_width: float, n: int) -> PeriodicGrid:
        """``n`` cell-centred points on ``[-L, L)``: :math:`x_i = -L + (i + 1/2)\\,2L/n`."""
        if not (is_real(half_width) and np.isfinite(half_width) and half_width > 0):
            raise ValueError(f"half_width must be a finite number > 0, got {half_width!r}")
        n = _check_count("n", n)
        dx = 2 * half_width / n
        return cls(-half_width + (np.arange(n) + 0.5) * dx, 2 * half_width)

    @property
    def n(self) -> int:
        return int(self.points.size)

    @property
    def lower(self) -> float:
        """Left end of the period, chosen symmetric: ``points[0] - (gap across the wrap)/2``."""
        gap = self.points[0] + self.period - self.points[-1]
        return float(self.points[0] - gap / 2)

    @property
    def dx(self) -> NDArray[np.float64]:
        """Spacings including the one across the wrap (length n)."""
        return np.diff(np.concatenate([self.points, [self.points[0] + self.period]]))

    def integrate(self, values: ArrayLike, axis: int = 0) -> NDArray[np.float64] | float:
        vals = np.asarray(values, dtype=float)
        return np.moveaxis(vals, axis, -1) @ self.h

    def wrap(self, q: ArrayLike) -> NDArray[np.float64]:
        """Points ``q`` wrapped into the period ``[lower, lower + P)``."""
        lo = self.lower
        return lo + np.mod(np.asarray(q, dtype=float) - lo, self.period)

    def _reach_table(self, reach: float) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
        """Which neighbours each point's window holds.

        ``within[s, d - 1, i]``: the point d places from point i (s = 0: ahead, 1: behind) lies
        within ``reach``, for the d that the window looks at (up to the first d at which no
        point has a neighbour in reach, at most n // 2); ``clipped[i]``: at some (s, d) where
        another point has its neighbour in reach, i has not (its window maximum is then
        taken with 0, as the neighbour-by-neighbour loop it replaces did: for the
        non-negative lines it serves this changes nothing).
        """
        x, n, P = self.points, self.n, self.period
        idx = np.arange(n)
        steps = np.arange(1, n // 2 + 1)[:, None]
        within = np.empty((2, steps.size, n), dtype=bool)
        for side, sign in enumerate((1, -1)):
            pos = idx + sign * steps
            within[side] = np.abs(x[pos % n] + P * (pos // n) - x) <= reach
        reached = within.any(axis=(0, 2))
        d0 = int(np.argmin(reached)) if not reached.all() else steps.size
        within = within[:, :d0]
        # the loop compares with 0 only on the sides and offsets where some point is in reach
        looked = within.any(axis=2, keepdims=True)
        return within, np.any(looked & ~within, axis=(0, 1))

    def _window_max(self, f: NDArray[np.float64], reach: float) -> NDArray[np.float64]:
        """Per point, the largest value of its line within ``reach`` (cyclically), itself included.

        Exactly the maximum over the neighbours that :meth:`vacuum_coordinate` defines, but in
        O(N log N) per line: the neighbours within reach form a run of consecutive points on
        each side (the distance grows with the index offset), so each window is an interval,
        and its maximum is that of two overlapping power-of-two blocks of a sparse table
        (maxima are exact in any order).  A point whose neighbours in reach do not form a run
        (possible only through rounding) is done neighbour by neighbour.
        """
        n = self.n
        within, clipped = self._reach_table(reach)
        ahead = within[0].sum(axis=0)
        behind = within[1].sum(axis=0)
        runs = np.all(within[0] == (np.arange(within.shape[1])[:, None] < ahead), axis=0) & np.all(
            within[1] == (np.arange(within.shape[1])[:, None] < behind), axis=0
        )
        half = within.shape[1]
        ext = np.concatenate([f[..., n - half :], f, f[..., :half]], axis=-1) if half else f.copy()
        lo = np.arange(n) + half - behind  # window [lo, hi] in ext
        hi = np.arange(n) + half + ahead
        length = hi - lo + 1
        level = np.floor(np.log2(length)).astype(int)
        out = np.empty_like(f)
        table = ext
        for k in range(int(level.max()) + 1):
            if k:
                w = 1 << (k - 1)
                table = np.maximum(table[..., :-w], table[..., w:])
            sel = np.flatnonzero(level == k)
            if sel.size:
                out[..., sel] = np.maximum(table[..., lo[sel]], table[..., hi[sel] - (1 << k) + 1])
        for i in np.flatnonzero(~runs):
            offs = np.concatenate([[0], np.flatnonzero(within[0][:, i]) + 1, -(np.flatnonzero(within[1][:, i]) + 1)])
            out[..., i] = f[..., (i + offs) % n].max(axis=-1)
        return np.where(clipped, np.maximum(out, 0.0), out)

    def vacuum_coordinate(self, lines: ArrayLike, reach: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Per line, the coordinate :math:`\\xi = (x - c) \\bmod P` cut in the line's vacuum.

        A first moment on a periodic axis depends on where the period is cut; a moment
        that is to be kept through a transport step or a remap must be cut where the line
        has no mass, or mass moving across the cut changes it by P times that mass.  The
        cut c is the grid point whose neighbourhood (the points within ``reach`` of it)
        holds the smallest maximum.

        Parameters
        ----------
        lines : array_like, shape (..., N)
            Non-negative values at the grid points, one line per leading index.
        reach : float
            The distance that mass may travel (transport) or that an interpolant couples
            (remap) across the cut.

        Returns
        -------
        xi : ndarray, shape (..., N)
            The cut coordinate of every point, in [0, P).
        near_cut : ndarray, shape (...)
            The largest value within ``reach`` of the cut: mass crossing it is bounded by
            ``near_cut`` times the distance travelled.
        """
        f = np.asarray(lines, dtype=float)
        x, P = self.points, self.period
        window_max = self._window_max(f, reach)
        i = np.argmin(window_max, axis=-1)
        cut = x[i][..., None]
        near_cut = np.take_along_axis(window_max, i[..., None], axis=-1)[..., 0]
        return np.mod(x - cut, P), near_cut
