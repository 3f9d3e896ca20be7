"""A first-order run whose concentration moves: the verdict warns that the fitted time lags (not in its bar)."""

import numpy as np

from jko_cvx import shipped_scene, simulate
from jko_cvx.diagnostics import diagnostics
from jko_cvx.engine.verdict import moved
from jko_cvx.grid import Grid, PeriodicGrid

APART = {"initial.amplitudes": [1.0, 1.0], "initial.rates": [8.0, 8.0], "initial.centres": [-0.8, 0.8],
         "v.n": 241, "time.dt": 0.005, "t_end": 0.8}  # fmt: skip


def test_the_diagnostics_record_where_f_is_largest():
    vg = Grid.uniform(-2.0, 2.0, 81)
    f = np.exp(-8 * (vg.points - 0.55) ** 2)
    assert diagnostics(vg, f)["v_at_max"] == vg.points[int(np.argmax(f))]
    xg = PeriodicGrid.uniform(1.0, 8)
    F = np.outer(np.linspace(1, 2, xg.n), f)  # the largest value on the last x-slice, at the same v
    assert diagnostics(vg, F, xg)["v_at_max"] == vg.points[int(np.argmax(f))]


def test_a_first_order_run_with_a_moving_concentration_is_flagged_and_a_second_order_one_is_not():
    """Two bumps at -0.8 and 0.8 (exact T = 0.5) move towards the centre as they concentrate: with first-order
    steps T_b_fit comes late by more than its bar (measured 0.560 +- 0.033) and the verdict says why; with
    second-order steps (0.5006 +- 0.0048) there is no such warning.  A still peak (g1) is not flagged."""
    first = simulate(shipped_scene("tab_bu_g1", APART)).verdict
    assert first.blowup_kind == "finite_time" and abs(first.T_b_fit - 0.5) > first.T_b_fit_err
    assert "moved" in first.blowup_reason and "time.order = 2" in first.blowup_reason
    assert "WARNING" in first.describe_fit()
    second = simulate(shipped_scene("tab_bu_g1", {**APART, "time.order": 2})).verdict
    assert "moved" not in second.blowup_reason and "WARNING" not in second.describe_fit()
    still = simulate(shipped_scene("tab_bu_g1")).verdict
    assert still.blowup_kind == "finite_time" and "moved" not in still.blowup_reason


def test_a_switch_between_mirror_bumps_is_no_motion_and_their_travel_is():
    """The place of max f jumping between two mirror bumps (rounding decides which holds the maximum) is no motion;
    the bumps' own travel is: tab_bu_g4 refined (bumps moving in from -+1.5, exact T = 0.5) is flagged with
    first-order steps, where its bar does not cover the exact time (measured 0.5764 +- 0.056), and not with
    second-order steps."""
    rows = [{"t": 0.01 * k, "v_at_max": 1.3 * (-1) ** (k // 3), "min_dv": 1e-3} for k in range(30)]
    assert moved(rows, (0, 30), 40.0) is None  # switches only
    rows = [{"t": 0.01 * k, "v_at_max": (-1) ** (k // 3) * (1.3 - 0.01 * k), "min_dv": 1e-3} for k in range(30)]
    assert "moved" in moved(rows, (0, 30), 40.0)  # 10 spacings a step, a quarter of the set, switches and all
    first = simulate(shipped_scene("tab_bu_g4", {"v.n": 161, "time.dt": 0.004})).verdict
    assert "moved" in first.blowup_reason and abs(first.T_b_fit - 0.5) > first.T_b_fit_err
    second = simulate(shipped_scene("tab_bu_g4", {"v.n": 161, "time.dt": 0.004, "time.order": 2})).verdict
    assert "moved" not in second.blowup_reason and abs(second.T_b_fit - 0.5) <= second.T_b_fit_err
