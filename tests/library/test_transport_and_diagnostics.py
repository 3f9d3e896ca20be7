"""Semi-Lagrangian transport on a periodic non-uniform grid; diagnostics."""

import numpy as np
import pytest

from jko_cvx import Grid
from jko_cvx.diagnostics import diagnostics
from jko_cvx.grid import PeriodicGrid
from jko_cvx.mesh.interpolate import pchip_columns, periodic_pchip
from jko_cvx.transport import transport_step


def _nonuniform_periodic(n=160, L=2.0):
    s = np.linspace(-1, 1, n, endpoint=False) + 1 / n
    return PeriodicGrid(L * (s + 0.3 * np.sin(np.pi * s) / np.pi), 2 * L)


def test_periodic_grid_weights_sum_to_the_period():
    g = _nonuniform_periodic()
    assert g.h.sum() == pytest.approx(g.period, rel=1e-14)
    u = PeriodicGrid.uniform(4.0, 121)
    assert np.allclose(u.h, 8.0 / 121) and u.points[0] == pytest.approx(-4 + 4 / 121)


def test_transport_shifts_a_periodic_profile_and_keeps_mass():
    g = _nonuniform_periodic()
    x, L = g.points, g.period / 2
    v = np.array([1.0, -0.7, 0.0])
    prof = lambda y: np.exp(np.sin(np.pi * y / L))  # noqa: E731  (smooth, periodic)
    f = np.stack([prof(x)] * 3, axis=1)
    dt = 0.37  # not a multiple of any spacing
    out = transport_step(g, v, f, dt)
    for j, vj in enumerate(v):
        exact = prof(x - vj * dt)
        assert np.abs(out[:, j] - exact).max() < 5e-3 * exact.max()
    assert np.allclose(g.h @ out, g.h @ f, rtol=1e-14, atol=0)
    assert np.allclose(out[:, 2], f[:, 2], rtol=1e-14, atol=0)  # v = 0: identity (PCHIP exact at nodes)


def test_transport_error_falls_with_the_grid():
    errs = []
    for n in (40, 80, 160):
        g = PeriodicGrid.uniform(1.0, n)
        prof = lambda y: 1 + 0.5 * np.cos(np.pi * y)  # noqa: E731
        out = transport_step(g, np.array([1.0]), prof(g.points)[:, None], 0.317)
        errs.append(np.abs(out[:, 0] - prof(g.points - 0.317)).max())
    assert errs[0] > errs[1] > errs[2]
    assert np.log2(errs[0] / errs[2]) / 2 > 1.8  # second order (PCHIP is second order at extrema)


def test_transport_rejects_bad_shapes():
    g = PeriodicGrid.uniform(1.0, 10)
    with pytest.raises(ValueError, match=r"f must have shape \(Nx, Nv\)"):
        transport_step(g, np.zeros(3), np.ones((9, 3)), 0.1)


def test_diagnostics_match_gaussian_moments():
    vg = Grid.uniform(-8, 8, 801)
    f = np.exp(-(vg.points**2) / 2) / np.sqrt(2 * np.pi)
    d = diagnostics(vg, f)
    assert d["mass"] == pytest.approx(1, rel=1e-10)
    assert d["momentum"] == pytest.approx(0, abs=1e-14)
    assert d["moment2"] == pytest.approx(1, rel=1e-8)
    assert d["moment4"] == pytest.approx(3, rel=1e-8)
    assert d["moment3"] == pytest.approx(2 * np.sqrt(2 / np.pi), rel=1e-6)
    assert d["entropy"] == pytest.approx(-0.5 * np.log(2 * np.pi * np.e), rel=1e-8)
    xg = PeriodicGrid.uniform(1.0, 10)
    d2 = diagnostics(vg, np.tile(f, (10, 1)) / 2, xg)
    assert d2["mass"] == pytest.approx(1, rel=1e-10) and d2["min_dx"] == pytest.approx(0.2)


def test_velocity_spread_and_density_indicators_are_exact_on_gaussian_slices():
    """min_spread_v: the smallest local velocity std over slices with rho >= 0.1 max rho; max_rho: max int f dv."""
    vg = Grid.uniform(-8, 8, 1601)
    xg = PeriodicGrid.uniform(1.0, 4)
    rho = np.array([1.0, 0.5, 0.05, 2.0])  # the third slice is below 0.1 max rho: not counted
    u = np.array([0.5, -1.0, 0.0, 2.0])
    sigma = np.array([0.6, 0.3, 0.1, 0.9])
    f = rho[:, None] * np.exp(-((vg.points - u[:, None]) ** 2) / (2 * sigma[:, None] ** 2))
    f /= np.sqrt(2 * np.pi) * sigma[:, None]
    d = diagnostics(vg, f, xg)
    assert d["max_rho"] == pytest.approx(2.0, rel=1e-10)
    assert d["min_spread_v"] == pytest.approx(0.3, rel=1e-8)
    d_hom = diagnostics(vg, f[0])
    assert d_hom["max_rho"] == pytest.approx(1.0, rel=1e-10) and d_hom["min_spread_v"] == pytest.approx(0.6, rel=1e-8)
    assert np.isnan(diagnostics(vg, np.zeros(vg.n))["min_spread_v"])


def _centre(g: PeriodicGrid, f: np.ndarray, around: float) -> float:
    """Centre of mass of one line in the unwrapped coordinate nearest ``around``."""
    x = around + np.mod(g.points - around + g.period / 2, g.period) - g.period / 2
    return float(x @ (g.h * f) / (g.h @ f))


@pytest.mark.parametrize("n", [61, 121])
def test_moment_conserving_transport_moves_a_coarse_bump_at_its_exact_speed(n):
    """The exact step moves a v-line rigidly by v dt; PCHIP alone lags on coarse grids.

    Periodic Gaussians of standard deviation 0.29 (two points per deviation at n = 61)
    travel for t = 0.3 at v = 2.5 and, for v = -1.5, across the periodic boundary.
    """
    g = PeriodicGrid.uniform(5.0, n)
    v, starts, t = np.array([2.5, -1.5]), np.array([-2.5, -4.5]), 0.3

    def bumps(centres):
        d = g.points[:, None] - centres
        return np.maximum(sum(np.exp(-6 * (d + k * g.period) ** 2) for k in (-1, 0, 1)), 1e-10)

    f = bumps(starts)
    plain, kept = f.copy(), f.copy()
    for _ in range(30):
        plain = transport_step(g, v, plain, t / 30)
        kept = transport_step(g, v, kept, t / 30, conserve_moment=True)
    exact = bumps(starts + v * t)
    for j, centre in enumerate(starts + v * t):
        assert _centre(g, kept[:, j], centre) == pytest.approx(centre, abs=1e-6)  # floor mass, other cut
        if n == 61:  # the paper's step lags by 0.08 here: the correction is not a no-op
            assert abs(_centre(g, plain[:, j], centre) - centre) > 0.05
    np.testing.assert_allclose(g.h @ kept, g.h @ f, rtol=1e-13)
    assert np.all(kept > 0)
    assert np.abs(kept - exact).max() < np.abs(plain - exact).max()  # closer to the exact solution


def test_moment_conserving_transport_leaves_lines_without_vacuum_to_the_mass_rescaling():
    """A line with no vacuum has no safe cut: mass may cross any cut, so only the mass is restored."""
    g = _nonuniform_periodic()
    f = (1.5 + np.sin(np.pi * g.points / (g.period / 2)))[:, None]
    v = np.array([0.8])
    plain = transport_step(g, v, f, 0.3)
    kept = transport_step(g, v, f, 0.3, conserve_moment=True)
    np.testing.assert_allclose(kept, plain, rtol=1e-13)


def test_pchip_columns_equals_the_column_by_column_interpolant_bit_for_bit():
    """Transport's one-interpolant-for-all-lines path against one PCHIP per line (the old path):
    identical to the last bit on non-uniform grids, vacuum tails, any shift sign and wrap."""
    rng = np.random.default_rng(3)
    for trial in range(60):
        x = np.unique(rng.uniform(-2.5, 2.5, rng.integers(6, 60)))
        grid = PeriodicGrid(x, 5.0)
        f = rng.uniform(0, 1, (x.size, 7)) ** 3
        if trial % 2:
            f[rng.uniform(size=f.shape) < 0.5] = 1e-300  # underflowing slopes in vacuum
        shift = rng.normal(size=7) * rng.uniform(0.1, 20)  # several periods too
        queries = x[:, None] - shift[None, :]
        expected = np.stack([periodic_pchip(grid, f[:, j])(queries[:, j]) for j in range(7)], axis=1)
        assert np.array_equal(pchip_columns(grid, f, queries), expected)
    with pytest.raises(ValueError, match="values must have shape"):
        pchip_columns(grid, f[:-1], queries)


@pytest.mark.parametrize("order", ["C", "F"])
def test_transport_equals_the_per_line_loop_bit_for_bit(order):
    """The vectorised step against the per-line PCHIP loop it replaced (same layout, same mass sums):
    whole runs stay bitwise reproducible across the change."""
    rng = np.random.default_rng(5)
    x = np.sort(rng.uniform(-5, 5, 40))
    grid = PeriodicGrid(x, 10.0)
    v = np.linspace(-3, 3, 9)
    f = np.asarray(np.exp(-((x[:, None] - 1.0) ** 2) - v[None, :] ** 2) + 1e-10, order=order)
    loop = np.empty_like(f)
    for j, vj in enumerate(v):
        loop[:, j] = periodic_pchip(grid, f[:, j])(x - vj * 0.07)
    loop = np.maximum(loop, 1e-10)
    expected = loop * ((grid.h @ f) / (grid.h @ loop))
    assert np.array_equal(transport_step(grid, v, f, 0.07), expected)
