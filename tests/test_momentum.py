"""Momentum: the constrained collision step, moment-restoring remaps, and whole runs."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from jko_cvx import CollisionProblem, PowerKernel, Status, solve_collision
from jko_cvx.collision.newton import _direction, _fused
from jko_cvx.collision.problem import add_pentadiagonal
from jko_cvx.engine.loop import simulate
from jko_cvx.grid import Grid
from jko_cvx.mesh.moments import restore_moments
from jko_cvx.mesh.remapping import remap
from jko_cvx.scene.model import Scene, SceneError, load_scene, scene_from_dict
from jko_cvx.testing import random_problem

from .engine.test_simulate import BASE

SCENES = Path(__file__).parent.parent / "jko_cvx" / "scene" / "shipped"


def _constrained(prob: CollisionProblem) -> CollisionProblem:
    return CollisionProblem(
        prob.grid, prob.kernel, prob.f_star, prob.dt, prob.strength, prob.beta, prob.fisher, conserve_momentum=True
    )


@pytest.mark.parametrize("gamma", [1.0, 1.5, 2.0, 3.0])
def test_constrained_step_conserves_momentum_and_agrees_with_conic(gamma):
    rng = np.random.default_rng(int(10 * gamma) + 5)
    free = random_problem(rng, gamma, n=61)
    prob = _constrained(free)
    newton = solve_collision(prob, "newton")
    conic = solve_collision(prob, "conic")
    assert newton.status is Status.CONVERGED and conic.status is Status.CONVERGED
    assert prob.momentum_change(newton.f) <= 1e-14 and prob.momentum_change(conic.f) <= 1e-14
    assert np.abs(newton.f - conic.f).max() <= 1e-5 * newton.f.max()
    # The paper's (unconstrained) step moves the momentum: its solution is not a KKT point
    # of the constrained problem, and the constrained solution is not one of the free problem.
    unconstrained = solve_collision(free, "newton")
    assert free.momentum_change(unconstrained.f) > 1e-8
    assert prob.kkt_residual(unconstrained.f, unconstrained.m).total > 1e-7
    assert free.kkt_residual(newton.f, newton.m).total > 1e-7


@pytest.mark.parametrize("gamma", [1.0, 2.0, 3.0])
def test_constrained_direction_solves_the_bordered_kkt_system(gamma):
    """p = p0 - w (a'p0)/(a'w) equals the solution of [[H, a], [a', 0]] [p; u] = [-g; 0]."""
    rng = np.random.default_rng(21)
    prob = _constrained(random_problem(rng, gamma, n=40))
    m = rng.normal(size=39) * 1e-3
    m -= prob.grid.dv * (m @ prob.grid.dv) / (prob.grid.dv @ prob.grid.dv)
    f = prob.density_from_flux(m)
    g, bands, _ = _fused(prob, f[None], m[None])
    p, pd, _ = _direction(prob, bands, g)
    H = add_pentadiagonal(2 * prob.energy_coef * prob.energy.flux_block(), *bands)[0]
    a = prob.grid.dv
    K = np.block([[H, a[:, None]], [a[None, :], np.zeros((1, 1))]])
    ref = np.linalg.solve(K, np.r_[-g[0], 0.0])[:-1]
    assert pd[0]
    assert np.abs(p[0] - ref).max() <= 1e-8 * np.abs(ref).max()
    assert abs(p[0] @ a) <= 1e-13 * np.abs(p[0]).max() * a.sum()


def test_batched_constrained_newton_matches_single_solves():
    rng = np.random.default_rng(4)
    prob = _constrained(random_problem(rng, 3.0, n=51))
    batch = prob.with_f_star(np.stack([prob.f_star, prob.f_star[::-1] * 1.3, prob.f_star**1.2]))
    res = solve_collision(batch, "newton")
    assert all(s is Status.CONVERGED for s in res.status)
    for i in range(3):
        single = solve_collision(batch.slice(i), "newton")
        assert np.abs(res.f[i] - single.f).max() <= 1e-10 * single.f.max()
        assert batch.slice(i).momentum_change(res.f[i]) <= 1e-14


def test_restore_moments_is_exact_positive_and_refuses_unreachable_targets():
    grid = Grid.uniform(-3.0, 3.0, 61)
    v, h = grid.points, grid.h
    f = np.exp(-2 * (v - 0.3) ** 2) + 0.5 * np.exp(-4 * (v + 1) ** 2) + 1e-10
    mass, mom = f @ h, f @ (v * h)
    # exact to rounding: a 61-term dot product summed in another order differs by at most ~61 ulp / 2
    g, ok = restore_moments(f * (1 + 1e-3 * np.sin(5 * v)), h, v, mass, mom)
    assert ok and abs(g @ h - mass) <= 1e-14 * mass and abs(g @ (v * h) - mom) <= 1e-14 * mass
    # A large shift of the mean velocity (a linear correction would turn the tails negative)
    g, ok = restore_moments(f, h, v, mass, mom + 1.5 * mass)
    assert ok and g.min() > 0 and abs(g @ (v * h) - (mom + 1.5 * mass)) <= 1e-14 * mass
    # A mean velocity outside the grid cannot be reached: refused, mass kept.
    g, ok = restore_moments(f, h, v, mass, 10.0 * mass)
    assert not ok and abs(g @ h - mass) <= 1e-14 * mass


@pytest.mark.parametrize("width", [0.3, 0.08, 0.03])
def test_restore_moments_above_a_floor_keeps_the_floor_and_both_moments(width):
    """With ``floor`` the tilt moves only f - floor: every value stays >= floor (the whole-row tilt
    sent the far tail of a narrow bump to exp(-beta span) times the floor), mass and first
    moment are still exact, and a row whose excess cannot carry the target falls back to the
    whole-row tilt (still exact, reported reached)."""
    grid = Grid.uniform(-3.0, 3.0, 121)
    v, h = grid.points, grid.h
    floor = 1e-10
    f = np.maximum(np.exp(-((v - 0.2) ** 2) / (2 * width**2)) * (1 + 0.05 * np.sin(40 * v)), 0) + floor
    mass, mom = f @ h, f @ (v * h) + 0.02 * width * (f @ h)  # shift the mean by 2 % of the width
    whole, ok_whole = restore_moments(f, h, v, mass, mom)
    above, ok = restore_moments(f, h, v, mass, mom, floor=floor)
    assert ok and ok_whole
    assert above.min() >= floor * (1 - 1e-15)
    assert abs(above @ h - mass) <= 1e-14 * mass and abs(above @ (v * h) - mom) <= 1e-14 * mass
    assert np.abs(above - whole).max() <= 1e-3 * f.max()  # the same correction where the mass is
    # the excess (one point above the floor) cannot move its mean: the whole-row tilt does it
    spike = np.full_like(v, floor)
    spike[60] = 1.0
    m, p = spike @ h, spike @ (v * h) + 0.01 * (spike @ h)
    g, ok = restore_moments(spike, h, v, m, p, floor=floor)
    assert ok and abs(g @ h - m) <= 1e-15 * m and abs(g @ (v * h) - p) <= 1e-14 * m


def test_velocity_remap_restores_momentum_only_when_asked():
    old = Grid.uniform(-4.0, 4.0, 81)
    new = Grid(4 * np.sinh(2 * np.linspace(-1, 1, 81)) / np.sinh(2))
    f = np.stack([np.exp(-6 * (old.points - c) ** 2) + 1e-3 for c in (-1.3, 0.2, 2.1)])
    p_old = f @ (old.points * old.h)
    plain = remap(old, f, new)
    kept = remap(old, f, new, conserve_momentum=True)
    assert np.abs(plain @ (new.points * new.h) - p_old).max() > 1e-6  # interpolation moves it
    assert np.abs(kept @ (new.points * new.h) - p_old).max() <= 1e-14
    assert np.allclose(kept @ new.h, f @ old.h, rtol=1e-14, atol=0)
    assert np.abs(kept - plain).max() <= 1e-2 * plain.max()


def test_sqp_refuses_the_momentum_constraint():
    prob = _constrained(random_problem(np.random.default_rng(0), 1.0, n=31))
    with pytest.raises(ValueError, match="conserve_momentum"):
        solve_collision(prob, "sqp")
    d = BASE
    assert scene_from_dict({**d, "collision": {"method": "sqp"}}).collision.conserve_momentum is False
    assert scene_from_dict(d).collision.conserve_momentum is True
    with pytest.raises(SceneError, match=r"collision\.conserve_momentum"):
        scene_from_dict({**d, "collision": {"method": "sqp", "conserve_momentum": True}})


@dataclasses.dataclass(frozen=True)
class _LopsidedScene(Scene):
    """eqn:f0 with one bump heavier: no symmetry keeps the momentum at zero."""

    def initial_density(self, xgrid, vgrid):
        f = super().initial_density(xgrid, vgrid)
        return f * (1 + 0.4 * np.tanh(xgrid.points[:, None]))


def test_inhomogeneous_momentum_is_conserved_without_help_from_symmetry():
    base = load_scene(SCENES / "inhom_gamma3_lambda4.toml")
    fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(base)}
    s = _LopsidedScene(**fields).replace({"v.n": 41, "x.n": 41, "t_end": 0.5})
    kept = simulate(s).diagnostics
    drift = simulate(s.replace({"collision.conserve_momentum": False})).diagnostics
    p0 = kept.momentum.iloc[0]
    assert abs(p0) > 1e-2  # the datum really carries momentum
    assert np.abs(kept.momentum - p0).max() <= 1e-13
    assert np.abs(drift.momentum - p0).max() > 1e-9  # the paper's step, for contrast


def test_gamma2_energy_concavity_lies_along_the_momentum_constraint():
    """gamma = 2: the energy block -(dv)(dv)' is along the constraint normal a = dv.

    At the minimiser of a strongly aggregating step (dt * strength = 10) the full Hessian in
    the fluxes is indefinite, so the paper's unconstrained step is non-convex there, while
    on the tangent space a'm = 0 it is positive definite: the second-order test and the
    Newton direction must use the tangent space (before, both reported NONCONVEX).
    """
    v = np.linspace(-2.0, 2.0, 61)
    f_star = np.exp(-4 * (v - 0.3) ** 2) + 0.2 * np.exp(-10 * (v + 1) ** 2)
    args = (Grid(v), PowerKernel(2.0), f_star, 0.01, 1000.0, 30.0, "perspective")
    prob, free = CollisionProblem(*args, conserve_momentum=True), CollisionProblem(*args)
    conic = solve_collision(prob, "conic")
    assert conic.status is Status.CONVERGED
    assert free.convexity_margin(conic.f, conic.m) < -0.1 < 0 < prob.convexity_margin(conic.f, conic.m)
    # halfway from f* to the minimiser (a'm = 0 still holds): a point where Newton steps
    m = 0.5 * conic.m
    g, bands, _ = _fused(prob, prob.density_from_flux(m)[None], m[None])
    H = add_pentadiagonal(2 * prob.energy_coef * prob.energy.flux_block(), *bands)[0]
    assert np.linalg.eigvalsh(H)[0] < 0
    p, pd, valid = _direction(prob, bands, g)
    a = prob.grid.dv
    K = np.block([[H, a[:, None]], [a[None, :], np.zeros((1, 1))]])
    ref = np.linalg.solve(K, np.r_[-g[0], 0.0])[:-1]
    assert pd[0] and valid[0]
    assert np.abs(p[0] - ref).max() <= 1e-7 * np.abs(ref).max()
