"""Conservation and dissipation diagnostics (``prop:properties``) and blow-up indicators.

For a phase-space density :math:`f(x_i, v_j)` (or a homogeneous :math:`f(v_j)`), with the
grids' trapezoidal weights: mass :math:`\\iint f`, momentum :math:`\\iint v f`, moments
:math:`\\iint |v|^p f` for p = 2, 3, 4 (non-increasing for p >= 2), the entropy integral
:math:`\\iint f \\log f` (non-decreasing: the paper's "increase of internal energy" with
:math:`U(f) = f\\log f`), max f and the velocity where it is reached (``v_at_max``: a concentration
that moves shows there), and the smallest spacings min dx, min dv that the blow-up criteria compare
with :math:`\\epsilon_x, \\epsilon_v`.

Two indicators do not depend on the mesh maps: the largest spatial density
:math:`\\max_x \\rho(x)`, :math:`\\rho = \\int f \\,dv` (blow-up in x is :math:`\\rho \\to \\infty`), and
the smallest local velocity spread

.. math:: \\sigma_v = \\min_{x:\\ \\rho(x) \\ge \\rho_{\\min}}
          \\Big(\\int (v - u(x))^2 f \\,dv \\big/ \\rho(x)\\Big)^{1/2}, \\qquad u = \\int v f \\,dv / \\rho,

over the populated slices, :math:`\\rho_{\\min} = 10^{-1} \\max_x \\rho` (blow-up in v at a
point x of positive density is :math:`\\sigma_v \\to 0` there).  min dv measures the grid the
map built, sigma_v the density itself: a map whose concentration set shrinks faster than
the density does shows as min dv falling while sigma_v does not.  Homogeneous: rho is the
mass and sigma_v the spread of the whole f (a single bump's width; two bumps keep it large).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from jko_cvx.grid import Grid, PeriodicGrid

__all__ = ["diagnostics"]


def diagnostics(vgrid: Grid, f: ArrayLike, xgrid: PeriodicGrid | None = None) -> dict[str, float]:
    """Diagnostics of ``f`` (shape (Nv,) homogeneous, or (Nx, Nv) with ``xgrid``)."""
    f = np.asarray(f, dtype=float)
    v = vgrid.points
    if xgrid is None:
        if f.shape != (vgrid.n,):
            raise ValueError(f"a homogeneous f must have shape ({vgrid.n},), got {f.shape}")
        w = vgrid.h
        min_dx = np.nan
        rho, spread = _spread(vgrid.h, v, f[None, :])
    else:
        if f.shape != (xgrid.n, vgrid.n):
            raise ValueError(f"f must have shape (Nx, Nv) = ({xgrid.n}, {vgrid.n}), got {f.shape}")
        w = np.outer(xgrid.h, vgrid.h)
        min_dx = float(xgrid.dx.min())
        rho, spread = _spread(vgrid.h, v, f)
    with np.errstate(divide="ignore", invalid="ignore"):
        flogf = np.where(f > 0, f * np.log(np.where(f > 0, f, 1.0)), 0.0)
    return {
        "mass": float(np.sum(w * f)),
        "momentum": float(np.sum(w * f * v)),
        "moment2": float(np.sum(w * f * v**2)),
        "moment3": float(np.sum(w * f * np.abs(v) ** 3)),
        "moment4": float(np.sum(w * f * v**4)),
        "entropy": float(np.sum(w * flogf)),
        "max_f": float(f.max()),
        "v_at_max": float(v[np.unravel_index(np.argmax(f), f.shape)[-1]]),
        "min_dx": min_dx,
        "min_dv": float(vgrid.dv.min()),
        "max_rho": float(rho.max()),
        "min_spread_v": float(spread[rho >= POPULATED * rho.max()].min()) if rho.max() > 0 else np.nan,
    }


POPULATED = 0.1
"""Slices with rho(x) >= POPULATED max rho count for the velocity spread ``min_spread_v``."""


def _spread(h: np.ndarray, v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per slice (rows of f): the density rho and the velocity standard deviation (nan where rho = 0)."""
    rho = f @ h
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (f @ (h * v)) / rho
        var = ((v[None, :] - u[:, None]) ** 2 * f) @ h / rho
    return rho, np.sqrt(np.maximum(var, 0.0))
