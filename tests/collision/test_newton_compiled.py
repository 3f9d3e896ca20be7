"""The compiled Newton iteration (``solve_newton(..., compiled=True)``) against the NumPy one, in one process.

Where the compiled attempt returns the point it must be the NumPy iteration's to rounding (same status,
f within 1e-12 of max f, a KKT residual within ``tol``); where it hands the step back the result must be
the NumPy iteration's bit for bit (the cascade runs from the start).  Kernels other than gamma = 1 and
batched problems never take it.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status
from jko_cvx.collision import newton as newton_module
from jko_cvx.collision import solve_collision, solve_newton
from jko_cvx.collision.newton import NewtonOptions
from jko_cvx.testing import random_problem

from .test_extremes import CASES

pytest.importorskip("numba")


def _bitwise(a, b) -> None:
    assert a.status == b.status and a.iterations == b.iterations
    assert np.array_equal(a.f, b.f) and np.array_equal(a.m, b.m)
    assert a.kkt_residual == b.kkt_residual or (np.isnan(a.kkt_residual) and np.isnan(b.kkt_residual))


def _agree(a, b) -> None:
    assert a.status == b.status
    assert np.abs(a.f - b.f).max() <= 1e-12 * np.abs(b.f).max()
    assert np.abs(a.m - b.m).max() <= 1e-10 * max(np.abs(b.m).max(), 1e-300) + 1e-15 * np.abs(b.f).max()
    assert abs(a.objective - b.objective) <= 1e-12 * abs(b.objective)
    assert a.kkt_residual <= 1e-10 and a.mass_error <= 1e-13


def _family(gamma: float = 1.0):
    """gamma = 1 (or 3) on uniform and non-uniform grids: every Fisher form, with and without the momentum
    constraint, weak to strong Fisher terms, small to large steps (the large ones need the NumPy devices)."""
    rng = np.random.default_rng(7)
    for fisher, conserve, beta, dt in itertools.product(
        (None, "perspective", "log"), (False, True), (1.0, 30.0, 1000.0), (1e-3, 0.03, 0.3, 3.0)
    ):
        n = int(rng.integers(31, 130))
        if rng.uniform() < 0.5:
            grid = Grid.uniform(-2.0, 2.0, n)
        else:
            grid = Grid(np.cumsum(np.r_[-2.0, rng.uniform(0.2, 2.0, n - 1) * 4 / n]))
        v = grid.points - grid.points.mean()
        f = np.exp(-4 * v**2) + 0.5 * np.exp(-8 * (v - 0.7) ** 2) + 1e-3
        yield CollisionProblem(grid, PowerKernel(gamma), f, dt, beta=beta, fisher=fisher, conserve_momentum=conserve)


@pytest.mark.parametrize("gamma", [1.0, 3.0])
def test_the_compiled_iteration_is_the_numpy_one_to_rounding_and_hands_back_what_it_does_not_finish(gamma):
    """gamma = 3: the structured solve (band LU of the interleaved core, Woodbury's capacitance) compiled."""
    handled = 0
    problems = list(_family(gamma))
    for P in problems:
        a, b = solve_newton(P, compiled=True), solve_newton(P)
        assert b.info["compiled"] is False
        if a.info["compiled"]:
            handled += 1
            _agree(a, b)
            assert a.info["warm_started"] is False and a.info["jammed"] is False
        else:
            _bitwise(a, b)
    # the test must exercise both branches: most steps are handled, the largest ones are handed back
    assert 0.4 * len(problems) <= handled < len(problems)


@pytest.mark.parametrize("seed", range(6))
def test_random_agreement_problems_take_the_compiled_path(seed):
    rng = np.random.default_rng(seed)
    P = random_problem(rng, 1.0, fisher=("perspective", "log", None)[seed % 3])
    a, b = solve_newton(P, compiled=True), solve_newton(P)
    assert a.info["compiled"]
    _agree(a, b)


@pytest.mark.parametrize("name", sorted(CASES))
def test_the_extremes_are_certified_or_flagged_as_by_the_numpy_iteration(name):
    grid, gamma, f, dt, beta = CASES[name]
    P = CollisionProblem(grid, PowerKernel(gamma), f, dt, beta=beta)
    a, b = solve_newton(P, compiled=True), solve_newton(P)
    if a.info["compiled"]:
        assert gamma in (1.0, 3.0)  # the kernels with a compiled direction
        _agree(a, b)
    else:
        _bitwise(a, b)


def test_a_warm_start_and_the_zero_start_are_those_of_the_numpy_iteration():
    grid = Grid.uniform(-2.0, 2.0, 81)
    P = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.02, beta=30.0, fisher="log")
    first = solve_newton(P)
    near = 0.9 * first.m  # a start near the solution, keeping f > 0
    for kwargs in ({"m0": near}, {"m0": 1e3 * np.ones(80)}, {"start": "zero"}):  # used, refused (f < 0), none
        a, b = solve_newton(P, compiled=True, **kwargs), solve_newton(P, **kwargs)
        assert a.info["compiled"] and a.info["warm_started"] == b.info["warm_started"]
        _agree(a, b)
    assert solve_newton(P, compiled=True, m0=near).info["warm_started"] is True


@pytest.mark.parametrize("gamma", [1.5, 2.0, 4.0])
def test_other_kernels_take_the_numpy_iteration(gamma):
    grid = Grid.uniform(-2.0, 2.0, 61)
    P = CollisionProblem(grid, PowerKernel(gamma), np.exp(-2 * grid.points**2), 0.01, beta=10.0)
    a, b = solve_newton(P, compiled=True), solve_newton(P)
    assert a.info["compiled"] is False
    _bitwise(a, b)


def _batches(gamma: float):
    """gamma = 1 (or 3) batches on one grid each: bumps moving across the grid, one row with an empty cell (never
    compiled), every Fisher form, with and without the momentum constraint, small to large steps."""
    rng = np.random.default_rng(3)
    for fisher, conserve, dt in itertools.product((None, "perspective", "log"), (False, True), (1e-3, 0.03, 0.3, 3.0)):
        n = int(rng.integers(31, 90))
        grid = Grid.uniform(-2.0, 2.0, n) if rng.uniform() < 0.5 else Grid(
            np.cumsum(np.r_[-2.0, rng.uniform(0.2, 2.0, n - 1) * 4 / n]))  # fmt: skip
        v = grid.points - grid.points.mean()
        rows = [np.exp(-4 * (v - c) ** 2) + 0.5 * np.exp(-8 * (v + c) ** 2) + 1e-3 for c in (-0.6, 0.0, 0.3, 0.9)]
        if fisher != "log":
            rows.append(rows[1].copy())
            rows[-1][n // 4] = 0.0
        yield CollisionProblem(grid, PowerKernel(gamma), np.stack(rows), dt, beta=30.0, fisher=fisher,
                               conserve_momentum=conserve)  # fmt: skip


@pytest.mark.parametrize("gamma", [1.0, 3.0])
def test_a_batch_is_its_slices_compiled_one_by_one_and_the_cascade_solves_the_rest(gamma):
    """Each slice the batch's compiled loop returns is the compiled single solve's bit for bit (and the NumPy
    iteration's to rounding); the others are the cascade's on the batch of those slices."""
    handled = handed_back = 0
    for P in _batches(gamma):
        a, numpy_batch = solve_newton(P, compiled=True), solve_newton(P)
        assert not numpy_batch.info["compiled"].any()
        mine = a.info["compiled"]
        for i in np.flatnonzero(mine):
            single = solve_newton(P.slice(int(i)), compiled=True)
            assert single.info["compiled"] is True
            assert np.array_equal(a.f[i], single.f) and np.array_equal(a.m[i], single.m)
            assert a.status[i] == single.status and a.iterations[i] == single.iterations
            assert a.kkt_residual[i] == single.kkt_residual and a.objective[i] == single.objective
            assert a.info["warm_started"][i] == single.info["warm_started"]
            assert abs(a.mass_error[i] - single.mass_error) <= 1e-15
            _agree(single, solve_newton(P.slice(int(i))))
        rest = ~mine
        if rest.any():
            cascade = solve_newton(P.rows(rest))
            for name in ("f", "m", "iterations", "kkt_residual", "objective"):
                assert np.array_equal(getattr(a, name)[rest], getattr(cascade, name), equal_nan=name != "iterations")
            assert list(a.status[rest]) == list(cascade.status)
            flags = ("warm_started", "jammed", "interior_damping", "barrier", "lower_minimum", "row_shift", "continued",
                     "filled_start")
            for name in flags:
                assert np.array_equal(a.info[name][rest], cascade.info[name])
        handled += int(mine.sum())
        handed_back += int(rest.sum())
        if P.fisher != "log":
            assert not mine[-1]  # the row with an empty cell
    assert handled >= 40 and handed_back >= 12  # both branches exercised


def test_a_warm_started_batch_takes_the_start_the_numpy_iteration_takes():
    grid = Grid.uniform(-2.0, 2.0, 61)
    F = np.stack([np.exp(-2 * grid.points**2), np.exp(-3 * (grid.points - 0.2) ** 2)])
    P = CollisionProblem(grid, PowerKernel(1.0), F, 0.01, beta=10.0)
    first = solve_newton(P)
    m0 = np.stack([0.9 * first.m[0], 1e3 * np.ones(60)])  # used, refused (f < 0)
    a, b = solve_newton(P, compiled=True, m0=m0), solve_newton(P, m0=m0)
    assert a.info["compiled"].all() and list(a.info["warm_started"]) == list(b.info["warm_started"]) == [True, False]
    for i in range(2):  # the refused start's explicit step is the batch's (NumPy, batched): to rounding
        b_i = solve_newton(P.slice(i), m0=m0[i])
        assert a.status[i] == b_i.status and np.abs(a.f[i] - b_i.f).max() <= 1e-12 * b_i.f.max()
        assert abs(a.objective[i] - b_i.objective) <= 1e-12 * abs(b_i.objective) and a.kkt_residual[i] <= 1e-10


def test_data_with_a_zero_is_refused_as_by_the_numpy_iteration():
    grid = Grid.uniform(-2.0, 2.0, 41)
    f = np.exp(-2 * grid.points**2)
    f[3] = 0.0
    P = CollisionProblem(grid, PowerKernel(1.0), f, 0.01, beta=10.0)
    a, b = solve_newton(P, compiled=True), solve_newton(P)
    assert a.status == b.status == Status.NUMERICAL_ERROR and a.info["compiled"] is False


def test_a_point_the_certificate_does_not_accept_goes_through_the_whole_cascade():
    """The cascade goes on from a first attempt that is not CONVERGED (damped, barrier attempts): so must the
    compiled path, by handing the step back."""
    grid = Grid.uniform(-2.0, 2.0, 21)
    P = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2) + 1e-3, 0.5, beta=10.0)
    a, b = solve_newton(P, compiled=True, tol=1e-2, kkt_tol=1e-12), solve_newton(P, tol=1e-2, kkt_tol=1e-12)
    assert b.status == Status.NOT_CERTIFIED and a.info["compiled"] is False
    _bitwise(a, b)
    assert a.info == {**b.info, "compiled": False}
    huge = Grid.uniform(-2.0, 2.0, 41)  # J overflows at the point: NUMERICAL_ERROR, then the damped attempt
    Q = CollisionProblem(huge, PowerKernel(1.0), 1e154 * np.exp(-(huge.points**2)), 1e-200, beta=30.0)
    a, b = solve_newton(Q, compiled=True), solve_newton(Q)
    assert a.info["compiled"] is False and a.info["interior_damping"] == b.info["interior_damping"]
    _bitwise(a, b)


def test_a_scene_asking_for_the_compiled_iteration_without_numba_is_refused_at_load(monkeypatch):
    from jko_cvx.scene import SceneError
    from jko_cvx.scene.model import default_scene, scene_from_dict, with_overrides

    real = newton_module.importlib.util.find_spec
    monkeypatch.setattr(
        newton_module.importlib.util, "find_spec", lambda name, *a: None if name == "numba" else real(name, *a)
    )
    with pytest.raises(SceneError, match=r"collision\.options\.compiled.*jko_cvx\[fast\]"):
        scene_from_dict(with_overrides(default_scene().to_dict(), {"collision.options.compiled": True}))


def test_the_option_is_checked_and_reaches_solve_collision():
    grid = Grid.uniform(-2.0, 2.0, 41)
    P = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.01, beta=10.0)
    with pytest.raises(TypeError, match="compiled"):
        solve_newton(P, compiled="yes")
    assert solve_collision(P, "newton", compiled=True).info["compiled"] is True


def test_without_numba_compiled_true_is_refused_before_any_work(monkeypatch):
    real = newton_module.importlib.util.find_spec
    monkeypatch.setattr(
        newton_module.importlib.util, "find_spec", lambda name, *a: None if name == "numba" else real(name, *a)
    )
    with pytest.raises(ImportError, match=r"jko_cvx\[fast\]"):
        NewtonOptions(compiled=True)
    NewtonOptions(compiled=False)  # the default needs nothing


def _compiled_kkt(P: CollisionProblem, f, m):
    from jko_cvx.collision._compiled import kkt_residual

    parts = P.gradient_parts(f, m)
    split = (parts.wasserstein[0], parts.fisher[0], parts.energy[0], parts.wasserstein[1])
    g = P.grid
    return kkt_residual(f, m, P.f_star, g.h, g.points, g.dv, split, P.conserve_momentum)


def test_the_compiled_kkt_residual_is_the_shared_one_to_rounding():
    """At the solver's points, near them and far from them, positive and with empty cells, every Fisher form."""
    rng = np.random.default_rng(11)
    compared = 0
    for P in _family():
        res = solve_newton(P)
        n = P.grid.n
        points = [(res.f, res.m)]
        for size in (1e-9, 1e-4, 1e-1):
            m = res.m + size * np.abs(res.m).max() * rng.standard_normal(n - 1)
            points.append((P.density_from_flux(m), m))
        if P.fisher is None:  # an emptied cell and a negative one: the weights w, omega vanish there
            f = res.f.copy()
            f[n // 3], f[n // 2] = 0.0, -1e-3 * f.max()
            points.append((f, P.flux_from_density(f)))
        for f, m in points:
            with np.errstate(all="ignore"):
                shared = P.kkt_residual(f, m)
            s, fe, po, phi = _compiled_kkt(P, f, m)
            for mine, theirs in ((s, shared.stationarity), (fe, shared.feasibility), (po, shared.positivity)):
                assert abs(mine - theirs) <= 1e-9 * abs(theirs) + 1e-15, (P.fisher, P.conserve_momentum, mine, theirs)
            theirs = shared.multiplier
            assert np.array_equal(np.isnan(phi), np.isnan(theirs))  # NaN where a flux meets an emptied cell
            ok = ~np.isnan(theirs)
            size = max(np.abs(theirs[ok]).max(initial=0), 1e-300)
            assert np.abs(phi[ok] - theirs[ok]).max(initial=0.0) <= 1e-8 * size
            compared += 1
    assert compared >= 24 * 4


def test_a_step_the_compiled_path_returns_reports_the_shared_residual_of_its_point():
    for P in _family():
        res = solve_newton(P, compiled=True)
        if res.info["compiled"]:
            # the residual at its rounding floor (~1e-16) is noise in either form: an absolute 1e-14 above that
            assert abs(res.kkt_residual - P.kkt_residual(res.f, res.m).total) <= 1e-9 * res.kkt_residual + 1e-14
            assert abs(res.objective - P.objective(res.f, res.m)) <= 1e-13 * abs(res.objective)


def test_the_compiled_products_with_the_abs_kernel_are_the_dense_ones_to_rounding():
    from jko_cvx.collision._compiled import _matvec

    rng = np.random.default_rng(5)
    for n in (3, 4, 41, 300):
        grid = Grid(np.sort(rng.uniform(-3, 2, n)) if n > 4 else np.linspace(-1.0, 1.5, n))
        P = CollisionProblem(grid, PowerKernel(1.0), rng.uniform(0, 1, n), 0.01)
        for f in (rng.uniform(0, 1, n), np.r_[np.zeros(n - 1), 1.0], rng.standard_normal(n)):
            out = np.empty(n)
            _matvec(grid.h[None, :], grid.points, f, out)
            dense = P.energy.dense() @ f
            scale = np.abs(grid.points).max() * (grid.h * np.abs(f)).sum() * grid.h
            assert np.all(np.abs(out - dense) <= 1e-13 * scale)


def test_the_compiled_band_lu_pivots_as_dense_elimination_does():
    """Gaussian elimination with partial pivoting in band storage, against the dense solve: matrices whose
    diagonal is small (every column pivots off it), indefinite ones, and a singular one refused."""
    from jko_cvx.collision._compiled import _band_lu_solve

    rng = np.random.default_rng(2)
    kl = 4
    for n, diag_size in ((9, 1.0), (40, 1e-8), (61, 0.0), (200, 3.0)):
        A = np.zeros((n, n))
        for d in range(-kl, kl + 1):
            A += np.diag(rng.standard_normal(n - abs(d)), d)
        A[np.arange(n), np.arange(n)] *= diag_size
        X = rng.standard_normal((n, 3))
        W = np.zeros((n, 3 * kl + 1))
        for i in range(n):
            for j in range(max(0, i - kl), min(n, i + kl + 1)):
                W[i, j - i + kl] = A[i, j]
        R = A @ X
        assert _band_lu_solve(W, kl, R)
        assert np.abs(R - X).max() <= 1e-8 * np.abs(X).max() * np.linalg.cond(A) ** 0.5
    W = np.zeros((5, 3 * kl + 1))
    W[:, kl] = [1.0, 2.0, 0.0, 1.0, 1.0]  # a zero column: no pivot
    assert not _band_lu_solve(W, kl, np.ones((5, 1)))


def test_a_compiled_batch_in_slice_threads_is_the_same_bit_for_bit(monkeypatch):
    from jko_cvx.threads import THREADS_ENV

    P = next(iter(_batches(3.0)))
    monkeypatch.setenv(THREADS_ENV, "1")
    one = solve_newton(P, compiled=True)
    monkeypatch.setenv(THREADS_ENV, "3")
    three = solve_newton(P, compiled=True)
    assert one.info["compiled"].any()
    for name in ("f", "m", "iterations", "kkt_residual", "objective"):
        assert np.array_equal(getattr(one, name), getattr(three, name))
    assert list(one.status) == list(three.status)


@pytest.mark.parametrize("gamma", [1.0, 3.0])
def test_the_constants_kept_with_the_energy_operator_are_those_of_each_step(gamma):
    """The compiled constants are kept per energy operator under the step's scalars: steps on one grid that
    differ in dt, strength, beta, the Fisher form or the momentum constraint, each solved after the others
    filled the store (and after it overflowed), are each the same bits as when solved from an empty store;
    a new Grid object with the same points shares the operator and the stored constants."""
    from jko_cvx.collision.newton import _CONSTANTS_PER_OPERATOR

    grid = Grid.uniform(-2.0, 2.0, 61)
    f = np.exp(-4 * grid.points**2) + 1e-3
    steps = [
        dict(dt=0.01, strength=1.0, beta=10.0, fisher="perspective", conserve_momentum=False),
        dict(dt=0.02, strength=1.0, beta=10.0, fisher="perspective", conserve_momentum=False),
        dict(dt=0.01, strength=2.0, beta=10.0, fisher="perspective", conserve_momentum=False),
        dict(dt=0.01, strength=1.0, beta=30.0, fisher="perspective", conserve_momentum=False),
        dict(dt=0.01, strength=1.0, beta=10.0, fisher="log", conserve_momentum=False),
        dict(dt=0.01, strength=1.0, beta=np.inf, fisher=None, conserve_momentum=False),
        dict(dt=0.01, strength=1.0, beta=10.0, fisher="perspective", conserve_momentum=True),
    ]
    steps += [dict(steps[0], dt=0.001 * (k + 1)) for k in range(_CONSTANTS_PER_OPERATOR)]  # overflow the store

    def problem(g, kw):
        return CollisionProblem(g, PowerKernel(gamma), f, **kw)

    def empty_store(p):
        p.energy.__dict__.pop("_compiled_constants", None)

    fresh = []
    for kw in steps:
        p = problem(grid, kw)
        empty_store(p)
        fresh.append(solve_newton(p, compiled=True))
    assert all(r.info["compiled"] for r in fresh)
    empty_store(problem(grid, steps[0]))
    for _ in range(2):  # in order, then in reverse, each time after every other step filled the store
        for kw, ref in zip(steps, fresh, strict=True):
            _bitwise(solve_newton(problem(Grid(grid.points.copy()), kw), compiled=True), ref)
        steps, fresh = steps[::-1], fresh[::-1]
    store = problem(grid, steps[0]).energy.__dict__["_compiled_constants"]
    assert 0 < len(store) <= _CONSTANTS_PER_OPERATOR
