"""Newton's single call made cheaper gives the same bits.

The edge-term derivatives, the reduced-Hessian bands and the banded factorisation take
their grid and term constants as ``(1, n)`` rows for a batch and share subexpressions; each
is compared, as int64 bit patterns (signed zeros and NaN payloads included), with a verbatim
copy of the code it replaced, on batches with vacuum tails, zeros, NaN and signed zeros, and
on single rows.  The J values Newton reuses (at its start and at its last iterate) are
``problem.objective``'s bits, and its options are still checked on every call.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import lapack

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.collision._linalg import divergence, pentadiagonal_cholesky
from jko_cvx.collision.terms import FISHER_TERMS, band_coefficients, reduced_bands, wasserstein_derivatives


def _bits(a) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=float)).view(np.int64)


def _same(a, b) -> bool:
    return np.asarray(a).shape == np.asarray(b).shape and np.array_equal(_bits(a), _bits(b))


def _points(rng, b: int = 6, n: int = 41):
    """Edge data of a batch: vacuum tails, a zero, a NaN, a signed zero, an infinite flux."""
    v = np.linspace(-4, 4, n)
    f = np.exp(-4 * (v - np.linspace(-2, 2, b)[:, None]) ** 2) * (1 + 0.3 * rng.random((b, n)))
    f[1, :5] = 1e-300
    f[2, 7] = 0.0
    f[3, 3] = np.nan
    m = 1e-3 * rng.standard_normal((b, n - 1))
    m[4, 2] = -0.0
    m[5, 9] = np.inf
    return Grid(v), f, m


# verbatim copies of the replaced code
def _old_wasserstein_derivatives(m, s, w):
    u = m / s
    return -w * u * u, 2 * w * u, 2 * w * u * u / s, -2 * w * u / s, 2 * w / s


def _old_reduced_bands(grid, xx, yy, xy, h_sm, h_mm):
    h = grid.h
    a, b = -1 / h[:-1], 1 / h[1:]
    aa, ab2, bb = a * a, 2 * a * b, b * b
    o1a, o1b, o1c, o2 = a[:-1] * a[1:], b[:-1] * a[1:], b[:-1] * b[1:], b[:-2] * a[2:]
    d = np.zeros((*xx.shape[:-1], xx.shape[-1] + 1))
    d[..., :-1] += xx
    d[..., 1:] += yy
    diag = h_mm + aa * d[..., :-1] + ab2 * xy + bb * d[..., 1:] + 2 * (a + b) * h_sm
    off1 = o1a * xy[..., :-1] + o1b * d[..., 1:-1] + o1c * xy[..., 1:] + b[:-1] * h_sm[..., 1:] + a[1:] * h_sm[..., :-1]
    off2 = o2 * xy[..., 1:-1]
    return diag, off1, off2


def _old_perspective(x, y, s, c):
    r = (y - x) / s
    r2 = 2 * r * r
    k = 16 * c / (s * s * s)
    grad = (c * (-4 * r - 2 * r * r), c * (4 * r - 2 * r * r))
    return grad, (k * y * y, k * x * x, -(k * x * y)), (c * (-4 * r - r2), c * (4 * r - r2), k * y * y, k * x * x)


def _old_log(x, y, s, c):
    L = np.log(y) - np.log(x)
    half_l2 = 0.5 * L * L
    q = c * (s + L * (y - x))
    grad = (c * (-L * s / x + 0.5 * L * L), c * (L * s / y + 0.5 * L * L))
    hess = (q / (x * x), q / (y * y), c * (-s + L * (x - y)) / (x * y))
    return grad, hess, (c * (-L * s / x + half_l2), c * (L * s / y + half_l2), q / (x * x), q / (y * y))


def _rows(*arrays):
    """The batch itself and each of its rows alone, as 1-D arrays and as batches of one."""
    yield arrays
    for i in range(arrays[0].shape[0]):
        yield tuple(a[i] for a in arrays)
        yield tuple(a[i : i + 1] for a in arrays)


def test_band_coefficient_rows_are_the_flat_constants():
    grid, _, _ = _points(np.random.default_rng(0))
    for flat, row in zip(band_coefficients(grid), band_coefficients(grid, 2), strict=True):
        assert row.shape == (1, flat.size) and _same(row[0], flat)


def test_wasserstein_derivatives_and_bands_are_the_old_ones():
    grid, f, m = _points(np.random.default_rng(1))
    w = 2.0 * grid.dv
    for fi, mi in _rows(f, m):
        s = fi[..., :-1] + fi[..., 1:]
        with np.errstate(all="ignore"):
            wd = wasserstein_derivatives(mi, s, w)
            ref = _old_wasserstein_derivatives(mi, s, w)
            got = (wd.g_s, wd.g_m, wd.h_ss, wd.h_sm, wd.h_mm)
            assert all(_same(a, r) for a, r in zip(got, ref, strict=True))
            xx, xy = wd.h_ss + 1.5 * wd.h_sm, wd.h_ss - 0.5 * wd.h_mm
            bands = reduced_bands(grid, xx, wd.h_ss, xy, wd.h_sm, wd.h_mm)
            old = _old_reduced_bands(grid, xx, wd.h_ss, xy, wd.h_sm, wd.h_mm)
        assert all(_same(a, r) for a, r in zip(bands, old, strict=True))
    assert not np.isfinite(ref[3]).all()  # the NaN and infinite entries are exercised


@pytest.mark.parametrize("name", sorted(FISHER_TERMS))
def test_fisher_terms_with_coefficient_rows_are_the_old_ones(name):
    grid, f, _ = _points(np.random.default_rng(2))
    c = 1e-4 / grid.dv
    c[0] = -0.0  # signed zeros propagate alike
    term = FISHER_TERMS[name]
    old = {"perspective": _old_perspective, "log": _old_log}[name]
    for (fi,) in _rows(f):
        x, y = fi[..., :-1], fi[..., 1:]
        s = x + y
        with np.errstate(all="ignore"):
            grad, hess, both = old(x, y, s, c)
            assert all(_same(a, r) for a, r in zip(term.gradient(x, y, s, c), grad, strict=True))
            assert all(_same(a, r) for a, r in zip(term.hessian(x, y, s, c), hess, strict=True))
            got = term.gradient_and_hessian(x, y, s, c)
            assert all(_same(a, r) for a, r in zip(got[:4], both, strict=True))
            assert _same(got[4], hess[2])


def test_one_banded_factorisation_is_the_old_storage():
    rng = np.random.default_rng(4)
    n = 30
    for case in range(4):
        diag = 4 + rng.random(n)
        off1, off2 = rng.standard_normal(n - 1), 0.3 * rng.standard_normal(n - 2)
        if case == 1:
            diag[5] = -1.0  # not positive definite
        if case == 2:
            off1[3] = np.nan
        A = np.zeros((1, n, 3))  # the old storage: _pentadiagonal_storage(...)[0].T
        A[:, :, 0], A[:, :-1, 1], A[:, :-2, 2] = diag, off1, off2
        c0, info = lapack.dpbtrf(A[0].T, lower=1)
        old = c0 if info == 0 and np.isfinite(c0[0, -1]) else None
        new = pentadiagonal_cholesky(diag, off1, off2)
        assert (old is None) == (new is None)
        if old is not None:
            assert _same(new, old)


def _problem(gamma: float, beta: float, fisher: str, n: int = 61) -> CollisionProblem:
    grid = Grid.uniform(-2.0, 2.0, n)
    f = np.exp(-2 * grid.points**2) + 0.2 * np.exp(-8 * (grid.points - 0.7) ** 2)
    return CollisionProblem(grid, PowerKernel(gamma), f, 0.01, beta=beta, fisher=fisher)


@pytest.mark.parametrize("gamma", [1.0, 2.0, 3.0])
@pytest.mark.parametrize(("beta", "fisher"), [(10.0, "perspective"), (1000.0, "log"), (np.inf, None)])
def test_the_reported_objective_is_problem_objective_at_the_returned_point(gamma, beta, fisher):
    prob = _problem(gamma, beta, fisher)
    for options in ({}, {"start": "zero"}, {"tol": 1e-6}):
        res = solve_collision(prob, method="newton", **options)
        assert res.success
        assert _same(res.objective, prob.objective(res.f, res.m))  # Newton's own J, reused
    warm = solve_collision(prob, method="newton", m0=0.5 * res.m)
    assert warm.info["warm_started"] and _same(warm.objective, prob.objective(warm.f, warm.m))
    # (a batch's objective is problem.objective's on the batch, or on the sub-batch of a
    # retry: for a dense kernel its last bits depend on the batch shape, so no bitwise test)


def test_the_explicit_start_value_is_j_at_the_start():
    """J at the start point is the explicit step's own evaluation: the first Armijo test uses it."""
    from jko_cvx.collision.newton import NewtonOptions, _objective_interior, _start

    for gamma, beta, fisher in ((1.0, 10.0, "perspective"), (3.0, 1000.0, "log")):
        P = _problem(gamma, beta, fisher)
        batch = CollisionProblem(P.grid, P.kernel, np.stack([P.f_star, 0.0 * P.f_star + 1e-300]), P.dt, beta=beta,
                                 fisher=fisher)  # fmt: skip
        st, _ = _start(batch, None, NewtonOptions())
        assert _same(st.f, batch.f_star - divergence(st.m) / batch.grid.h)
        with np.errstate(all="ignore"):
            assert _same(st.phi, _objective_interior(batch, st.f, st.m))
        assert np.any(st.m[0] != 0)  # the explicit step was taken on the first slice


@pytest.mark.parametrize(
    ("option", "value"),
    [("tol", 1.5), ("tol", True), ("max_iter", 0), ("max_iter", True), ("max_iter", 2.0), ("start", "Zero"),
     ("check_convexity", 1), ("kkt_tol", 0.0)],
)  # fmt: skip
def test_bad_options_are_refused_on_every_call(option, value):
    prob = _problem(1.0, 10.0, "perspective", n=21)
    solve_collision(prob, method="newton", max_iter=1, tol=0.5)  # fill the cache with neighbours
    for _ in range(3):  # a failed check is never cached
        with pytest.raises((ValueError, TypeError), match=option):
            solve_collision(prob, method="newton", **{option: value})
    ok = {"tol": 1e-8, "max_iter": 50, "start": "zero", "check_convexity": False, "kkt_tol": 1e-6}[option]
    assert solve_collision(prob, method="newton", **{option: ok}).iterations >= 1
