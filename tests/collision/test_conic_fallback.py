"""The conic reference's sequence of attempts (``conic._solve_forms``): the cone forms in f units, then in edge
units where none settled (edge units first at a density floor); which attempt's answer is returned."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status, solve_collision
from jko_cvx.collision import conic
from jko_cvx.collision.conic import ConicOptions


def _fake(outcomes):
    """A stand-in for one attempt: the (status, kkt) of each call in turn, recording (form, edge_units)."""
    calls = []

    def solve_form(problem, opts, form, edge_units=False):
        status, kkt = outcomes[len(calls)]
        calls.append((form, edge_units))
        return SimpleNamespace(status=status, kkt_residual=kkt, info={"edge_units": edge_units}, seconds=1.0)

    return solve_form, calls


_ROUND = [("raw", False), ("centred", False), ("raw", True), ("centred", True)]  # the attempts at one tol


@pytest.mark.parametrize(
    ("outcomes", "calls", "picked"),
    [
        # the first form settles: returned alone, as without the fallbacks
        ([(Status.CONVERGED, 1e-9)], [("raw", False)], 0),
        ([(Status.TIME_LIMIT, 0.3)], [("raw", False)], 0),
        # the second form converges: it is the answer
        ([(Status.NOT_CERTIFIED, 1e-5), (Status.CONVERGED, 1e-9)], [("raw", False), ("centred", False)], 1),
        # the second runs out of time: the better of the two by the residual (the first)
        ([(Status.NOT_CERTIFIED, 1e-5), (Status.TIME_LIMIT, 0.5)], [("raw", False), ("centred", False)], 0),
        # neither settles in f units: the edge units, the first form's settles
        (
            [(Status.NOT_CERTIFIED, 1e-5), (Status.SOLVER_ERROR, 0.2), (Status.CONVERGED, 1e-8)],
            [("raw", False), ("centred", False), ("raw", True)],
            2,
        ),
        # nothing settles at tol: the same four at the retry tolerance; the first that settles is the answer
        (
            [
                (Status.NOT_CERTIFIED, 1e-5),
                (Status.SOLVER_ERROR, 0.2),
                (Status.INACCURATE, 3e-6),
                (Status.MAX_ITERATIONS, 1e-4),
                (Status.NOT_CERTIFIED, 2e-6),
                (Status.CONVERGED, 1e-9),
            ],
            [*_ROUND, *_ROUND[:2]],
            5,
        ),
        # nothing settles in either round: the smallest residual of all eight
        (
            [
                (Status.NOT_CERTIFIED, 1e-5),
                (Status.SOLVER_ERROR, 0.2),
                (Status.INACCURATE, 3e-6),
                (Status.MAX_ITERATIONS, 1e-4),
                *[(Status.SOLVER_ERROR, 0.2)] * 4,
            ],
            [*_ROUND, *_ROUND],
            2,
        ),
    ],
)
def test_the_attempts_and_the_answer(monkeypatch, outcomes, calls, picked):
    fake, seen = _fake(outcomes)
    monkeypatch.setattr(conic, "_solve_form", fake)
    monkeypatch.setattr(conic, "_refined", lambda *args: None)  # the fakes carry no point to refine
    g = Grid.uniform(-2.0, 2.0, 21)
    prob = CollisionProblem(g, PowerKernel(1.0), np.exp(-2 * g.points**2), 0.01, beta=10.0)
    res = conic._solve_forms(prob, ConicOptions.checked(prob), ["raw", "centred"])
    assert seen == calls
    assert res.kkt_residual == outcomes[picked][1] and res.status is outcomes[picked][0]
    assert ("fallback_from" in res.info) == (len(calls) > 1)
    assert res.info["edge_units"] == calls[picked][1]
    assert res.info.get("tol") == (1e-12 if picked >= len(_ROUND) else None)


def test_an_explicit_form_falls_back_to_its_own_edge_units(monkeypatch):
    fake, seen = _fake([(Status.INACCURATE, 1e-3), (Status.CONVERGED, 1e-9)])
    monkeypatch.setattr(conic, "_solve_form", fake)
    g = Grid.uniform(-2.0, 2.0, 21)
    prob = CollisionProblem(g, PowerKernel(1.0), np.exp(-2 * g.points**2), 0.01, beta=10.0)
    res = conic._solve_forms(prob, ConicOptions.checked(prob, fisher_cone="centred"), ["centred"])
    assert seen == [("centred", False), ("centred", True)] and res.status is Status.CONVERGED
    assert "fallback_from" not in res.info


def test_edge_units_give_the_f_unit_answer_where_both_settle():
    """The same minimiser in either units (a floor of 1e-7 under a bump, both cone forms, with and without the
    momentum constraint)."""
    g = Grid.uniform(-3.0, 3.0, 41)
    f = np.exp(-4 * g.points**2) + 1e-7
    for cone in ("raw", "centred"):
        for momentum in (False, True):
            prob = CollisionProblem(g, PowerKernel(3.0), f, 0.02, 2.0, 30.0, "perspective", momentum)
            opts = ConicOptions.checked(prob, fisher_cone=cone)
            plain = conic._solve_form(prob, opts, cone, edge_units=False)
            edge = conic._solve_form(prob, opts, cone, edge_units=True)
            assert plain.success and edge.success, (plain.message, edge.message)
            assert np.abs(plain.f - edge.f).max() <= 1e-6 * plain.f.max()
            assert edge.info["edge_units"] and not plain.info.get("edge_units")
    assert solve_collision(prob, method="conic").success


def _near_vacuum_problem():
    """A bump over a floor of 1e-10 of its peak: the cones of the floor's edges sit below the solver's tolerance."""
    g = Grid.uniform(-4.0, 4.0, 41)
    return CollisionProblem(g, PowerKernel(3.0), np.exp(-6 * (g.points - 1) ** 2) + 1e-10, 0.02, 2.0, 30.0,
                            "perspective")  # fmt: skip


@pytest.mark.parametrize(
    ("outcomes", "calls", "picked"),
    [
        # near vacuum, the edge units first: where they settle, the answer alone
        ([(Status.CONVERGED, 1e-9)], [("raw", True)], 0),
        # neither form settles in edge units: the f units after them
        (
            [(Status.SOLVER_ERROR, 0.2), (Status.NOT_CERTIFIED, 1e-5), (Status.CONVERGED, 1e-9)],
            [("raw", True), ("centred", True), ("raw", False)],
            2,
        ),
    ],
)
def test_a_near_vacuum_step_tries_the_edge_units_first(monkeypatch, outcomes, calls, picked):
    fake, seen = _fake(outcomes)
    monkeypatch.setattr(conic, "_solve_form", fake)
    prob = _near_vacuum_problem()
    res = conic._solve_forms(prob, ConicOptions.checked(prob), ["raw", "centred"])
    assert seen == calls and res.status is outcomes[picked][0]
    assert res.info["edge_units"] == calls[picked][1] and res.info["attempts"] == len(calls)


def test_a_slice_of_the_papers_gamma3_scene_at_its_density_floor_goes_straight_to_the_edge_units():
    """inhom_gamma3_lambda4 at 41 x 41 (perspective, beta = 30) after one step: x-slice 24, max f 0.10 over the run's
    floor 1e-10 (smallest edge sum 1e-9 of the largest).  Measured before: both cone forms fail in f units
    (SOLVER_ERROR), and the raw form in edge units converges; now the edge units come first."""
    from jko_cvx.collision.estimate import solve_reference
    from jko_cvx.engine.loop import simulate
    from jko_cvx.scene import shipped_scene

    over = {"v.n": 41, "x.n": 41, "collision.fisher": "perspective", "collision.beta": 30.0, "t_end": 0.05}
    sc = shipped_scene("inhom_gamma3_lambda4", over)
    run = simulate(sc)
    prob = CollisionProblem(run.vgrid, PowerKernel(3.0), run.f[24], sc.time.dt, sc.strength, 30.0, "perspective",
                            sc.collision.conserve_momentum)  # fmt: skip
    res = solve_reference(prob, "conic", {})
    ref = solve_collision(prob, method="newton", tol=1e-12)
    assert res.success and res.info["edge_units"] and res.info["attempts"] <= 2, res.message  # no f-unit attempt
    assert np.abs(res.f - ref.f).max() <= 1e-6 * ref.f.max()


@pytest.mark.parametrize(("floor", "edge_first"), [(1e-13, False), (3e-12, False), (3e-11, True), (1e-7, True),
                                                   (3e-6, False)])  # fmt: skip
def test_the_density_floors_that_go_to_the_edge_units_first(monkeypatch, floor, edge_first):
    """The range of the smallest edge sum relative to the largest (about the floor here) that starts in edge units:
    1e-11 to 1e-6; below it the edge units failed in both forms on Gaussians over floors of 1e-12 to 5e-12."""
    fake, seen = _fake([(Status.CONVERGED, 1e-9)])
    monkeypatch.setattr(conic, "_solve_form", fake)
    g = Grid.uniform(-4.0, 4.0, 41)
    prob = CollisionProblem(g, PowerKernel(1.0), np.exp(-6 * g.points**2) + floor, 0.02, 2.0, 30.0, "perspective")
    conic._solve_forms(prob, ConicOptions.checked(prob), ["raw", "centred"])
    assert seen == [("raw", edge_first)]


def test_a_bump_over_a_floor_of_1e_10_is_certified_in_one_attempt():
    """Measured before (f units first, the loop linearised first at f*): NOT_CERTIFIED in every cone form and units,
    KKT 1.6e-6 to 3.8e-1; now one attempt in edge units, KKT 1.7e-7, within 2e-9 of Newton."""
    prob = _near_vacuum_problem()
    res = solve_collision(prob, method="conic")
    ref = solve_collision(prob, method="newton", tol=1e-12)
    assert res.success and res.info["edge_units"] and res.info["attempts"] == 1, res.message
    assert np.abs(res.f - ref.f).max() <= 1e-6 * ref.f.max()


@pytest.mark.parametrize(
    ("options", "retried"),
    [
        ({}, True),
        ({"tol": 1e-6}, False),  # a tol the caller loosened is answered at that tol
        ({"solver": "SCS"}, False),  # a first-order solver is not asked for 1e-12
        ({"solver_options": {"tol_gap_rel": 1e-9}}, False),  # the caller set the gap tolerance itself
    ],
)
def test_the_retry_at_the_tighter_tolerance_is_clarabels_from_the_default_down(monkeypatch, options, retried):
    tols = []

    def solve_form(problem, opts, form, edge_units=False):
        tols.append(opts.tol)
        return SimpleNamespace(status=Status.NOT_CERTIFIED, kkt_residual=1e-5, info={}, seconds=1.0)

    monkeypatch.setattr(conic, "_solve_form", solve_form)
    monkeypatch.setattr(conic, "_refined", lambda *args: None)
    g = Grid.uniform(-2.0, 2.0, 21)
    prob = CollisionProblem(g, PowerKernel(1.0), np.exp(-2 * g.points**2), 0.01, beta=10.0)
    conic._solve_forms(prob, ConicOptions.checked(prob, **options), ["raw", "centred"])
    assert (1e-12 in tols) == retried and len(tols) == (8 if retried else 4)


def test_the_refinement_is_refused_where_its_answer_would_not_be_the_asked_one():
    """One Newton correction would certify this loose answer; it is not taken for a linearised energy, for an
    inaccurate solve the caller wants reported, or after the time limit."""
    g = Grid.uniform(-2.0, 2.0, 41)
    prob = CollisionProblem(g, PowerKernel(1.5), np.exp(-2 * g.points**2), 0.01, 1.0, 10.0, "perspective")
    loose = solve_collision(prob, method="newton", tol=1e-7)
    res = replace_status(loose, Status.NOT_CERTIFIED)
    assert conic._refined(prob, res, ConicOptions.checked(prob, kkt_tol=1e-10)).status is Status.CONVERGED
    for status, opts in (
        (Status.NOT_CERTIFIED, {"energy": "linearized", "kkt_tol": 1e-10}),
        (Status.INACCURATE, {"accept_inaccurate": False, "kkt_tol": 1e-10}),
        (Status.TIME_LIMIT, {"kkt_tol": 1e-10}),
    ):
        assert conic._refined(prob, replace_status(loose, status), ConicOptions.checked(prob, **opts)) is None


def replace_status(res, status):
    import dataclasses

    return dataclasses.replace(res, status=status, info={"solver_status": "optimal"})
