"""A batched tridiagonal solve gives each row the solution it has alone (``linalg.solve_sym_tridiagonal``).

The batch goes to LAPACK as one chained system; before, one row with a non-finite entry
turned every row of the batch into NaN (0 * inf across the zero links, both ways), and one
indefinite row sent the whole batch to the elimination loop.  The KKT residual and the
explicit step solve their batches this way, so one slice's residual depended on the others.
"""

from __future__ import annotations

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel
from jko_cvx.collision._linalg import solve_sym_tridiagonal
from jko_cvx.collision.problem import TermParts


def _batch(rng, rows, n):
    off = -rng.uniform(0.1, 1.0, (rows, n - 1))
    diag = rng.uniform(0.1, 1.0, (rows, n))
    diag[:, :-1] -= off
    diag[:, 1:] -= off
    return diag, off, rng.normal(size=(rows, n))


def _spoil(diag, off, rhs, how, row):
    d, o, r = diag.copy(), off.copy(), rhs.copy()
    if how == "inf rhs":
        r[row, 3] = np.inf
    elif how == "nan rhs at the end":
        r[row, -1] = np.nan
    elif how == "nan diagonal":
        d[row, 2] = np.nan
    elif how == "inf off-diagonal":
        o[row, 0] = -np.inf
    elif how == "indefinite":
        d[row] *= -1.0
    elif how == "overflowing solution":  # finite data, a solution beyond float range
        d[row, 0], r[row, 0] = 1e-300, 1e300
        o[row, 0] = 0.0
    return d, o, r


@pytest.mark.parametrize(
    "how", ["inf rhs", "nan rhs at the end", "nan diagonal", "inf off-diagonal", "indefinite", "overflowing solution"]
)
@pytest.mark.parametrize("row", [0, 3, 6])
def test_each_row_is_solved_as_alone_whatever_the_others(how, row):
    rng = np.random.default_rng(11)
    d, o, r = _spoil(*_batch(rng, 7, 12), how, row)
    with np.errstate(all="ignore"):  # the spoilt row's own solution is not finite
        x = solve_sym_tridiagonal(d, o, r)
        for i in range(7):
            np.testing.assert_array_equal(x[i], solve_sym_tridiagonal(d[i], o[i], r[i]), err_msg=f"row {i}")
    healthy = np.arange(7) != row
    assert np.isfinite(x[healthy]).all()


def test_a_healthy_batch_is_one_chained_call_with_the_rows_own_bits():
    rng = np.random.default_rng(5)
    d, o, r = _batch(rng, 9, 30)
    x = solve_sym_tridiagonal(d, o, r)
    for i in range(9):
        np.testing.assert_array_equal(x[i], solve_sym_tridiagonal(d[i], o[i], r[i]))
    # a shared matrix broadcasts over right-hand sides
    shared = solve_sym_tridiagonal(d[0], o[0], r)
    for i in range(9):
        np.testing.assert_array_equal(shared[i], solve_sym_tridiagonal(d[0], o[0], r[i]))


def test_one_slices_residual_does_not_depend_on_the_other_slices():
    """An exact zero in one slice (log Fisher: an infinite gradient there) left every other
    slice of the batch with an infinite KKT residual."""
    grid = Grid.uniform(-3.0, 3.0, 41)
    rng = np.random.default_rng(2)
    f_star = np.exp(-(grid.points[None, :] - rng.uniform(-0.5, 0.5, (4, 1))) ** 2) + 1e-3
    P = CollisionProblem(grid, PowerKernel(1.5), f_star, 0.01, strength=2.0, beta=100.0, fisher="log")
    f = f_star * (1 + 0.01 * rng.normal(size=f_star.shape))
    f *= (f_star @ grid.h / (f @ grid.h))[:, None]
    m = 1e-3 * rng.normal(size=(4, grid.n - 1))
    f[2, 5] = 0.0
    with np.errstate(all="ignore"):
        parts = P.gradient_parts(f, m)
        batch = P.kkt_residual(f, m, parts).total
        assert not np.isfinite(batch[2])
        others = np.arange(4) != 2
        sub = TermParts(*((g[others], h[others]) for g, h in (parts.wasserstein, parts.fisher, parts.energy)))
        alone = P.rows(others).kkt_residual(f[others], m[others], sub).total
    np.testing.assert_array_equal(batch[others], alone)
    assert np.isfinite(alone).all()


@pytest.mark.parametrize("fisher", ["log", "perspective", None])
@pytest.mark.parametrize("conserve_momentum", [False, True])
def test_newtons_residual_test_on_the_checked_slices_is_the_whole_batchs(fisher, conserve_momentum):
    """Newton computes the residual (and the gradient split it needs) on the checked slices only:
    the same numbers as those slices of the whole batch's residual, bit for bit."""
    from jko_cvx.collision.newton import _fused

    grid = Grid.uniform(-3.0, 3.0, 33)
    rng = np.random.default_rng(7)
    B = 6
    f_star = np.exp(-2 * (grid.points[None, :] - rng.uniform(-0.5, 0.5, (B, 1))) ** 2) + 1e-4
    P = CollisionProblem(grid, PowerKernel(1.5), f_star, 0.02, 3.0, 50.0, fisher, conserve_momentum)
    m = 1e-7 * rng.normal(size=(B, grid.n - 1))
    f = P.f_star - np.diff(np.pad(m, ((0, 0), (1, 1))), axis=-1) / grid.h
    assert (f > 0).all()
    f[4, 7] = 0.0  # a slice at the vacuum boundary (non-finite log-Fisher terms) in the batch
    check = np.array([True, False, True, True, False, True])
    with np.errstate(all="ignore"):
        _, _, whole = _fused(P, f, m, want_parts=True)
        _, _, some = _fused(P, f, m, want_parts=check)
        for mine, theirs in zip(
            (some.wasserstein, some.fisher, some.energy), (whole.wasserstein, whole.fisher, whole.energy), strict=True
        ):
            for a, b in zip(mine, theirs, strict=True):
                np.testing.assert_array_equal(a, b[check])
        full = P.kkt_residual(f, m, whole).total
        part = P.rows(check).kkt_residual(f[check], m[check], some).total
    np.testing.assert_array_equal(part, full[check])
    assert np.isfinite(part).all()
