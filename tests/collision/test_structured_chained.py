"""The chained structured solves of the dense-kernel Newton directions are bitwise the per-slice ones.

``jko_cvx.collision._structured`` solves a chunk of at least ``_CHAIN_MIN`` slices with one chained
LAPACK call per phase (``banded_lu_solve_batch`` for the gamma = 3 interleaved system,
``pentadiagonal_cholesky_batch`` / ``pentadiagonal_solve_batch`` for the low-rank and certified
paths), and a smaller chunk slice by slice (the code the chain replaced).  Solving each slice of a
batch on its own is therefore the reference: solutions, positive-definiteness verdicts and the
``decided`` flags must agree bit for bit, also on slices that fail (indefinite, NaN, inf, overflow)
and on their neighbours, which a chained call could touch.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import lapack

from jko_cvx import Grid, PowerKernel
from jko_cvx.collision import _structured as structured
from jko_cvx.collision._linalg import banded_lu_solve_batch
from jko_cvx.collision.newton import _PD_TOL

from .test_banded_cholesky_batch import _assert_same_bits


def _grid(rng, n: int) -> Grid:
    return Grid(np.concatenate([[-4.0], -4.0 + np.cumsum(rng.uniform(0.03, 1.0, n - 1))]))


def _bands(rng, b: int, n1: int) -> tuple:
    diag = 10.0 ** rng.uniform(0, 6, (b, n1))
    off1 = rng.uniform(-0.45, 0.45, (b, n1 - 1)) * np.sqrt(diag[:, :-1] * diag[:, 1:])
    off2 = rng.uniform(-0.2, 0.2, (b, n1 - 2)) * np.sqrt(diag[:, :-2] * diag[:, 2:])
    return diag, off1, off2


def _spoil(bands, rhs):
    """Rows that fail or misbehave in every way a chain could carry over to a neighbour."""
    diag, off1, off2 = (band.copy() for band in bands)
    rhs = rhs.copy()
    diag[1, -1] = 1e-3 * abs(off1[1, -1]) ** 2  # G indefinite at its last pivot
    diag[3, diag.shape[1] // 2] = -2.0  # a non-positive diagonal
    off1[5, 2] = 50 * np.sqrt(diag[5, 2] * diag[5, 3])  # G indefinite mid-slice
    off1[7, 0] = np.nan
    off2[9, -1] = np.inf  # next to the following slice
    diag[11] *= 1e300  # overflow in the scaled system and the solve
    rhs[11] *= 1e300
    rhs[13, 3] = np.inf  # a non-finite right-hand side
    return (diag, off1, off2), rhs


def _solve(solver, scale, bands, rhs):
    b = rhs.shape[0]
    x, pd, decided = np.zeros(rhs.shape), np.zeros(b, dtype=bool), np.zeros(b, dtype=bool)
    solver.solve(scale, bands, rhs, _PD_TOL, (x, pd, decided), 0, b)
    return x, pd, decided


def _solvers(rng, n: int):
    grid = _grid(rng, n)
    fb = PowerKernel(4.0).energy_operator(grid).flux_structure()
    E = PowerKernel(2.5).energy_operator(grid).flux_block()
    return {
        "gamma3": structured.Semiseparable3(grid),
        "lowrank": structured.LowRankFlux(fb.basis, fb.coef),
        "certified": structured.Certified(E),
    }


@pytest.mark.parametrize("kind", ["gamma3", "lowrank", "certified"])
@pytest.mark.parametrize(
    "n, k, b, spoil", [(40, 1, 16, True), (90, 2, 16, True), (25, 2, 11, False), (60, 1, 32, False)]
)
def test_chained_chunks_are_bitwise_the_per_slice_solves(kind, n, k, b, spoil, monkeypatch):
    """The same chunks solved chained and, with the chain switched off, by one LAPACK call per slice."""
    assert b >= structured._CHAIN_MIN  # the whole batch goes through the chained path
    rng = np.random.default_rng(n + 7 * k + b)
    solver = _solvers(rng, n)[kind]
    bands = _bands(rng, b, n - 1)
    rhs = rng.standard_normal((b, n - 1, k))
    if spoil:
        bands, rhs = _spoil(bands, rhs)
    seen_pd = seen_not = False
    for scale in (1e-3, 0.3, 30.0):
        with np.errstate(all="ignore"):
            x, pd, decided = _solve(solver, scale, bands, rhs)
            with monkeypatch.context() as mp:
                mp.setattr(structured, "_CHAIN_MIN", 10**9)
                xr, pdr, decr = _solve(solver, scale, bands, rhs)
        assert np.array_equal(pd, pdr) and np.array_equal(decided, decr)
        _assert_same_bits(x[pd], xr[pdr])
        seen_pd |= bool(pd.any())
        seen_not |= bool((~pd).any())
    assert seen_pd and (seen_not or not spoil)  # the family has both outcomes where it is spoilt


def _band_matrix(rng, n: int, kl: int) -> tuple[np.ndarray, np.ndarray]:
    """A random non-symmetric band matrix in dgbsv storage (rows x cols transposed) and densely."""
    A = np.zeros((n, n))
    for d in range(-kl, kl + 1):
        idx = np.arange(max(0, -d), min(n, n - d))
        A[idx, idx + d] = rng.standard_normal(idx.size) * (10.0 if d == 0 and rng.random() < 0.5 else 1.0)
    ab = np.zeros((n, 3 * kl + 1))
    for j in range(n):
        for i in range(max(0, j - kl), min(n, j + kl + 1)):
            ab[j, 2 * kl + i - j] = A[i, j]
    return ab, A


@pytest.mark.parametrize("kl", [1, 4])
def test_banded_lu_batch_equals_one_dgbsv_call_per_matrix(kl):
    """Pivoting included (diagonals sometimes small), a singular block and a NaN block mid-batch."""
    rng = np.random.default_rng(kl)
    b, n, k = 12, 30, 3
    pairs = [_band_matrix(rng, n, kl) for _ in range(b)]
    ab = np.stack([p[0] for p in pairs])
    ab[4, :, 2 * kl] = 0.0  # a zero diagonal: pivoting still finds pivots below
    ab[6, 5, :] = 0.0  # column 5 of block 6 empty: singular, the chain meets a zero pivot
    ab[9, 3, 2 * kl] = np.nan
    rhs = rng.standard_normal((b, n, k))
    with np.errstate(all="ignore"):
        x, ok = banded_lu_solve_batch(ab.copy(), rhs, kl)
        for i in range(b):
            _, _, xi, info = lapack.dgbsv(kl, kl, ab[i].T.copy(order="F"), rhs[i])
            assert ok[i] == (info == 0)
            if ok[i]:
                _assert_same_bits(x[i], xi)
    assert not ok[6] and ok[4] and ok.sum() >= b - 2
    good = [i for i in range(b) if ok[i] and np.isfinite(x[i]).all()]
    for i in good:
        A = pairs[i][1].copy()
        if i == 4:
            np.fill_diagonal(A, 0.0)
        assert np.abs(A @ x[i] - rhs[i]).max() <= 1e-9 * np.abs(A).max() * np.abs(x[i]).max()
    # without a failing block the chain is one call: same bits
    clean = np.delete(np.arange(b), [6, 9])
    x2, ok2 = banded_lu_solve_batch(ab[clean].copy(), rhs[clean], kl)
    assert ok2.all()
    _assert_same_bits(x2, x[clean])
