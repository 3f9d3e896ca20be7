"""Mesh maps (mu1, mu2) and mass-conserving remapping."""

import numpy as np
import pytest

from jko_cvx import Grid
from jko_cvx.grid import PeriodicGrid
from jko_cvx.mesh.maps import OneBumpMap, TwoBumpMap, periodic_map_grid
from jko_cvx.mesh.remapping import remap, remap_periodic

S = np.linspace(-1, 1, 2001)


def _check_map(mu, L, n_conc_frac, n=121, inside=None):
    v = mu(S)
    assert np.all(np.diff(v) > 0), "strictly increasing"
    assert v[0] == pytest.approx(-L, abs=1e-12) and v[-1] == pytest.approx(L, abs=1e-12)
    assert np.allclose(mu(-S), -v), "odd"
    # continuity: no jumps larger than the local slope allows
    jumps = np.abs(np.diff(v))
    assert jumps.max() < 20 * np.median(jumps) * 10
    g = mu.grid(n)
    frac = np.mean(inside(g.points))
    assert frac == pytest.approx(n_conc_frac, abs=2.5 / n)


@pytest.mark.parametrize("r, delta", [(0.3, 0.5), (0.1, 0.2), (1.8, 0.5), (1.2, 0.8), (1.0, 0.5)])
def test_one_bump_map_properties(r, delta):
    L = 2.0
    mu = OneBumpMap(L, r, delta)
    assert mu.outer_kind == ("quintic" if r / delta <= L else "logistic")
    _check_map(mu, L, delta, inside=lambda v: np.abs(v) <= r + 1e-12)
    # continuity at the interface
    assert mu(delta) == pytest.approx(r) and mu(delta + 1e-12) == pytest.approx(r, abs=1e-9)


@pytest.mark.parametrize("r1, r2, delta", [(1.8, 2.2, 0.5), (1.0, 3.0, 0.5), (0.5, 0.9, 0.3)])
def test_two_bump_map_properties(r1, r2, delta):
    L = 4.0
    mu = TwoBumpMap(L, r1, r2, delta)
    _check_map(mu, L, delta, inside=lambda v: (np.abs(v) >= r1 - 1e-12) & (np.abs(v) <= r2 + 1e-12))
    s1 = 0.5 - delta / 2
    assert mu(s1) == pytest.approx(r1) and mu(s1 - 1e-10) == pytest.approx(r1, abs=1e-8)


def test_maps_from_densities_put_points_where_the_mass_is():
    g = Grid.uniform(-2, 2, 121)
    f = np.exp(-30 * g.points**2)
    mu = OneBumpMap.from_density(g, f, delta0=0.5, delta=0.5)
    # half-width of {f > 0.5 max f} on the grid
    assert mu.r == pytest.approx(np.sqrt(np.log(2) / 30), abs=g.dv.max())
    new = mu.grid(121)
    assert new.dv.min() < g.dv.min() / 5
    g4 = Grid.uniform(-4, 4, 161)
    f2 = np.exp(-50 * (g4.points - 2) ** 2) + np.exp(-50 * (g4.points + 2) ** 2)
    mu2 = TwoBumpMap.from_density(g4, f2, delta0=0.2, delta=0.5)
    assert 1.7 < mu2.r1 < 2 < mu2.r2 < 2.3


def test_impossible_maps_raise_clear_errors():
    with pytest.raises(ValueError, match="delta must lie in"):
        OneBumpMap(2.0, 0.5, 1.5)
    with pytest.raises(ValueError, match=r"r must lie in \(0, L\)"):
        OneBumpMap(2.0, 2.5, 0.5)
    # needs L/r = 1.33 > 1.2 (the logistic's largest ratio) and r > the quintic's range
    with pytest.raises(ValueError, match=r"not increasing|no logistic"):
        OneBumpMap(2.0, 1.5, 0.5)
    with pytest.raises(ValueError, match="inner piece cannot be increasing"):
        TwoBumpMap(4.0, 0.1, 2.0, 0.5)  # slope 3.8 * s1 0.25 >= 5 r1 = 0.5
    # a set resolved by one grid point is widened to that point's cell
    g = Grid.uniform(-4, 4, 61)
    f = np.exp(-50 * (g.points - 2) ** 2) + np.exp(-50 * (g.points + 2) ** 2)
    mu = TwoBumpMap.from_density(g, f, 0.8, 0.5)
    assert mu.r1 == pytest.approx(2 - g.dv[0] / 2) and mu.r2 == pytest.approx(2 + g.dv[0] / 2)


def test_remap_conserves_mass_and_is_accurate():
    old = Grid.uniform(-2, 2, 121)
    f = np.exp(-30 * old.points**2) + 1e-3
    new = OneBumpMap.from_density(old, f, 0.5, 0.5).grid(121)
    g = remap(old, f, new)
    assert abs(g @ new.h - f @ old.h) <= 1e-12 * (f @ old.h)
    exact = np.exp(-30 * new.points**2) + 1e-3
    # PCHIP from dv = 0.033 onto a peak of width 0.13: a few 1e-3
    assert np.abs(g - exact).max() < 1e-2 * exact.max()
    # batched along the first axis (x-lines of a phase-space density)
    F = np.stack([f, 2 * f])
    G = remap(old, F, new)
    assert np.allclose(G @ new.h, F @ old.h, rtol=1e-12)
    # the paper's floor 1e-10 (eqn:mass_conserv_v): data with an empty tail come back floored
    # there (then rescaled by a mass factor 1 + O(1e-10)), never at 0
    empty_tail = np.where(np.abs(old.points) < 1.0, f, 0.0)
    floored = remap(old, empty_tail, new)
    assert floored.min() == pytest.approx(1e-10, rel=1e-6)
    assert abs(floored @ new.h - empty_tail @ old.h) <= 1e-12 * (empty_tail @ old.h)


def test_periodic_remap_can_keep_each_lines_first_moment():
    """A change of grid moves no mass: with conserve_moment every line keeps mass and x-moment.

    Two bumps per v-line at x = -2.5 and 4.7 (next to the periodic boundary), remapped
    from 61 uniform points to a mapped grid: PCHIP alone moves the centres by ~1e-3.
    """
    old = PeriodicGrid.uniform(5.0, 61)
    amps = np.array([1.0, 0.3, 1e-6])
    f = np.maximum(
        amps * np.exp(-6 * (old.points[:, None] + 2.5) ** 2)
        + 0.5 * amps * np.exp(-6 * (old.points[:, None] - 4.7) ** 2),
        1e-10,
    )
    mu = OneBumpMap.from_density(
        Grid(np.concatenate([[-5.0], old.points, [5.0]])), np.r_[1e-10, f[:, 0], 1e-10], 0.5, 0.5
    )
    new = periodic_map_grid(mu, 61, old.period)
    cut = 0.9  # a vacuum point of every line: the moments are compared in (x - cut) mod P
    moment = lambda g, F: (np.mod(g.points - cut, g.period) * g.h) @ F  # noqa: E731
    plain = remap_periodic(old, f, new)
    kept = remap_periodic(old, f, new, conserve_moment=True)
    np.testing.assert_allclose(new.h @ kept, old.h @ f, rtol=1e-13)
    # the lines' own cuts differ from this one: floor-level mass (1e-9) between them counts P times
    np.testing.assert_allclose(moment(new, kept), moment(old, f), rtol=1e-10, atol=1e-7)
    assert np.abs(moment(new, plain) / moment(old, f) - 1)[:2].max() > 1e-5  # PCHIP alone does not
    assert np.all(kept > 0)
    assert np.abs(kept - plain).max() < 0.05


@pytest.mark.parametrize(
    "r1, r2, delta, kind",
    [
        (2.0, 3.5, 0.5, "quintic"),  # (r2 - r1)/delta = 3 < L: the paper's a3 s^5 + b3 s (concave down here)
        (1.8, 2.2, 0.5, "quintic"),  # 0.8 < L
        (0.3, 2.4, 0.5, "quintic"),  # 4.2 >= L: the paper's logistic cannot join (2.4 -> 4): fallback
    ],
)
def test_two_bump_outer_piece_follows_the_papers_test(r1, r2, delta, kind):
    """``mu2``: the outer piece is a3 s^5 + b3 s iff (r2 - r1)/delta < L (``eqn mu2``), not by slopes."""
    L = 4.0
    mu = TwoBumpMap(L, r1, r2, delta)
    assert mu.outer_kind == kind
    _check_map(mu, L, delta, inside=lambda v: (np.abs(v) >= r1 - 1e-12) & (np.abs(v) <= r2 + 1e-12))
    s2 = 0.5 + delta / 2
    assert mu(s2) == pytest.approx(r2) and mu(s2 + 1e-10) == pytest.approx(r2, abs=1e-8)


def test_two_bump_outer_logistic_where_the_paper_asks_for_it():
    # (r2 - r1)/delta = 4.2 >= L = 4 and L/r2 = 1.05 within the logistic's range (1.083 at s2 = 0.75)
    mu = TwoBumpMap(4.0, 1.7, 3.8, 0.5)
    assert mu.outer_kind == "logistic"
    assert np.all(np.diff(mu(S)) > 0)


def test_energy_restoring_remap_keeps_mass_momentum_second_moment_and_positivity():
    old = OneBumpMap(4.0, 0.05, 0.5).grid(61)  # coarse outer piece: PCHIP changes the energy there
    v = old.points
    f = np.stack([np.exp(-40 * (v - 0.3) ** 2) + 1e-10, np.exp(-3 * (v + 1) ** 2) + 0.2 * np.exp(-30 * (v - 2) ** 2)])
    new = Grid.uniform(-4, 4, 61)

    def moments(grid, g):
        return np.stack([g @ (grid.points**p * grid.h) for p in (0, 1, 2)], axis=-1)

    plain = remap(old, f, new, conserve_momentum=True)
    assert np.abs(moments(new, plain)[:, 2] / moments(old, f)[:, 2] - 1).max() > 1e-6  # the defect
    g = remap(old, f, new, conserve_energy=True)
    assert np.all(g > 0)
    np.testing.assert_allclose(moments(new, g), moments(old, f), rtol=1e-12, atol=1e-14)
    assert np.abs(g - plain).max() < 0.05 * f.max()  # a small correction of the interpolant


def test_three_moment_tilt_reports_an_unreachable_target():
    from jko_cvx.mesh.moments import restore_three_moments

    g = Grid.uniform(-1, 1, 21)
    f = np.exp(-(g.points**2))
    # a second moment above L^2 M cannot be reached on [-1, 1]
    out, ok = restore_three_moments(f[None], g.h, g.points, f @ g.h, 0.0, 2 * f @ g.h)
    assert not ok[0]
    assert out[0] @ g.h == pytest.approx(f @ g.h)


def test_energy_conserving_remap_of_a_narrow_slice_keeps_the_floor():
    """The quadratic tilt of the whole row sent a concentrated slice's floor-level tails far below
    the floor; with the floor passed on, only the mass above it is tilted: the three moments
    are exact and no value is below the paper's floor."""
    old = Grid.uniform(-4.0, 4.0, 81)
    new = Grid(4 * np.sinh(2 * np.linspace(-1, 1, 81)) / np.sinh(2))
    f = np.maximum(np.stack([np.exp(-((old.points - c) ** 2) / (2 * 0.08**2)) for c in (-1.3, 0.2, 2.1)]), 1e-10)
    g = remap(old, f, new, conserve_energy=True)
    assert g.min() >= 1e-10 * (1 - 1e-12)
    for p in (0, 1, 2):
        np.testing.assert_allclose(g @ (new.points**p * new.h), f @ (old.points**p * old.h), rtol=1e-11, atol=1e-11)


def test_quadrant_set_is_the_papers_and_empty_for_the_two_bump_phase_datum():
    from jko_cvx.mesh.maps import quadrant_set

    x = np.linspace(-4, 4, 81)
    v = np.linspace(-4, 4, 81)
    X, V = np.meshgrid(x, v, indexing="ij")
    # eqn:f0-like: bumps at (x, v) = (-1.5, 2) and (1.5, -2): nothing in x > 0, v > 0
    f = np.exp(-6 * (X + 1.5) ** 2 - 6 * (V - 2) ** 2) + np.exp(-6 * (X - 1.5) ** 2 - 6 * (V + 2) ** 2)
    assert quadrant_set(x, v, f, 0.5) is None
    g = np.exp(-6 * (X - 1) ** 2 - 6 * (V - 2) ** 2)
    (x1, x2), (v1, v2) = quadrant_set(x, v, g, 0.5)
    half = np.sqrt(np.log(2) / 6)
    assert x1 == pytest.approx(1 - half, abs=0.1) and x2 == pytest.approx(1 + half, abs=0.1)
    assert v1 == pytest.approx(2 - half, abs=0.1) and v2 == pytest.approx(2 + half, abs=0.1)
    with pytest.raises(ValueError, match="f_star must have shape"):
        quadrant_set(x, v, g[:, :-1], 0.5)


def _phase_scene(c, d, concentration_set, bumps_v=1, t_end=0.1):
    from jko_cvx.scene.model import scene_from_dict

    return scene_from_dict(
        {
            "name": "quadrant",
            "gamma": 3.0,
            "strength": 2.0,
            "t_end": t_end,
            "v": {"L": 3.0, "n": 31},
            "x": {"L": 3.0, "n": 25},
            "initial": {"kind": "two_bump_phase", "a": 4.0, "b": 4.0, "c": c, "d": d},
            "time": {"policy": "fixed", "dt": 0.05},
            "refine": {
                "concentration_set": concentration_set,
                "v": {"bumps": bumps_v, "delta0": 0.5, "delta": 0.5},
                "x": {"bumps": 1, "delta0": 0.5, "delta": 0.5},
            },
            "collision": {"method": "newton", "beta": 100.0, "fisher": "log"},
        }
    )


def _quadrant_extent(x, v, f, delta0):
    """The paper's set by loops (independent of quadrant_set): extents on each axis."""
    top = f.max()
    xs, vs = [], []
    for i, xi in enumerate(x):
        for j, vj in enumerate(v):
            if xi > 0 and vj > 0 and f[i, j] > delta0 * top:
                xs.append(xi)
                vs.append(vj)
    return (min(xs), max(xs)), (min(vs), max(vs))


def test_quadrant_rule_on_eqn_f0_at_t0_keeps_the_uniform_grids():
    """eqn:f0 (bumps at (-c, d), (c, -d)) has no point of its set in x > 0, v > 0: the uniform grids."""
    from jko_cvx.engine.loop import initial_state

    scene = _phase_scene(1.0, 1.0, "quadrant")
    st = initial_state(scene)
    np.testing.assert_array_equal(st.vgrid.points, scene.vgrid().points)
    np.testing.assert_array_equal(st.xgrid.points, scene.xgrid().points)
    np.testing.assert_array_equal(st.f, scene.initial_density(scene.xgrid(), scene.vgrid()))
    # the projections rule refines the same datum (its v-set is {v > 0 : max_x f > delta0 max f})
    assert not np.array_equal(initial_state(_phase_scene(1.0, 1.0, "projections")).vgrid.points, st.vgrid.points)


@pytest.mark.parametrize("bumps_v", [1, 2])
def test_quadrant_rule_builds_each_map_from_the_sets_extent_on_its_axis(bumps_v):
    """c = -1, d = 1 puts a bump at (x, v) = (1, 1): the maps are those of the set's extents (one bump:
    r = its largest point, capped at L delta; two bumps: [min, max], through TwoBumpMap.from_extent)."""
    from jko_cvx.engine.loop import initial_state

    scene = _phase_scene(-1.0, 1.0, "quadrant", bumps_v)
    x, v = scene.xgrid().points, scene.vgrid().points
    f0 = scene.initial_density(scene.xgrid(), scene.vgrid())
    (_, x2), (v1, v2) = _quadrant_extent(x, v, f0, 0.5)
    st = initial_state(scene)
    want_v = OneBumpMap(3.0, min(v2, 1.5), 0.5) if bumps_v == 1 else TwoBumpMap.from_extent(scene.vgrid(), v1, v2, 0.5)
    np.testing.assert_allclose(st.vgrid.points, want_v.grid(31).points, rtol=0, atol=1e-14)
    want_x = periodic_map_grid(OneBumpMap(3.0, min(x2, 1.5), 0.5), 25, 6.0)
    np.testing.assert_allclose(st.xgrid.points, want_x.points, rtol=0, atol=1e-14)
    assert st.f.sum() > 0 and np.all(st.f > 0)


def test_quadrant_rule_reads_the_density_entering_the_collision(monkeypatch):
    """alg:SPMCSL-JKO step 4 takes f*, the density after transport and before the collision: the set
    is built from exactly transport_step(f^n) (computed here on its own), not from f^{n+1}."""
    import jko_cvx.engine.loop as sim
    import jko_cvx.mesh.policy as policy
    from jko_cvx.transport import transport_step

    scene = _phase_scene(-1.0, 1.0, "quadrant", t_end=0.05)
    st = sim.initial_state(scene)
    want = transport_step(st.xgrid, st.vgrid.points, st.f, 0.05, conserve_moment=scene.x.conserve_moment)
    seen = []
    real = policy.quadrant_set
    monkeypatch.setattr(policy, "quadrant_set", lambda x, v, f, d0: seen.append(np.array(f)) or real(x, v, f, d0))
    stepper = sim.Stepper(scene)
    out = stepper.solve(st)
    assert out.ok
    stepper.commit(st, out)
    assert len(seen) == 2  # one per refined axis
    for f in seen:
        np.testing.assert_array_equal(f, want)
    assert not np.allclose(out.f, want)  # the collision changed it: the test tells them apart


def test_quadrant_rule_state_survives_a_checkpoint_and_resumes_bit_for_bit(tmp_path):
    """The 'uniform grid' extent of an empty quadrant set must read back as itself: a resumed run then
    takes exactly the steps of the uninterrupted one (no extra remap on the uniform grids)."""
    import jko_cvx.engine.loop as sim

    scene = _phase_scene(1.0, 1.0, "quadrant", t_end=0.15)
    st = sim.initial_state(scene)
    stepper = sim.Stepper(scene)
    out = stepper.solve(st)
    stepper.commit(st, out)  # one step: the set is still empty, the grids uniform
    st.rows.append({"dt": out.dt})  # the diagnostics row the loop's tracker would add
    st.save(tmp_path / "ck.npz", {"scene_sha256": "x", "jko_cvx": "y"})
    back, _ = type(st).load(tmp_path / "ck.npz", scene.xgrid().period)
    for a, b in ((st.v_params, back.v_params), (st.x_params, back.x_params)):
        assert a is not None and b is not None
        np.testing.assert_array_equal(a, b)
    for s in (st, back):
        stepper.commit(s, stepper.solve(s))
    np.testing.assert_array_equal(st.f, back.f)
    np.testing.assert_array_equal(st.vgrid.points, back.vgrid.points)


@pytest.mark.parametrize(
    "bad, match",
    [
        ({"f": "nan"}, "f must be finite"),
        ({"floor": -1e-10}, "floor must be a finite number >= 0"),
        ({"floor": float("nan")}, "floor must be a finite number >= 0"),
        ({"f": "short"}, "f must have length 41 along axis 0"),
        ({"new": "other period"}, "new must have the period of old"),
        ({"new": "not a grid"}, "old and new must be jko_cvx.PeriodicGrid"),
    ],
)
def test_periodic_remap_refuses_bad_input_before_any_work(bad, match):
    """As remap: non-finite f, a negative or NaN floor, a wrong length, another period or another
    grid type is refused, naming the argument (before: NaN went through PCHIP into the result,
    a negative floor let negative densities through, another period was remapped silently)."""
    old = PeriodicGrid.uniform(5.0, 41)
    f = np.exp(-(old.points[:, None] ** 2)) * np.ones((1, 3)) + 1e-10
    new = PeriodicGrid.uniform(5.0, 41)
    kwargs = {"floor": bad.get("floor", 1e-10)}
    if bad.get("f") == "nan":
        f[3, 1] = np.nan
    elif bad.get("f") == "short":
        f = f[:-1]
    if bad.get("new") == "other period":
        new = PeriodicGrid(old.points * 1.1, 11.0)
    elif bad.get("new") == "not a grid":
        new = Grid(old.points)
    with pytest.raises((ValueError, TypeError), match=match):
        remap_periodic(old, f, new, **kwargs)


def test_remesh_policy_refuses_an_unknown_concentration_set():
    from jko_cvx.mesh import RemeshPolicy

    with pytest.raises(ValueError, match=r"concentration_set must be one of \['projections', 'quadrant'\]"):
        RemeshPolicy(None, None, 2.0, concentration_set="everywhere")
