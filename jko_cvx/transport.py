"""Semi-Lagrangian transport in x (``sec:SL``, ``eqn:semi_update``).

One step of :math:`f_t + v f_x = 0` on a periodic, possibly non-uniform x-grid:
:math:`f^{n+1}(x_i, v_j) = f^n(x_i - v_j \\Delta t, v_j)`, evaluated by periodic PCHIP
interpolation (:meth:`PeriodicGrid.pchip`),
floored at ``floor`` (the paper's :math:`10^{-10}`) and rescaled per velocity so that every
v-line keeps its mass.  The mass uses the grid's periodic trapezoidal weights on both
sides (``eqn:semi_update`` mixes the foot points into :math:`M_{n+1}`; the transported values
live on the grid points, so one consistent quadrature is used -- DESIGN.md asks for it).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .grid import PeriodicGrid

__all__ = ["transport_step"]


def transport_step(
    xgrid: PeriodicGrid, v: ArrayLike, f: ArrayLike, dt: float, floor: float = 1e-10
) -> NDArray[np.float64]:
    """Advance ``f[x_i, v_j]`` by one semi-Lagrangian step of length ``dt``.

    Parameters
    ----------
    xgrid : PeriodicGrid
        The x-grid (periodic).
    v : array_like, shape (Nv,)
        Velocities (the v-grid points).
    f : array_like, shape (Nx, Nv)
        Density at the grid points.
    dt : float
        Time step (any sign; ``dt = 0`` is the identity).
    floor : float, default 1e-10
        Lower bound applied before the mass rescaling.

    Returns
    -------
    ndarray, shape (Nx, Nv)
        The transported density; each column has the mass of the corresponding column of ``f``.
    """
    f = np.asarray(f, dtype=float)
    v = np.asarray(v, dtype=float)
    if f.ndim != 2 or f.shape != (xgrid.n, v.size):
        raise ValueError(f"f must have shape (Nx, Nv) = ({xgrid.n}, {v.size}), got {f.shape}")
    if not np.isfinite(dt):
        raise ValueError(f"dt must be finite, got {dt!r}")
    x = xgrid.points
    out = np.empty_like(f)
    for j, vj in enumerate(v):
        out[:, j] = xgrid.pchip(f[:, j])(x - vj * dt)  # foot points, wrapped into the period
    out = np.maximum(out, floor)
    m_old = xgrid.h @ f
    m_new = xgrid.h @ out
    return out * (m_old / m_new)
