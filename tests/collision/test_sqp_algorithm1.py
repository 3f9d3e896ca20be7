"""The SQP against Algorithm 1 (``alg:non_uni_JKO``) as written: its exit flag and its safeguard options.

Algorithm 1 runs ``while l < I_max: if zeta > eps: (QP, relax, zeta) else break; l = l + 1``
and sets ``e_f = 1 if l = I_max``.  The loop counter only reaches I_max when I_max
iterations ran, whatever the last zeta: a run whose zeta test passes on exactly the
I_max-th iteration still ends with ``e_f = 1`` (the test is never reached again).
"""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status, solve_collision
from jko_cvx.collision.terms import FISHER_TERMS

G = Grid.uniform(-2.0, 2.0, 61)
F_GAUSS = np.exp(-2 * G.points**2)
F_PEAK = np.exp(-(G.points**2) / (2 * 0.1**2)) + 1e-3


def _converged_run():
    prob = CollisionProblem(G, PowerKernel(1.0), F_GAUSS, 0.01, beta=10.0)
    free = solve_collision(prob, method="sqp")
    assert free.status is Status.CONVERGED and free.info["exit_flag"] == 0
    return prob, int(free.iterations)


def test_zeta_test_passing_on_the_last_allowed_iteration_is_the_papers_exit_flag():
    """Converging on iteration K: I_max = K gives l = I_max, so e_f = 1 (MAX_ITERATIONS), I_max = K + 1 not."""
    prob, k = _converged_run()
    at_limit = solve_collision(prob, method="sqp", max_iter=k)
    assert at_limit.iterations == k and at_limit.info["zeta"] <= 1e-10  # the zeta test passed ...
    assert at_limit.info["exit_flag"] == 1 and at_limit.status is Status.MAX_ITERATIONS  # ... at l = I_max
    assert not at_limit.success
    above = solve_collision(prob, method="sqp", max_iter=k + 1)
    assert above.iterations == k and above.info["exit_flag"] == 0 and above.status is Status.CONVERGED
    np.testing.assert_array_equal(above.f, solve_collision(prob, method="sqp").f)


def test_the_safeguard_variants_agree_bitwise_where_the_safeguard_is_idle():
    prob = CollisionProblem(G, PowerKernel(1.0), F_GAUSS, 0.01, beta=10.0)
    runs = {sg: solve_collision(prob, method="sqp", safeguard=sg) for sg in ("floor", "cut", "none")}
    assert all(r.info["safeguard_steps"] == 0 and r.status is Status.CONVERGED for r in runs.values())
    for r in runs.values():
        np.testing.assert_array_equal(r.f, runs["floor"].f)
        assert r.iterations == runs["floor"].iterations


def _peak():
    """The peaked datum at dt = 0.3 without Fisher term: non-convex, the relaxation steps get cut."""
    return CollisionProblem(G, PowerKernel(1.0), F_PEAK, 0.3)


def test_without_the_floor_a_cut_step_can_pass_the_zeta_test_and_the_certificate_catches_it():
    """safeguard="cut": zeta as Algorithm 1 computes it; a short cut step ends the loop before I_max,
    at a point that is not a certified minimiser (with "floor" the same run goes on to I_max)."""
    zetas = []
    res = solve_collision(
        _peak(), method="sqp", max_iter=300, safeguard="cut", callback=lambda i, f, m, z: zetas.append(z)
    )
    assert res.iterations < 300 and res.info["exit_flag"] == 0 and res.info["safeguard_steps"] >= 1
    assert zetas[-1] <= 1e-10  # the zeta test passed ...
    assert not res.success and res.status in (Status.NOT_CERTIFIED, Status.NONCONVEX)  # ... the KKT test did not
    floor = solve_collision(_peak(), method="sqp", max_iter=300, safeguard="floor")
    assert floor.iterations == 300 and floor.status is Status.MAX_ITERATIONS


def test_without_the_safeguard_the_literal_algorithm_leaves_the_domain():
    """safeguard="none": the first full relaxation step drives some f_j below 0 (seen in the callback,
    independently of the solver's report), and the solve says so: NUMERICAL_ERROR at that iteration."""
    seen = []
    res = solve_collision(
        _peak(), method="sqp", max_iter=300, safeguard="none", callback=lambda i, f, m, z: seen.append(float(f.min()))
    )
    first_negative = next(i for i, fmin in enumerate(seen, start=1) if fmin <= 0)
    assert res.status is Status.NUMERICAL_ERROR and not res.success
    assert res.info["left_domain"] == first_negative == res.iterations == len(seen)
    assert res.info["safeguard"] == "none" and res.info["safeguard_steps"] == 0


@pytest.mark.parametrize("bad", ["literal", "", None, 1])
def test_safeguard_must_be_one_of_the_variants(bad):
    prob = CollisionProblem(G, PowerKernel(1.0), F_GAUSS, 0.01, beta=10.0)
    with pytest.raises((ValueError, TypeError), match="safeguard"):
        solve_collision(prob, method="sqp", safeguard=bad)


@pytest.mark.parametrize("fisher", ["log", "perspective", None])
@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0])
def test_fused_gradient_and_step_are_bitwise_the_two_calls(fisher, gamma):
    """One SQP iteration's gradient and banded step, with the shared Wasserstein terms computed once,
    equal ``problem.gradient`` followed by ``sqp_step`` bit for bit; an empty edge takes the guarded path."""
    from jko_cvx.collision.sqp import gradient_and_sqp_step, sqp_step

    rng = np.random.default_rng(int(gamma * 10) + (fisher is None))
    grid = Grid(np.cumsum(rng.uniform(0.02, 0.2, 61)) - 3.0)
    f_star = np.exp(-2 * grid.points**2) + 1e-9
    beta = np.inf if fisher is None else 300.0
    prob = CollisionProblem(grid, PowerKernel(gamma), f_star, 0.01, 2.0, beta, fisher or "log")
    m = rng.normal(scale=1e-3, size=grid.n - 1) * f_star[1:]  # |m|/s ~ 1e-3: both Hessian parts count
    f = prob.density_from_flux(m)
    starts = [(f, m)]
    vac = f.copy()
    vac[10:12] = 0.0  # an empty edge
    starts.append((vac, m * (np.arange(m.size) != 10)))
    for fi, mi in starts:
        with np.errstate(all="ignore"):
            gf, gm = prob.gradient(fi, mi)
            want = (gf, gm, *sqp_step(prob, fi, mi, gf, gm))
            got = gradient_and_sqp_step(prob, fi, mi)
        for a, b in zip(got, want, strict=True):
            assert np.array_equal(a, b, equal_nan=True)
            fin = np.isfinite(b)
            assert np.array_equal(a[fin].view(np.int64), b[fin].view(np.int64))


def test_relaxation_step_is_bitwise_the_gathered_minimum():
    from jko_cvx.collision.sqp import _FRACTION_TO_BOUNDARY, _relaxation

    rng = np.random.default_rng(9)
    for _ in range(200):
        f = 10.0 ** rng.uniform(-12, 1, 50)
        pf = rng.standard_normal(50) * 10.0 ** rng.uniform(-14, 2, 50)
        pf[rng.uniform(size=50) < 0.3] = 0.0
        neg = pf < 0
        want = float(np.min(-f[neg] / pf[neg])) * _FRACTION_TO_BOUNDARY if neg.any() else None
        lam, cut = _relaxation(f, pf, 1.0)
        if want is not None and want < 1.0:
            assert cut and lam == want
        else:
            assert not cut and lam == 1.0


# ---------------------------------------------------------------- the fast SQP loop, bit for bit
# The loop (``sqp._iterate`` with ``sqp.sqp_stepper``) is written for few NumPy calls per
# iteration; these tests hold it to the formulas it replaced, kept here verbatim.


def _literal_relaxation(f, pf, step):
    """``sqp._relaxation`` before the fast loop, verbatim."""
    neg = pf < 0
    if neg.any():
        to_boundary = float(np.where(neg, -f / np.where(neg, pf, -1.0), np.inf).min())
        if to_boundary * 0.995 < step:
            return to_boundary * 0.995, True
    return step, False


def _literal_iterate(problem, qp_step, step, tol, max_iter, safeguard, callback):
    """``sqp._iterate`` before the fast loop, verbatim (the banded path through ``gradient_and_sqp_step``)."""
    from jko_cvx.collision.sqp import gradient_and_sqp_step, sqp_step

    f, m = problem.initial_point()
    zeta, it, safeguarded = 1.0, 0, 0
    with np.errstate(all="ignore"):
        while it < max_iter and zeta > tol:
            if qp_step is sqp_step:
                gf, gm, pf, pm = gradient_and_sqp_step(problem, f, m)
            else:
                gf, gm = problem.gradient(f, m)
                try:
                    pf, pm = qp_step(problem, f, m, gf, gm)
                except FloatingPointError:
                    return f, m, zeta, it, safeguarded, Status.NUMERICAL_ERROR
            if not (np.all(np.isfinite(pf)) and np.all(np.isfinite(pm))):
                return f, m, zeta, it, safeguarded, Status.NUMERICAL_ERROR
            lam, truncated = (step, False) if safeguard == "none" else _literal_relaxation(f, pf, step)
            safeguarded += truncated
            norm_u = np.sqrt(f @ f + m @ m)
            f = f + lam * pf
            m = m + lam * pm
            zeta = lam * np.sqrt(pf @ pf + pm @ pm) / norm_u
            if truncated and safeguard == "floor":
                zeta = max(zeta, 2 * tol)
            it += 1
            if callback is not None:
                callback(it, f, m, zeta)
            if safeguard == "none" and np.any(f <= 0):
                return f, m, zeta, it, safeguarded, Status.NUMERICAL_ERROR
    return f, m, zeta, it, safeguarded, None


def _same_bits(a, b):
    """Equal bit for bit: every finite entry (the sign of a zero included), NaN where NaN."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype
    assert np.array_equal(a, b, equal_nan=True)
    fin = np.isfinite(b)
    assert np.array_equal(a[fin].view(np.int64), b[fin].view(np.int64))


def _random_problem(rng, fisher, gamma, zeros=False):
    grid = Grid(np.cumsum(rng.uniform(0.02, 0.2, 41)) - 2.0)
    f_star = np.exp(-2 * grid.points**2) * rng.uniform(0.5, 1.5, grid.n) + (0.0 if zeros else 1e-9)
    if zeros:
        f_star[5:9] = 0.0  # three empty edges: the guarded general path
    beta = np.inf if fisher is None else 30.0
    return CollisionProblem(grid, PowerKernel(gamma), f_star, 0.01, 2.0, beta, fisher or "log")


_FORMS = [*FISHER_TERMS, None]


@pytest.mark.parametrize("fisher", _FORMS)
@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0])
def test_sqp_stepper_is_bitwise_the_fused_step(fisher, gamma):
    """``sqp_stepper(problem)(f, m)`` is ``gradient_and_sqp_step(problem, f, m)[2:]`` bit for bit, at
    interior points (m with exact zeros: signed zeros), at points with an empty edge and at
    points with a non-finite step; the same stepper, called in turn, carries nothing over."""
    from jko_cvx.collision.sqp import gradient_and_sqp_step, sqp_stepper

    rng = np.random.default_rng(int(gamma * 10) + 7 * _FORMS.index(fisher))
    prob = _random_problem(rng, fisher, gamma)
    stepper = sqp_stepper(prob)
    points = []
    for scale in (0.0, 1e-6, 1e-3, 1e-1):
        m = rng.normal(scale=scale, size=prob.n - 1) * prob.f_star[1:]
        m[rng.uniform(size=m.size) < 0.2] = 0.0
        f = prob.density_from_flux(m)
        points.append((f, m))
        vac = f.copy()
        vac[10:12] = 0.0  # an empty edge
        points.append((vac, m * (np.arange(m.size) != 10)))
        tiny = f.copy()
        tiny[20] = 1e-300  # steps that overflow (inf, NaN)
        points.append((tiny, m))
    for i in rng.permutation(len(points)).tolist() * 2:
        f, m = points[i]
        with np.errstate(all="ignore"):
            want = gradient_and_sqp_step(prob, f, m)[2:]
            got = stepper(f, m)
        for a, b in zip(got, want, strict=True):
            _same_bits(a, b)


@pytest.mark.parametrize("fisher", _FORMS)
@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0])
@pytest.mark.parametrize("safeguard", ["floor", "cut", "none"])
@pytest.mark.parametrize("datum", ["smooth", "peak", "zeros"])
def test_sqp_loop_is_bitwise_the_literal_loop(fisher, gamma, safeguard, datum):
    """Every iterate ``(f, m, zeta)`` of the SQP loop, and what it returns, is that of the loop it
    replaced bit for bit: interior iterates, cut steps (the peaked datum at a large dt), the
    empty edges of a datum with zeros (no log Fisher term there), iterates that leave the domain."""
    from jko_cvx.collision.sqp import _iterate, sqp_step

    if datum == "zeros" and fisher == "log":
        pytest.skip("the log Fisher term needs f_star > 0")
    rng = np.random.default_rng(int(gamma * 10) + 7 * _FORMS.index(fisher))
    if datum == "peak":
        f_star = np.exp(-(G.points**2) / (2 * 0.1**2)) + 1e-3
        prob = CollisionProblem(
            G, PowerKernel(gamma), f_star, 0.3, 1.0, np.inf if fisher is None else 30.0, fisher or "log"
        )
    else:
        prob = _random_problem(rng, fisher, gamma, zeros=datum == "zeros")
    runs = []
    for loop in (_iterate, _literal_iterate):
        seen: list = []
        record = seen.append
        out = loop(
            prob, sqp_step, 0.9, 1e-12, 150, safeguard, lambda i, f, m, z, rec=record: rec((i, f.copy(), m.copy(), z))
        )
        runs.append((out, seen))
    (got, got_seen), (want, want_seen) = runs
    assert len(got_seen) == len(want_seen) == got[3]
    for (i, f, m, z), (j, g, n, y) in zip(got_seen, want_seen, strict=True):
        assert i == j and type(z) is type(y)
        _same_bits(f, g)
        _same_bits(m, n)
        _same_bits(z, y)
    _same_bits(got[0], want[0])
    _same_bits(got[1], want[1])
    _same_bits(got[2], want[2])
    assert got[3:] == want[3:]


@pytest.mark.parametrize("kind", ["nan", "inf", "overflow", "finite"])
def test_sqp_loop_finiteness_test_is_the_literal_one(kind):
    """The loop tests the sum of squares of the step first: a step with an inf or NaN entry still
    ends the loop (NUMERICAL_ERROR) at the same iteration, a finite step whose squares overflow
    does not, as before."""
    from jko_cvx.collision.sqp import _iterate

    prob = CollisionProblem(G, PowerKernel(1.0), F_GAUSS, 0.01, beta=10.0)
    bad = {"nan": np.nan, "inf": np.inf, "overflow": 1e200, "finite": 1e-3}[kind]

    def qp_steps():
        """A QP step (the OSQP path's signature) whose every third step has ``bad`` in p_m[7]."""
        calls = []

        def qp_step(problem, f, m, gf, gm):
            calls.append(1)
            pm = 1e-3 * np.cos(np.arange(m.size)) * (f[:-1] + f[1:])
            if len(calls) % 3 == 0:
                pm[7] = bad
            return -np.diff(np.r_[0.0, pm, 0.0]) / problem.grid.h, pm

        return qp_step

    for sg in ("floor", "none"):
        want = _literal_iterate(prob, qp_steps(), 0.5, 1e-12, 10, sg, None)
        got = _iterate(prob, qp_steps(), 0.5, 1e-12, 10, sg, None)
        for a, b in zip(got[:3], want[:3], strict=True):
            _same_bits(a, b)
        assert got[3:] == want[3:]
        if sg == "floor" and kind in ("nan", "inf"):
            assert got[3] == 2 and got[5] is Status.NUMERICAL_ERROR
        elif sg == "floor":
            assert got[3] > 2
