"""method="nlp" (CVXPY nonlinear mode + IPOPT) against independent solvers: Newton (log form), conic (perspective)."""

from pathlib import Path

import numpy as np
import pytest

from jko_cvx import Grid, PowerKernel
from jko_cvx.collision import CollisionProblem, Status, solve_collision, solve_nlp
from jko_cvx.collision import nlp as nlp_module
from jko_cvx.engine.loop import simulate
from jko_cvx.scene.model import load_scene
from jko_cvx.testing import random_problem

pytest.importorskip("cyipopt")

SCENES = Path(__file__).parents[2] / "studies" / "scenes"


def _log_family(seed: int) -> CollisionProblem:
    """Random log-Fisher problem: gamma in [1, 3], non-uniform grid, beta in [30, 1e4]."""
    rng = np.random.default_rng(seed)
    gamma = float(rng.uniform(1.0, 3.0))
    beta = float(10 ** rng.uniform(np.log10(30), 4))
    return random_problem(rng, gamma, n=int(rng.integers(31, 121)), beta=beta, fisher="log")


def _check_against_newton(prob: CollisionProblem) -> None:
    ref = solve_collision(prob, "newton", tol=1e-12)
    assert ref.status is Status.CONVERGED
    res = solve_collision(prob, "nlp")
    assert res.status is Status.CONVERGED, res.info["ipopt_message"]
    assert np.abs(res.f - ref.f).max() <= 1e-6 * ref.f.max()
    assert abs(res.objective - ref.objective) <= 1e-8 * abs(ref.objective)
    assert res.kkt_residual <= 1e-6
    assert res.mass_error <= 1e-14


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_nlp_matches_newton_on_log_fisher_family(seed):
    _check_against_newton(_log_family(seed))


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3, 23))
def test_nlp_matches_newton_on_log_fisher_family_many(seed):
    _check_against_newton(_log_family(seed))


@pytest.mark.parametrize("seed, gamma", [(10, 1.0), (11, 3.0)])
def test_nlp_matches_conic_on_perspective_problems(seed, gamma):
    prob = random_problem(np.random.default_rng(seed), gamma, n=61, beta=30.0, fisher="perspective")
    ref = solve_collision(prob, "conic")
    assert ref.status is Status.CONVERGED
    res = solve_collision(prob, "nlp")
    assert res.status is Status.CONVERGED
    assert np.abs(res.f - ref.f).max() <= 1e-5 * ref.f.max()


def test_nlp_certifies_perspective_steps_at_vacuum_edges_like_conic():
    """Compact support: Newton and SQP cannot start (exact zeros); the interior-point methods can."""
    grid = Grid.uniform(-2.0, 2.0, 61)
    prob = CollisionProblem(grid, PowerKernel(2.0), np.maximum(1 - grid.points**2, 0.0), 0.01, beta=10.0)
    ref = solve_collision(prob, "conic")
    res = solve_collision(prob, "nlp")
    assert ref.status is Status.CONVERGED and res.status is Status.CONVERGED
    assert np.abs(res.f - ref.f).max() <= 1e-5 * ref.f.max()
    assert solve_collision(prob, "newton").status is Status.NUMERICAL_ERROR


@pytest.mark.parametrize("conserve_momentum", [False, True])
def test_nlp_certifies_a_floor_level_slice_that_barely_moves(conserve_momentum):
    """A vacuum slice at the 1e-10 floor: the step moves ~1e-17 of mass, so a flux rebuilt from f
    by the cumulative sum of h (f - f*) cancels to IPOPT's relative accuracy times 1e7 (KKT
    residual 4.6e-8 at a point within 5e-16 of Newton's).  IPOPT's own flux, with f rebuilt
    from it, is the flux-variable point Newton certifies: both must pass at the engine's 1e-8."""
    g = Grid.uniform(-4.0, 4.0, 31)
    v = g.points
    f_star = 1e-10 * (
        1 - 0.125 * (np.exp(-(v**2) / 0.05) + np.exp(-((v - 4) ** 2) / 0.05) + np.exp(-((v + 4) ** 2) / 0.05))
    )
    prob = CollisionProblem(
        g, PowerKernel(3.0), f_star, 0.05, strength=2.0, beta=1000.0, fisher="log", conserve_momentum=conserve_momentum
    )
    ref = solve_collision(prob, "newton", tol=1e-12)
    res = solve_collision(prob, "nlp", kkt_tol=1e-8)
    assert ref.status is Status.CONVERGED and res.status is Status.CONVERGED, res.message
    assert res.kkt_residual <= 1e-10
    assert np.abs(res.f - ref.f).max() <= 1e-12 * ref.f.max()
    assert res.mass_error <= 1e-14
    if conserve_momentum:
        assert prob.momentum_change(res.f) <= 1e-14


def test_nlp_momentum_constraint_matches_newton():
    prob = _log_family(4)
    prob = CollisionProblem(
        prob.grid, prob.kernel, prob.f_star, prob.dt, beta=prob.beta, fisher="log", conserve_momentum=True
    )
    ref = solve_collision(prob, "newton", tol=1e-12)
    res = solve_collision(prob, "nlp")
    assert res.status is Status.CONVERGED
    assert prob.momentum_change(res.f) <= 1e-14
    assert np.abs(res.f - ref.f).max() <= 1e-6 * ref.f.max()
    unconstrained = CollisionProblem(prob.grid, prob.kernel, prob.f_star, prob.dt, beta=prob.beta, fisher="log")
    assert unconstrained.momentum_change(solve_collision(unconstrained, "nlp").f) > 1e-9  # the constraint acts


def test_cached_model_is_refilled_for_new_data():
    """Same N, another grid, kernel, dt and Fisher weight: the cached model must not answer with stale data."""
    a = _log_family(5)
    rng = np.random.default_rng(6)
    b = random_problem(rng, 1.5 if a.kernel.gamma > 2 else 2.5, n=a.n, beta=3 * a.beta, fisher="log")
    first = solve_collision(a, "nlp")
    second = solve_collision(b, "nlp")
    assert not second.info["built_now"] and second.info["build_seconds"] == 0.0
    assert second.info["model_build_seconds"] > 0
    for key in ("canonicalize_seconds", "solver_seconds"):
        assert second.info[key] > 0
    ref = solve_collision(b, "newton", tol=1e-12)
    assert np.abs(second.f - ref.f).max() <= 1e-6 * ref.f.max()
    assert first.status is Status.CONVERGED


def test_batched_problem_is_solved_slice_by_slice():
    prob = _log_family(7)
    rng = np.random.default_rng(8)
    f2 = prob.f_star * (1 + 0.05 * rng.uniform(-1, 1, prob.n))
    batch = prob.with_f_star(np.stack([prob.f_star, f2]))
    res = solve_collision(batch, "nlp")
    ref = solve_collision(batch, "newton", tol=1e-12)
    assert res.f.shape == (2, prob.n) and np.all(res.success)
    assert np.abs(res.f - ref.f).max() <= 1e-6 * ref.f.max()
    with pytest.raises(ValueError, match="one problem at a time"):
        solve_nlp(batch)


def test_ipopt_outcomes_are_mapped_and_certified():
    prob = _log_family(9)
    capped = solve_collision(prob, "nlp", max_iter=1)
    assert capped.status is Status.MAX_ITERATIONS and capped.info["ipopt_status"] == -1
    assert not capped.success
    # IPOPT reports success; the KKT test at an impossible threshold must refuse it.
    strict = solve_collision(prob, "nlp", kkt_tol=1e-300)
    assert strict.info["ipopt_status"] == 0 and strict.status is Status.NOT_CERTIFIED
    ok = solve_collision(prob, "nlp")
    assert ok.iterations > 0 and ok.info["scale"] > 0


def test_status_table_covers_every_ipopt_return_code():
    from cvxpy.reductions.solvers.nlp_solvers.ipopt_nlpif import IPOPT

    assert set(IPOPT.STATUS_MAP) <= set(nlp_module.IPOPT_STATUS)
    successes = {code for code, st in nlp_module.IPOPT_STATUS.items() if st.success}
    assert successes == {0}


@pytest.mark.parametrize(
    "options, error, match",
    [
        ({"tol": 0.0}, ValueError, r"tol must lie in \(0, 1\)"),
        ({"kkt_tol": 2.0}, ValueError, r"kkt_tol must lie in \(0, 1\)"),
        ({"max_iter": 0}, ValueError, "max_iter must be an integer >= 1"),
        ({"max_iter": 2.5}, ValueError, "max_iter must be an integer >= 1"),
        ({"solver_options": [("tol", 1e-8)]}, TypeError, "solver_options must be a dict"),
        ({"solver_options": {"tol": 1e-8}}, ValueError, r"solver_options\['tol'\] is set by method='nlp'.*tol="),
        ({"solver_options": {"no_such_option": 1}}, ValueError, r"solver_options\['no_such_option'\] = 1 is rejected"),
        ({"solver_options": {"acceptable_iter": 2.5}}, ValueError, r"solver_options\['acceptable_iter'\]"),
        ({"solver_options": {"mu_strategy": True}}, TypeError, r"solver_options\['mu_strategy'\] must be"),
        ({"check_convexity": "yes"}, TypeError, "check_convexity must be True or False"),
    ],
)
def test_bad_options_raise_before_any_work(monkeypatch, options, error, match):
    def no_work(*args, **kwargs):
        raise AssertionError("work started before the options were checked")

    monkeypatch.setattr(nlp_module, "_get_model", no_work)
    with pytest.raises(error, match=match):
        solve_collision(_log_family(0), "nlp", **options)


def test_unknown_keyword_is_rejected_by_solve_collision():
    with pytest.raises(TypeError, match=r"unknown option\(s\) \['solver'\] for method='nlp'"):
        solve_collision(_log_family(0), "nlp", solver="IPOPT")


def test_missing_ipopt_says_how_to_install(monkeypatch):
    from cvxpy.reductions.solvers import defines

    monkeypatch.setattr(defines, "INSTALLED_SOLVERS", [s for s in defines.INSTALLED_SOLVERS if s != "IPOPT"])
    with pytest.raises(ImportError, match=r'pip install "jko_cvx\[nlp\]"'):
        solve_collision(_log_family(0), "nlp")


def test_whole_run_with_nlp_matches_newton():
    """A short inhomogeneous log-Fisher scene (16 x 31, two steps): nlp and Newton runs agree."""
    base = load_scene(SCENES / "inhom_gamma3_lambda4.toml")
    base = base.replace({"v.n": 31, "x.n": 16, "t_end": 0.1})
    assert base.collision.problem_fisher == "log" and base.collision.conserve_momentum
    newton = simulate(base)
    nlp = simulate(base.replace({"collision.method": "nlp"}))
    assert nlp.t == pytest.approx(0.1) and newton.t == pytest.approx(0.1)
    assert (nlp.diagnostics.failed == 0).all()
    assert np.array_equal(nlp.vgrid.points, newton.vgrid.points)
    # Newton's steps are certified to KKT 1e-8, nlp's to its own tolerance: f agrees to ~1e-7.
    assert np.abs(nlp.f - newton.f).max() <= 1e-6 * newton.f.max()
    for col in ("mass", "moment2"):
        np.testing.assert_allclose(nlp.diagnostics[col], newton.diagnostics[col], rtol=1e-8)


def test_scene_accepts_nlp_with_allow_listed_ipopt_options():
    from jko_cvx.scene.model import SceneError, scene_from_dict

    d = {
        "gamma": 1.0,
        "t_end": 0.1,
        "v": {"L": 2.0, "n": 41},
        "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
        "time": {"dt": 0.01},
        "collision": {"method": "nlp", "fisher": "log", "beta": 100.0, "options": {"tol": 1e-8}},
    }
    d["collision"]["options"]["solver_options"] = {"max_cpu_time": 5.0}
    scene = scene_from_dict(d)
    assert scene.collision.method == "nlp" and scene.collision.options["solver_options"] == {"max_cpu_time": 5.0}
    d["collision"]["options"]["solver_options"] = {"output_file": "ipopt.out"}  # writes a file: never from a scene
    with pytest.raises(SceneError, match="output_file"):
        scene_from_dict(d)
