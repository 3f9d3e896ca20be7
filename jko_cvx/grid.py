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

from collections.abc import Callable
from dataclasses import dataclass, field
from numbers import Real
from weakref import WeakKeyDictionary

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Grid", "PeriodicGrid"]

_PERIODIC_IMAGES = 3  # periodic images on each side for PCHIP's four-point stencils

# Per grid object: the breakpoints and spacing terms of its PCHIP interpolants (they depend
# on the points only; rebuilding them cost as much as the interpolation at 121 points).
_PCHIP_SPACINGS: WeakKeyDictionary = WeakKeyDictionary()


def _spacing_terms(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
    """The x-only terms of SciPy's PCHIP on breakpoints ``x``, as ``_find_derivatives`` forms them.

    ``hk`` (a column), ``w1 = 2 h_k + h_{k-1}``, ``w2 = h_k + 2 h_{k-1}``, ``w1 + w2``, and per
    end the one-sided scheme's ``2 h0 + h1``, ``h0`` and ``h0 + h1``.
    """
    hk = (x[1:] - x[:-1])[:, None]
    w1 = 2 * hk[1:] + hk[:-1]
    w2 = hk[1:] + 2 * hk[:-1]
    return (
        x,
        hk,
        w1,
        w2,
        w1 + w2,
        (2 * hk[0] + hk[1], hk[0], hk[0] + hk[1]),
        (2 * hk[-1] + hk[-2], hk[-1], hk[-1] + hk[-2]),
    )


def _pchip_edge(ends: tuple[NDArray[np.float64], ...], m0: NDArray[np.float64], m1: NDArray[np.float64]):
    """SciPy's ``PchipInterpolator._edge_case`` (the one-sided end slope), masks as ``np.where``."""
    a, h0, s = ends
    d = (a * m0 - h0 * m1) / s
    mask = np.sign(d) != np.sign(m0)
    mmm = ~mask & ((np.sign(m0) != np.sign(m1)) & (np.abs(d) > 3.0 * np.abs(m0)))
    return np.where(mask, 0.0, np.where(mmm, 3.0 * m0, d))


def pchip_coefficients(
    terms: tuple[NDArray[np.float64], ...], y: NDArray[np.float64]
) -> NDArray[np.float64]:
    """The coefficients ``c`` of ``scipy.interpolate.PchipInterpolator(x, y, axis=0)``, bit for bit.

    The same operations on the same operands as SciPy's ``_find_derivatives`` and
    ``CubicHermiteSpline`` (elementwise only, so the layout does not matter; tested against
    SciPy), without its input checks and array-namespace dispatch, which cost as much as the
    arithmetic at 121 points, and with the x-only terms (:func:`_spacing_terms`) built once
    per grid.  Non-finite ``y`` is refused, with SciPy's message.

    Parameters
    ----------
    terms : tuple
        :func:`_spacing_terms` of the breakpoints x (n >= 3 of them).
    y : ndarray, shape (n, ...)
        Values at the breakpoints along the first axis.

    Returns
    -------
    ndarray, shape (4, n - 1, ...)
        Highest power first, as ``PPoly.c``.
    """
    if not np.isfinite(y).all():
        raise ValueError("`y` must contain only finite values.")
    _, hk, w1, w2, wsum, left, right = terms
    shape = y.shape
    y = y.reshape(shape[0], -1)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        mk = (y[1:] - y[:-1]) / hk  # also CubicHermiteSpline's slope (the same quotient)
        smk = np.sign(mk)
        condition = (smk[1:] != smk[:-1]) | (mk[1:] == 0) | (mk[:-1] == 0)
        whmean = (w1 / mk[:-1] + w2 / mk[1:]) / wsum
        dk = np.empty_like(y)
        dk[1:-1] = np.where(condition, 0.0, 1.0 / whmean)
        dk[0] = _pchip_edge(left, mk[0], mk[1])
        dk[-1] = _pchip_edge(right, mk[-1], mk[-2])
        t = (dk[:-1] + dk[1:] - 2 * mk) / hk
        c = np.stack((t / hk, (mk - dk[:-1]) / hk - t, dk[:-1], y[:-1]))
    return c.reshape((4, shape[0] - 1, *shape[1:]))


def pchip_terms(grid: Grid | PeriodicGrid) -> tuple[NDArray[np.float64], ...]:
    """:func:`_spacing_terms` of the grid's PCHIP breakpoints (a periodic grid's extended by
    :data:`_PERIODIC_IMAGES` images on each side), cached per grid object."""
    terms = _PCHIP_SPACINGS.get(grid)
    if terms is None:
        x = grid.points
        if isinstance(grid, PeriodicGrid):
            k = _PERIODIC_IMAGES
            x = np.concatenate([x[-k:] - grid.period, x, x[:k] + grid.period])
        terms = _PCHIP_SPACINGS[grid] = _spacing_terms(x)
    return terms


def pchip_ppoly(terms: tuple[NDArray[np.float64], ...], vals: NDArray[np.float64]):
    """``PchipInterpolator(x, vals, axis=-1)`` (extrapolating) as a ``PPoly`` built from
    :func:`pchip_coefficients`: the same coefficients, so the same values when evaluated."""
    from scipy.interpolate import PPoly

    c = pchip_coefficients(terms, np.moveaxis(vals, -1, 0))
    return PPoly.construct_fast(c, terms[0], extrapolate=True, axis=vals.ndim - 1)


def _is_real(x: object) -> bool:
    """A real number (Python or NumPy), not a bool or a string that float() would parse."""
    return isinstance(x, Real) and not isinstance(x, (bool, np.bool_))


def _check_count(name: str, n: object, minimum: int = 3) -> int:
    """``n`` as an int ``>= minimum`` (an integral float such as 5.0 passes), else ``ValueError`` naming it."""
    if not (_is_real(n) and float(n).is_integer() and n >= minimum):
        raise ValueError(f"{name} must be an integer >= {minimum}, got {n!r}")
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
    >>> g = Grid.uniform(-2.0, 2.0, 5)
    >>> g.h
    array([0.5, 1. , 1. , 1. , 0.5])
    """

    points: NDArray[np.float64]
    dv: NDArray[np.float64] = field(init=False, repr=False)
    h: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        try:
            pts = np.array(self.points, dtype=float, copy=True)
        except (TypeError, ValueError) as exc:
            raise TypeError(f"points must be a 1-D array of real numbers, got {self.points!r}") from exc
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
        if not (_is_real(a) and _is_real(b) and np.isfinite(a) and np.isfinite(b)):
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
    """

    points: NDArray[np.float64]
    period: float
    h: NDArray[np.float64] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        pts = np.array(self.points, dtype=float, copy=True)
        if pts.ndim != 1 or pts.size < 3:
            raise ValueError(f"points must be one-dimensional with at least 3 entries, got shape {pts.shape}")
        if not np.all(np.isfinite(pts)) or not np.all(np.diff(pts) > 0):
            raise ValueError("points must be finite and strictly increasing")
        P = float(self.period)
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
        if not (_is_real(half_width) and np.isfinite(half_width) and half_width > 0):
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

    def pchip(self, values: ArrayLike, axis: int = -1) -> Callable[[ArrayLike], NDArray[np.float64]]:
        """Periodic PCHIP interpolant of ``values`` (given at the points, along ``axis``).

        Built on the data extended by three periodic images on each side (enough for
        PCHIP's four-point stencils); the returned callable wraps any query point into
        the period first.  Shared by transport and periodic remapping.
        """
        interp = self._extended_pchip(np.moveaxis(np.asarray(values, dtype=float), axis, -1))

        def evaluate(q: ArrayLike) -> NDArray[np.float64]:
            return interp(self._wrap(q))

        return evaluate

    def _extended_pchip(self, vals: NDArray[np.float64]):
        """SciPy's PCHIP of ``vals`` (along the last axis) on the points extended by three periodic
        images on each side (enough for PCHIP's four-point stencils)."""
        k = _PERIODIC_IMAGES
        ve = np.concatenate([vals[..., -k:], vals, vals[..., :k]], axis=-1)
        # scipy's weighted harmonic mean of the slopes divides by slopes that underflow in
        # vacuum tails; the overflow gives 1/inf = 0, the correct limit (a flat derivative).
        return pchip_ppoly(pchip_terms(self), ve)

    def _wrap(self, q: ArrayLike) -> NDArray[np.float64]:
        """Query points wrapped into the period [lower, lower + P)."""
        lo = self.lower
        return lo + np.mod(np.asarray(q, dtype=float) - lo, self.period)

    def pchip_columns(self, values: ArrayLike, queries: ArrayLike) -> NDArray[np.float64]:
        """Column j of ``values`` interpolated (periodic PCHIP) at column j of ``queries``.

        The same interpolant as :meth:`pchip` for every column, built once for all columns
        and evaluated with the piecewise-cubic form of SciPy's ``PPoly`` (same operations in
        the same order, so the result equals the column-by-column :meth:`pchip` bit for bit;
        tested).  Transport needs it: every v-line has its own foot points, and one
        interpolant per line cost a third of an inhomogeneous step at 121 x 121.

        Parameters
        ----------
        values : array_like, shape (N, L)
            Values at the grid points, one column per line.
        queries : array_like, shape (M, L)
            Query points of each line (any real numbers: wrapped into the period).
        """
        vals = np.asarray(values, dtype=float)
        q = np.asarray(queries, dtype=float)
        if vals.ndim != 2 or vals.shape[0] != self.n or q.ndim != 2 or q.shape[1] != vals.shape[1]:
            raise ValueError(
                f"values must have shape (N, L) = ({self.n}, L) and queries (M, L), got {vals.shape} and {q.shape}"
            )
        k = _PERIODIC_IMAGES
        terms = pchip_terms(self)
        xe = terms[0]
        # c: (4, len(xe) - 1, L), highest power first (the extended PCHIP's, without a PPoly)
        c = pchip_coefficients(terms, np.concatenate([vals[-k:], vals, vals[:k]], axis=0))
        qw = self._wrap(q)
        cell = np.clip(np.searchsorted(xe, qw, side="right") - 1, 0, xe.size - 2)
        s = qw - xe[cell]
        col = np.broadcast_to(np.arange(vals.shape[1]), q.shape)
        # PPoly's evaluation order: c3 + c2 s + c1 s^2 + c0 s^3, the powers built by repeated products
        out = c[3, cell, col] + c[2, cell, col] * s
        z = s * s
        out = out + c[1, cell, col] * z
        z = z * s
        return out + c[0, cell, col] * z

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
