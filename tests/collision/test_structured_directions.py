"""Structured Newton directions for dense kernels (jko_cvx.collision._structured) against dense linear algebra."""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status
from jko_cvx.collision import _structured as structured
from jko_cvx.collision._linalg import divergence
from jko_cvx.collision.newton import _PD_TOL, _fused, _newton_direction, solve_newton
from jko_cvx.collision.problem import add_pentadiagonal


def _exact_block_gamma3(grid: Grid) -> np.ndarray:
    """E_kl = -2 int_k int_l |s - t| over the cells [v_k, v_k+1] (independent of kernels.py)."""
    dv = grid.dv
    c = 0.5 * (grid.points[:-1] + grid.points[1:])
    A = np.outer(dv, dv) * np.abs(c[:, None] - c[None, :])
    A[np.diag_indices_from(A)] = dv**3 / 3
    return -2 * A


def _random_grid(rng, n: int) -> Grid:
    """A non-uniform grid: spacings spread over a decade and a half, like the refined ones."""
    return Grid(np.concatenate([[-4.0], -4.0 + np.cumsum(rng.uniform(0.03, 1.0, n - 1))]))


def _random_bands(rng, b: int, n1: int, scale: float = 1.0) -> tuple:
    """Positive definite pentadiagonal bands with diagonals spread over six decades."""
    diag = scale * 10.0 ** rng.uniform(0, 6, (b, n1))
    off1 = rng.uniform(-0.3, 0.3, (b, n1 - 1)) * np.sqrt(diag[:, :-1] * diag[:, 1:])
    off2 = rng.uniform(-0.1, 0.1, (b, n1 - 2)) * np.sqrt(diag[:, :-2] * diag[:, 2:])
    return diag, off1, off2


def _dense_shifted(E: np.ndarray, scale: float, bands: tuple, i: int) -> np.ndarray:
    H = add_pentadiagonal(scale * E, *(band[i] for band in bands))
    return H + _PD_TOL * np.diag(np.diag(H))


def test_block_formula_matches_flux_block():
    """The closed form of the gamma = 3 energy block used by the O(N) solver is kernels.py's block."""
    grid = _random_grid(np.random.default_rng(0), 60)
    E = PowerKernel(3.0).energy_operator(grid).flux_block()
    assert np.allclose(_exact_block_gamma3(grid), E, rtol=1e-10, atol=1e-12 * np.abs(E).max())


@pytest.mark.parametrize("seed", range(4))
def test_semiseparable_solve_matches_dense_solve(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(20, 90))
    grid = _random_grid(rng, n)
    scale = float(10.0 ** rng.uniform(-3, 1))
    b = 5
    bands = _random_bands(rng, b, n - 1)
    rhs = rng.standard_normal((b, n - 1, 2))
    x, pd, decided = np.zeros(rhs.shape), np.zeros(b, bool), np.zeros(b, bool)
    structured.Semiseparable3(grid).solve(scale, bands, rhs, _PD_TOL, (x, pd, decided), 0, b)
    E = _exact_block_gamma3(grid)
    for i in range(b):
        Hs = _dense_shifted(E, scale, bands, i)
        assert decided[i]
        assert pd[i] == (np.linalg.eigvalsh(Hs).min() > 0)
        if pd[i]:
            ref = np.linalg.solve(Hs, rhs[i])
            assert np.abs(x[i] - ref).max() <= 1e-10 * np.abs(ref).max()


def test_semiseparable_detects_indefinite_hessians():
    """Weak bands and a strong energy: H_s loses definiteness along the flux mean; the inertia test sees it."""
    rng = np.random.default_rng(7)
    grid = _random_grid(rng, 40)
    E = _exact_block_gamma3(grid)
    b = 12
    t = 10.0 ** np.linspace(-2, 4, b)[:, None]
    bands = (t * rng.uniform(1, 2, (b, 39)), 0.1 * t * rng.uniform(-1, 1, (b, 38)), np.zeros((b, 37)))
    x, pd, decided = np.zeros((b, 39, 1)), np.zeros(b, bool), np.zeros(b, bool)
    structured.Semiseparable3(grid).solve(1.0, bands, np.ones((b, 39, 1)), _PD_TOL, (x, pd, decided), 0, b)
    truth = np.array([np.linalg.eigvalsh(_dense_shifted(E, 1.0, bands, i)).min() > 0 for i in range(b)])
    assert decided.all()
    assert truth.any() and not truth.all()  # the family crosses the boundary
    assert np.array_equal(pd, truth)


def _inhom_batch(n: int, gamma: float, slices: int = 6) -> CollisionProblem:
    """Slices of the two-bump datum (vacuum tails down to 1e-80) at dt = 0.02, log Fisher beta = 1000."""
    v = np.linspace(-4, 4, n)
    x = np.linspace(-3, 3, slices)[:, None]
    f = np.exp(-6 * (v - 1.5) ** 2 - 6 * (x - 2) ** 2) + np.exp(-6 * (v + 1.5) ** 2 - 6 * (x + 2) ** 2)
    return CollisionProblem(
        Grid(v), PowerKernel(gamma), np.maximum(f, 1e-300), 0.02, 2.0, 1000.0, "log", conserve_momentum=True
    )


@pytest.mark.parametrize("gamma, n", [(3.0, 121), (1.5, 321)])
def test_directions_match_the_dense_cholesky(gamma, n):
    """Realistic bands (vacuum tails, condition numbers ~1e40): same pd, same direction to rounding."""
    P = _inhom_batch(n, gamma)
    B = P.f_star.shape[0]
    for m in (np.zeros((B, n - 1)), solve_newton(P, max_iter=2).m):  # the start and an iterate
        f = P.f_star - divergence(m) / P.grid.h
        g, bands, _ = _fused(P, f, m, False)
        rhs = np.stack([-g, np.broadcast_to(P.grid.dv, g.shape)], axis=-1)
        scale = 2 * P.energy_coef
        ref, pd_ref = _newton_direction(add_pentadiagonal(scale * P.energy.flux_block(), *bands), rhs)
        x, pd = structured.dense_kernel_direction(P.energy, scale, bands, rhs, _PD_TOL)
        assert np.array_equal(pd, pd_ref) and pd.all()
        assert np.abs(x - ref).max() <= 1e-10 * np.abs(ref).max()


def test_threaded_dense_path_is_bitwise_the_old_one():
    P = _inhom_batch(61, 1.5)
    m = np.zeros((P.f_star.shape[0], 60))
    g, bands, _ = _fused(P, P.f_star, m, False)
    rhs = -g[..., None]
    scale = 2 * P.energy_coef
    ref, pd_ref = _newton_direction(add_pentadiagonal(scale * P.energy.flux_block(), *bands), rhs)
    x, pd = structured.dense_direction(P.energy.flux_block(), scale, bands, rhs, _PD_TOL)
    assert np.array_equal(x, ref) and np.array_equal(pd, pd_ref)


def test_dense_path_is_bitwise_the_old_one_on_hard_rows():
    """Two right-hand sides, a row subset, rows that fail (negative diagonal, NaN, indefinite), and an
    energy block that is not bitwise symmetric: the per-slice path reads the lower triangle as
    ``_newton_direction`` does, and gives the same bits and verdicts."""
    rng = np.random.default_rng(7)
    n1, b = 40, 9
    E = PowerKernel(1.5).energy_operator(_random_grid(rng, n1 + 1)).flux_block()
    E = E + np.tril(rng.standard_normal(E.shape)) * 1e-13 * np.abs(E).max()  # lower != upper
    diag, off1, off2 = _random_bands(rng, b, n1, scale=1.0)
    diag[2, 5] = -1.0  # a non-positive diagonal: skipped before any factorisation
    diag[3, 0] = np.nan
    diag[4] *= 1e-9  # weak bands: the energy block makes it indefinite
    bands = (diag, off1, off2)
    rhs = rng.standard_normal((b, n1, 2))
    rows = np.ones(b, dtype=bool)
    rows[[1, 6]] = False
    for scale in (0.5, 3.0):
        H = add_pentadiagonal(scale * E, *bands)
        ref, pd_ref = _newton_direction(H, rhs)
        x, pd = structured.dense_direction(E, scale, bands, rhs, _PD_TOL)
        assert np.array_equal(x, ref) and np.array_equal(pd, pd_ref)
        assert pd_ref.any() and not pd_ref.all()
        xr, pdr = structured.dense_direction(E, scale, bands, rhs, _PD_TOL, rows=rows)
        assert np.array_equal(pdr, pd_ref & rows)
        assert np.array_equal(xr[rows], ref[rows]) and not xr[~rows].any()


def test_certificate_falls_back_to_the_dense_verdict():
    """gamma = 3/2 with weak bands: uncertified slices get the dense Cholesky's verdict, certified ones CG."""
    rng = np.random.default_rng(3)
    grid = _random_grid(rng, 330)
    energy = PowerKernel(1.5).energy_operator(grid)
    E = energy.flux_block()
    b = 6
    bands = _random_bands(rng, b, 329, scale=1e-4)
    bands = (bands[0] * 10.0 ** np.linspace(0, 5, b)[:, None], *bands[1:])
    rhs = rng.standard_normal((b, 329, 1))
    x, pd = structured.dense_kernel_direction(energy, 1.0, bands, rhs, _PD_TOL)
    truth = np.array([np.linalg.eigvalsh(_dense_shifted(E, 1.0, bands, i)).min() > 0 for i in range(b)])
    assert truth.any() and not truth.all()
    assert np.array_equal(pd, truth)
    for i in np.flatnonzero(pd):
        ref = np.linalg.solve(_dense_shifted(E, 1.0, bands, i), rhs[i])
        assert np.abs(x[i] - ref).max() <= 1e-10 * np.abs(ref).max()


def _auto_matches_dense(P: CollisionProblem, tol: float, monkeypatch):
    """Newton with the default (structured) directions against the dense Cholesky: statuses and f."""
    monkeypatch.setenv(structured.LINALG_ENV, "dense")
    ref = solve_newton(P, tol=tol)
    monkeypatch.setenv(structured.LINALG_ENV, "auto")
    res = solve_newton(P, tol=tol)
    assert list(res.status) == list(ref.status) and all(s is Status.CONVERGED for s in res.status)
    assert np.abs(res.f - ref.f).max() <= 1e-9 * np.abs(ref.f).max()
    return res


@pytest.mark.parametrize("gamma, n", [(3.0, 121), (1.5, 321)])
def test_newton_gives_the_dense_paths_results(gamma, n, monkeypatch):
    _auto_matches_dense(_inhom_batch(n, gamma, slices=4), 1e-9, monkeypatch)


def test_nonconvex_steps_stay_nonconvex():
    """gamma = 3/2, N = 301 (the certified-CG path), concentrated data and a long step.

    The first slice has no minimiser the interior iteration reaches (IPOPT too stops at a stationary point that is
    not a minimiser): it must stay NONCONVEX.  The second slice's minimiser lies on the vacuum boundary (two empty
    cells; IPOPT certifies it): the barrier attempt certifies it, and the point is checked to be a local minimiser.
    """
    g = Grid.uniform(-3.0, 3.0, 301)
    F = np.stack([np.exp(-(g.points**2) / 0.18) + 1e-3, 0.2 * np.exp(-2 * g.points**2)])
    P = CollisionProblem(g, PowerKernel(1.5), F, 10.0)
    res = solve_newton(P)
    assert res.status[0] is Status.NONCONVEX
    assert res.status[1] is Status.CONVERGED and res.info["barrier"][1]
    second = P.rows(np.array([False, True]))
    assert second.is_local_minimiser(res.f[1], res.m[1])


def test_linalg_mode_setting_is_checked(monkeypatch):
    monkeypatch.setenv(structured.LINALG_ENV, "fast")
    with pytest.raises(ValueError, match="JKO_CVX_NEWTON_LINALG must be one of"):
        structured.linalg_mode()


def _exact_block_even(grid: Grid, gamma: int) -> np.ndarray:
    """E_kl = -int_k int_l W''(s - t) for W = v^gamma / gamma, by Gauss-Legendre (independent of kernels.py)."""
    x, w = np.polynomial.legendre.leggauss(gamma)  # exact for the degree gamma - 2 integrand
    lo, dv = grid.points[:-1], grid.dv
    s = lo[:, None] + 0.5 * dv[:, None] * (x + 1)  # (N-1, q) nodes per cell
    ws = 0.5 * dv[:, None] * w
    d = s[:, :, None, None] - s[None, None, :, :]
    return -np.einsum("kq,lr,kqlr->kl", ws, ws, (gamma - 1) * d ** (gamma - 2))


@pytest.mark.parametrize("gamma", [4, 6, 8])
def test_even_power_block_is_low_rank_and_exact(gamma):
    """Even integer gamma: the flux block is U C U' of rank gamma - 1, as its integral says."""
    grid = _random_grid(np.random.default_rng(gamma), 50)
    energy = PowerKernel(float(gamma)).energy_operator(grid)
    fb = energy.flux_structure()
    assert fb.kind == "lowrank" and fb.basis.shape == (49, gamma - 1)
    E = _exact_block_even(grid, gamma)
    scale = np.abs(E).max()
    assert np.abs(fb.basis @ fb.coef @ fb.basis.T - E).max() <= 1e-11 * scale
    assert np.abs(energy.flux_block() - E).max() <= 1e-9 * scale


@pytest.mark.parametrize("gamma", [1.5, 3.0, 5.0, 10.0])
def test_other_gammas_keep_their_block_forms(gamma):
    grid = _random_grid(np.random.default_rng(1), 30)
    assert PowerKernel(gamma).energy_operator(grid).flux_structure().kind == "dense"


@pytest.mark.parametrize("seed", range(4))
def test_low_rank_solve_matches_dense_solve_and_inertia(seed):
    """Random bands, weak to strong energy: same positive-definiteness verdict and solution as dense."""
    rng = np.random.default_rng(10 + seed)
    gamma = int(rng.choice([4, 6]))
    n = int(rng.integers(20, 90))
    grid = _random_grid(rng, n)
    energy = PowerKernel(float(gamma)).energy_operator(grid)
    fb = energy.flux_structure()
    b = 8
    bands = _random_bands(rng, b, n - 1)
    E = energy.flux_block()
    # from a weak energy (definite) to a strong one (indefinite: C has negative eigenvalues)
    scales = bands[0].min() / np.abs(E).max() * 10.0 ** np.linspace(-3, 5, b)
    solver = structured.LowRankFlux(fb.basis, fb.coef)
    truth, got = [], []
    for i in range(b):
        rhs = rng.standard_normal((1, n - 1, 2))
        x, pd, decided = np.zeros(rhs.shape), np.zeros(1, bool), np.zeros(1, bool)
        one = tuple(band[i : i + 1] for band in bands)
        solver.solve(scales[i], one, rhs, _PD_TOL, (x, pd, decided), 0, 1)
        Hs = _dense_shifted(E, scales[i], bands, i)
        truth.append(np.linalg.eigvalsh(Hs).min() > 0)
        got.append(bool(pd[0]))
        assert decided[0]
        if pd[0]:
            ref = np.linalg.solve(Hs, rhs[0])
            assert np.abs(x[0] - ref).max() <= 1e-8 * np.abs(ref).max()
    assert got == truth and any(truth) and not all(truth)


@pytest.mark.parametrize("conserve_momentum", [False, True])
def test_newton_gives_the_dense_paths_results_for_gamma_4(conserve_momentum, monkeypatch):
    """Whole solves, log Fisher: the low-rank path (with the momentum-plane reduction where the
    momentum is conserved) reaches the dense path's points and statuses."""
    n = 121
    v = np.linspace(-4, 4, n)
    f = np.stack([np.exp(-4 * (v - c) ** 2) + 1e-8 for c in (-1.0, 0.0, 1.5)])
    P = CollisionProblem(Grid(v), PowerKernel(4.0), f, 0.01, 1.0, 1000.0, "log", conserve_momentum)
    res = _auto_matches_dense(P, 1e-10, monkeypatch)
    if conserve_momentum:
        assert np.abs(P.momentum_change(res.f)).max() <= 1e-12


def test_momentum_plane_reduction_keeps_the_constrained_step():
    """gamma = 4 with momentum conservation: Newton's direction (on the reduced block) is the
    step of the KKT system [[H, a], [a', 0]] with the full block, solved densely."""
    from jko_cvx.collision.newton import _direction

    n = 81
    v = np.linspace(-3, 3, n)
    f = np.stack([np.exp(-3 * (v - c) ** 2) + 1e-6 for c in (-0.5, 0.8)])
    P = CollisionProblem(Grid(v), PowerKernel(4.0), f, 0.01, 1.0, 1000.0, "log", conserve_momentum=True)
    m = np.zeros((2, n - 1))
    g, bands, _ = _fused(P, P.f_star, m, False)
    p, pd, valid = _direction(P, bands, g)
    assert valid.all() and pd.all()
    a = P.grid.dv
    for i in range(2):
        H = add_pentadiagonal(2 * P.energy_coef * P.energy.flux_block(), *(band[i] for band in bands))
        H = H + _PD_TOL * np.diag(np.diag(H))
        K = np.block([[H, a[:, None]], [a[None, :], np.zeros((1, 1))]])
        ref = np.linalg.solve(K, np.concatenate([-g[i], [0.0]]))[:-1]
        assert np.abs(p[i] - ref).max() <= 1e-8 * np.abs(ref).max()
        assert abs(p[i] @ a) <= 1e-12 * np.abs(p[i]).max() * np.abs(a).sum()
