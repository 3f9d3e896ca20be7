"""The faster non-collision step helpers against the code they replace, bit for bit.

``mesh.interpolate.pchip_coefficients`` against SciPy's ``PchipInterpolator`` (its coefficients and its
values, through ``remap`` and the periodic interpolants), and the Newton loop of
``mesh.moments._tilt_exponent`` against a verbatim copy of the loop before the row data
were gathered once per row set.  Compared as int64 bit patterns (signed zeros and NaN
payloads included).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import PchipInterpolator

from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.mesh import moments as conservation
from jko_cvx.mesh.interpolate import (
    _spacing_terms,
    pchip_coefficients,
    pchip_columns,
    pchip_ppoly,
    pchip_terms,
    periodic_pchip,
)
from jko_cvx.mesh.maps import OneBumpMap, TwoBumpMap, periodic_map_grid
from jko_cvx.mesh.remapping import remap, remap_periodic
from jko_cvx.transport import transport_step


def _bits(a) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=float)).view(np.int64)


def _same(a, b) -> None:
    assert np.shape(a) == np.shape(b)
    np.testing.assert_array_equal(_bits(a), _bits(b))


def _lines(rng: np.random.Generator, shape: tuple[int, ...], floor: float = 1e-10) -> np.ndarray:
    """Bumps on a floor, with exact zeros, plateaus, sign changes' worth of flat runs and tiny values."""
    n = shape[-1]
    s = np.linspace(-1, 1, n)
    centre = rng.uniform(-0.8, 0.8, (*shape[:-1], 1))
    width = rng.uniform(0.01, 0.5, (*shape[:-1], 1))
    f = np.exp(-((s - centre) / width) ** 2) * rng.uniform(0.1, 50, (*shape[:-1], 1))
    f = np.maximum(f, floor)
    flat = rng.random(shape) < 0.1
    f[flat] = 0.0
    f[rng.random(shape) < 0.05] = 1e-300
    f[rng.random(shape) < 0.05] *= -1.0  # negative values (PCHIP accepts any finite data)
    if f.ndim > 1:
        f[0] = floor  # a line entirely at the floor
    return f


def _grids(rng: np.random.Generator, n: int):
    """Uniform, random non-uniform and mapped grids."""
    yield Grid.uniform(-5.0, 5.0, n)
    yield Grid(np.sort(rng.uniform(-5, 5, n)) + np.linspace(0, 1e-6, n))
    yield OneBumpMap(L=5.0, r=0.5, delta=0.4).grid(n)
    yield TwoBumpMap(L=5.0, r1=1.0, r2=2.0, delta=0.3).grid(n)


def _periodic_grids(rng: np.random.Generator, n: int):
    yield PeriodicGrid.uniform(5.0, n)
    yield PeriodicGrid(np.sort(rng.uniform(-5, 5, n)), 10.0 + 1e-3)
    yield periodic_map_grid(TwoBumpMap(L=5.0, r1=1.0, r2=2.0, delta=0.3), n, 10.0)


@pytest.mark.parametrize("seed", range(6))
def test_pchip_coefficients_are_scipys(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for n in (3, 4, 9, 121):
        for grid in _grids(rng, n):
            x = grid.points
            for shape in ((n,), (n, 7), (n, 3, 5)):
                y = _lines(rng, (*shape[1:], n)) if len(shape) > 1 else _lines(rng, (n,))
                y = np.moveaxis(y, -1, 0) if y.ndim > 1 else y
                y = y * rng.choice([1.0, 1e-200, 1e200])  # underflowing and overflowing slopes
                with np.errstate(all="ignore"):
                    ref = PchipInterpolator(x, y, axis=0).c
                _same(pchip_coefficients(_spacing_terms(x), y), ref)


@pytest.mark.parametrize("seed", range(4))
def test_pchip_ppoly_values_are_scipys(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    for grid in _grids(rng, 41):
        f = _lines(rng, (6, 41))
        q = np.concatenate([rng.uniform(-6, 6, 50), grid.points, [-0.0, 0.0, -5.0, 5.0]])
        with np.errstate(all="ignore"):
            ref = PchipInterpolator(grid.points, f, axis=-1, extrapolate=True)(q)
        _same(pchip_ppoly(pchip_terms(grid), f)(q), ref)
    with pytest.raises(ValueError, match="finite"):
        pchip_ppoly(pchip_terms(Grid.uniform(0.0, 1.0, 5)), np.array([0.0, 1.0, np.nan, 1.0, 0.0]))


def _old_extended_pchip(grid: PeriodicGrid, vals: np.ndarray):
    """``interpolate._extended_pchip`` (``PeriodicGrid._extended_pchip`` then) before the direct
    coefficients (verbatim)."""
    x, P, k = grid.points, grid.period, 3
    xe = np.concatenate([x[-k:] - P, x, x[:k] + P])
    ve = np.concatenate([vals[..., -k:], vals, vals[..., :k]], axis=-1)
    with np.errstate(over="ignore", divide="ignore"):
        return PchipInterpolator(xe, ve, axis=-1)


def _old_pchip_columns(grid: PeriodicGrid, vals: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``interpolate.pchip_columns`` (``PeriodicGrid.pchip_columns`` then) before the direct coefficients
    (verbatim but for the wrap, now the public ``PeriodicGrid.wrap``)."""
    interp = _old_extended_pchip(grid, vals.T)
    xe, c = interp.x, interp.c
    qw = grid.wrap(q)
    cell = np.clip(np.searchsorted(xe, qw, side="right") - 1, 0, xe.size - 2)
    s = qw - xe[cell]
    col = np.broadcast_to(np.arange(vals.shape[1]), q.shape)
    out = c[3, cell, col] + c[2, cell, col] * s
    z = s * s
    out = out + c[1, cell, col] * z
    z = z * s
    return out + c[0, cell, col] * z


@pytest.mark.parametrize("seed", range(4))
def test_periodic_pchip_is_the_old_one(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    for grid in _periodic_grids(rng, 33):
        f = _lines(rng, (33, 9))
        q = grid.points[:, None] - rng.uniform(-3, 3, 9)[None, :] * rng.uniform(0, 2)
        _same(pchip_columns(grid, f, q), _old_pchip_columns(grid, f, q))
        qq = np.concatenate([rng.uniform(-20, 20, 40), grid.points])
        _same(periodic_pchip(grid, f, axis=0)(qq), _old_extended_pchip(grid, f.T)(grid.wrap(qq)))
        with pytest.raises(ValueError, match="finite"):
            pchip_columns(grid, np.where(f > 1, np.nan, f), q)


# --- the moment restoration's Newton loop, as it was (verbatim) -----------------------------


def _old_shifted_exp(expo, f):
    top = np.max(np.where(f > 0, expo, -np.inf), axis=-1, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    return np.exp(np.minimum(expo - top, 0.0))


def _old_tilted_mean_var(f, h, dv, beta):
    w = h * f * _old_shifted_exp(beta[..., None] * dv, f)
    w0 = w.sum(axis=-1)
    mean = np.divide((w * dv).sum(axis=-1), w0, out=np.zeros_like(w0), where=w0 > 0)
    c = dv - mean[..., None]
    var = np.divide((w * c * c).sum(axis=-1), w0, out=np.zeros_like(w0), where=w0 > 0)
    return mean, var


def _old_tilt_exponent(f, h, dv, goal, beta, lo, hi, span, active):
    beta, lo, hi = beta.copy(), lo.copy(), hi.copy()
    tol = 4 * np.finfo(float).eps * np.maximum(span, 1e-300)
    accept = 1e-12 * np.maximum(span, 1e-300)
    err = np.full(beta.shape, np.inf)
    evaluated = np.full(beta.shape, np.nan)
    found = np.zeros(beta.shape, dtype=bool)
    inside = (goal > np.min(np.where(f > 0, dv, np.inf), axis=-1)) & (
        goal < np.max(np.where(f > 0, dv, -np.inf), axis=-1)
    )
    active = active & inside
    for _ in range(conservation._MAX_NEWTON):
        rows = np.flatnonzero(active)
        if rows.size == 0:
            break
        b, lo_r, hi_r = beta[rows], lo[rows], hi[rows]
        b = np.where((b > lo_r) & (b < hi_r), b, 0.5 * (lo_r + hi_r))
        mean, tvar = _old_tilted_mean_var(f[rows], h, dv[rows], b)
        e = mean - goal[rows]
        stalled = ~(np.abs(e) < 0.5 * err[rows])
        done = (np.abs(e) <= tol[rows]) | ((np.abs(e) <= accept[rows]) & stalled)
        err[rows], evaluated[rows] = np.abs(e), b
        lo[rows] = np.where(e < 0, b, lo_r)
        hi[rows] = np.where(e > 0, b, hi_r)
        beta[rows] = b - np.divide(e, tvar, out=np.zeros_like(e), where=tvar > 0)
        found[rows[done]] = True
        active[rows[done]] = False
    found |= active & (err <= accept)
    return np.where(found, evaluated, np.nan)


def _moment_cases(rng: np.random.Generator):
    """(f, h, v, mass, momentum, floor): perturbed lines on uniform, non-uniform and mapped
    grids, per-row coordinates, unreachable targets, rows without mass, NaN."""
    for grid in _grids(rng, 61):
        f = np.abs(_lines(rng, (12, 61)))
        g = f * (1 + 1e-3 * rng.standard_normal(f.shape))  # an interpolation's error
        g[3] = 0.0  # no mass
        mass = f @ grid.h
        momentum = f @ (grid.points * grid.h)
        momentum[4] = mass[4] * 100.0  # target mean out of reach
        for floor in (0.0, 1e-10):
            yield np.maximum(g, floor), grid.h, grid.points, mass, momentum, floor
    grid = PeriodicGrid.uniform(5.0, 61)
    f = np.maximum(np.abs(_lines(rng, (9, 61))), 1e-10)
    xi = np.mod(grid.points - rng.uniform(-5, 5, (9, 1)), grid.period)  # per-row cut coordinates
    yield f * (1 + 1e-4 * rng.standard_normal(f.shape)), grid.h, xi, f @ grid.h, np.sum(f * xi * grid.h, -1), 1e-10
    g = f.copy()
    g[2, 5] = np.nan  # NaN passes through (restore_moments does not check)
    yield g, grid.h, grid.points, f @ grid.h, f @ (grid.points * grid.h), 0.0


@pytest.mark.parametrize("seed", range(5))
def test_restore_moments_is_the_old_loop(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(300 + seed)
    cases = list(_moment_cases(rng))
    new = [conservation.restore_moments(*c[:5], floor=c[5]) for c in cases]
    monkeypatch.setattr(conservation, "_tilt_exponent", _old_tilt_exponent)
    old = [conservation.restore_moments(*c[:5], floor=c[5]) for c in cases]
    for (g_new, ok_new), (g_old, ok_old) in zip(new, old, strict=True):
        _same(g_new, g_old)
        np.testing.assert_array_equal(ok_new, ok_old)


@pytest.mark.parametrize("seed", range(5))
def test_tilt_exponent_is_the_old_loop(seed: int) -> None:
    rng = np.random.default_rng(400 + seed)
    n, rows = 41, 30
    h = Grid(np.sort(rng.uniform(-4, 4, n)) + np.linspace(0, 1e-6, n)).h
    f = np.abs(_lines(rng, (rows, n), floor=0.0))
    dv = rng.uniform(-4, 4, (rows, n))
    span = np.abs(dv).max(axis=-1)
    goal = rng.uniform(-1, 1, rows) * span
    beta = rng.standard_normal(rows)
    limit = 600 / span
    active = rng.random(rows) < 0.9
    args = (f, h, dv, goal, beta, -limit, limit, span, active)
    _same(conservation._tilt_exponent(*args), _old_tilt_exponent(*args))
    m_new = conservation._tilted_moments(h * f, f > 0, dv, beta)
    m_old = _old_tilted_mean_var(f, h, dv, beta)
    for a, b in zip(m_new, m_old, strict=True):
        _same(a, b)


@pytest.mark.parametrize("seed", range(3))
def test_remaps_and_transport_are_the_scipy_path(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """remap, remap_periodic and transport_step through the old SciPy interpolants, end to end."""
    import jko_cvx.mesh.interpolate as interpolate_mod
    import jko_cvx.mesh.remapping as remap_mod
    import jko_cvx.transport as transport_mod

    rng = np.random.default_rng(500 + seed)
    vg, vg2 = Grid.uniform(-5.0, 5.0, 41), TwoBumpMap(L=5.0, r1=1.0, r2=2.0, delta=0.3).grid(41)
    xg, xg2 = PeriodicGrid.uniform(5.0, 33), periodic_map_grid(TwoBumpMap(L=5.0, r1=1.0, r2=2.0, delta=0.3), 33, 10.0)
    f = np.maximum(np.abs(_lines(rng, (33, 41))), 1e-10)

    def run():
        return (
            remap(vg, f, vg2, conserve_momentum=True),
            remap(vg2, f, vg, conserve_momentum=False),
            remap(vg, f[0], vg2),
            remap_periodic(xg, f, xg2, conserve_moment=True),
            remap_periodic(xg2, f, xg, conserve_moment=False),
            transport_step(xg2, vg.points, f, 0.05, conserve_moment=True),
            transport_step(xg, vg.points, f, -0.2, conserve_moment=False),
        )

    new = run()

    def old_ppoly(terms, vals):
        with np.errstate(over="ignore", divide="ignore"):
            return PchipInterpolator(terms[0], vals, axis=-1, extrapolate=True)

    def old_pchip_columns(grid, values, queries):
        return _old_pchip_columns(grid, np.asarray(values, dtype=float), np.asarray(queries, dtype=float))

    monkeypatch.setattr(remap_mod, "pchip_ppoly", old_ppoly)
    monkeypatch.setattr(transport_mod, "pchip_columns", old_pchip_columns)
    monkeypatch.setattr(interpolate_mod, "_extended_pchip", _old_extended_pchip)
    for a, b in zip(new, run(), strict=True):
        _same(a, b)
