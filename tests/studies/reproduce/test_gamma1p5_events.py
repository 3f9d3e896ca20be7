"""Blow-up or collapse: the gamma = 3/2 event named from the record of sigma_v, and the entry on the shipped files."""

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jko_cvx.studies.reproduce import REPRODUCTIONS
from jko_cvx.studies.reproduce.gamma1p5 import COLLAPSE_SPREAD, spread_event
from jko_cvx.studies.reproduce.gamma1p5_events import EVENT_FILES, events, reproduce_inhom_gamma1p5_events

SHIPPED = Path(__file__).parents[3] / "studies/results/reproduce"


def test_a_collapse_that_comes_back_is_named_reversed_and_one_that_stays_is_not():
    t = np.linspace(0.0, 1.0, 101)
    dip = 0.3 * np.exp(-((t - 0.5) ** 2) / 0.02) * -1 + 0.31  # falls to 0.01 at t = 0.5, back to 0.31
    e = spread_event(t.tolist(), dip.tolist())
    assert e["t(min sigma_v)"] == pytest.approx(0.5) and e["min sigma_v"] == pytest.approx(0.01)
    below, back = t[dip < COLLAPSE_SPREAD][0], t[(t > 0.5) & (dip >= COLLAPSE_SPREAD)][0]
    assert e["t below"] == pytest.approx(below) and e["t back above"] == pytest.approx(back)
    assert e["event"] == f"collapse at t = {below:.3g}, reversed by t = {back:.3g}"
    # a blow-up in v: sigma_v -> 0 and stays there
    fall = 0.3 * (1 - t) ** 2
    e = spread_event(t.tolist(), fall.tolist())
    assert e["event"].endswith("not reversed by t = 1") and np.isnan(e["t back above"])
    assert spread_event([0.0, 0.2], [0.3, 0.2])["event"] == "no collapse by t = 0.2"
    stopped = spread_event([0.0, 0.25], [0.3, 0.049], followed=False)
    assert stopped["event"] == "collapse at t = 0.25, not followed past it"
    with pytest.raises(ValueError, match="t increasing"):
        spread_event([0.2, 0.1], [0.1, 0.2])


def test_the_shipped_runs_collapse_and_reverse_on_every_mapped_grid_followed_past_it():
    df = events(SHIPPED)
    followed = df[df.followed & df["t below"].notna() & df.grid.str.endswith("mapped")]
    assert len(followed) >= 6 and followed["t back above"].notna().all()
    # the return comes after the collapse, by T_b, and the spread at the end is several times its minimum.  The
    # minimum is the whole record's: on some grids it comes after the return (sigma_v dips a second time, deeper)
    assert (followed["t back above"] > followed["t below"]).all()
    assert (followed["t back above"] <= followed["t (end)"]).all() and (followed["end / min"] > 2).all()
    assert (followed["t(min sigma_v)"] > followed["t below"]).all()
    # every grid of both files is a row: 41-121 (run past the collapse) and 121-481 (stopped at it)
    res, conv = (pd.read_csv(SHIPPED / n) for n in EVENT_FILES)
    assert len(df) == len(res) + int(conv.case.isin(res.case.unique()).sum())


def test_the_entry_reads_the_files_and_its_shipped_table_is_current(tmp_path):
    assert REPRODUCTIONS["inhom_gamma1p5_events"] is reproduce_inhom_gamma1p5_events
    with pytest.raises(FileNotFoundError, match="inhom_gamma1p5_resolution"):
        reproduce_inhom_gamma1p5_events(tmp_path)
    for name in EVENT_FILES:
        shutil.copy(SHIPPED / name, tmp_path)
    reproduce_inhom_gamma1p5_events(tmp_path)
    assert (tmp_path / "inhom_gamma1p5_events.png").is_file() and "reversed by" in (
        tmp_path / "inhom_gamma1p5_events.md"
    ).read_text()
    assert pd.read_csv(SHIPPED / "inhom_gamma1p5_events.csv").equals(
        pd.read_csv(tmp_path / "inhom_gamma1p5_events.csv")
    )
    # the record is read, not assumed: a run whose whole record stays collapsed is named so
    res = pd.read_csv(tmp_path / EVENT_FILES[0])
    k = res.index[(res.case == "before") & (res.grid == "121 x 121")][0]
    stayed = res.copy()
    edited = ["sigma_v(t=0.6)", "sigma_v (end)", "min sigma_v", "t(min sigma_v)"]
    stayed.loc[k, edited] = [0.01, 0.001, 0.001, res.T_b[k]]
    stayed.loc[k, "t(sigma_v back >= 0.05)"] = np.nan
    stayed.to_csv(tmp_path / EVENT_FILES[0], index=False)
    row = events(tmp_path).iloc[k]
    assert row.event == f"collapse at t = {res.loc[k, 't(sigma_v < 0.05)']:.3g}, not reversed by t = {res.T_b[k]:.3g}"
    assert np.isnan(row["t back above"]) and row["min sigma_v"] == 0.001


@pytest.mark.parametrize(
    "edit",
    [
        {"sigma_v (end)": 0.001},  # a sample below the record's minimum
        {"sigma_v(t=0.6)": 0.01, "sigma_v (end)": 0.001, "t(sigma_v back >= 0.05)": np.nan},
        {"t(sigma_v back >= 0.05)": np.nan},  # never back, but the sample at t = 0.6 is above the threshold
        {"t(sigma_v back >= 0.05)": 0.1},  # back before the collapse
        {"t(min sigma_v)": 5.0},  # past the run's end
    ],
)
def test_a_resolution_row_whose_samples_disagree_with_its_record_is_refused(tmp_path, edit):
    for name in EVENT_FILES:
        shutil.copy(SHIPPED / name, tmp_path)
    res = pd.read_csv(tmp_path / EVENT_FILES[0])
    k = res.index[(res.case == "before") & (res.grid == "121 x 121")][0]
    for key, value in edit.items():
        res.loc[k, key] = value
    res.to_csv(tmp_path / EVENT_FILES[0], index=False)
    with pytest.raises(ValueError, match="before 121 x 121"):
        events(tmp_path)
