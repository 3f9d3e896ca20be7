"""The energy-operator cache: one K and one DC split per (grid points, gamma), never a wrong hit, bounded."""

import numpy as np
import pytest

import jko_cvx.kernels as kernels
from jko_cvx import Grid, PowerKernel
from jko_cvx.kernels import clear_operator_cache, operator_cache_info


def _fresh_split(gamma, points):
    """The split computed from scratch (cache emptied first)."""
    clear_operator_cache()
    return PowerKernel(gamma).energy_operator(Grid(points)).split()


def test_equal_grids_and_kernels_share_one_operator_and_split():
    pts = np.linspace(-2.0, 2.0, 41)
    a = PowerKernel(3.0).energy_operator(Grid(pts))
    b = PowerKernel(3.0).energy_operator(Grid(pts.copy()))  # new grid and kernel objects, same content
    assert b is a
    assert b.split() is a.split()


def test_the_cached_split_is_the_freshly_computed_one():
    pts = np.sort(np.random.default_rng(3).uniform(-3, 3, 57))
    fresh = _fresh_split(3.0, pts)
    P_plus, P_minus = fresh.P_plus.copy(), fresh.P_minus.copy()
    cached = PowerKernel(3.0).energy_operator(Grid(pts.copy())).split()
    assert np.array_equal(cached.P_plus, P_plus) and np.array_equal(cached.P_minus, P_minus)


@pytest.mark.parametrize("index", [0, 17, 40])
def test_grids_differing_in_one_point_get_their_own_split(index):
    pts = np.linspace(-2.0, 2.0, 41)
    other = pts.copy()
    other[index] = np.nextafter(other[index], -np.inf)  # one point, one ulp
    a = PowerKernel(3.0).energy_operator(Grid(pts))
    b = PowerKernel(3.0).energy_operator(Grid(other))
    assert b is not a
    assert np.array_equal(b.grid.points, other)
    # b's split is the one computed from scratch on its own grid, not a's
    got = b.split().P_plus.copy()
    assert np.array_equal(got, _fresh_split(3.0, other).P_plus)


def test_gammas_get_their_own_operator():
    g = Grid(np.linspace(-2.0, 2.0, 31))
    ops = {gamma: PowerKernel(gamma).energy_operator(g) for gamma in (1.0, 1.5, 2.0, 3.0, 3.0 + 1e-15)}
    assert len({id(op) for op in ops.values()}) == len(ops)
    K3 = np.abs(g.points[:, None] - g.points[None, :]) ** 3 / 3 * np.outer(g.h, g.h)
    assert np.array_equal(ops[3.0].dense(), K3)
    assert not np.array_equal(ops[3.0 + 1e-15].dense(), K3)


def test_the_cache_is_bounded_in_memory(monkeypatch):
    clear_operator_cache()
    n = 25
    monkeypatch.setattr(kernels, "_OPERATOR_CACHE_BYTES", 3 * kernels._operator_bytes(n))
    first = PowerKernel(3.0).energy_operator(Grid(np.linspace(-1.0, 1.0, n)))
    for k in range(20):
        PowerKernel(3.0).energy_operator(Grid(np.linspace(-1.0, 1.0 + k + 1, n)))
        info = operator_cache_info()
        assert info["bytes"] <= info["max_bytes"] and info["entries"] <= 3
    # the least recently used was evicted: the same points now build a new operator
    assert PowerKernel(3.0).energy_operator(Grid(np.linspace(-1.0, 1.0, n))) is not first
    # a grid larger than the whole budget is still served (and is then the only entry)
    PowerKernel(3.0).energy_operator(Grid(np.linspace(-1.0, 1.0, 4 * n)))
    assert operator_cache_info()["entries"] == 1


def test_rho_is_computed_once_per_split():
    sp = PowerKernel(3.0).energy_operator(Grid(np.linspace(-2.0, 2.0, 31))).split()
    rho = sp.rho
    assert rho == float(np.linalg.eigvalsh(sp.P_plus @ sp.P_plus.T).max()) and sp.rho is rho
