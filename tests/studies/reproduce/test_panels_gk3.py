"""The gamma = 3 panels (``gk3_panels``) and the zoom window they share with ``gk2_bu``."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jko_cvx.studies.reproduce.gk3_panels import FIGURES, reproduce_gk3_panels
from jko_cvx.studies.reproduce.inhomogeneous import PAPER_TIMES
from jko_cvx.studies.reproduce.phase_views import zoom_window

SHIPPED = Path(__file__).parents[3] / "studies/results/reproduce"


def test_zoom_window_is_the_padded_box_of_the_superlevel_set():
    x, v = np.linspace(-4, 4, 81), np.linspace(-3, 3, 61)
    X, V = np.meshgrid(x, v, indexing="ij")
    f = np.exp(-((X - 1) ** 2) / 0.1 - V**2 / 0.05) + 0.5 * np.exp(-((X + 2) ** 2) / 0.1 - (V - 1) ** 2 / 0.05)
    sx, sv = zoom_window(f, level=0.1, pad=2)
    inside = np.zeros_like(f, dtype=bool)
    inside[sx, sv] = True
    assert f[~inside].max() < 0.1 * f.max()  # nothing at or above the level is left out
    above = f >= 0.1 * f.max()
    rows, cols = np.flatnonzero(above.any(1)), np.flatnonzero(above.any(0))
    assert (sx.start, sx.stop - 1) == (rows[0] - 2, rows[-1] + 2)  # and the box is no larger than asked
    assert (sv.start, sv.stop - 1) == (cols[0] - 2, cols[-1] + 2)
    assert x[sx.start] < -2 < 1 < x[sx.stop - 1]  # both bumps: the second holds half the maximum
    wide = zoom_window(f, level=0.1, pad=1000)
    assert wide == (slice(0, 81), slice(0, 61))  # padding is clipped at the grid's ends


@pytest.mark.parametrize(
    ("f", "kw", "word"),
    [(np.zeros((3, 3)), {}, "positive maximum"), (np.ones(3), {}, "2-D"), (np.ones((3, 3)), {"level": 0.0}, "level")],
)
def test_zoom_window_rejects_bad_input(f, kw, word):
    with pytest.raises(ValueError, match=word):
        zoom_window(f, **kw)


def test_quick_gk3_panels_are_at_the_papers_times_and_conserve_mass(tmp_path):
    df = reproduce_gk3_panels(tmp_path, quick=True, executor="serial", progress=False)
    records = pd.read_csv(tmp_path / "gk3_panels_records.csv").set_index("lambda")
    for name in ("gk3_panels.csv", "gk3_panels.md", "fig_gk3_ih_2_C2_2.png", "fig_gk3_ih_2_C5.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert df["mass rel. diff"].max() < 1e-12  # prop:properties: mass is conserved
    for lam, (snap_fig, final_fig) in FIGURES.items():
        mine = df[df["lambda"] == lam]
        snaps, final = mine[mine.figure == snap_fig], mine[mine.figure == final_fig]
        assert np.allclose(snaps.t, [tk for tk in PAPER_TIMES[lam] if tk <= 2.0], atol=1e-9)
        assert len(final) == 1 and final.t.iloc[0] == pytest.approx(2.0, abs=1e-9)
        row = final.iloc[0]
        # the panel's f is the run's last state: its numbers are the diagnostics' last record
        assert row["max f"] == records.loc[lam, "max_f at end"]
        assert row["min dx"] == pytest.approx(records.loc[lam, "min_dx at end"], rel=1e-12)
        assert row["zoom x from"] <= row["x at max f"] <= row["zoom x to"]
        assert row["zoom v from"] <= row["v at max f"] <= row["zoom v to"]
        assert snaps[[c for c in df if c.startswith("zoom")]].isna().all().all()  # no zoom on the snapshots


def test_shipped_gk3_panels_come_from_the_shipped_inhom_gamma3_runs():
    """Same runs (N = 121, t = 4), so the records equal ``inhom_gamma3.csv``'s; a stale file fails."""
    records = pd.read_csv(SHIPPED / "gk3_panels_records.csv").set_index("lambda")
    summary = pd.read_csv(SHIPPED / "inhom_gamma3.csv").set_index("lambda")
    for lam in FIGURES:
        assert records.loc[lam, "N"] == summary.loc[lam, "N"] == 121
        assert records.loc[lam, "max_f extreme"] == pytest.approx(summary.loc[lam, "max f (peak)"], rel=1e-12)
        assert records.loc[lam, "min_dx extreme"] == pytest.approx(summary.loc[lam, "min dx (min)"], rel=1e-12)
        assert records.loc[lam, "min_dx at end"] == pytest.approx(summary.loc[lam, "min dx at end"], rel=1e-12)


def test_shipped_gk3_records_turn_as_the_paper_reads_them():
    """sec:sp_inhom_gamma_3: min dx falls then rises (lambda = 4 and 10), max f rises then falls (lambda = 4)."""
    records = pd.read_csv(SHIPPED / "gk3_panels_records.csv").set_index("lambda")
    panels = pd.read_csv(SHIPPED / "gk3_panels.csv")
    assert panels["mass rel. diff"].max() < 1e-12
    for lam in FIGURES:
        r = records.loc[lam]
        assert r["min_dx falls then rises"] and 0 < r["t of min_dx extreme"] < r["t end"]
        assert r["min_dx at end"] > r["min_dx extreme"]
    r = records.loc[4.0]
    assert r["max_f rises then falls"] and 0 < r["t of max_f extreme"] < r["t end"]
    assert r["max_f at end"] < r["max_f extreme"]
