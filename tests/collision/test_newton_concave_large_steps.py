"""Newton on steps whose energy is concave at a large CFL number (gamma < 2, the explicit step moving
mass many cells): certified where the nonlinear reference certifies.

Two failures of an independent review's held-out families (``studies/newton_certification.py``,
seeds ``review``): at the explicit start the reduced Hessian had diagonal entries <= 0, so no
modified-Newton shift was tried and the point was called NONCONVEX after no iteration (KKT 4e-2);
a step whose shifted iteration crawls, which the continuation in dt solves; a step whose shifts, floored
by an emptied cell's curvature, froze the iteration; a barrier attempt that stalled from one start;
and steps whose minimiser fills an emptied interval, which no start of the iterates at f* reaches.
"""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status, solve_collision
from jko_cvx.collision.certify import certify
from jko_cvx.collision.nlp import nlp_available

from ..studies.scripts import load_study_script


def _certified_minimiser(P: CollisionProblem, res) -> None:
    assert res.status is Status.CONVERGED, (res.status, res.message)
    assert certify(P, res.f, res.m, kkt_tol=1e-8).status is Status.CONVERGED  # the run's threshold, re-judged
    assert P.is_local_minimiser(res.f, res.m)


@pytest.mark.parametrize("fisher", ["perspective", "log"])
def test_a_start_without_a_positive_diagonal_is_shifted_not_called_nonconvex(fisher):
    grid = Grid.uniform(-2.0, 2.0, 81)
    P = CollisionProblem(grid, PowerKernel(0.8), 10 * np.exp(-2 * (grid.points - 0.5) ** 2), 0.3, beta=300.0,
                         fisher=fisher)  # fmt: skip
    H = P.reduced_hessian(*P.initial_point())
    assert (np.diag(H) <= 0).any()  # the case: no positive diagonal to shift by at the start
    res = solve_collision(P, method="newton")
    _certified_minimiser(P, res)
    if nlp_available():  # the independent reference reaches the same minimiser
        ref = solve_collision(P, method="nlp", kkt_tol=1e-8)
        assert ref.status is Status.CONVERGED
        assert abs(res.objective - ref.objective) <= 1e-9 * abs(ref.objective)
        assert np.abs(res.f - ref.f).max() <= 1e-5 * ref.f.max()


def test_a_step_the_shifted_iteration_cannot_finish_is_solved_by_continuation_in_dt():
    study = load_study_script("newton_certification.py")
    P, par = study.review_problem("extreme_dt", 85)  # gamma 0.89, N = 42, log form, CFL 31
    assert par["gamma"] < 1 and par["cfl"] > 20
    res = solve_collision(P, method="newton")
    _certified_minimiser(P, res)
    assert res.info["continued"]


def test_a_shift_floored_by_an_emptied_cell_does_not_freeze_the_step():
    """Two bumps concentrating apart empty the cell between them (edge sums 1e-31, curvatures 4 / s_k near
    1e40) while the energy is concave: shifts floored at 1e-8 of the largest diagonal entry (1e32 on every
    edge) left a step of 1e-27 and Newton stalled where it started (NOT_CERTIFIED, KKT 5.5e-2); shifts of
    each row's own size reach a certified local minimiser."""
    study = load_study_script("newton_certification.py")
    P, par = study.review_problem("vacuum", 4)  # gamma 1.23, N = 235, log form, CFL 512, tails 1e-26
    assert par["gamma"] < 2 and par["cfl"] > 100 and P.f_star.min() < 1e-20 * P.f_star.max()
    res = solve_collision(P, method="newton")
    _certified_minimiser(P, res)
    assert res.info["row_shift"]


def test_a_barrier_attempt_that_stalls_above_tol_starts_again_from_the_other_start():
    """A step at CFL 3000 (gamma 4.6, spacing ratio 27) whose minimiser empties cells: the barrier attempt from
    the explicit start stalled at KKT 4.3e-6; from the zero start it reaches the minimiser, certified at a
    run's threshold (Newton certifies at min(tol, 1e-8) in a run)."""
    study = load_study_script("newton_certification.py")
    P, par = study.review_problem("nonuniform", 89)
    assert par["cfl"] > 1000
    res = solve_collision(P, method="newton", tol=1e-8)
    _certified_minimiser(P, res)
    assert res.info["barrier"] and res.info["row_shift"]
    # warm-started at the explicit start's point: m0 is taken (warm_started), and the point returned comes from
    # the retry's cold zero start (row_shift, barrier)
    from jko_cvx.collision import newton

    m0 = newton._start(P.rows(slice(None)), None, newton.NewtonOptions())[0].m[0]
    warm = solve_collision(P, method="newton", tol=1e-8, m0=m0)
    _certified_minimiser(P, warm)
    assert warm.info["warm_started"] and warm.info["row_shift"] and warm.info["barrier"]


@pytest.mark.parametrize("index", [70, 95])
def test_a_step_that_must_fill_a_vacuum_is_solved_from_the_filled_start(index):
    """Gamma ~ 1 at CFL 142 and 469 with tails at 1e-22 of the maximum: the minimiser spreads mass over the
    whole interval (its tails at about 1e-10 of its maximum), but every attempt from the explicit or the zero
    start stalled where it began (f equal to f* to 3 digits, NOT_CERTIFIED at KKT 6e-2, J 3 to 6 times nlp's):
    a step into an emptied cell is bounded by the cell's own content.  The barrier attempt from f* with a floor
    of 1e-8 of the mass spread over the interval reaches a certified local minimiser."""
    study = load_study_script("newton_certification.py")
    P, par = study.review_problem("vacuum", index)
    assert par["gamma"] < 1.1 and par["cfl"] > 100 and P.f_star.min() < 1e-20 * P.f_star.max()
    res = solve_collision(P, method="newton")
    _certified_minimiser(P, res)
    assert res.info["filled_start"] and not res.info["warm_started"]
    if nlp_available():  # the independent reference: a certified point with J no lower than Newton's
        ref = solve_collision(P, method="nlp", kkt_tol=1e-8)
        assert ref.status is Status.CONVERGED
        assert res.objective <= ref.objective * (1 + 1e-9)


def test_a_step_the_filled_start_leaves_without_descent_is_solved_with_row_sized_shifts():
    """Gamma 1.4 at CFL 1970 with three bumps (a fresh draw of the review's offcentre family): every attempt before
    the last ends NONCONVEX at a point that is not stationary (KKT 8e-3 to 5e-2), and so does the barrier from the
    filled start with the global shifts (1.6e-2); with each row's own shifts it reaches a certified minimiser."""
    study = load_study_script("newton_certification.py")
    P, par = study.review_problem("offcentre", 35, study.REVIEW_SEED_SETS["review_b"])
    assert par["cfl"] > 1000 and par["gamma"] < 2
    res = solve_collision(P, method="newton")
    _certified_minimiser(P, res)
    assert res.info["filled_start"] and res.info["row_shift"] and res.info["barrier"]
    if nlp_available():
        ref = solve_collision(P, method="nlp", kkt_tol=1e-8)
        assert ref.status is Status.CONVERGED
        assert res.objective <= ref.objective * (1 + 1e-9)


def test_the_filled_start_touches_only_the_slices_it_serves_in_a_batch(monkeypatch):
    """In a batch, the filled start runs on the slice every earlier stage left stalled and certifies it; the
    other slice (certified by the first attempt) is the same, bit for bit, with the stage taken away."""
    from jko_cvx.collision import newton

    study = load_study_script("newton_certification.py")
    P1, _ = study.review_problem("vacuum", 70)
    easy = 10 * np.exp(-2 * (P1.grid.points - 0.3) ** 2) + 1e-2  # explicit CFL number 4.5
    P = P1.with_f_star(np.stack([easy, P1.f_star]))
    batch = solve_collision(P, method="newton")
    assert batch.info["filled_start"].tolist() == [False, True]
    assert list(batch.status) == [Status.CONVERGED, Status.CONVERGED]
    assert not batch.info["barrier"][0] and batch.iterations[0] < batch.iterations[1]
    alone = solve_collision(P1, method="newton")  # the same minimiser as the slice solved alone
    assert alone.info["filled_start"]
    assert abs(batch.objective[1] - alone.objective) <= 1e-12 * abs(alone.objective)
    # without the stage (its start replaced by NaN: _start then starts cold), and without the trust-region stage
    # after it (its start likewise), the stalled slice stays stalled
    monkeypatch.setattr(newton, "_filled_start", lambda Pr: np.full((Pr.batch_size, Pr.n - 1), np.nan))
    monkeypatch.setattr(newton, "_TrustRegionPhase", _WithoutTrustRegion)
    without = solve_collision(P, method="newton")
    assert without.status[0] is Status.CONVERGED and without.status[1] is not Status.CONVERGED
    assert np.array_equal(without.f[0], batch.f[0]) and np.array_equal(without.m[0], batch.m[0])


def test_a_slice_that_leaves_the_continuation_early_is_never_returned_as_a_solution_of_its_smaller_step(monkeypatch):
    """In a batch, a slice whose intermediate stage (a smaller dt) is not certified leaves the continuation; the
    result at dt holds only the slices that reached dt itself, each a solution of the step as posed."""
    import dataclasses

    from jko_cvx.collision import newton

    study = load_study_script("newton_certification.py")
    P1, _ = study.review_problem("extreme_dt", 85)
    P = P1.with_f_star(np.stack([P1.f_star, P1.f_star]))
    real = newton._cascade

    def second_slice_fails_below_dt(Pk, m0, opts, continuation=True):
        res = real(Pk, m0, opts, continuation=continuation)
        if Pk.dt < P.dt and Pk.batch_size == 2:  # the first stage: the second slice is not certified there
            status = res.status.copy()
            status[1] = Status.NOT_CERTIFIED
            res = dataclasses.replace(res, status=status)
        return res

    monkeypatch.setattr(newton, "_cascade", second_slice_fails_below_dt)
    opts = newton._check_newton_args(P, 1e-10, None, 100, None, "explicit", True, True, False)
    res, reached, iterations = newton._continuation(P, opts)
    assert reached.tolist() == [True, False] and (iterations > 0).all()
    assert res.f.shape == (1, P.n) and res.status[0] is Status.CONVERGED
    assert certify(P1, res.f[0], res.m[0], kkt_tol=1e-8).status is Status.CONVERGED  # a solution at dt itself
    monkeypatch.setattr(newton, "_cascade", real)
    whole = solve_collision(P, method="newton")  # the batch: every certified slice certified for the step as posed
    for i in range(2):
        assert certify(P1, whole.f[i], whole.m[i], kkt_tol=1e-8).status is whole.status[i] is Status.CONVERGED


# Steps of the review families (seed sets in the study's REVIEW_SEED_SETS) that every line-search attempt left
# without a solution where the nonlinear reference certifies: (seeds, family, index, gamma, CFL number).
TRUST_REGION_STEPS = [
    ("review", "offcentre", 30),  # gamma 0.82, CFL 109: the barrier needs 176 iterations, 146 of them non-convex
    ("review_c", "extreme_dt", 89),  # gamma 2.9, CFL 6.8e5: the barrier needs 108 iterations
    ("review_c", "special_gamma", 58),  # gamma 0.95, CFL 168: the damped attempt crawls linearly
    ("review_d", "offcentre", 89),  # gamma 0.65, CFL 522: no shifted direction descends
    ("review_d", "vacuum", 93),  # gamma 0.52, CFL 1165: stalled
    ("review_d", "special_gamma", 4),  # gamma 0.95, CFL 2881: no shifted direction descends
]


class _WithoutTrustRegion:
    """The trust-region phase taken away: its point is NaN, so the barrier attempt after it starts cold."""

    def __init__(self, P, opts):
        self.m, self.iterations, self.ended = np.full((1, P.n - 1), np.nan), 0, False

    def run(self, handover):
        self.ended = True


@pytest.mark.parametrize(("seeds", "family", "index"), TRUST_REGION_STEPS)
def test_the_trust_region_stage_certifies_steps_every_line_search_attempt_left_unsolved(
    seeds, family, index, monkeypatch
):
    """Concave steps at CFL numbers above 100: the modified-Newton directions of every line-search attempt crawl
    through the non-convex region or find no descent there (each attempt within the default max_iter = 100); the
    trust-region phase follows negative curvature to the barrier function's Newton region, and the barrier attempt
    from there certifies a local minimiser within the same budget."""
    from jko_cvx.collision import newton

    study = load_study_script("newton_certification.py")
    P, par = study.review_problem(family, index, study.REVIEW_SEED_SETS[seeds])
    assert par["cfl"] > 100
    res = solve_collision(P, method="newton")
    _certified_minimiser(P, res)
    assert res.info["trust_region"] and res.info["barrier"] and not res.info["filled_start"]
    monkeypatch.setattr(newton, "_TrustRegionPhase", _WithoutTrustRegion)
    without = solve_collision(P, method="newton")
    assert not without.success and certify(P, without.f, without.m, kkt_tol=1e-8).status is not Status.CONVERGED
    if nlp_available():  # the reference certifies these steps too (a local minimiser each, not always the same)
        assert solve_collision(P, method="nlp", kkt_tol=1e-8).status is Status.CONVERGED


def test_max_iter_bounds_the_trust_region_phase_like_every_attempt():
    """The phase and the barrier attempt after it each stop at max_iter: with a budget of 20 the step the stage
    certifies at the default budget is not certified, and the result says so."""
    study = load_study_script("newton_certification.py")
    P, _ = study.review_problem("offcentre", 30)
    short = solve_collision(P, method="newton", max_iter=20)
    assert not short.success and short.status is not Status.CONVERGED
    assert certify(P, short.f, short.m, kkt_tol=1e-8).status is not Status.CONVERGED


def test_the_trust_region_phase_keeps_the_momentum_constraint():
    """With ``conserve_momentum`` the phase steps on the plane sum_k m_k dv_k = 0 (a Householder basis of it in the
    scaled fluxes): review_c special_gamma #58 (gamma 0.95, CFL 168) is certified there by the stage, with f*'s
    momentum to rounding."""
    study = load_study_script("newton_certification.py")
    P0, _ = study.review_problem("special_gamma", 58, study.REVIEW_SEED_SETS["review_c"])
    P = CollisionProblem(P0.grid, P0.kernel, P0.f_star, P0.dt, P0.strength, P0.beta, P0.fisher, conserve_momentum=True)
    res = solve_collision(P, method="newton")
    _certified_minimiser(P, res)
    assert res.info["trust_region"]
    assert abs(P.momentum_change(res.f)) <= 1e-14 * P.grid.mass(np.abs(P.grid.points) * P.f_star)


def test_the_trust_region_stage_keeps_a_stationary_point_it_finds_where_nothing_was_stationary():
    """review bigcfl #14 (gamma 1.27, CFL 156, no Fisher term): no attempt finds a minimiser (nor does nlp, which
    stops at a stationary non-minimiser); the barrier attempt after the trust-region phase reaches a stationary
    point, NONCONVEX within tol, which replaces a point that is not stationary (KKT 2.4e-5) as the cascade's other
    stages do: the answer and its status then agree with nlp's."""
    study = load_study_script("newton_certification.py")
    P, _ = study.review_problem("bigcfl", 14)
    res = solve_collision(P, method="newton")
    assert res.status is Status.NONCONVEX and res.kkt_residual <= 1e-10 and not P.is_local_minimiser(res.f, res.m)
    assert res.info["trust_region"] and "hint" not in res.info  # the hint names points that are not stationary
    if nlp_available():
        ref = solve_collision(P, method="nlp", kkt_tol=1e-8)
        assert ref.status is Status.NONCONVEX
        assert abs(res.objective - ref.objective) <= 1e-9 * abs(ref.objective)
