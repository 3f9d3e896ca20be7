"""The grid-convergence entry (issue 15): its convergence arithmetic, its sweep and its files."""

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from jko_cvx.studies.reproduce import REPRODUCTIONS
from jko_cvx.studies.reproduce.grid_convergence import (
    G2BU_N_V,
    GRID_KINDS,
    GRIDS,
    T_END,
    _points,
    convergence,
    reproduce_grid_convergence,
)
from jko_cvx.studies.reproduce.paper import TAB_G2BU


@pytest.mark.parametrize("p", [0.5, 1.0, 2.0, 3.7])
def test_convergence_recovers_the_order_of_a_power_law(p):
    h = np.array([0.1, 0.05, 0.025, 0.0125])
    result = convergence(list(2.5 - 3.0 * h**p))
    assert result["order"] == pytest.approx(p, rel=1e-10)
    assert result["d2"] == pytest.approx(-3.0 * (h[3] ** p - h[2] ** p), rel=1e-12)
    assert abs(result["d2"]) < abs(result["d1"])


def test_convergence_has_no_order_when_the_differences_change_sign_or_vanish():
    assert np.isnan(convergence([1.0, 1.5, 1.2])["order"])  # oscillating: no asymptotic order
    assert np.isnan(convergence([1.0, 1.0, 1.0])["order"])  # d2 = 0
    assert np.isnan(convergence([0.3, float("nan"), 0.2])["order"])
    with pytest.raises(ValueError, match="at least 3 grids"):
        convergence([1.0, 2.0])


def test_the_full_sweep_covers_every_grid_and_runs_the_finest_last():
    points = _points(quick=False)
    g1p5 = [p for p in points if p["study"] == "gamma1p5"]
    g2 = [p for p in points if p["study"] == "g2bu"]
    assert {(p["case"], p["n"], p["grid"]) for p in g1p5} == {
        (c, n, g) for c in ("before", "after") for n in GRIDS for g in GRID_KINDS
    }
    assert all(p["t_end"] == T_END for p in g1p5)
    assert {(p["lam"], p["n_v"]) for p in g2} == {(float(lam), n) for lam in TAB_G2BU for n in G2BU_N_V}
    assert all(p["n_x"] == 121 for p in g2)
    # the two finest levels come after every coarser point (a killed sweep keeps the cheap ones)
    finest = [i for i, p in enumerate(points) if p.get("n") == GRIDS[-1] or p.get("n_v") == G2BU_N_V[-1]]
    assert finest == list(range(len(points) - len(finest), len(points)))
    assert "grid_convergence" in REPRODUCTIONS


@pytest.mark.slow
def test_quick_grid_convergence_runs_both_studies_and_keeps_the_invariants(tmp_path):
    rows = reproduce_grid_convergence(tmp_path, quick=True, executor="serial", progress=False)
    for name in ("grid_convergence.csv", "grid_convergence_gamma1p5.csv", "grid_convergence_g2bu.csv"):
        assert (tmp_path / name).exists()
    assert (tmp_path / "grid_convergence.png").stat().st_size > 0
    assert (rows["mass drift"] < 1e-12).all() and (rows["momentum drift"] < 1e-12).all()
    uniform = rows[rows.grid == "uniform"]
    # no maps on the reference: its spacing stays the uniform 2 L / (n - 1), and the mesh criterion never fires
    assert np.allclose(uniform["min dv (stop)"], 10.0 / (uniform.n - 1))
    assert uniform["T_b (paper's criteria)"].isna().all()
    stopped = rows[rows.grid != "continued uniform"]
    collapse = stopped["t(sigma_v < 0.05)"]
    assert (collapse.notna() == stopped.stop.str.startswith("min spread_v")).all()
    assert ((rows["t stop"] <= 0.25 + 1e-12) & (rows["t(sigma_v < 0.05)"].fillna(0) <= rows["t stop"] + 1e-12)).all()
    # a continued run is the uniform run, not stopped at the collapse: the same record up to it, then on to t_end
    continued = rows[rows.grid == "continued uniform"].set_index(["case", "n"])
    same = uniform.set_index(["case", "n"]).loc[continued.index]
    assert len(continued) == len(uniform) and (continued["t stop"] == 0.25).all()
    for q in ("t(sigma_v < 0.05)", "sigma_v(t=0.1)", "sigma_v(t=0.2)"):
        assert continued[q].equals(same[q]), q
    assert (continued["min sigma_v"] <= same["sigma_v (stop)"]).all()
    g2 = pd.read_csv(tmp_path / "grid_convergence_g2bu.csv")
    assert g2["lambda"].tolist() == [310]
    assert {"T_b (N_v = 61)", "T_b (N_v = 81)"} <= set(g2.columns)
    assert {"T_b_fit (61)", "T_b_fit_err (81)", "blowup_kind (61)"} <= set(g2.columns)
    assert rows.blowup_kind.isin(["finite_time", "no_finite_time", "undetermined"]).all()
    assert "the fit of max f:" in (tmp_path / "grid_convergence.md").read_text()

    # a stopped sweep: the partial report lists the point it lacks and refuses a tampered entry
    cache = sorted((tmp_path / "cache" / "grid_convergence").glob("*.json"))
    lost_entry = json.loads(cache[0].read_text())
    lost = lost_entry["point"]
    cache[0].unlink()
    # the lost point's result as another code would have cached it (another key, a valid digest):
    # it must not be reported as this code's result
    foreign = {"key": "0" * 32, "point": lost, "result": {**lost_entry["result"], "seconds": 0.5}}
    foreign["digest"] = hashlib.sha256(json.dumps(foreign, sort_keys=True, default=float).encode()).hexdigest()
    (cache[0].parent / f"{'0' * 32}.json").write_text(json.dumps(foreign))
    script = Path(__file__).resolve().parents[3] / "studies" / "grid_convergence_partial.py"
    cmd = [
        sys.executable,
        str(script),
        "--cache",
        str(cache[0].parent),
        "--note",
        "test",
        "--quick",
        "--allow-modified",
    ]
    done = subprocess.run([*cmd, "--out", str(tmp_path / "partial")], capture_output=True, text=True, check=True)
    assert f"{len(cache) - 1} of {len(cache)} points reported, 1 missing" in done.stdout
    assert "1 entry of other code or other points ignored" in done.stdout
    report = (tmp_path / "partial" / "grid_convergence.md").read_text()
    assert "**Points not run**" in report and ", ".join(f"{k} = {v}" for k, v in lost.items()) in report
    assert "package sha256" in report and "test" in report  # the code is recorded, not typed in
    entry = json.loads(cache[1].read_text())
    entry["result"]["seconds"] += 1.0
    cache[1].write_text(json.dumps(entry))
    refused = subprocess.run([*cmd, "--out", str(tmp_path / "p2")], capture_output=True, text=True, check=False)
    assert refused.returncode != 0 and "fails its digest" in refused.stderr


def test_partial_report_refuses_a_checkout_whose_code_it_cannot_name(tmp_path, monkeypatch, capsys):
    """Uncommitted changes to jko_cvx: nothing would say which code computed the points."""
    from tests.studies.scripts import load_study_script

    script = load_study_script("grid_convergence_partial.py")
    prov = {"git_commit": "f" * 40, "jko_cvx_modified": True, "package_version": "0", "package_sha256": "a" * 64}
    monkeypatch.setattr(script, "code_provenance", lambda func: prov)
    (tmp_path / "c").mkdir()
    with pytest.raises(SystemExit):
        script.main(["--cache", str(tmp_path / "c"), "--out", str(tmp_path / "o")])
    assert "differs from its commit" in capsys.readouterr().err
    assert "uncommitted changes" in script.provenance_text(prov, None)


def test_the_shipped_report_is_consistent_with_its_runs():
    """The shipped convergence table follows from the shipped runs; the report covers every point of the
    sweep; every shipped run conserved mass and momentum."""
    from jko_cvx.studies.reproduce.grid_convergence import _gamma1p5_convergence

    results = Path(__file__).resolve().parents[3] / "studies" / "results" / "reproduce"
    rows = pd.read_csv(results / "grid_convergence.csv")
    shipped = pd.read_csv(results / "grid_convergence_gamma1p5.csv")
    pd.testing.assert_frame_equal(_gamma1p5_convergence(rows), shipped, check_dtype=False, atol=1e-12)
    assert (rows["mass drift"] < 1e-12).all() and (rows["momentum drift"] < 1e-12).all()
    report = (results / "grid_convergence.md").read_text()
    assert "Points not run" not in report
    assert len(rows) == 2 * len(GRIDS) * len(GRID_KINDS)
    assert len(pd.read_csv(results / "grid_convergence_g2bu.csv")) == 9


def test_the_blowup_fit_columns_reach_the_g2bu_table_and_the_conclusions():
    """T_b_fit, its error bar and the kind of each run stand beside T_b per N_v, and the restated
    conclusions count the kinds; rows of code that predates the fit give NaN, not an error."""
    from jko_cvx.studies.reproduce.grid_convergence import _conclusions, _g2bu_table

    runs = pd.DataFrame(
        {
            "lam": [310.0] * 3,
            "n_v": [201, 401, 801],
            "T_b": [0.0935, 0.0941, 0.0944],
            "T_b_fit": [0.0952, 0.0961, float("nan")],
            "T_b_fit_err": [0.002, 0.001, float("nan")],
            "blowup_kind": ["finite_time", "finite_time", "undetermined"],
            "B_x": [True] * 3,
            "B_v": [False] * 3,
            "blowup": [True] * 3,
            "components": [[1], [1], [1]],
            "split slices": [0, 0, 0],
            "slices": [10, 10, 10],
            "seconds": [1.0, 2.0, 3.0],
        }
    )
    table = _g2bu_table(runs)
    assert table["T_b_fit (401)"].iloc[0] == 0.0961 and table["T_b_fit_err (201)"].iloc[0] == 0.002
    assert table["blowup_kind (801)"].iloc[0] == "undetermined"
    empty = pd.DataFrame(columns=["case", "grid", "n"])
    lines = _conclusions(empty, runs)
    assert any("kinds {'undetermined': 1}" in line for line in lines)  # the finest grid only
    old = _g2bu_table(runs.drop(columns=["T_b_fit", "T_b_fit_err", "blowup_kind"]))
    assert np.isnan(old["T_b_fit (201)"].iloc[0])
    assert not any("power-law fit" in line for line in _conclusions(empty, runs.drop(columns=["blowup_kind"])))
