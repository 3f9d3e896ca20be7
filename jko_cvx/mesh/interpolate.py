"""PCHIP interpolation on grids: SciPy's ``PchipInterpolator``, bit for bit, without its per-call overhead.

Shared by the remaps (:mod:`jko_cvx.mesh.remapping`) and transport (:mod:`jko_cvx.transport`).
The coefficients are SciPy's (:func:`pchip_coefficients`, tested against it); the x-only
terms are built once per grid object (:func:`pchip_terms`).  A periodic grid's interpolant
is built on its points extended by :data:`_PERIODIC_IMAGES` images on each side (enough for
PCHIP's four-point stencils), and its query points are wrapped into the period first.
"""

from __future__ import annotations

from collections.abc import Callable
from weakref import WeakKeyDictionary

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jko_cvx.grid import Grid, PeriodicGrid

__all__ = ["pchip_coefficients", "pchip_columns", "pchip_on", "pchip_ppoly", "pchip_terms", "periodic_pchip"]

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


def pchip_on(x: ArrayLike, vals: NDArray[np.float64]):
    """``PchipInterpolator(x, vals, axis=-1)`` on breakpoints ``x`` that are no grid's points (e.g. the
    edges of a grid's dual cells), as :func:`pchip_ppoly` builds it."""
    return pchip_ppoly(_spacing_terms(np.asarray(x, dtype=float)), vals)


def periodic_pchip(
    grid: PeriodicGrid, values: ArrayLike, axis: int = -1
) -> Callable[[ArrayLike], NDArray[np.float64]]:
    """Periodic PCHIP interpolant of ``values`` (given at the points of ``grid``, along ``axis``).

    Built on the data extended by three periodic images on each side (enough for
    PCHIP's four-point stencils); the returned callable wraps any query point into
    the period first (:meth:`~jko_cvx.grid.PeriodicGrid.wrap`).  Shared by transport and
    periodic remapping.
    """
    interp = _extended_pchip(grid, np.moveaxis(np.asarray(values, dtype=float), axis, -1))

    def evaluate(q: ArrayLike) -> NDArray[np.float64]:
        return interp(grid.wrap(q))

    return evaluate


def _extended_pchip(grid: PeriodicGrid, vals: NDArray[np.float64]):
    """SciPy's PCHIP of ``vals`` (along the last axis) on the points of ``grid`` extended by three
    periodic images on each side (enough for PCHIP's four-point stencils)."""
    k = _PERIODIC_IMAGES
    ve = np.concatenate([vals[..., -k:], vals, vals[..., :k]], axis=-1)
    # scipy's weighted harmonic mean of the slopes divides by slopes that underflow in
    # vacuum tails; the overflow gives 1/inf = 0, the correct limit (a flat derivative).
    return pchip_ppoly(pchip_terms(grid), ve)


def pchip_columns(grid: PeriodicGrid, values: ArrayLike, queries: ArrayLike) -> NDArray[np.float64]:
    """Column j of ``values`` interpolated (periodic PCHIP on ``grid``) at column j of ``queries``.

    The same interpolant as :func:`periodic_pchip` for every column, built once for all
    columns and evaluated with the piecewise-cubic form of SciPy's ``PPoly`` (same operations
    in the same order, so the result equals the column-by-column :func:`periodic_pchip` bit
    for bit; tested).  Transport needs it: every v-line has its own foot points, and one
    interpolant per line cost a third of an inhomogeneous step at 121 x 121.

    Parameters
    ----------
    grid : PeriodicGrid
        The grid the values are given on.
    values : array_like, shape (N, L)
        Values at the grid points, one column per line.
    queries : array_like, shape (M, L)
        Query points of each line (any real numbers: wrapped into the period).

    Returns
    -------
    ndarray, shape (M, L)
        The interpolated values.
    """
    vals = np.asarray(values, dtype=float)
    q = np.asarray(queries, dtype=float)
    if vals.ndim != 2 or vals.shape[0] != grid.n or q.ndim != 2 or q.shape[1] != vals.shape[1]:
        raise ValueError(
            f"values must have shape (N, L) = ({grid.n}, L) and queries (M, L), got {vals.shape} and {q.shape}"
        )
    k = _PERIODIC_IMAGES
    terms = pchip_terms(grid)
    xe = terms[0]
    # c: (4, len(xe) - 1, L), highest power first (the extended PCHIP's, without a PPoly)
    c = pchip_coefficients(terms, np.concatenate([vals[-k:], vals, vals[:k]], axis=0))
    qw = grid.wrap(q)
    cell = np.clip(np.searchsorted(xe, qw, side="right") - 1, 0, xe.size - 2)
    s = qw - xe[cell]
    col = np.broadcast_to(np.arange(vals.shape[1]), q.shape)
    # PPoly's evaluation order: c3 + c2 s + c1 s^2 + c0 s^3, the powers built by repeated products
    out = c[3, cell, col] + c[2, cell, col] * s
    z = s * s
    out = out + c[1, cell, col] * z
    z = z * s
    return out + c[0, cell, col] * z
