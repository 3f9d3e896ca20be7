"""Maps that place their sets where the bumps are: two bumps in v, one or two on the periodic x-axis
(``jko_cvx.mesh.following``), through the remeshing policy, and an asymmetric two-bump blow-up found where it forms."""

import numpy as np
import pytest

from jko_cvx.engine.loop import simulate
from jko_cvx.exact import GaussianMixture, blowup_time_gamma1
from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.mesh.following import ClusterMap, concentration_clusters, periodic_following_grid
from jko_cvx.mesh.maps import OneBumpMap, periodic_map_grid
from jko_cvx.mesh.policy import RefineSpec, RemeshPolicy
from jko_cvx.scene import shipped_scene
from jko_cvx.scene.model import _resolve_centre


def _inside(points, sets, period=None):
    d = [np.abs(points - c) if period is None else np.minimum(np.abs(points - c), period - np.abs(points - c))
         for c, _ in sets]  # fmt: skip
    return np.any([di <= r for di, (_, r) in zip(d, sets, strict=True)], axis=0)


@pytest.mark.parametrize("n", [61, 121, 481])
@pytest.mark.parametrize("sets", [((-1.0, 0.1), (0.5, 0.05)), ((0.097, 0.02),), ((-2.0, 0.5), (2.0, 0.5))])
def test_the_sets_hold_delta_of_the_points_evenly_spaced_and_the_grid_grades_smoothly(sets, n):
    mu = ClusterMap(4.0, sets, 0.5)
    v = mu.grid(n).points
    assert v[0] == -4.0 and v[-1] == 4.0 and np.all(np.diff(v) > 0)
    inside = _inside(v, sets)
    assert abs(inside.sum() / n - 0.5) <= 2.5 / n + 0.01  # delta N points, up to the cells cut by the set ends
    h = np.diff(v)
    both = inside[1:] & inside[:-1]  # spacings with both ends inside one set: K is constant there
    for c, r in sets:
        in_set = both & (np.abs(v[1:] - c) <= r)
        assert np.ptp(h[in_set]) <= 1e-2 * h[in_set].mean()  # the monitor read off samples: measured <= 1.3e-3
    ratio = np.exp(np.abs(np.diff(np.log(h)))).max()
    paper = OneBumpMap(4.0, min(r for _, r in sets), 0.5).grid(n).points
    assert ratio < np.exp(np.abs(np.diff(np.log(np.diff(paper))))).max()  # gentler than the paper's mu1 at its edge
    assert ratio < 1 + 600 / n  # 1 + O(1/N): measured 4.9, 2.4, 1.26 at N = 61, 121, 481


def test_a_set_wider_than_its_share_gives_the_uniform_grid():
    mu = ClusterMap(4.0, ((0.0, 3.0),), 0.5)
    assert mu.K == 1.0
    assert np.allclose(mu.grid(81).points, np.linspace(-4, 4, 81), rtol=0, atol=1e-12)


@pytest.mark.parametrize(("kw", "match"), [
    ({"sets": ()}, "at least one"), ({"sets": ((4.5, 0.1),)}, "each set"), ({"sets": ((0.0, 0.0),)}, "each set"),
    ({"delta": 1.0}, "delta"), ({"L": -1.0}, "L must"),
])  # fmt: skip
def test_bad_cluster_maps_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        ClusterMap(**{"L": 4.0, "sets": ((0.0, 0.1),), "delta": 0.5, **kw})


def test_the_periodic_following_grid_is_the_paper_grid_rotated():
    L, n, r = 5.0, 81, 0.4
    base = periodic_map_grid(OneBumpMap(L=L, r=r, delta=0.5), n, 2 * L)
    assert np.array_equal(periodic_following_grid(L, 0.0, r, 0.5, n).points, base.points)
    for c in (1.3, 4.8, -4.9):
        g = periodic_following_grid(L, c, r, 0.5, n)
        assert isinstance(g, PeriodicGrid) and g.points[0] >= -L and g.points[-1] < L
        # the same cell widths, cyclically shifted; the refined set sits about c (wrapping round the ends)
        k = int(np.argmin(np.abs(((g.points - c + L) % (2 * L)) - L - base.points[0])))
        assert np.allclose(np.roll(g.h, -k), base.h, rtol=0, atol=1e-12)
        assert _inside(g.points, [(c, r)], 2 * L).sum() == _inside(base.points, [(0.0, r)]).sum()


def test_clusters_are_found_where_the_bumps_are_and_across_the_periodic_wrap():
    v = Grid.uniform(-2.0, 2.0, 401).points
    f = np.exp(-(((v - 0.5) / 0.05) ** 2)) + 0.8 * np.exp(-(((v + 1.0) / 0.1) ** 2)) + 0.1 * np.exp(-((v - 1.5) ** 2))
    (c1, r1), (c2, r2) = concentration_clusters(v, f, 0.5, 2)
    assert (c1, c2) == pytest.approx((-1.0, 0.5), abs=0.01)
    assert r1 == pytest.approx(0.1 * np.sqrt(np.log(1.6)), abs=0.02)
    assert r2 == pytest.approx(0.05 * np.sqrt(np.log(2)), abs=0.011)
    assert len(concentration_clusters(v, f, 0.5, 1)) == 1 and concentration_clusters(v, f, 0.5, 1)[0][0] == c2
    x = PeriodicGrid.uniform(5.0, 100)
    d = np.minimum(np.abs(x.points - 4.9), 10 - np.abs(x.points - 4.9))  # a bump straddling x = +-5
    (c, r), = concentration_clusters(x.points, np.exp(-4 * d**2), 0.5, 2, period=10.0)
    assert c == pytest.approx(4.9, abs=0.051) and r == pytest.approx(np.sqrt(np.log(2) / 4), abs=0.11)


def _phase(x, v, xc, vc):
    return np.exp(-6 * (x[:, None] - xc) ** 2 - 6 * (v[None, :] - vc) ** 2)


@pytest.mark.parametrize("bumps", [1, 2])
def test_the_policy_refines_x_where_the_bump_is_and_keeps_the_mass(bumps):
    xg, vg = PeriodicGrid.uniform(5.0, 101), Grid.uniform(-5.0, 5.0, 61)
    f = _phase(xg.points, vg.points, 3.7, 0.0) + (0.9 * _phase(xg.points, vg.points, -1.2, 1.0) if bumps == 2 else 0)
    policy = RemeshPolicy(None, RefineSpec(bumps=bumps, centre="follow"), 5.0, 5.0)
    g, _, xnew, _, extent = policy.refine(vg, xg, f, None, None, None)
    assert extent.size == 2 * bumps
    fine = xnew.h < 0.5 * xg.h.mean()
    centres = (3.7, -1.2)[:bumps]
    for c in centres:  # each bump sits in the refined part
        assert fine[np.argmin(np.abs(xnew.points - c))]
    assert not fine[np.argmin(np.abs(xnew.points - 0.0 if bumps == 1 else xnew.points - 1.3))]
    mass = lambda h, f: float((h[:, None] * f).sum())  # noqa: E731
    assert mass(xnew.h, g) == pytest.approx(mass(xg.h, f), rel=1e-12)
    # the paper's maps refine about 0 (one bump) or +-[r1, r2] from the positive half-axis (two): not at -1.2
    origin = RemeshPolicy(None, RefineSpec(bumps=bumps), 5.0, 5.0).refine(vg, xg, f, None, None, None)[2]
    c = centres[-1]
    assert origin.h[np.argmin(np.abs(origin.points - c))] > 2 * xnew.h[np.argmin(np.abs(xnew.points - c))]


def test_the_policy_places_two_velocity_sets_on_asymmetric_bumps():
    vg = Grid.uniform(-2.0, 2.0, 121)
    f = np.exp(-30 * (vg.points + 0.9) ** 2) + 0.7 * np.exp(-60 * (vg.points - 0.35) ** 2)
    _, grid, _, extent, _ = RemeshPolicy(RefineSpec(bumps=2, centre="follow"), None, 2.0).refine(
        vg, None, f, None, None, None
    )
    h = np.diff(grid.points)
    mid = 0.5 * (grid.points[1:] + grid.points[:-1])
    for c in (-0.9, 0.35):
        assert h[np.argmin(np.abs(mid - c))] < 0.3 * vg.h.mean()
    assert extent.size == 4 and extent[0] < -0.9 < extent[1] < extent[2] < 0.35 < extent[3]


def test_auto_follows_on_x_where_max_v_f0_is_not_even_in_x():
    sc = shipped_scene("inhom_gamma1p5_before")
    x, v = sc.xgrid().points, sc.vgrid().points
    even = _phase(x, v, -2.5, 2.5) + _phase(x, v, 2.5, -2.5)
    assert _resolve_centre(sc, even, ("v", "x")).refine == sc.refine  # the paper's datum: both maps at 0
    moved = _phase(x, v, x[20], 2.5) + _phase(x, v, x[90], -2.5)  # both bumps on grid points: max_x f0 even in v
    shifted = _resolve_centre(sc, moved, ("v", "x")).refine
    assert (shifted.x.centre, shifted.v.centre) == ("follow", "origin")
    assert _resolve_centre(sc, moved, ("v",)).refine.x.centre == "origin"  # x given as origin: kept


def test_an_asymmetric_two_bump_blowup_is_found_where_it_forms():
    """gamma = 1, f0 = e^{-6(v + 0.5)^2} + 0.7 e^{-3(v - 0.6)^2}: exact T = 1/(2 max f0) = 0.4906, the delta at
    v = -0.151 (the characteristic of the maximum, v0 + (M - 2 F0(v0)) T)."""
    ic = {"initial.amplitudes": [1.0, 0.7], "initial.rates": [6.0, 3.0], "initial.centres": [-0.5, 0.6]}
    scene = {**ic, "t_end": 1.0, "refine.v.bumps": 2, "time.dt": 0.0025}
    g = GaussianMixture([1.0, 0.7], [6.0, 3.0], [-0.5, 0.6], -2.0, 2.0)
    T = blowup_time_gamma1(g)
    vs = np.linspace(-2, 2, 400001)
    v0 = vs[np.argmax(g.pdf(vs))]
    v_star = v0 + (g.mass - 2 * g.cdf(v0)) * T
    follow = shipped_scene("tab_bu_g1", scene)
    assert follow.refine.v == RefineSpec(bumps=2, centre="follow")  # auto: max f0 is not even in v
    run = simulate(follow)
    assert run.blowup and abs(run.verdict.T_b - T) <= 0.03  # measured 0.51
    last = run.diagnostics.iloc[-1]
    assert last.max_f > 10 * g.max
    assert abs(run.vgrid.points[np.argmax(run.f)] - v_star) < 0.02
    # the paper's two-bump map, symmetric about 0, fires its threshold long before any concentration
    centred = simulate(shipped_scene("tab_bu_g1", {**scene, "refine.v.centre": "origin"}))
    assert centred.verdict.T_b < 0.7 * T and centred.diagnostics.max_f.max() < 3 * g.max  # measured 0.31, 2.4


def test_an_inhomogeneous_run_with_both_axes_following_keeps_the_mass_and_refines_at_the_density_peaks():
    over = {"v.n": 41, "x.n": 41, "t_end": 0.1, "output.times": []}
    follow = {"refine.x.centre": "follow", "refine.x.bumps": 2, "refine.v.centre": "follow"}
    run = simulate(shipped_scene("inhom_gamma1p5_before", {**over, **follow}))
    assert run.verdict.reason == "reached t_end"
    mass = run.diagnostics.mass
    assert abs(mass.iloc[-1] - mass.iloc[0]) <= 1e-12 * mass.iloc[0]
    rho = run.f @ run.vgrid.h
    h = run.xgrid.h
    x = run.xgrid.points
    for half in (x < 0, x > 0):  # a bump on each side
        peak = int(np.argmax(np.where(half, rho, -1.0)))
        assert h[peak] < 0.6 * h.mean()


def _offcentre_scene(centre: str, x: bool):
    """gamma = 1, f0(x, v) = exp(-2 (v - 0.3)^2) on every x-cell: the transport term vanishes on an x-independent
    density, so each x-slice solves the homogeneous equation, whose blow-up time is 1 / (2 max f0) = 0.5 (exact),
    with the delta away from v = 0."""
    from jko_cvx.scene import scene_from_dict

    d = {
        "name": "offcentre", "gamma": 1.0, "strength": 1.0, "t_end": 0.8, "v": {"L": 2.0, "n": 121},
        "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.3]},
        "time": {"policy": "fixed", "dt": 0.01},
        "refine": {"v": {"bumps": 1, "delta0": 0.5, "delta": 0.5, "centre": centre}},
        "collision": {"method": "newton", "beta": 6000.0, "fisher": "log"},
        "stop": {"eps_v": 2.5e-4, "on_solver_failure": False},
    }  # fmt: skip
    return scene_from_dict({**d, "x": {"L": 1.0, "n": 8}} if x else d)


def test_an_inhomogeneous_blowup_away_from_v0_is_found_by_the_map_that_follows_it_and_missed_by_the_centred_one():
    follow = simulate(_offcentre_scene("auto", x=True))
    assert follow.scene.refine.v.centre == "follow"  # auto: max_x f0 is not even in v
    v = follow.verdict
    assert follow.blowup and abs(v.T_b - 0.5) <= 0.03  # measured 0.48
    assert v.blowup_kind == "finite_time" and abs(v.T_b_fit - 0.5) <= v.T_b_fit_err  # measured 0.497 +- 0.010
    assert abs(follow.vgrid.points[np.argmax(follow.f[0])] - 0.3) < 0.02  # the delta, where it forms
    # the exact reduction: every x-slice is the homogeneous run's density (to rounding), with its verdict
    hom = simulate(_offcentre_scene("auto", x=False))
    assert np.abs(follow.f - follow.f[0]).max() <= 1e-10 * follow.f.max()
    assert np.array_equal(follow.vgrid.points, hom.vgrid.points)
    assert np.abs(follow.f[0] - hom.f).max() <= 1e-10 * hom.f.max()
    assert (v.T_b, v.blowup_kind) == (hom.verdict.T_b, hom.verdict.blowup_kind)
    assert v.T_b_fit == pytest.approx(hom.verdict.T_b_fit, abs=1e-8)
    # the paper's map centred at v = 0 never reaches eps_v: no threshold time, and the verdict says max f grew
    centred = simulate(_offcentre_scene("origin", x=True))
    c = centred.verdict
    assert not centred.blowup and c.T_b is None and c.unflagged_growth is not None and c.unflagged_growth > 20
    assert "no blow-up rule fired" in centred.summary()  # measured: max f grew by 87, min dv 0.0101
