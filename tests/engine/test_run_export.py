"""Runs as data: load_run, Run.to_xarray, jko-cvx export, jko_cvx.engine.plot, and the run summary."""

import dataclasses
import json
import sys
import tomllib
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import jko_cvx
from jko_cvx.cli import main
from jko_cvx.engine.errors import RunDirError
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.plot import exact_max_f, plot_records, plot_solution, refinement_switches, save_figures
from jko_cvx.engine.run import Run
from jko_cvx.engine.verdict import StopReason
from jko_cvx.scene.model import default_scene, load_scene

from ._inject import failing

xr = pytest.importorskip("xarray")

ROOT = Path(__file__).parents[2]
SCENES = ROOT / "jko_cvx" / "scene" / "shipped"


def _inhomogeneous():
    s = load_scene(SCENES / "inhom_gamma3_lambda4.toml")
    return s.replace({"v.n": 31, "x.n": 21, "t_end": 0.3, "output.every": 2, "output.times": (0.15,)})


def _failing():
    """The default scene whose second solve fails (imposed in the test): stops on a solver failure at step 2,
    right after the snapshot of step 1 (every = 1)."""
    return default_scene().replace(
        {"time.dt": 0.05, "t_end": 0.3, "stop.on_solver_failure": True, "output.every": 1}
    )


def _assert_same_run(a: Run, b: Run):
    assert a.scene == b.scene and a.t == b.t and a.verdict == b.verdict and a.seconds == b.seconds
    assert np.array_equal(a.f, b.f) and np.array_equal(a.vgrid.points, b.vgrid.points)
    assert (a.xgrid is None) == (b.xgrid is None)
    if a.xgrid is not None:
        assert np.array_equal(a.xgrid.points, b.xgrid.points) and a.xgrid.period == b.xgrid.period
    pd.testing.assert_frame_equal(a.diagnostics, b.diagnostics, check_exact=True)
    assert len(a.snapshots) == len(b.snapshots)
    for s, r in zip(a.snapshots, b.snapshots, strict=True):
        assert s.keys() == r.keys() and s["step"] == r["step"] and s["t"] == r["t"]
        assert all(np.array_equal(s[k], r[k]) for k in ("v", "f", "x") if k in s)


@pytest.mark.parametrize("make", [default_scene, _inhomogeneous, _failing], ids=["refined", "inhomogeneous", "failed"])
def test_load_run_returns_the_run_that_simulate_returned(tmp_path, make):
    with failing(lambda attempt, accepted, dt: attempt >= 1) if make is _failing else nullcontext():
        run = simulate(make(), out=tmp_path / "r")
    _assert_same_run(jko_cvx.load_run(tmp_path / "r"), run)
    if make is _failing:
        assert run.verdict.stop is StopReason.SOLVER_FAILURE and [s["step"] for s in run.snapshots] == [0, 1]


def test_load_run_refuses_an_unfinished_run_unless_asked(tmp_path):
    out = tmp_path / "r"
    run = simulate(default_scene(), out=out)
    (out / "verdict.json").unlink()
    with pytest.raises(RunDirError, match=rf"has not ended \(no verdict.json; checkpoint at step {run.steps}\b"):
        jko_cvx.load_run(out)
    assert jko_cvx.load_run(out, allow_partial=True).t == run.t
    with pytest.raises(RunDirError, match="does not exist"):
        jko_cvx.load_run(tmp_path / "nowhere")
    with pytest.raises(RunDirError, match=r"is not a run directory: it has no scene\.json"):
        jko_cvx.load_run(out / "snapshots")
    (out / "scene.json").write_text(json.dumps({**json.loads((out / "scene.json").read_text()), "gamma": 2.0}))
    with pytest.raises(RunDirError, match="does not rebuild the scene"):  # an edited scene.json is caught
        jko_cvx.load_run(out, allow_partial=True)
    flat = {"name": "default_tab_bu_g1", "gamma": 1.0, "t_end": 1.0, "v_L": 2.0, "v_n": 121, "dt": 0.01}
    (out / "scene.json").write_text(json.dumps(flat))  # the flat layout of earlier versions: refused, not misread
    with pytest.raises(RunDirError, match=r"records the scene as flat fields \(v_n, dt, \.\.\.\)"):
        jko_cvx.load_run(out, allow_partial=True)


def test_to_xarray_lays_out_snapshots_and_diagnostics_with_named_dimensions():
    run = simulate(default_scene())
    ds = run.to_xarray()
    d = run.diagnostics
    assert ds["f"].dims == ("t_snap", "iv") and ds["v"].dims == ("t_snap", "iv")
    assert np.array_equal(ds["t"].values, d["t"].to_numpy())
    assert np.array_equal(ds["min_dv"].values, d["min_dv"].to_numpy())
    assert np.array_equal(ds["t_snap"].values, [s["t"] for s in run.snapshots])
    for k, s in enumerate(run.snapshots):
        assert np.array_equal(ds["f"].isel(t_snap=k).values, s["f"]) and np.array_equal(ds["v"][k].values, s["v"])
    assert not np.array_equal(ds["v"][0].values, ds["v"][-1].values)  # refinement moved the grid: one per snapshot
    assert ds.attrs["stop"] == "EPS_V" and ds.attrs["B_v"] == 1 and ds.attrs["T_b"] == run.verdict.T_b
    assert json.loads(ds.attrs["scene"])["gamma"] == 1.0


def test_to_xarray_of_an_inhomogeneous_run_has_x_and_v():
    run = simulate(_inhomogeneous())
    ds = run.to_xarray()
    assert ds["f"].dims == ("t_snap", "ix", "iv") and ds["x"].dims == ("t_snap", "ix")
    assert np.array_equal(ds["f"].sel(t_snap=run.t).values, run.f)
    assert np.array_equal(ds["x"][-1].values, run.xgrid.points)
    assert np.isnan(ds.attrs["T_b"]) and ds.attrs["blowup"] == 0


def test_export_writes_the_dataset_as_netcdf(tmp_path):
    out = tmp_path / "r"
    run = simulate(_inhomogeneous(), out=out)
    assert main(["export", str(out), "--netcdf", str(tmp_path / "r.nc")]) == 0
    with xr.open_dataset(tmp_path / "r.nc", engine="h5netcdf") as back:
        xr.testing.assert_identical(back.load(), run.to_xarray())


@pytest.mark.parametrize("target", ["checkpoint.npz", "verdict.json", "snapshots/step_0000002.npz", "link.nc"])
def test_export_refuses_a_file_of_a_run_directory_or_a_link(tmp_path, capsys, target):
    out = tmp_path / "r"
    simulate(dataclasses.replace(default_scene(), t_end=0.02), out=out)
    elsewhere = tmp_path / "elsewhere.nc"
    (out / "link.nc").symlink_to(elsewhere)
    assert main(["export", str(out), "--netcdf", str(out / target)]) == 2
    assert "jko-cvx: error:" in capsys.readouterr().err
    assert not elsewhere.exists() and jko_cvx.load_run(out).steps == 2  # the run is intact
    assert main(["export", str(out), "--netcdf", str(out / "run.nc")]) == 0  # a new file beside the run is fine


def test_export_refuses_a_run_file_reached_by_a_relative_path_or_a_linked_folder(tmp_path, monkeypatch):
    from jko_cvx.engine.errors import RunDirError
    from jko_cvx.engine.run import export_netcdf

    out = tmp_path / "r"
    run = simulate(dataclasses.replace(default_scene(), t_end=0.02), out=out)
    (tmp_path / "snaps").symlink_to(out / "snapshots")
    monkeypatch.chdir(out / "snapshots")
    for target in ("step_0000002.npz", tmp_path / "snaps" / "step_0000002.npz", "../checkpoint.npz"):
        with pytest.raises(RunDirError, match="file of the run directory"):
            export_netcdf(run, target)
    assert jko_cvx.load_run(out).steps == 2


def test_a_missing_extra_is_named(tmp_path, monkeypatch, capsys):
    run = simulate(dataclasses.replace(default_scene(), t_end=0.02), out=tmp_path / "r")
    monkeypatch.setitem(sys.modules, "xarray", None)  # as if not installed
    with pytest.raises(ImportError, match=r"install the optional extra jko_cvx\[netcdf\]"):
        run.to_xarray()
    assert main(["export", str(tmp_path / "r"), "--netcdf", str(tmp_path / "r.nc")]) == 2
    assert "jko_cvx[netcdf]" in capsys.readouterr().err and not (tmp_path / "r.nc").exists()


def test_the_netcdf_extra_is_declared_and_tested():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    names = {r.split(">")[0].split("[")[0] for r in extras["netcdf"]}
    assert names == {"xarray", "h5netcdf"} and "h5netcdf[h5py]>=1.1" in extras["netcdf"]
    assert set(extras["netcdf"]) <= set(extras["test"])


# --- jko_cvx.engine.plot -------------------------------------------------------------------------------


def test_records_figure_of_a_loaded_run_shows_thresholds_exact_law_and_blowup(tmp_path):
    import matplotlib.pyplot as plt

    simulate(default_scene(), out=tmp_path / "r")
    run = jko_cvx.load_run(tmp_path / "r")
    fig = plot_records(run)
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "eps_v = 0.00025" in labels and "v-grid remeshed" in labels
    assert any(lab.startswith("exact max f") for lab in labels) and "exact T = 0.5001" in labels
    assert f"T_b = {run.verdict.T_b:.4g}" in labels and 0.45 < run.verdict.T_b < 0.55
    plt.close(fig)
    _t, law, T = exact_max_f(run)
    m0 = run.diagnostics.max_f.iloc[0]
    assert T == 1 / (2 * m0) and law[0] == m0 and np.all(np.diff(law) > 0)  # f0 / (1 - 2 f0 t)
    assert exact_max_f(simulate(_inhomogeneous())) is None


def test_refinement_switches_are_the_steps_whose_grid_changed():
    """Checked against the grids themselves: a snapshot at every step of a run that remeshes only when the set moved."""
    s = load_scene(SCENES / "ibu_gamma3.toml").replace({"t_end": 1.0, "v.n": 61, "output.every": 1})
    run = simulate(s)
    pairs = zip(run.snapshots[1:], run.snapshots[:-1], strict=True)
    changed = [snap["step"] for snap, prev in pairs if not np.array_equal(snap["v"], prev["v"])]
    assert 0 < len(changed) < run.steps  # tol = 0.1: some steps remesh, most do not
    assert list(refinement_switches(run, "v")) == changed
    assert refinement_switches(run, "x").size == 0


def test_save_figures_writes_both_without_pyplot(tmp_path):
    import matplotlib.pyplot as plt

    run = simulate(_inhomogeneous())
    paths = save_figures(run, tmp_path)
    assert [p.name for p in paths] == ["solution.png", "records.png"] and all(p.stat().st_size > 0 for p in paths)
    assert plt.get_fignums() == []
    fig = plot_solution(run)
    assert fig.axes[0].get_title().startswith("f(t = 0.3")
    plt.close(fig)


# --- the run summary ----------------------------------------------------------------------------


def test_summary_counts_steps_as_verdict_json_and_a_failure_stop_as_a_failed_step(tmp_path, capsys):
    scene = tmp_path / "fails.toml"
    scene.write_text(
        'name = "fails"\ngamma = 1.0\nt_end = 0.3\n[v]\nL = 2.0\nn = 121\n[initial]\nkind = "gaussians"\n'
        "amplitudes = [1.0]\nrates = [2.0]\ncentres = [0.0]\n[time]\ndt = 0.05\n"
        '[refine.v]\nbumps = 1\n[collision]\nbeta = 1000.0\nfisher = "log"\noptions = { max_iter = 6 }\n'
    )
    assert main(["run", str(scene), "--out", str(tmp_path / "r"), "--quiet"]) == 0
    text = capsys.readouterr().out
    verdict = json.loads((tmp_path / "r" / "verdict.json").read_text())
    assert verdict["stop"] == "SOLVER_FAILURE" and verdict["steps"] == 1
    assert f"steps = {verdict['steps']}," in text
    assert "steps with a failed collision solve: 1" in text
    assert "max f over the run" in text


def test_an_edited_metadata_json_is_refused_and_an_export_names_the_code_that_ran(tmp_path):
    """metadata.json holds the digests, so no digest covers it: its provenance fields are checked against the
    checkpoint's (whose digest it holds), and an export records the version that computed the run."""
    out = tmp_path / "r"
    run = simulate(default_scene().replace({"t_end": 0.03, "v.n": 41}), out=out)
    back = jko_cvx.load_run(out)
    assert back.made_by == run.made_by and set(run.made_by) == {"jko_cvx", "code_sha256"}
    pytest.importorskip("xarray")
    made = dataclasses.replace(back, made_by={"jko_cvx": "0.0.9", "code_sha256": "ab" * 32})
    attrs = made.to_xarray().attrs
    assert attrs["jko_cvx"] == "0.0.9" and attrs["code_sha256"] == "ab" * 32
    meta = json.loads((out / "metadata.json").read_text())
    for key, forged in (("jko_cvx", "0.0.9"), ("code_sha256", "0" * 64), ("scene_sha256", "1" * 64)):
        (out / "metadata.json").write_text(json.dumps({**meta, key: forged}))
        with pytest.raises(RunDirError, match=rf"metadata.json records {key} = '{forged}', but the checkpoint"):
            jko_cvx.load_run(out)
        with pytest.raises(RunDirError, match=rf"records {key} = '{forged}'"):
            simulate(run.scene, out=out, resume=True)
    (out / "metadata.json").write_text(json.dumps(meta))
    assert jko_cvx.load_run(out).t == run.t
