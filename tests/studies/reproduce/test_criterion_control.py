"""The control of the paper's criterion (quick form): gamma = 1.5 (finite-time collapse by the Osgood
criterion) against gamma = 2 (the linear contraction, no blow-up), read from the runs."""

import numpy as np
import pandas as pd

from jko_cvx.studies.reproduce.criterion_control import osgood_finite_time, reproduce_criterion_control


def test_osgood_threshold_is_gamma_2():
    assert osgood_finite_time(1.99) and not osgood_finite_time(2.0) and not osgood_finite_time(3.0)


def test_the_quick_control_shows_the_criterion_firing_where_theory_forbids(tmp_path):
    table = reproduce_criterion_control(tmp_path, quick=True, executor="serial", progress=False)
    assert list(table.gamma) == [1.5, 2.0]
    cols = [c for c in table.columns if c.startswith("T_b (eps_v = ")]
    lin = table.set_index("gamma").loc[2.0]
    # gamma = 2: max f = e^{M t} max f0, no finite time; the mesh rule still fires, later for each smaller eps_v
    times = lin[cols].to_numpy(dtype=float)
    assert lin["fires where theory forbids"] and np.all(np.isfinite(times)) and np.all(np.diff(times) > 0)
    assert lin["blowup_kind"] == "no_finite_time" and lin["kind right"]
    # the exponential law: T_b grows by about 1/(rate) per e-fold of 1/eps_v; here at least 0.3 per e-fold
    assert lin["drift dT_b/dln(1/eps)"] > 0.3
    assert not table.set_index("gamma").loc[1.5, "fires where theory forbids"]
    # the rate a beside T_b_fit where the fit locates a time (gamma = 1.5), none for the contraction
    g15 = table.set_index("gamma").loc[1.5]
    assert np.isnan(lin["blowup_rate"]) and np.isnan(lin["T_b_fit"])
    assert g15["blowup_kind"] != "finite_time" or g15["blowup_rate"] > 0
    shipped = pd.read_csv(tmp_path / "criterion_control.csv")
    pd.testing.assert_frame_equal(shipped, table.reset_index(drop=True), check_dtype=False)
    md = (tmp_path / "criterion_control.md").read_text()
    assert "fired in 1 of 1 runs" in md and "*Environment: jko_cvx" in md
    assert (tmp_path / "criterion_control.png").stat().st_size > 0

