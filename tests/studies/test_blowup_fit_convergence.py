"""The estimator's convergence study runs, writes its tables, and its errors fall with the grid (slow: 16 runs)."""

import pandas as pd
import pytest

from tests.studies.scripts import load_study_script


@pytest.mark.slow
def test_the_quick_study_writes_its_tables_and_the_error_falls_with_the_grid(tmp_path):
    mod = load_study_script("blowup_fit_convergence.py")
    mod.main(["--quick", "--out", str(tmp_path)])
    df = pd.read_csv(tmp_path / "blowup_fit_convergence_quick.csv")
    assert len(df) == 16 and (df.kind == "finite_time").all() and set(df.remap) == {"paper", "cumulative"}
    assert df.covered.all()  # measured 16 of 16
    key = ["remap", "datum", "dt"]
    err = df.assign(e=df.error.abs()).groupby(key).apply(lambda g: g.sort_values("N_v").e.to_numpy())
    assert all(e[1] < e[0] for e in err)  # 241 points beat 121 for every remap, datum and dt (measured 1.05-2.2x)
    # the cumulative remap is the closer one in every cell (measured 1.1 to 3.4x closer than the paper's)
    pair = df.pivot_table(index=["datum", "N_v", "dt"], columns="remap", values="error")
    assert (pair.cumulative.abs() < pair.paper.abs()).all()
    assert (df.tau_error > 0).all()  # these data are not cut by the walls: the records lag the exact law
    md = (tmp_path / "blowup_fit_convergence_quick.md").read_text()
    assert "tau_error" in md and "git" in md
    assert (tmp_path / "blowup_fit_convergence_quick.png").stat().st_size > 0
