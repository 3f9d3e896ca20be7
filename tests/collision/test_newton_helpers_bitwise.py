"""The Newton loop's faster helpers give the old bits.

Each rewritten helper is compared, as int64 bit patterns (signed zeros and NaN payloads
included), with a verbatim copy of the code it replaced, on random batches with
non-finite rows and slices at the vacuum boundary.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import lapack

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status
from jko_cvx.collision import _structured as structured
from jko_cvx.collision._linalg import _solve_one, _thomas, divergence, divergence_adjoint, solve_sym_tridiagonal
from jko_cvx.collision.certify import _judge, certify
from jko_cvx.collision.newton import _fused
from jko_cvx.collision.problem import TermParts
from jko_cvx.collision.terms import FISHER_TERMS, reduced_bands, wasserstein_derivatives


def _bits(a) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=float)).view(np.int64)


def _same(a, b) -> bool:
    return np.asarray(a).shape == np.asarray(b).shape and np.array_equal(_bits(a), _bits(b))


def _problem(gamma: float, fisher: str, rng, b: int = 7, n: int = 41) -> CollisionProblem:
    """A batch with vacuum tails (1e-300), one slice at the boundary, one rough slice."""
    v = np.linspace(-4, 4, n)
    x = np.linspace(-2, 2, b)[:, None]
    f = np.exp(-4 * (v - x) ** 2) * (1 + 0.3 * rng.random((b, n)))
    f[1, :5] = 1e-300
    f[2] = np.maximum(f[2] * 10.0 ** rng.uniform(-40, 0, n), 1e-300)
    return CollisionProblem(Grid(v), PowerKernel(gamma), f, 0.02, 2.0, 300.0, fisher, conserve_momentum=True)


def _points(P: CollisionProblem, rng) -> tuple[np.ndarray, np.ndarray]:
    """Iterates near f*, with a zero flux row, a row with f = 0 somewhere, and a NaN row."""
    b, n = P.f_star.shape
    m = 1e-3 * rng.standard_normal((b, n - 1)) * np.sqrt(P.f_star[:, :-1] * P.f_star[:, 1:])
    m[3] = 0.0
    f = P.f_star - divergence(m) / P.grid.h
    f[4, 7] = 0.0  # at the vacuum boundary: log(0), 0/0
    f[5, 3] = np.nan
    m[6, 2] = -0.0
    return f, m


# --------------------------------------------------------------------------- Fisher terms
@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0])
@pytest.mark.parametrize("name", sorted(FISHER_TERMS))
def test_gradient_and_hessian_is_gradient_then_hessian(name, gamma):
    rng = np.random.default_rng(11)
    P = _problem(gamma, name, rng)
    f, _ = _points(P, rng)
    x, y = f[..., :-1], f[..., 1:]
    s = x + y
    c = np.broadcast_to(P.fisher_coef, x.shape).copy()
    c[0, 0] = -0.0  # signed zeros propagate alike
    term = FISHER_TERMS[name]
    with np.errstate(all="ignore"):
        got = term.gradient_and_hessian(x, y, s, c)
        ref = (*term.gradient(x, y, s, c), *term.hessian(x, y, s, c))
    assert len(got) == 5
    for a, r in zip(got, ref, strict=True):
        assert _same(a, r)
    with np.errstate(all="ignore"):
        diagonal = term.gradient_and_hessian(x, y, s, c, mixed=False)  # the SQP's: no mixed entry
    assert diagonal[4] is None
    for a, r in zip(diagonal[:4], ref[:4], strict=True):
        assert _same(a, r)
    assert not np.isfinite(got[0]).all()  # the boundary and NaN rows are exercised


# --------------------------------------------------------------------------- _fused
def _old_fused(problem, f, m, want_parts=True):
    """Verbatim copy of newton._fused before gradient_and_hessian."""
    h = problem.grid.h
    x, y = f[..., :-1], f[..., 1:]
    s = x + y
    wd = wasserstein_derivatives(m, s, problem.wass_coef)
    gx = gy = wd.g_s
    xx = yy = xy = wd.h_ss
    if problem.fisher is not None:
        term = FISHER_TERMS[problem.fisher]
        c = problem.fisher_coef
        fx, fy = term.gradient(x, y, s, c)
        gx, gy = wd.g_s + fx, wd.g_s + fy
        hx, hy, hxy = term.hessian(x, y, s, c)
        xx, yy, xy = wd.h_ss + hx, wd.h_ss + hy, wd.h_ss + hxy
    gfe = 2 * problem.energy_coef * problem.energy.matvec(f)
    gf = gfe.copy()
    gf[..., :-1] += gx
    gf[..., 1:] += gy
    g = wd.g_m - divergence_adjoint(gf / h)
    parts = None
    if want_parts is not False:
        rows = slice(None) if want_parts is True else want_parts
        g_s, g_m, gf_r, gfe_r = wd.g_s[rows], wd.g_m[rows], gf[rows], gfe[rows]
        gfw = np.zeros_like(gf_r)
        gfw[..., :-1] += g_s
        gfw[..., 1:] += g_s
        gff = gf_r - gfe_r - gfw
        zero = np.zeros_like(g_m)
        parts = TermParts((gfw, g_m), (gff, zero), (gfe_r, zero))
    return g, reduced_bands(problem.grid, xx, yy, xy, wd.h_sm, wd.h_mm), parts


@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0])
@pytest.mark.parametrize("name", [*sorted(FISHER_TERMS), None])
def test_fused_is_the_old_fused(name, gamma):
    rng = np.random.default_rng(5)
    P = _problem(gamma, name, rng)
    f, m = _points(P, rng)
    mask = rng.random(f.shape[0]) < 0.5
    for want in (True, False, mask):
        with np.errstate(all="ignore"):
            g, bands, parts = _fused(P, f, m, want)
            g0, bands0, parts0 = _old_fused(P, f, m, want)
        assert _same(g, g0)
        for band, band0 in zip(bands, bands0, strict=True):
            assert _same(band, band0)
        if want is False:
            assert parts is None and parts0 is None
            continue
        for term in ("wasserstein", "fisher", "energy"):
            p, p0 = getattr(parts, term), getattr(parts0, term)
            assert _same(p[0], p0[0]) and _same(p[1], p0[1])


# --------------------------------------------------------------------------- tridiagonal solve
def _old_solve_sym_tridiagonal(diag, off, rhs):
    """Verbatim copy of linalg.solve_sym_tridiagonal before the gather-free chain."""
    diag = np.asarray(diag, dtype=float)
    off = np.asarray(off, dtype=float)
    rhs = np.asarray(rhs, dtype=float)
    if diag.ndim == 1 and rhs.ndim == 1:
        return _solve_one(diag, off, rhs)
    shape = np.broadcast_shapes(diag.shape, rhs.shape)
    n = shape[-1]
    if n == 1:
        return _thomas(diag, off, rhs, shape)
    rows = int(np.prod(shape[:-1]))
    D = np.broadcast_to(diag, shape).reshape(rows, n)
    E = np.broadcast_to(off, (*shape[:-1], n - 1)).reshape(rows, n - 1)
    R = np.broadcast_to(rhs, shape).reshape(rows, n)
    x = np.empty((rows, n))
    finite = np.isfinite(D).all(axis=-1) & np.isfinite(E).all(axis=-1) & np.isfinite(R).all(axis=-1)
    chain = np.flatnonzero(finite)
    alone = ~finite
    if chain.size:
        links = np.zeros((chain.size, n))
        links[:, :-1] = E[chain]
        _, _, xc, info = lapack.dptsv(D[chain].ravel(), links.ravel()[:-1], R[chain].ravel())
        xc = xc.reshape(chain.size, n)
        if info == 0 and np.isfinite(xc).all():
            x[chain] = xc
        else:
            alone[chain] = True
    for i in np.flatnonzero(alone):
        x[i] = _solve_one(D[i], E[i], R[i])
    return x.reshape(shape)


def _tridiagonal_cases(rng):
    b, n = 9, 30
    diag = 2 + rng.random((b, n))
    off = -rng.random((b, n - 1))
    rhs = rng.standard_normal((b, n))
    rhs[0, 3] = -0.0
    yield diag, off, rhs  # every row finite: one chain, no gathers
    d2, r2 = diag.copy(), rhs.copy()
    r2[4, 5] = np.inf
    d2[6, 0] = np.nan
    yield d2, off, r2  # non-finite rows alone
    d3 = diag.copy()
    d3[2, 10] = -5.0  # one indefinite row fails the chain
    yield d3, off, rhs
    yield diag[0], off[0], rhs  # broadcast diagonal
    yield diag[:, None], off[:, None], np.stack([rhs, -rhs], axis=1)  # three dimensions
    yield diag[:1], off[:1], rhs[:1]  # a batch of one
    yield diag[:, :1], off[:, :0], rhs[:, :1]  # n = 1


def test_solve_sym_tridiagonal_is_the_old_one():
    rng = np.random.default_rng(3)
    for diag, off, rhs in _tridiagonal_cases(rng):
        keep = [a.copy() for a in (diag, off, rhs)]
        with np.errstate(all="ignore"):
            x = solve_sym_tridiagonal(diag, off, rhs)
            x0 = _old_solve_sym_tridiagonal(diag, off, rhs)
        assert _same(x, x0)
        for a, k in zip((diag, off, rhs), keep, strict=True):  # the inputs are not overwritten
            assert _same(a, k)
        assert not any(np.shares_memory(x, a) for a in (diag, off, rhs))


# --------------------------------------------------------------------------- certify
def test_certify_batch_is_the_per_row_judgement():
    """The batch's finiteness test gives the statuses of the old per-row test (``finite=None``)."""
    rng = np.random.default_rng(9)
    P = _problem(1.5, "log", rng)
    f, m = P.project_feasible(P.f_star)
    f, m = f.copy(), m.copy()
    f[1, 2] = np.nan
    m[2, 4] = np.inf
    claimed = np.array([None, Status.CONVERGED, None, Status.MAX_ITERATIONS, None, None, None], dtype=object)
    residual = np.array([1e-12, 1e-12, 1e-12, 1e-12, 1e-3, 1e-12, 1e-12])
    second = np.array([True, True, True, True, True, False, True])
    cert = certify(P, f, m, kkt_tol=1e-10, claimed=claimed, residual=residual, second_order=second)
    with np.errstate(all="ignore"):
        objective = P.objective(f, m)
    old = [
        _judge(P, f[i], m[i], residual[i], objective[i], 1e-10, True, claimed[i], second[i], i)
        for i in range(f.shape[0])
    ]
    assert list(cert.status) == old
    assert old[1] is Status.NUMERICAL_ERROR and old[2] is Status.NUMERICAL_ERROR and old[5] is Status.NONCONVEX


# --------------------------------------------------------------------------- dense direction
def test_dense_direction_cache_gives_the_uncached_bits():
    """The kept ``scale * E`` is that of the block and scale asked for (signed zero included)."""
    rng = np.random.default_rng(4)
    n1, b = 30, 5
    E = PowerKernel(1.5).energy_operator(Grid(np.linspace(-4, 4, n1 + 1))).flux_block()
    assert not E.flags.writeable
    diag = 10.0 ** rng.uniform(0, 3, (b, n1))
    off1 = 0.1 * rng.uniform(-1, 1, (b, n1 - 1))
    off2 = 0.05 * rng.uniform(-1, 1, (b, n1 - 2))
    rhs = rng.standard_normal((b, n1, 2))
    fresh = E.copy()  # writeable: never kept
    for scale in (0.3, 0.3, -0.2, 0.3, 0.0, -0.0, 0.0):
        x, pd = structured.dense_direction(E, scale, (diag, off1, off2), rhs, 1e-10)
        x0, pd0 = structured.dense_direction(fresh, scale, (diag, off1, off2), rhs, 1e-10)
        assert _same(x, x0) and np.array_equal(pd, pd0)
        SE, _ = structured._scaled_block(E, scale)
        assert _same(SE, scale * E)
