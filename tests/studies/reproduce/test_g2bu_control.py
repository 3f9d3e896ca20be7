"""The tab:g2bu control (quick form): one lambda below the threshold, one above, and what the report
says about them is read from the runs, not typed."""

import pandas as pd

from jko_cvx.studies.reproduce.g2bu_control import THRESHOLD, reproduce_tab_g2bu_control


def test_the_quick_control_runs_across_the_threshold_and_reports_it(tmp_path):
    table = reproduce_tab_g2bu_control(tmp_path, quick=True, executor="serial", progress=False)
    assert 309 < THRESHOLD < 310
    assert list(table["lambda"]) == [100.0, 310.0] and list(table["above threshold"]) == [False, True]
    assert set(table.verdict) <= {"blow-up", "no blow-up", "undetermined"}
    above = table[table["above threshold"]].iloc[0]
    # at 310 the datum concentrates in x before t = 0.12 on this grid (tab:g2bu: 0.0985 at 121 x 201)
    assert above.verdict == "blow-up" and above.direction == "x" and 0.08 < above.T_b < 0.12
    # the fit's columns, beside the paper's T_b: the rate a only where the fit locates a time
    assert {"T_b_fit", "T_b_fit_err", "blowup_rate", "blowup_kind"} <= set(table.columns)
    located = table.T_b_fit.notna()
    assert table.blowup_rate[located].gt(0).all() and table.blowup_rate[~located].isna().all()
    shipped = pd.read_csv(tmp_path / "tab_g2bu_control.csv")
    pd.testing.assert_frame_equal(shipped, table.reset_index(drop=True), check_dtype=False)
    md = (tmp_path / "tab_g2bu_control.md").read_text()
    fired = int((table[~table["above threshold"]].verdict == "blow-up").sum())
    assert f"the criterion fired in {fired} of them" in md and "*Environment: jko_cvx" in md
