"""Adaptive mesh refinement (``sec:mr``): the mesh maps, PCHIP interpolation, remapping with moment
restoration, and the remeshing policy of a run.

* :mod:`~jko_cvx.mesh.maps`: the maps ``mu1`` / ``mu2``, their concentration sets and grids;
* :mod:`~jko_cvx.mesh.following`: maps with each set where its bump is (``refine.<axis>.centre = "follow"``);
* :mod:`~jko_cvx.mesh.interpolate`: SciPy's PCHIP, bit for bit, on grids and periodic grids;
* :mod:`~jko_cvx.mesh.remapping`: PCHIP, floor and per-line mass (``eqn:mass_conserv_v``), with
  :mod:`~jko_cvx.mesh.moments` restoring the first and second moments;
* :mod:`~jko_cvx.mesh.policy`: when and from which set each axis is remeshed.
"""

from jko_cvx.mesh.following import ClusterMap, concentration_clusters, periodic_following_grid
from jko_cvx.mesh.maps import FollowingMap, OneBumpMap, TwoBumpMap, concentration_set, periodic_map_grid, quadrant_set
from jko_cvx.mesh.moments import restore_moments, restore_three_moments
from jko_cvx.mesh.policy import RefineSpec, RemeshPolicy
from jko_cvx.mesh.remapping import remap, remap_periodic

__all__ = [
    "ClusterMap",
    "FollowingMap",
    "OneBumpMap",
    "RefineSpec",
    "RemeshPolicy",
    "TwoBumpMap",
    "concentration_clusters",
    "concentration_set",
    "periodic_following_grid",
    "periodic_map_grid",
    "quadrant_set",
    "remap",
    "remap_periodic",
    "restore_moments",
    "restore_three_moments",
]
