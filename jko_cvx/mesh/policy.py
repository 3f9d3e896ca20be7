"""The remeshing policy of a run: when each axis is refined, from which concentration set, and the remap.

After every accepted step the time loop hands the density and its grids to
:meth:`RemeshPolicy.refine`: each refined axis (a :class:`RefineSpec`) gets the map of its
concentration set (one bump ``mu1`` or two bumps ``mu2``, :mod:`jko_cvx.mesh.maps`) and the
density is remapped onto the map's grid (:mod:`jko_cvx.mesh.remapping`), v first, then x.  The
set comes from one of two rules (``concentration_set``):

* ``"projections"``: the v-set from the post-collision f maximised over x, the x-set from it
  maximised over v (each on its positive half-axis, ``eqn:Sr``);
* ``"quadrant"`` (``alg:SPMCSL-JKO`` step 4): one set
  :math:`S = \\{(x_i, v_j): f^*_{ij} > \\delta_0 \\max f^*, x_i > 0, v_j > 0\\}` from ``f_star``,
  the density entering the collision step, each map from S's extent on its axis; an empty S
  gives the axis the uniform grid (extent :data:`UNIFORM_EXTENT`).

The map is centred at 0 (``centre = "origin"``, the paper's maps) or on the concentration
(``centre = "follow"``, so a delta that forms away from 0 is refined where it forms): one bump
in v is :class:`~jko_cvx.mesh.maps.FollowingMap` centred at the grid point of max f, one bump in
x the paper's periodic map rotated onto it (:func:`~jko_cvx.mesh.following.periodic_following_grid`),
and two bumps on either axis a :class:`~jko_cvx.mesh.following.ClusterMap` with each set where
its bump is (:func:`~jko_cvx.mesh.following.concentration_clusters`).

An axis is remeshed only when its set's extent moved by more than ``tol`` times its width
(always with ``tol = 0``, the paper's every-step remesh).  The extents the grids were built
for are carried by the caller between steps (and through checkpoints).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.mesh.following import ClusterMap, concentration_clusters, periodic_following_grid
from jko_cvx.mesh.maps import JUNCTIONS, FollowingMap, OneBumpMap, TwoBumpMap, periodic_map_grid, quadrant_set
from jko_cvx.mesh.remapping import REMAPS, remap, remap_periodic

__all__ = ["CENTRES", "CONCENTRATION_SETS", "UNIFORM_EXTENT", "RefineSpec", "RemeshPolicy"]

CONCENTRATION_SETS = ("projections", "quadrant")
"""Where the maps' sets come from (:attr:`RemeshPolicy.concentration_set`; a scene's
``refine.concentration_set``)."""

CENTRES = ("origin", "follow")
"""Where a map's sets are (:attr:`RefineSpec.centre`): at 0 (symmetric about it), or on the concentration."""

UNIFORM_EXTENT = np.zeros(1)
"""The extent recorded for an empty quadrant set (the uniform grid): r = 0, which no map has (r > 0),
and non-empty, so a checkpoint (where an empty array means None) reads it back as itself."""


@dataclass(frozen=True)
class RefineSpec:
    """Mesh refinement on one axis: map type, delta0, delta, and the remeshing tolerance.

    ``centre``: ``"origin"`` (the paper's maps, centred at 0) or ``"follow"`` (each set centred on
    its concentration: the grid point of max f; its extent is recorded as (c - r, c + r) per set).
    ``junction`` (one-bump maps): ``"paper"`` (the paper's outer piece, with a kink at s = delta) or ``"c1"``
    (a C^1 outer piece, :mod:`jko_cvx.mesh.maps`).
    ``remap``: how a new grid receives the density (:data:`jko_cvx.mesh.remapping.REMAPS`): ``"paper"``
    (PCHIP of the values, rescaled to the mass) or ``"cumulative"`` (PCHIP of the cumulative mass: each new
    cell gets the old mass it covers; no rescaling that lifts the peak).
    ``tol = 0`` remeshes every step (the paper's Algorithm ``alg:one_step_MR_JKO``); ``tol > 0``
    remeshes only when the concentration set's extent has moved by more than ``tol`` times
    its width.  Measured (``ibu_gamma3``): remeshing every step moves the bumps inward by as
    much as their own motion per step (PCHIP remap bias), so the peaks ran ahead of the
    point-mass law 1/(2Mt) after t ~ 5; with ``tol = 0.1`` they follow it to t = 20.
    """

    bumps: int = 1
    delta0: float = 0.5
    delta: float = 0.5
    tol: float = 0.0
    conserve_energy: bool = False
    centre: str = "origin"
    junction: str = "paper"
    remap: str = "paper"

    def __post_init__(self) -> None:
        if self.centre not in CENTRES:
            raise ValueError(f"centre must be one of {list(CENTRES)}, got {self.centre!r}")
        if self.remap not in REMAPS:
            raise ValueError(f"remap must be one of {list(REMAPS)}, got {self.remap!r}")
        if self.junction not in JUNCTIONS:
            raise ValueError(f"junction must be one of {list(JUNCTIONS)}, got {self.junction!r}")
        if self.junction != "paper" and self.bumps != 1:
            raise ValueError(
                f"junction = {self.junction!r} is built for one-bump maps (bumps = 1), got bumps = {self.bumps}"
            )


def _map_params(mu) -> np.ndarray:
    """The extent of the concentration set a map was built for: (r,) or (r1, r2)."""
    return np.array([mu.r] if isinstance(mu, OneBumpMap) else [mu.r1, mu.r2])


def _is_uniform(extent: np.ndarray | None) -> bool:
    return extent is not None and extent.size == 1 and extent[0] == 0


def _moved(spec: RefineSpec, old: np.ndarray | None, new: np.ndarray) -> bool:
    """Remesh when the set's extent moved by more than ``spec.tol`` times its width (always if tol = 0).

    From one empty quadrant set (:data:`UNIFORM_EXTENT`) to the next nothing moves.
    """
    if _is_uniform(old) and _is_uniform(new):
        return False
    if old is None or old.size != new.size or spec.tol == 0:
        return True
    if spec.centre == "follow":  # (lo, hi) per set: the widest set's width
        width = float((new[1::2] - new[::2]).max())
    else:
        width = new[-1] - (new[0] if new.size == 2 else 0.0)
    return bool(np.abs(new - old).max() > spec.tol * width)


def _map_from_extent(spec: RefineSpec, grid: Grid, lo: float, hi: float):
    """The axis map for a set spanning [lo, hi] on the positive half of ``grid``."""
    if spec.bumps == 1:
        return OneBumpMap.from_extent(grid, hi, spec.delta, spec.junction)
    return TwoBumpMap.from_extent(grid, lo, hi, spec.delta)


Extent = np.ndarray | None
"""The extent of the set a refined grid was built for: (r,), (r1, r2), :data:`UNIFORM_EXTENT`, or None
(no map yet)."""


@dataclass(frozen=True)
class RemeshPolicy:
    """How a run refines its grids (see the module docstring).

    Parameters
    ----------
    v, x : RefineSpec or None
        The refinement of each axis (None: that grid stays as it is).
    v_L : float
        Half-width of the velocity domain ``[-v_L, v_L]`` (the uniform v-grid of an empty set).
    x_L : float or None
        Half-width of the periodic x-domain (inhomogeneous runs).
    concentration_set : str
        One of :data:`CONCENTRATION_SETS`: ``"projections"`` or ``"quadrant"``.
    conserve_momentum : bool
        The v-remap restores each x-slice's momentum (and its energy where ``v.conserve_energy``).
    conserve_x_moment : bool
        The x-remap restores each v-line's first x-moment.
    """

    v: RefineSpec | None
    x: RefineSpec | None
    v_L: float
    x_L: float | None = None
    concentration_set: str = "projections"
    conserve_momentum: bool = True
    conserve_x_moment: bool = True

    def __post_init__(self) -> None:
        if self.concentration_set == "quadrant" and any(
            sp is not None and sp.centre == "follow" for sp in (self.v, self.x)
        ):
            raise ValueError("centre = 'follow' builds its map from the projections, not the quadrant set")
        if self.concentration_set not in CONCENTRATION_SETS:
            raise ValueError(
                f"concentration_set must be one of {list(CONCENTRATION_SETS)}, got {self.concentration_set!r}"
            )

    def initial(
        self, vgrid: Grid, xgrid: PeriodicGrid | None, f: np.ndarray
    ) -> tuple[np.ndarray, Grid, PeriodicGrid | None, Extent, Extent]:
        """f0 refined where the policy refines (as the algorithms start): ``(f, vgrid, xgrid, v extent, x extent)``.

        With ``concentration_set = "quadrant"`` the set comes from f0 (no transport yet), and the
        given grids count as uniform-grid maps (an empty set leaves them as they are).
        """
        if self.concentration_set == "quadrant":
            u = UNIFORM_EXTENT
            return self._refine_quadrant(vgrid, xgrid, f, f, u, u)
        return self.refine(vgrid, xgrid, f, None, None, None)

    def refine(
        self,
        vgrid: Grid,
        xgrid: PeriodicGrid | None,
        f: np.ndarray,
        f_star: np.ndarray | None,
        v_extent: Extent,
        x_extent: Extent,
    ) -> tuple[np.ndarray, Grid, PeriodicGrid | None, Extent, Extent]:
        """Remesh after a step: ``(f, vgrid, xgrid, v extent, x extent)``, each grid the given one where not remeshed.

        ``f`` is the density after the step (it is remapped), ``f_star`` the density that entered
        the collision step (the quadrant rule's set; unused by the projections rule).
        """
        if self.concentration_set == "quadrant":
            return self._refine_quadrant(vgrid, xgrid, f, f_star, v_extent, x_extent)
        if self.v is not None:
            f, vgrid, v_extent = self._refine_v(vgrid, f, v_extent)
        if self.x is not None:
            f, xgrid, x_extent = self._refine_x(xgrid, f, x_extent)
        return f, vgrid, xgrid, v_extent, x_extent

    def floor_v(self, vgrid: Grid, f: np.ndarray) -> np.ndarray:
        """``v.floor_every_step``: ``eqn:mass_conserv_v`` on the unchanged v-grid.

        :math:`f \\leftarrow \\max(f, 10^{-10})\\, M/M'` per x-slice (with the slice's momentum,
        and energy where ``v.conserve_energy``, restored as the v-remap restores them):
        the remap of the paper's algorithm onto a grid that did not move.  Without it a fixed
        v-grid keeps whatever the collision leaves at the edges: on the uniform 481 x 481
        gamma = 3/2 grid the edge lines in v drained to 1e-17, and Newton could not certify the
        slices that carried them.
        """
        energy = self.v is not None and self.v.conserve_energy
        return remap(vgrid, f, vgrid, axis=-1, conserve_momentum=self.conserve_momentum, conserve_energy=energy)

    def _refine_v(self, vgrid: Grid, f: np.ndarray, params: Extent):
        spec = self.v
        fv = f if f.ndim == 1 else f.max(axis=0)
        if spec.centre == "follow" and spec.bumps == 1:
            mu = FollowingMap.from_density(vgrid, fv, spec.delta0, spec.delta, spec.junction)
            new = np.array([mu.c - mu.r, mu.c + mu.r])
        elif spec.centre == "follow":
            L = float(vgrid.points[-1])
            sets = concentration_clusters(vgrid.points, fv, spec.delta0, spec.bumps)
            mu = ClusterMap(L, tuple((c, min(r, L * spec.delta)) for c, r in sets), spec.delta)
            new = mu.extent()
        elif spec.bumps == 1:
            mu = OneBumpMap.from_density(vgrid, fv, spec.delta0, spec.delta, spec.junction)
            new = _map_params(mu)
        else:
            mu = TwoBumpMap.from_density(vgrid, fv, spec.delta0, spec.delta)
            new = _map_params(mu)
        if not _moved(spec, params, new):
            return f, vgrid, params
        grid = mu.grid(vgrid.n)
        f = remap(vgrid, f, grid, axis=-1, conserve_momentum=self.conserve_momentum,
                  conserve_energy=spec.conserve_energy, method=spec.remap)  # fmt: skip
        return f, grid, new

    def _refine_x(self, xgrid: PeriodicGrid, f: np.ndarray, params: Extent):
        spec = self.x
        fx = f.max(axis=1)
        if spec.centre == "follow":
            return self._follow_x(xgrid, f, fx, params)
        proxy = self._x_proxy(xgrid)
        fx_proxy = np.concatenate([[fx[0]], fx, [fx[-1]]])
        if spec.bumps == 1:
            mu = OneBumpMap.from_density(proxy, fx_proxy, spec.delta0, spec.delta, spec.junction)
        else:
            mu = TwoBumpMap.from_density(proxy, fx_proxy, spec.delta0, spec.delta)
        new = _map_params(mu)
        if not _moved(spec, params, new):
            return f, xgrid, params
        grid = periodic_map_grid(mu, xgrid.n, xgrid.period)
        f = remap_periodic(xgrid, f, grid, axis=0, conserve_moment=self.conserve_x_moment, method=spec.remap)
        return f, grid, new

    def _follow_x(self, xgrid: PeriodicGrid, f: np.ndarray, fx: np.ndarray, params: Extent):
        """``refine.x.centre = "follow"``: the sets of max_v f on the periodic axis, each where its bump is."""
        spec, L = self.x, float(self.x_L)
        sets = concentration_clusters(xgrid.points, fx, spec.delta0, spec.bumps, period=xgrid.period)
        sets = [(c, min(r, L * spec.delta)) for c, r in sets]
        if spec.bumps == 1:
            (c, r), mu = sets[0], None
            new = np.array([c - r, c + r])
        else:
            mu = ClusterMap(L, tuple(sets), spec.delta, periodic=True)
            new = mu.extent()
        if not _moved(spec, params, new):
            return f, xgrid, params
        if mu is None:
            grid = periodic_following_grid(L, c, r, spec.delta, xgrid.n, spec.junction)
        else:
            grid = mu.periodic_grid(xgrid.n)
        f = remap_periodic(xgrid, f, grid, axis=0, conserve_moment=self.conserve_x_moment, method=spec.remap)
        return f, grid, new

    def _x_proxy(self, xgrid: PeriodicGrid) -> Grid:
        """The maps assume [-L, L]; x-grids are periodic cell-centred grids inside it."""
        return Grid(np.concatenate([[-self.x_L], xgrid.points, [self.x_L]]))

    def _refine_quadrant(self, vgrid: Grid, xgrid: PeriodicGrid, f: np.ndarray, f_star: np.ndarray, vp, xp):
        """The quadrant rule: both maps from one set of ``f_star`` on the step's grids, each axis with its
        own delta0; ``f`` remapped, v first, then x."""
        spec_v, spec_x = self.v, self.x
        sets = {axis: quadrant_set(xgrid.points, vgrid.points, f_star, spec.delta0)
                for axis, spec in (("v", spec_v), ("x", spec_x)) if spec is not None}  # fmt: skip
        if spec_v is not None:
            s = sets["v"]
            mu = None if s is None else _map_from_extent(spec_v, vgrid, *s[1])
            new = UNIFORM_EXTENT if mu is None else _map_params(mu)
            if _moved(spec_v, vp, new):
                grid = Grid.uniform(-self.v_L, self.v_L, vgrid.n) if mu is None else mu.grid(vgrid.n)
                f = remap(vgrid, f, grid, axis=-1, conserve_momentum=self.conserve_momentum,
                          conserve_energy=spec_v.conserve_energy, method=spec_v.remap)  # fmt: skip
                vgrid, vp = grid, new
        if spec_x is not None:
            s = sets["x"]
            mu = None if s is None else _map_from_extent(spec_x, self._x_proxy(xgrid), *s[0])
            new = UNIFORM_EXTENT if mu is None else _map_params(mu)
            if _moved(spec_x, xp, new):
                grid = (PeriodicGrid.uniform(self.x_L, xgrid.n) if mu is None
                        else periodic_map_grid(mu, xgrid.n, xgrid.period))  # fmt: skip
                f = remap_periodic(xgrid, f, grid, axis=0, conserve_moment=self.conserve_x_moment,
                                   method=spec_x.remap)  # fmt: skip
                xgrid, xp = grid, new
        return f, vgrid, xgrid, vp, xp
