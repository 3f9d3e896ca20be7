"""Where the conic method's inner solves cannot drive the KKT residual below its threshold.

Two x-slices of ``inhom_gamma3_lambda4`` at 61 x 61 (perspective form) run under ``method = "conic"``, stored
in ``tests/data/conic_inner_accuracy_slices.npz``: at beta = 30, t = 0.3 (max f* 0.19) and at beta = 1000,
t = 0.05 (max f* 1.3e-3, tails at 8e-8 of it).  Each stopped its run: NOT_CERTIFIED after every cone form and
units, KKT 2.2e-6 and 2.9e-6 against the threshold 1e-6, where they were recorded (OpenBLAS SkylakeX kernel);
with another kernel's rounding Clarabel may certify them at once (Haswell: KKT 5.6e-7 and 8.0e-7).  So each test
checks the answer on the stored slice as it comes, and the path it names with the stall forced: every attempt
before the one under test reported as not certified (its own f and KKT residual kept).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status, f_error_estimate, solve_collision
from jko_cvx.collision import conic, solve_conic

DATA = np.load(Path(__file__).parents[1] / "data" / "conic_inner_accuracy_slices.npz")


def _problem(beta: int) -> CollisionProblem:
    grid = Grid(DATA[f"v_beta{beta}"])
    return CollisionProblem(grid, PowerKernel(3.0), DATA[f"f_star_beta{beta}"], float(DATA["dt"]),
                            float(DATA["strength"]), float(beta), "perspective", True)  # fmt: skip


def _close_to_newton(prob: CollisionProblem, res) -> bool:
    """Within twice its own error estimate of Newton's answer, in the estimate's measure: each cell's error weighted
    by f_j / max f (near-vacuum cells count little; on this data set the largest unweighted error sits in a cell at
    4e-5 of max f, 3.4 times the weighted one)."""
    newton = solve_collision(prob, method="newton", tol=1e-12, max_iter=500)
    bound = max(2 * f_error_estimate(prob, res.f, res.m), 1e-9)
    weighted = newton.f / newton.f.max() * np.abs(res.f - newton.f)
    return bool(weighted.max() <= bound * newton.f.max())


def _stall(monkeypatch, *, retry_too: bool) -> None:
    """Report every conic attempt at the default gap tolerance (and, with ``retry_too``, at the retry's) as not
    certified, keeping its point: the stall the stored slices showed where they were recorded."""
    solve_form = conic._solve_form

    def stalled(problem, opts, fisher_cone, edge_units=False):
        res = solve_form(problem, opts, fisher_cone, edge_units)
        if opts.tol > conic._RETRY_TOL or retry_too:
            return dataclasses.replace(res, status=Status.NOT_CERTIFIED)
        return res

    monkeypatch.setattr(conic, "_solve_form", stalled)


def test_a_stalled_slice_is_certified_at_the_tighter_inner_tolerance(monkeypatch):
    """beta = 30: where the attempts at tol 1e-10 do not certify (KKT 2.2e-6 on SkylakeX), the attempts at 1e-12 run
    and the first of them certifies it."""
    prob = _problem(30)
    res = solve_conic(prob)
    assert res.success and _close_to_newton(prob, res), res.message
    assert res.info.get("tol", 1e-12) == 1e-12  # where the first round stalled, the answer is the retry's
    _stall(monkeypatch, retry_too=False)
    forced = solve_conic(prob)
    assert forced.success and forced.info["tol"] == 1e-12, forced.message
    assert "refined_by" not in forced.info
    assert _close_to_newton(prob, forced)


def test_a_pinned_answer_above_the_threshold_is_certified_after_one_newton_correction(monkeypatch):
    """beta = 1000: where no attempt certifies at either tolerance (KKT 1.8e-6 to 2.9e-6 on SkylakeX), one Newton
    correction (a move of about 1e-9) certifies the best answer."""
    prob = _problem(1000)
    res = solve_conic(prob)
    assert res.success and res.kkt_residual <= 1e-6, res.message
    assert _close_to_newton(prob, res)
    _stall(monkeypatch, retry_too=True)
    forced = solve_conic(prob)
    assert forced.success and forced.kkt_residual <= 1e-6, forced.message
    assert 0 < forced.info["refined_by"] <= 1e-5 and forced.info["refined_from"] == "NOT_CERTIFIED"
    assert _close_to_newton(prob, forced)
