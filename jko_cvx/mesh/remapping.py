"""Mass-conserving remapping between grids (``eqn:mass_conserv_v``): PCHIP, floor, moments restored.

Two ways to carry a density from the old grid to the new one (:data:`REMAPS`):

``"paper"``
    the paper's: the values are interpolated with PCHIP (:mod:`jko_cvx.mesh.interpolate`),
    floored at 1e-10 and rescaled to the old mass with each grid's trapezoidal quadrature
    (``eqn:mass_conserv_v`` with one consistent quadrature).  The rescaling spreads the
    interpolation's mass error over the whole line, the peak included: where the line has a
    steep front (a vacuum opening at a wall) every remap lifts the peak a little, and remapping
    every step adds that up (measured on homogeneous gamma = 1 with a datum cut by the walls: on
    241 to 961 points with the smallest steps the blow-up came 1.0e-3 to 1.35e-3 early, and
    refining did not remove it; the blow-up estimator's convergence study on the results pages).
``"cumulative"``
    each new dual cell receives the old mass it covers: the cumulative mass
    :math:`F(e_{j+1/2}) = \\sum_{i \\le j} h_i f_i` at the edges :math:`e_{j+1/2}` of the old grid's
    dual cells (midpoints between points; :math:`e_{j+1/2} - e_{j-1/2} = h_j`, the trapezoidal
    weight) is interpolated with PCHIP at the new grid's edges and differenced,
    :math:`\\tilde f_j = (F(e'_{j+1/2}) - F(e'_{j-1/2})) / h'_j`.  The mass is kept without a
    rescaling, and PCHIP keeps F monotone, so :math:`\\tilde f \\ge 0`; the floor then adds at
    most 1e-10 per point, which the mass restoration takes back.  A node's value is read as its
    dual cell's average: second order where the spacing varies smoothly, first order where it
    jumps (the paper map's kink) and at a wall where f has a slope (the end node's cell is a half
    cell on one side of it).

Either is floored at 1e-10 (the paper's floor) and rescaled to the old mass; optionally the
first (and second) moments of each line are restored too (:mod:`jko_cvx.mesh.moments`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.mesh.interpolate import pchip_on, pchip_ppoly, pchip_terms, periodic_pchip
from jko_cvx.mesh.moments import check_floor, restore_moments, restore_three_moments

__all__ = ["REMAPS", "check_line_density", "remap", "remap_periodic"]

REMAPS = ("paper", "cumulative")
"""How a remap carries a density to a new grid: PCHIP of the values, then a rescaling (the paper's), or
PCHIP of the cumulative mass at the dual cells' edges (each new cell gets the old mass it covers)."""

_CUMULATIVE_IMAGES = 3  # periodic images of the cumulative mass on each side (PCHIP's stencils, shifted grids)


def remap(
    old: Grid,
    f: ArrayLike,
    new: Grid,
    floor: float = 1e-10,
    axis: int = -1,
    conserve_momentum: bool = False,
    conserve_energy: bool = False,
    method: str = "paper",
) -> NDArray[np.float64]:
    """PCHIP-interpolate ``f`` from ``old`` to ``new`` along ``axis``, floor, restore each line's mass.

    Implements ``eqn:mass_conserv_v``: :math:`f \\leftarrow \\max(f, \\text{floor})\\, M_{old}/M_{new}`
    with the trapezoidal quadrature of each grid, so the mass is conserved to rounding.
    With ``conserve_momentum`` (a velocity axis) the first moment
    :math:`\\sum_j v_j h_j f_j` of each line is restored too, by the smallest relative
    correction :math:`\\alpha + \\beta (v - \\bar v)` (:func:`jko_cvx.mesh.moments.restore_moments`,
    an exponential tilt of the mass above ``floor``).
    With ``conserve_energy`` (implies the momentum) the second moment :math:`\\sum_j v_j^2 h_j f_j`
    is restored as well, by the quadratic tilt of
    :func:`jko_cvx.mesh.moments.restore_three_moments` (not in the paper): PCHIP on the
    coarse side of a map adds energy, which ``prop:properties`` forbids once the collision
    dissipates less than the interpolation adds (``jko-cvx reproduce property_budget``).
    ``method``: ``"paper"`` (PCHIP of the values) or ``"cumulative"`` (PCHIP of the cumulative
    mass at the dual cells' edges, differenced; the module docstring).
    """
    if not (isinstance(old, Grid) and isinstance(new, Grid)):
        raise TypeError(f"old and new must be jko_cvx.Grid, got {type(old).__name__} and {type(new).__name__}")
    _check_method(method)
    f = np.moveaxis(np.asarray(f, dtype=float), axis, -1)
    check_line_density(f, floor)
    if f.shape[-1] != old.n:
        raise ValueError(f"f must have length {old.n} along axis {axis}, got shape {f.shape}")
    if new.points[0] < old.points[0] - 1e-12 * old.length or new.points[-1] > old.points[-1] + 1e-12 * old.length:
        raise ValueError("the new grid must lie within the old grid's interval")
    if method == "cumulative":
        lo, hi = old.points[0], old.points[-1]
        F = _cumulative_mass(f * old.h)
        g = np.diff(pchip_on(_dual_edges(old.points), F)(np.clip(_dual_edges(new.points), lo, hi)), axis=-1) / new.h
    else:
        # SciPy's PchipInterpolator(old.points, f, axis=-1) without its checks (same coefficients:
        # interpolate.pchip_coefficients); underflowed slopes give flat derivatives (as SciPy's)
        interp = pchip_ppoly(pchip_terms(old), f)
        g = interp(np.clip(new.points, old.points[0], old.points[-1]))
    g = np.maximum(g, floor)
    if conserve_energy:
        moments = [f @ (old.points**p * old.h) for p in (0, 1, 2)]
        g, _ = restore_three_moments(g, new.h, new.points, *moments, floor=floor)
        return np.moveaxis(g, -1, axis)
    momentum = f @ (old.points * old.h) if conserve_momentum else None
    g, _ = restore_moments(g, new.h, new.points, f @ old.h, momentum, floor=floor)
    return np.moveaxis(g, -1, axis)


def check_line_density(f: NDArray[np.float64], floor: float) -> None:
    """``ValueError`` naming ``f`` or ``floor`` unless f is finite and floor a finite number >= 0.

    PCHIP would refuse a NaN from inside SciPy, and a negative floor would let negative
    densities through the mass restoration (shared by :func:`remap` and
    :func:`~jko_cvx.transport.transport_step`).
    """
    check_floor(floor)
    if not np.all(np.isfinite(f)):
        raise ValueError("f must be finite (found NaN or inf)")


def remap_periodic(
    old: PeriodicGrid,
    f: ArrayLike,
    new: PeriodicGrid,
    floor: float = 1e-10,
    axis: int = 0,
    conserve_moment: bool = False,
    method: str = "paper",
) -> NDArray[np.float64]:
    """:func:`remap` for periodic grids (``PeriodicGrid``): periodic PCHIP, floor, per-line mass.

    With ``conserve_moment`` the first moment :math:`\\sum_i x_i h_i f_i` of each line is
    restored too (by the exponential tilt of :func:`jko_cvx.mesh.moments.restore_moments`, of
    the mass above ``floor``).
    A change of grid moves no mass, so the exact remap keeps every moment; PCHIP on the
    coarse side of a mapped grid does not.  The moment is taken in the coordinate
    :math:`\\xi = (x - c) \\bmod P` cut in the line's vacuum
    (:meth:`~jko_cvx.grid.PeriodicGrid.vacuum_coordinate`), so the cut, where :math:`\\xi`
    jumps by the period P, lies across no bump.  Measured on ``inhom_gamma1p5_before``
    (121 x 121, both maps, to t = 0.3): without it the remaps moved the right-moving bump's
    centre of mass ahead by 0.164.

    ``method`` as in :func:`remap`; ``"cumulative"`` takes the cumulative mass over the period, extended by
    its periodic images (:math:`F(e + P) = F(e) + M`).

    As :func:`remap`, it refuses (before any work, naming the argument) non-finite ``f``, a
    floor that is not a finite number >= 0, a length other than ``old.n`` along ``axis``,
    grids of another type or of different periods, and an unknown ``method``.
    """
    if not (isinstance(old, PeriodicGrid) and isinstance(new, PeriodicGrid)):
        raise TypeError(
            f"old and new must be jko_cvx.PeriodicGrid, got {type(old).__name__} and {type(new).__name__}"
        )
    if new.period != old.period:
        raise ValueError(f"new must have the period of old ({old.period!r}), got {new.period!r}")
    _check_method(method)
    f = np.moveaxis(np.asarray(f, dtype=float), axis, -1)
    check_line_density(f, floor)
    if f.shape[-1] != old.n:
        raise ValueError(f"f must have length {old.n} along axis {axis}, got shape {f.shape}")
    if method == "cumulative":
        g = np.maximum(_periodic_cumulative(old, f, new), floor)
    else:
        g = np.maximum(periodic_pchip(old, f, axis=-1)(new.points), floor)
    if not conserve_moment:
        g, _ = restore_moments(g, new.h, new.points, f @ old.h)
        return np.moveaxis(g, -1, axis)
    # PCHIP couples two cells on each side: cut where the old line is vacuum that far out
    xi_old, _ = old.vacuum_coordinate(f, 2 * float(np.diff(old.points).max()))
    cut = (old.points - xi_old)[..., :1]  # the cut point itself (xi = 0 there)
    xi_new = np.mod(new.points - cut, new.period)
    moment = np.sum(f * (xi_old * old.h), axis=-1)
    g, _ = restore_moments(g, new.h, xi_new, f @ old.h, moment, floor=floor)
    return np.moveaxis(g, -1, axis)


def _check_method(method: str) -> None:
    if method not in REMAPS:
        raise ValueError(f"method must be one of {list(REMAPS)}, got {method!r}")


def _dual_edges(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """The edges of the dual cells of a grid on [points[0], points[-1]]: the ends and the midpoints."""
    return np.concatenate([points[:1], 0.5 * (points[1:] + points[:-1]), points[-1:]])


def _cumulative_mass(masses: NDArray[np.float64]) -> NDArray[np.float64]:
    """0 and the running sums of the cell masses along the last axis (one more entry than cells)."""
    return np.concatenate([np.zeros((*masses.shape[:-1], 1)), np.cumsum(masses, axis=-1)], axis=-1)


def _periodic_edges(grid: PeriodicGrid) -> NDArray[np.float64]:
    """The n + 1 edges of a periodic grid's dual cells, from the one across the wrap to its image a period on."""
    x, P = grid.points, grid.period
    first = 0.5 * (x[-1] - P + x[0])
    return np.concatenate([[first], 0.5 * (x[1:] + x[:-1]), [first + P]])


def _periodic_cumulative(old: PeriodicGrid, f: NDArray[np.float64], new: PeriodicGrid) -> NDArray[np.float64]:
    """The ``"cumulative"`` remap on a periodic axis (last axis of ``f``), before the floor.

    The new edges are shifted by whole periods to start within a period of the old first edge
    (a grid may sit in any window of the period), where the images cover them.
    """
    P, k = old.period, _CUMULATIVE_IMAGES
    e, F = _periodic_edges(old), _cumulative_mass(f * old.h)
    M = F[..., -1:]
    edges = np.concatenate([e[:-1] + j * P for j in range(-k, k)] + [e[-1:] + (k - 1) * P])
    F_ext = np.concatenate([F[..., :-1] + j * M for j in range(-k, k)] + [F[..., -1:] + (k - 1) * M], axis=-1)
    e_new = _periodic_edges(new)
    e_new = e_new - P * np.floor((e_new[0] - e[0]) / P)
    return np.diff(pchip_on(edges, F_ext)(e_new), axis=-1) / new.h
