"""Conservation and dissipation diagnostics (``prop:properties``) and blow-up indicators.

For a phase-space density :math:`f(x_i, v_j)` (or a homogeneous :math:`f(v_j)`), with the
grids' trapezoidal weights: mass :math:`\\iint f`, momentum :math:`\\iint v f`, moments
:math:`\\iint |v|^p f` for p = 2, 3, 4 (non-increasing for p >= 2), the entropy integral
:math:`\\iint f \\log f` (non-decreasing: the paper's "increase of internal energy" with
:math:`U(f) = f\\log f`), max f, and the smallest spacings min dx, min dv that the
blow-up criteria compare with :math:`\\epsilon_x, \\epsilon_v`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .grid import Grid, PeriodicGrid

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
    else:
        if f.shape != (xgrid.n, vgrid.n):
            raise ValueError(f"f must have shape (Nx, Nv) = ({xgrid.n}, {vgrid.n}), got {f.shape}")
        w = np.outer(xgrid.h, vgrid.h)
        min_dx = float(xgrid.dx.min())
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
        "min_dx": min_dx,
        "min_dv": float(vgrid.dv.min()),
    }
