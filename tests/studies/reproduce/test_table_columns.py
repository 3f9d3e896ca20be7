"""One run per column of ``tab:bu`` / ``tab:bu_tb2`` / the beta scan (``blowup_tables.blowup_times``).

eps_v only decides when a run stops, so the run at the smallest eps_v holds the runs at
the larger ones as prefixes.  The entries read off it must be those of the separate runs
(:func:`blowup_time`), bit for bit; the replay of the stop must follow the time loop's
rules (the initial row is never tested, NaN never fires, a run that stopped first on
another rule or at t_end stops there at every eps_v).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from jko_cvx.engine.verdict import StopReason, Verdict
from jko_cvx.studies.reproduce import beta_scan, blowup_tables
from jko_cvx.studies.reproduce.blowup_tables import (
    blowup_time,
    blowup_times,
    replayed_entry,
    table_entries,
    table_points,
)

from .test_shared_runs import asked_points

INF = float("inf")


def _same(a: float, b: float) -> bool:
    return a == b or (math.isnan(a) and math.isnan(b))


@pytest.mark.parametrize(
    ("data", "dt", "beta", "eps"),
    [
        # beta = inf: the largest eps_v fires after 23 steps; the smaller ones never fire,
        # through 30 steps with failed slices, to t = 2 T
        ("g1", 0.02, INF, (1e-3, 2.5e-4, 6.25e-5)),
        ("g3", 0.02, INF, (2.5e-4, 1e-3)),  # listed out of order: each entry keeps its place
        ("g1", 0.02, 6000.0, (1e-3, 1e-3 / 16)),
    ],
)
def test_each_entry_of_a_column_is_the_separate_runs(data, dt, beta, eps):
    column = blowup_times(data, list(eps), dt, beta)
    assert column["eps_v"] == list(eps)
    for i, e in enumerate(eps):
        alone = blowup_time(data, e, dt, beta)
        assert _same(column["T_b"][i], alone["T_b"]), (e, column["T_b"][i], alone["T_b"])
        assert (column["steps"][i], column["failed_steps"][i]) == (alone["steps"], alone["failed_steps"])
        # the fit of the records up to the replayed stop is the separate run's fit
        assert column["blowup_kind"][i] == alone["blowup_kind"]
        assert _same(column["T_b_fit"][i], alone["T_b_fit"]) and _same(column["T_b_fit_err"][i], alone["T_b_fit_err"])
        assert _same(column["blowup_rate"][i], alone["blowup_rate"])  # the rate a stands beside T_b_fit
    # the column holds different stops, or the test would not tell a prefix from the whole run
    assert len(set(column["steps"])) > 1


def _records(min_dv, failed, dt=0.1):
    n = len(min_dv)
    return pd.DataFrame({"t": dt * np.arange(n), "min_dv": min_dv, "failed": failed})


def test_the_replay_tests_the_rows_of_accepted_steps_only_and_nan_never_fires():
    # row 0 (the initial state) lies below every threshold: the loop never tests it
    d = _records([1e-9, 1e-3, np.nan, 4e-4, 2e-4, 5e-5], [0, 1, 1, 0, 1, 0])
    ran = Verdict().stopped(StopReason.EPS_V, 0.5, "min dv = 5e-05 < eps_v")  # the run at 1e-4
    assert replayed_entry(d, ran, 5e-4) == {"T_b": 0.30000000000000004, "steps": 3, "failed_steps": 2}
    assert replayed_entry(d, ran, 2e-4) == {"T_b": 0.5, "steps": 5, "failed_steps": 3}  # 2e-4 is not < 2e-4
    assert replayed_entry(d, ran, 1e-4) == {"T_b": 0.5, "steps": 5, "failed_steps": 3}


@pytest.mark.parametrize(
    ("verdict", "T_b"),
    [
        # a solver failure stops a run at the end of the failing step, which has no row
        (Verdict().stopped(StopReason.SOLVER_FAILURE, 0.35, "collision solver failed"), 0.35),
        (Verdict().stopped(StopReason.EPS_V, 0.3, "min dv = 1e-13 < 1e-12 L_v"), 0.3),  # UnresolvedV
        (Verdict().stopped(StopReason.SPREAD_V, 0.3, "min spread_v = 0.01 < spread_v"), 0.3),
        (Verdict(), float("nan")),  # reached t_end
    ],
)
def test_a_run_that_stopped_first_on_another_rule_stops_there_at_every_eps(verdict, T_b):
    d = _records([0.1, 1e-3, 6e-4, 5e-4], [0, 1, 0, 1])
    assert replayed_entry(d, verdict, 1e-4) == pytest.approx({"T_b": T_b, "steps": 3, "failed_steps": 2}, nan_ok=True)
    # a larger eps_v that fires before the stop still stops where it fires
    assert replayed_entry(d, verdict, 7e-4) == {"T_b": 0.2, "steps": 2, "failed_steps": 1}


@pytest.mark.parametrize("eps", [[], [1e-3, -1e-4], [1e-3, 1e-3], [np.nan], [0.0], [INF]])
def test_thresholds_are_checked_before_any_run(eps, monkeypatch):
    monkeypatch.setattr(blowup_tables, "simulate", lambda *a, **k: pytest.fail("ran"))
    with pytest.raises(ValueError, match="eps_v must be distinct positive finite"):
        blowup_times("g1", eps, 0.02)


def test_entries_come_in_the_tables_order():
    eps, dts = (1e-3, 5e-4, 2.5e-4), (0.02, 0.01)
    points = [p for b in (1000.0, INF) for p in table_points(("g1", "g3"), eps, dts, b)]
    runs = pd.DataFrame(
        [
            {**p, "T_b": [hash((p["beta"], p["data"], p["dt"], e)) % 97 for e in eps], "steps": [1, 2, 3]}
            | {"failed_steps": [0, 0, 1], "seconds": 1.5, "cached": False}
            for p in points  # run_sweep's rows come in point order: data, then dt
        ]
    )
    entries = table_entries(runs)
    want = [(b, d, e, t) for b in (1000.0, INF) for d in ("g1", "g3") for e in eps for t in dts]
    assert list(zip(entries.beta, entries.data, entries.eps_v, entries["dt"], strict=True)) == want
    for row in entries.itertuples():
        assert row.T_b == hash((row.beta, row.data, row.dt, row.eps_v)) % 97
        assert row.steps == 1 + eps.index(row.eps_v)


def test_tab_bu_asks_for_the_beta_scans_points_in_the_same_form(monkeypatch, tmp_path):
    """A pool shared by the section runs a point once only if both entries ask for the same point."""
    entries = (blowup_tables.reproduce_tab_bu, beta_scan.reproduce_tab_bu_beta_scan)
    asked = asked_points(monkeypatch, tmp_path, (blowup_tables, beta_scan), entries)
    scan = asked["beta scan"]
    assert len(asked["tab_bu"]) == 15 and len(scan) == 15 * len(beta_scan.BETAS)
    assert all(pair in scan for pair in asked["tab_bu"])


def test_a_bar_too_wide_leaves_the_kind_undetermined_not_no_finite_time():
    """tab:bu_tb2's two-bump g4 (gamma = 1, exact T = 0.5) at dt = 0.01: the power law beats the
    exponential and its T lies inside the horizon, but the window choices move T by more than a
    quarter of the horizon: nothing excludes the collapse, so the kind is undetermined."""
    from jko_cvx.blowup import fit_blowup
    from jko_cvx.engine.loop import simulate
    from jko_cvx.studies.reproduce.blowup_tables import TAB_BU_TB2_BETA, blowup_scene

    run = simulate(blowup_scene("g4", 1e-3, 0.01, TAB_BU_TB2_BETA))
    d = run.diagnostics
    fit = fit_blowup(d.t.to_numpy(), d.max_f.to_numpy(), certified=(d.failed == 0).to_numpy())
    assert fit.blowup_kind == "undetermined", fit.reason
    assert fit.reason.startswith("error bar wider than a quarter of the horizon:")
    assert fit.T_b_fit_err > abs(fit.T_b_fit - 0.5)  # the honest bar covers the exact time


def test_threshold_columns_extrapolate_each_column_to_eps_zero():
    """Synthetic columns T_b = T0 - c eps^p (+ the step's rounding): T_0 is recovered per (beta, data, dt), the
    same value on each entry of the column; a column with fewer than three fired thresholds gets NaN."""
    eps = np.array([1e-3, 5e-4, 2.5e-4, 1.25e-4, 6.25e-5])
    rows = []
    for data, T0, c, p in (("g1", 0.5, 2.0, 0.5), ("g3", 0.125, 0.8, 0.7)):
        for dt in (0.01, 0.005):
            for e in eps:
                rows.append({"beta": 6000.0, "data": data, "dt": dt, "eps_v": e, "T_b": T0 - c * e**p})
    rows.append({"beta": 6000.0, "data": "g2", "dt": 0.01, "eps_v": 1e-3, "T_b": 0.2})
    rows.append({"beta": 6000.0, "data": "g2", "dt": 0.01, "eps_v": 5e-4, "T_b": float("nan")})
    df = blowup_tables.threshold_columns(pd.DataFrame(rows))
    T0, err = blowup_tables.THRESHOLD_COLUMNS
    for data, exact in (("g1", 0.5), ("g3", 0.125)):
        for dt in (0.01, 0.005):
            col = df[(df.data == data) & (df.dt == dt)]
            assert col[T0].nunique() == 1 and abs(col[T0].iloc[0] - exact) < 1e-6 and col[err].iloc[0] > 0
    assert df[df.data == "g2"][T0].isna().all()
