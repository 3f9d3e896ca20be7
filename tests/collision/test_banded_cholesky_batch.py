"""The chained banded Cholesky of the gamma = 1, 2 Newton directions is bitwise the per-slice one.

``newton._structured_direction`` factorises and solves a batch of pentadiagonal systems as one
block-diagonal LAPACK call (``linalg.pentadiagonal_cholesky_batch``/``_solve_batch``).  The
reference is the per-slice code it replaced (one ``dpbtrf``/``dpbtrs`` per slice), which it
still runs below ``_CHAIN_MIN`` slices, applied slice by slice (and the single LAPACK calls
themselves for the batch helpers): directions and positive-definiteness verdicts must agree bit for bit,
including on slices that fail (a non-positive pivot mid-batch, NaN, overflow, a denormal
pivot whose reciprocal is inf) and on their neighbours, which a chained call could touch.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import lapack

from jko_cvx.collision._linalg import pentadiagonal_cholesky_batch, pentadiagonal_solve_batch
from jko_cvx.collision.newton import _CHAIN_MIN, _structured_direction
from jko_cvx.kernels import FluxBlock


def _structured_direction_reference(fb, scale, bands, rhs):
    """One slice at a time: below ``_CHAIN_MIN`` slices ``_structured_direction`` makes one LAPACK call per
    slice (the code the chained path replaced, unchanged), so each row on its own is the reference."""
    assert _CHAIN_MIN > 1
    x = np.zeros_like(rhs)
    pd = np.zeros(rhs.shape[0], dtype=bool)
    for i in range(rhs.shape[0]):
        one = tuple(band[i : i + 1] for band in bands)
        x[i : i + 1], pd[i : i + 1] = _structured_direction(fb, scale, one, rhs[i : i + 1])
    return x, pd


def _bands(rng, b: int, n1: int, spread: float = 6.0) -> tuple:
    diag = 10.0 ** rng.uniform(0, spread, (b, n1))
    off1 = rng.uniform(-0.45, 0.45, (b, n1 - 1)) * np.sqrt(diag[:, :-1] * diag[:, 1:])
    off2 = rng.uniform(-0.2, 0.2, (b, n1 - 2)) * np.sqrt(diag[:, :-2] * diag[:, 2:])
    return diag, off1, off2


def _hard_rows(rng, bands, rhs):
    """Slices that fail or misbehave in every way a chain could carry over to a neighbour."""
    diag, off1, off2 = (band.copy() for band in bands)
    rhs = rhs.copy()
    n1 = diag.shape[1]
    diag[1, -1] = 1e-3 * abs(off1[1, -1]) ** 2  # indefinite at the very last pivot
    diag[3, n1 // 2] = -2.0  # non-positive diagonal: never factorised
    off1[5, 2] = 50 * np.sqrt(diag[5, 2] * diag[5, 3])  # indefinite mid-slice: LAPACK stops there
    off1[7, 0] = np.nan  # NaN inside the factor
    off2[9, -1] = np.inf  # inf at the slice's end, next to the following slice
    diag[11, -2:] = 1e-310  # denormal pivots at the end: 1/pivot overflows
    off1[11, -1] = 0.0
    off2[11, -1] = 0.0
    diag[13] *= 1e300  # overflow of the squares in the solve
    rhs[13] *= 1e300
    rhs[15, 3] = np.inf  # a non-finite right-hand side
    return (diag, off1, off2), rhs


def _assert_same_bits(x, ref):
    """Equal bit for bit where finite (the sign of a zero included), non-finite at the same entries."""
    fin = np.isfinite(ref)
    assert np.array_equal(np.isfinite(x), fin)
    assert np.array_equal(x[fin].view(np.int64), ref[fin].view(np.int64))


@pytest.mark.parametrize("kind", ["diagonal", "rank1"])
@pytest.mark.parametrize("n1, k, b", [(2, 1, 18), (3, 2, 18), (40, 1, 18), (120, 2, 18), (40, 2, 3), (6, 1, 1)])
def test_chained_direction_is_bitwise_the_per_slice_one(kind, n1, k, b):
    """Batches below _CHAIN_MIN take the per-slice path, larger ones the chained one: the same bits."""
    rng = np.random.default_rng(n1 * 10 + k + b)
    bands = _bands(rng, b, n1)
    rhs = rng.standard_normal((b, n1, k))
    if n1 >= 20 and b >= 16:
        bands, rhs = _hard_rows(rng, bands, rhs)
    if kind == "diagonal":
        fb = FluxBlock("diagonal", diag=rng.uniform(-0.5, 2.0, n1))
    else:
        u = rng.standard_normal(n1)
        fb = FluxBlock("rank1", u=u)
    for scale in (0.0, 0.3, 30.0):
        with np.errstate(all="ignore"):
            ref, pd_ref = _structured_direction_reference(fb, scale, bands, rhs)
            x, pd = _structured_direction(fb, scale, bands, rhs)
        assert np.array_equal(pd, pd_ref)
        _assert_same_bits(x, ref)
        if n1 >= 20 and b >= 16 and scale == 0.3:
            assert pd_ref.any() and not pd_ref.all()


def test_batch_factors_and_solves_equal_single_calls_bit_for_bit():
    """Realistic conditioning (diagonals over twelve decades), every slice checked on its own."""
    rng = np.random.default_rng(5)
    b, n1 = 25, 201
    diag, off1, off2 = _bands(rng, b, n1, spread=12.0)
    factors, ok = pentadiagonal_cholesky_batch(diag, off1, off2)
    assert ok.all()
    rhs = rng.standard_normal((b, n1, 3))
    sols = pentadiagonal_solve_batch(factors, rhs)
    assert sols.shape == rhs.shape
    for i in range(b):
        ab = np.zeros((3, n1))
        ab[0], ab[1, :-1], ab[2, :-2] = diag[i], off1[i], off2[i]
        c, info = lapack.dpbtrf(ab, lower=1)
        assert info == 0
        mask = np.ones((3, n1), dtype=bool)
        mask[1, -1] = mask[2, -2:] = False  # storage LAPACK never reads
        _assert_same_bits(factors[i].T[mask], c[mask])
        y, _ = lapack.dpbtrs(c, rhs[i], lower=1)
        _assert_same_bits(sols[i], y)


def test_empty_and_all_failing_batches():
    rng = np.random.default_rng(2)
    diag, off1, off2 = _bands(rng, 4, 10)
    factors, ok = pentadiagonal_cholesky_batch(diag[:0], off1[:0], off2[:0])
    assert factors.shape == (0, 10, 3) and ok.size == 0
    assert pentadiagonal_solve_batch(factors, np.zeros((0, 10, 1))).shape == (0, 10, 1)
    _, ok = pentadiagonal_cholesky_batch(-diag, off1, off2)
    assert not ok.any()
