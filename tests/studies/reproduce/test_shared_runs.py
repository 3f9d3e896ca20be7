"""Entries drawn from another entry's sweep point.

``g2bu_records`` is ``tab_g2bu``'s lambda = 310 run; ``ibu_panels`` is ``ibu``'s run.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from jko_cvx.engine.loop import simulate
from jko_cvx.studies.reproduce import g2bu, panels
from jko_cvx.studies.reproduce.g2bu import RECORDS, g2bu_scene


def test_the_records_are_the_runs_diagnostics(tmp_path):
    panels.reproduce_g2bu_records(tmp_path, quick=True, executor="serial", progress=False)
    ours = pd.read_csv(tmp_path / "g2bu_records.csv")
    run = simulate(g2bu_scene(310.0, t_end=0.05))
    want = run.diagnostics[list(RECORDS)]
    assert list(ours.columns) == list(RECORDS) and len(ours) == len(want) > 10
    for col in RECORDS:
        np.testing.assert_array_equal(ours[col].to_numpy(), want[col].to_numpy(), err_msg=col)
    assert f"verdict: {run.verdict['reason']} at t = {run.t:.5g}" in (tmp_path / "g2bu_records.md").read_text()


def asked_points(monkeypatch, tmp_path, modules, entries) -> dict[str, list]:
    """The (function, point) pairs each entry asks ``run_sweep`` for, by progress label; no point runs.

    ``modules``: where the entries look ``run_sweep`` up.  A section run computes a point
    two entries share once only if both ask for the same function and point.
    """
    asked: dict[str, list] = {}

    class Stop(Exception):
        pass

    def sweep(func, points, cache, desc, **kwargs):
        asked[desc] = [(func, p) for p in points]
        raise Stop

    for module in modules:
        monkeypatch.setattr(module, "run_sweep", sweep)
    for entry in entries:
        with pytest.raises(Stop):
            entry(tmp_path)
    return asked


def test_the_full_form_asks_for_tab_g2bus_point(monkeypatch, tmp_path):
    """In one section run the shared pool computes the lambda = 310 run once for both entries."""
    asked = asked_points(
        monkeypatch, tmp_path, (panels, g2bu), (panels.reproduce_g2bu_records, g2bu.reproduce_tab_g2bu)
    )
    assert len(asked["g2bu_records"]) == 1 and asked["g2bu_records"][0] in asked["tab_g2bu"]


def test_ibu_and_ibu_panels_ask_for_one_point(monkeypatch, tmp_path):
    """``fig:gk3``'s panels are drawn from ``ibu``'s run: one sweep point, which a section run computes once."""
    from jko_cvx.studies.reproduce import ibu

    asked = asked_points(monkeypatch, tmp_path, (ibu,), (ibu.reproduce_ibu, panels.reproduce_ibu_panels))
    assert asked["ibu"] == asked["ibu_panels"] and len(asked["ibu"]) == 1
