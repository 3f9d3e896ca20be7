"""Limits the mesh maps keep on purpose (``jko_cvx.mesh.maps``), checked on the grids they build."""

import numpy as np

from jko_cvx import Grid
from jko_cvx.mesh.maps import TwoBumpMap


def test_a_two_bump_set_reaching_zero_is_trimmed_so_the_grid_stays_resolved():
    """Two overlapping bumps whose level set reaches the first positive grid point: without the
    trim r1 >= r2 s1 / (4 delta + s1) the inner quintic's slope at 0 vanishes and packs points
    there with spacings of 1e-8 (measured on ibu_gamma3 at t = 15)."""
    g = Grid.uniform(-4.0, 4.0, 101)
    f = np.exp(-2 * (g.points - 0.8) ** 2) + np.exp(-2 * (g.points + 0.8) ** 2)
    delta = 0.5
    mu = TwoBumpMap.from_density(g, f, delta0=0.5, delta=delta)
    s1 = 0.5 - delta / 2
    assert mu.r1 >= mu.r2 * s1 / (4 * delta + s1) * (1 - 1e-12)
    grid = mu.grid(101)
    assert grid.dv.min() > 1e-3 * grid.dv.mean()
