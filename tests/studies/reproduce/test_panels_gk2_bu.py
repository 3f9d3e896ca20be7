"""``fig:gk2_bu`` (``gk2_bu``): f at the numerical blow-up time of the ``tab:g2bu`` runs."""

from pathlib import Path

import pandas as pd
import pytest

from jko_cvx.engine.loop import simulate
from jko_cvx.studies.reproduce.g2bu import g2bu_scene
from jko_cvx.studies.reproduce.gk2_bu import LAMBDAS, reproduce_gk2_bu

SHIPPED = Path(__file__).parents[3] / "studies/results/reproduce"


def test_quick_gk2_bu_is_drawn_at_the_blowup_time_of_the_table_run(tmp_path):
    df = reproduce_gk2_bu(tmp_path, quick=True, executor="serial", progress=False)
    assert (tmp_path / "fig_gk2_bu.png").stat().st_size > 0 and (tmp_path / "gk2_bu.md").exists()
    assert df["lambda"].tolist() == [310.0, 280.0]  # the caption's order, top to bottom
    assert (df.t == df.T_b).all()  # the panel is the state at T_b, not a later or earlier one
    assert df["mass rel. diff"].max() < 1e-12
    assert ((df["zoom x from"] <= df["x at max f"]) & (df["x at max f"] <= df["zoom x to"])).all()
    assert ((df["zoom v from"] <= df["v at max f"]) & (df["v at max f"] <= df["zoom v to"])).all()
    # the same lambda and grid run on its own (the tab:g2bu scene) stops at the same T_b
    own = simulate(g2bu_scene(280.0, 31, 51))
    assert own.blowup and df.set_index("lambda").loc[280.0, "T_b"] == own.verdict.T_b


def test_shipped_gk2_bu_holds_the_captions_rows_at_their_blowup_time():
    df = pd.read_csv(SHIPPED / "gk2_bu.csv")
    assert df["lambda"].tolist() == list(LAMBDAS) and (df.n_x == 121).all() and (df.n_v == 201).all()
    assert (df.t == df.T_b).all() and df["mass rel. diff"].max() < 1e-12
    assert ((df["zoom x from"] <= df["x at max f"]) & (df["x at max f"] <= df["zoom x to"])).all()


@pytest.mark.parametrize("lam", [310.0, 300.0, 290.0, 280.0])
def test_shipped_gk2_bu_has_the_T_b_of_the_shipped_tab_g2bu(lam):
    """The same runs (g2bu_run, 121 x 201), so the same T_b to rounding; a stale file fails."""
    row = pd.read_csv(SHIPPED / "gk2_bu.csv").set_index("lambda").loc[lam]
    table = pd.read_csv(SHIPPED / "tab_g2bu.csv")
    assert row.T_b == pytest.approx(table[table.n_v == 201].set_index("lambda").loc[int(lam), "T_b"], rel=1e-12)


def test_a_g2bu_point_carries_the_fit_of_its_own_records():
    """The fit columns of a tab:g2bu point are the power-law fit of that run's max f record."""
    import numpy as np

    from jko_cvx.blowup import fit_blowup
    from jko_cvx.studies.reproduce.g2bu import g2bu_run

    r = g2bu_run(310.0, 31, 51)
    assert r["failed_slices"] == 0  # every record certified: the fit takes them all
    rec = r["records"]
    fit = fit_blowup(np.array(rec["t"]), np.array(rec["max_f"]))
    assert r["blowup_kind"] == fit.blowup_kind
    assert r["T_b_fit"] == fit.T_b_fit and r["T_b_fit_err"] == fit.T_b_fit_err
