"""Views of a phase-space density f(x, v) on its (non-uniform) tensor grids, as the paper draws them.

The paper's inhomogeneous figures show f(t, x, v) as a surface over the (x, v) plane, a
"zoom-in" of it and a contour plot.  The zoom window is not given in the paper; here it is
the smallest box of grid indices that holds the superlevel set

.. math:: \\{(x_i, v_j) : f_{ij} \\ge \\theta \\max f\\}, \\qquad \\theta = 0.1,

widened by a few grid points on each side, so that it contains the maximum of f and every
point outside it has f < theta max f (the properties the tests check).  Mass and min dx are
those of the run's diagnostics (periodic trapezoidal weights and spacings in x, ``PeriodicGrid``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from jko_cvx.grid import Grid, PeriodicGrid

__all__ = ["ZOOM_LEVEL", "contour_view", "snapshot_numbers", "surface_view", "zoom_window"]

ZOOM_LEVEL = 0.1
"""theta: the zoom window holds {f >= theta max f}."""
_PAD = 3  # grid points added on each side of the superlevel box


def zoom_window(f: np.ndarray, level: float = ZOOM_LEVEL, pad: int = _PAD) -> tuple[slice, slice]:
    """Index slices (in x, in v) of the smallest box holding ``{f >= level max f}``, widened by ``pad`` points.

    Parameters
    ----------
    f : ndarray, shape (N_x, N_v)
        The density on the grid points; its maximum must be positive.
    level : float
        theta in (0, 1].
    pad : int
        Grid points added on each side (clipped at the ends of the grids).
    """
    f = np.asarray(f, dtype=float)
    if f.ndim != 2 or not np.all(np.isfinite(f)) or f.max() <= 0:
        raise ValueError(f"f must be a finite 2-D array with a positive maximum, got shape {f.shape}")
    if not 0 < level <= 1:
        raise ValueError(f"level must lie in (0, 1], got {level!r}")
    if pad < 0:
        raise ValueError(f"pad must be >= 0, got {pad!r}")
    above = f >= level * f.max()
    rows, cols = np.flatnonzero(above.any(axis=1)), np.flatnonzero(above.any(axis=0))
    n_x, n_v = f.shape
    return (
        slice(max(rows[0] - pad, 0), min(rows[-1] + pad, n_x - 1) + 1),
        slice(max(cols[0] - pad, 0), min(cols[-1] + pad, n_v - 1) + 1),
    )


def snapshot_numbers(snap: dict[str, Any], period: float) -> dict[str, float]:
    """What a panel of ``snap`` (keys t, x, v, f) shows: max f and where, mass, grid spacings, zoom window.

    ``period`` is the x-period of the scene (2 L_x), for the periodic trapezoidal weights in x.
    """
    x, v, f = np.asarray(snap["x"]), np.asarray(snap["v"]), np.asarray(snap["f"])
    i, j = np.unravel_index(int(np.argmax(f)), f.shape)
    xgrid = PeriodicGrid(x, period)
    sx, sv = zoom_window(f)
    return {
        "t": float(snap["t"]),
        "max f": float(f[i, j]),
        "x at max f": float(x[i]),
        "v at max f": float(v[j]),
        "mass": float(np.sum(np.outer(xgrid.h, Grid(v).h) * f)),
        "min dx": float(xgrid.dx.min()),
        "min dv": float(np.diff(v).min()),
        "zoom x from": float(x[sx.start]),
        "zoom x to": float(x[sx.stop - 1]),
        "zoom v from": float(v[sv.start]),
        "zoom v to": float(v[sv.stop - 1]),
    }


def surface_view(ax, snap: dict[str, Any], title: str, window: tuple[slice, slice] | None = None) -> None:
    """f over the (x, v) plane as a surface on every grid point (no down-sampling that could skip a spike)."""
    x, v, f = np.asarray(snap["x"]), np.asarray(snap["v"]), np.asarray(snap["f"])
    if window is not None:
        x, v, f = x[window[0]], v[window[1]], f[window]
    X, V = np.meshgrid(x, v, indexing="ij")
    ax.plot_surface(X, V, f, rcount=f.shape[0], ccount=f.shape[1], cmap="viridis", linewidth=0)
    ax.set_xlabel("x", fontsize=7)
    ax.set_ylabel("v", fontsize=7)
    ax.set_title(title, fontsize=8)
    ax.tick_params(labelsize=6)


def contour_view(ax, snap: dict[str, Any], title: str, decades: float = 3.0) -> None:
    """Filled contours of f over the (x, v) plane on logarithmic levels from 10^-decades max f to max f.

    Log levels keep a concentrated f readable over the whole domain (linear ones show only
    the spike); below the lowest level the plane is left white.
    """
    from matplotlib.colors import LogNorm

    x, v, f = np.asarray(snap["x"]), np.asarray(snap["v"]), np.asarray(snap["f"])
    levels = f.max() * np.geomspace(10.0**-decades, 1.0, 16)
    cs = ax.contourf(x, v, f.T, levels=levels, norm=LogNorm(levels[0], levels[-1]))
    ax.figure.colorbar(cs, ax=ax, format="%.3g")
    ax.set_xlabel("x")
    ax.set_ylabel("v")
    ax.set_title(f"{title} (log levels, 1e-{decades:g} to 1 times max f)", fontsize=8)
