"""Entries drawn from another entry's sweep point.

``g2bu_records`` is ``tab_g2bu``'s lambda = 310 run; ``ibu_panels`` is ``ibu``'s run.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from jko_cvx.reproduce import g2bu, panels
from jko_cvx.reproduce.g2bu import RECORDS, g2bu_scene
from jko_cvx.simulate import simulate


def test_the_records_are_the_runs_diagnostics(tmp_path):
    panels.reproduce_g2bu_records(tmp_path, quick=True, executor="serial", progress=False)
    ours = pd.read_csv(tmp_path / "g2bu_records.csv")
    run = simulate(g2bu_scene(310.0, t_end=0.05))
    want = run.diagnostics[list(RECORDS)]
    assert list(ours.columns) == list(RECORDS) and len(ours) == len(want) > 10
    for col in RECORDS:
        np.testing.assert_array_equal(ours[col].to_numpy(), want[col].to_numpy(), err_msg=col)
    assert f"verdict: {run.verdict['reason']} at t = {run.t:.5g}" in (tmp_path / "g2bu_records.md").read_text()


def test_the_full_form_asks_for_tab_g2bus_point(monkeypatch, tmp_path):
    """In one section run the shared pool computes the lambda = 310 run once for both entries."""
    asked = {}

    def sweep(func, points, cache, desc, **kwargs):
        asked[desc] = [(func, p) for p in points]
        raise _Stop

    monkeypatch.setattr(panels, "run_sweep", sweep)
    monkeypatch.setattr(g2bu, "run_sweep", sweep)
    for entry in (panels.reproduce_g2bu_records, g2bu.reproduce_tab_g2bu):
        with pytest.raises(_Stop):
            entry(tmp_path)
    assert len(asked["g2bu_records"]) == 1 and asked["g2bu_records"][0] in asked["tab_g2bu"]


class _Stop(Exception):
    pass


def test_ibu_and_ibu_panels_ask_for_one_point(monkeypatch, tmp_path):
    """``fig:gk3``'s panels are drawn from ``ibu``'s run: one sweep point, which a section run computes once."""
    from jko_cvx.reproduce import ibu

    asked = {}

    def sweep(func, points, cache, desc, **kwargs):
        asked[desc] = [(func, p) for p in points]
        raise _Stop

    monkeypatch.setattr(ibu, "run_sweep", sweep)
    for entry in (ibu.reproduce_ibu, panels.reproduce_ibu_panels):
        with pytest.raises(_Stop):
            entry(tmp_path)
    assert asked["ibu"] == asked["ibu_panels"] and len(asked["ibu"]) == 1
