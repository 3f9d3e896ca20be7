"""Run directories: provenance on resume, no silent overwrite, one run at a time, interruptions, damaged files."""

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest

import jko_cvx.engine._rundir as rundir_module
from jko_cvx import load_run
from jko_cvx.cli import main
from jko_cvx.engine._rundir import RunDir, scene_differences, scene_fingerprint
from jko_cvx.engine.errors import RunDirError
from jko_cvx.engine.loop import simulate
from jko_cvx.scene.model import load_scene, scene_from_dict

SMALL = {
    "name": "small",
    "gamma": 1.0,
    "t_end": 0.05,
    "v": {"L": 2.0, "n": 41},
    "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
    "time": {"dt": 0.01},
    "output": {"every": 2, "checkpoint_every": 2},
}

# gamma = 3, two bumps on a refined grid (ibu_gamma3 on a shorter interval): 800 steps, about 2 s
LONG_TOML = """
name = "interrupt_me"
gamma = 3.0
t_end = 8.0
[v]
L = 3.0
n = 101
[initial]
kind = "gaussians"
amplitudes = [1.0, 1.0]
rates = [10.0, 10.0]
centres = [1.5, -1.5]
[time]
dt = 0.01
[refine.v]
bumps = 2
delta0 = 0.8
delta = 0.5
tol = 0.1
[collision]
beta = 1e4
fisher = "log"
[output]
every = 20
checkpoint_every = 100000   # the only checkpoint is the one the interruption writes
"""


def _small(changes=None):
    return scene_from_dict(SMALL).replace(changes or {})


def _cli(*args, check_rc=None):
    env = dict(os.environ, PYTHONUNBUFFERED="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-m", "jko_cvx.cli", *args], env=env, capture_output=True, text=True)
    if check_rc is not None:
        assert proc.returncode == check_rc, proc.stderr
    return proc


# --- provenance --------------------------------------------------------------------------------


def test_the_fingerprint_is_the_scene_and_only_the_scene():
    a, b = _small(), _small()
    assert scene_fingerprint(a) == scene_fingerprint(b) and len(scene_fingerprint(a)) == 64
    assert scene_fingerprint(_small({"gamma": 2.0})) != scene_fingerprint(a)
    assert scene_fingerprint(_small({"collision.options": {"max_iter": 7}})) != scene_fingerprint(a)
    diff = scene_differences({"gamma": 1.0, "refine_v": {"tol": 0.1}}, {"gamma": 2.0, "refine_v": {"tol": 0.2}, "k": 1})
    assert diff == ["gamma: 1.0 -> 2.0", "k: (absent) -> 1", "refine_v.tol: 0.1 -> 0.2"]


def test_the_run_directory_records_the_fingerprint_and_version(tmp_path):
    scene = _small()
    simulate(scene, out=tmp_path / "r")
    meta = json.loads((tmp_path / "r" / "metadata.json").read_text())
    assert meta["scene_sha256"] == scene_fingerprint(scene) and meta["jko_cvx"] == rundir_module.__version__
    assert meta["numpy"] == np.__version__ and meta["blas"] and {"git_commit", "cvxpy", "clarabel"} <= set(meta)
    ck = np.load(tmp_path / "r" / "checkpoint.npz")
    assert str(ck["scene_sha256"]) == scene_fingerprint(scene) and str(ck["jko_cvx"]) == rundir_module.__version__


def test_resume_refuses_another_scene_and_names_what_differs(tmp_path):
    out = tmp_path / "r"
    simulate(_small({"t_end": 0.1}), out=out)
    changed = _small({"t_end": 0.1, "gamma": 2.0, "time.dt": 0.02})
    named = r"not the one its checkpoint was made from \(gamma: 1.0 -> 2.0; time\.dt: 0.01 -> 0.02\)"
    with pytest.raises(RunDirError, match=named):
        simulate(changed, out=out, resume=True)
    with pytest.raises(RunDirError, match="the keys cannot be named"):  # scene.json gone: still refused
        (out / "scene.json").unlink()
        simulate(changed, out=out, resume=True)


def test_scene_differences_name_the_keys_that_differ_and_nothing_else():
    """An empty table has no keys: solver options dropped from a scene differ by the option, not also by a
    "table: (absent) -> {}" line beside it."""
    from jko_cvx.engine._rundir import scene_differences

    old = {"gamma": 1.0, "collision": {"method": "newton", "options": {"max_iter": 5}}}
    new = {"gamma": 1.0, "collision": {"method": "newton", "options": {}}}
    assert scene_differences(old, new) == ["collision.options.max_iter: 5 -> (absent)"]
    assert scene_differences(new, old) == ["collision.options.max_iter: (absent) -> 5"]
    assert scene_differences(new, {"gamma": 1.0, "collision": {"method": "newton"}}) == []


def test_resume_refuses_a_checkpoint_of_another_package_version(tmp_path, monkeypatch):
    out = tmp_path / "r"
    simulate(_small(), out=out)
    monkeypatch.setattr(rundir_module, "__version__", "99.0")
    with pytest.raises(RunDirError, match=r"made by jko_cvx .* this is 99.0"):
        simulate(_small(), out=out, resume=True)


def test_resume_refuses_a_checkpoint_made_by_other_code_of_the_same_version(tmp_path, monkeypatch):
    # an edited checkout keeps its version number: the code itself must match, or the run would mix two codes
    out = tmp_path / "r"
    simulate(_small({"t_end": 0.1}), out=out)
    ck = np.load(out / "checkpoint.npz")
    meta = json.loads((out / "metadata.json").read_text())
    assert str(ck["code_sha256"]) == meta["code_sha256"] == rundir_module.code_fingerprint()
    monkeypatch.setattr(rundir_module, "code_fingerprint", lambda: "f" * 64)
    with pytest.raises(
        RunDirError,
        match=r"made by other jko_cvx code .*code SHA-256 [0-9a-f]{12}\.\.\. then, "
        r"ffffffffffff\.\.\. now.*--overwrite",
    ):
        simulate(_small({"t_end": 0.1}), out=out, resume=True)
    assert load_run(out).t == pytest.approx(0.1)  # reading the finished run back is not refused


def test_resume_refuses_a_checkpoint_without_a_code_fingerprint(tmp_path):
    from jko_cvx.engine._state import Ledger

    out = tmp_path / "r"
    simulate(_small({"t_end": 0.1}), out=out)
    with np.load(out / "checkpoint.npz") as ck:
        arrays = {k: ck[k] for k in ck.files if k != "code_sha256"}
    Ledger.read(out).save_npz(out / "checkpoint.npz", **arrays)  # as a version without the fingerprint wrote it
    with pytest.raises(RunDirError, match=r"records no code fingerprint .* cannot be continued.*--overwrite"):
        simulate(_small({"t_end": 0.1}), out=out, resume=True)
    assert load_run(out).t == pytest.approx(0.1)


def test_a_resume_records_where_its_environment_differs_from_the_first_legs(tmp_path, monkeypatch):
    # numbers computed with other library versions or another BLAS are not bit for bit the uninterrupted run's: the
    # resume is allowed (the code is the same) and metadata.json says which leg ran where
    out = tmp_path / "r"
    simulate(_small({"t_end": 0.1}), out=out)
    simulate(_small({"t_end": 0.1}), out=out, resume=True)
    legs = json.loads((out / "metadata.json").read_text())["resumed"]
    assert len(legs) == 1 and legs[0]["environment_differs"] == {} and legs[0]["at_step"] == 10
    real = rundir_module.environment
    monkeypatch.setattr(rundir_module, "environment", lambda: {**real(), "numpy": "0.0.1"})
    simulate(_small({"t_end": 0.1}), out=out, resume=True)
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["resumed"][1]["environment_differs"] == {"numpy": [np.__version__, "0.0.1"]}
    assert meta["numpy"] == np.__version__  # the first leg's record is kept
    assert load_run(out).steps == 10


def test_resume_with_nothing_to_resume_fails(tmp_path):
    with pytest.raises(RunDirError, match=r"nothing to resume: run directory .* does not exist"):
        simulate(_small(), out=tmp_path / "none", resume=True)
    (tmp_path / "empty").mkdir()
    with pytest.raises(RunDirError, match=r"nothing to resume in .*empty: it has no checkpoint\.npz"):
        simulate(_small(), out=tmp_path / "empty", resume=True)
    with pytest.raises(ValueError, match="need a run directory"):
        simulate(_small(), resume=True)


def test_a_checkpoint_without_provenance_is_refused(tmp_path):
    out = tmp_path / "r"
    simulate(_small(), out=out)
    ck = dict(np.load(out / "checkpoint.npz"))
    del ck["scene_sha256"]
    np.savez(out / "checkpoint.npz", **ck)
    with pytest.raises(RunDirError, match="records no scene fingerprint"):
        simulate(_small(), out=out, resume=True)


# --- no silent overwrite, one run at a time ------------------------------------------------------


def test_a_rerun_refuses_an_existing_run_unless_overwrite(tmp_path):
    out = tmp_path / "r"
    first = simulate(_small({"t_end": 0.1}), out=out)
    (out / "notes.txt").write_text("mine")
    (out / "snapshots" / "step_0009999.npz").write_bytes(b"stale")  # a file of the old run
    with pytest.raises(RunDirError, match=r"already holds a run \(scene.json, .*--overwrite"):
        simulate(_small(), out=out)
    assert np.array_equal(load_run(out).f, first.f)  # untouched by the refusal
    second = simulate(_small(), out=out, overwrite=True)
    assert (out / "notes.txt").read_text() == "mine"  # only the run's own files are replaced
    assert not (out / "snapshots" / "step_0009999.npz").exists()
    assert load_run(out).t == second.t == pytest.approx(0.05)
    with pytest.raises(ValueError, match="resume and overwrite exclude each other"):
        simulate(_small(), out=out, resume=True, overwrite=True)


def test_a_locked_run_directory_is_refused_and_the_lock_dies_with_its_run(tmp_path):
    out = tmp_path / "r"
    with RunDir.open(out, _small()):
        with pytest.raises(RunDirError, match=rf"run directory {out} is in use by another run \(process {os.getpid()}"):
            simulate(_small(), out=out, overwrite=True)
    simulate(_small(), out=out, overwrite=True)  # released on exit
    holder = subprocess.Popen(
        [sys.executable, "-c", f"import fcntl, os, time; fd = os.open({str(out / '.lock')!r}, os.O_RDWR); "
         "fcntl.flock(fd, fcntl.LOCK_EX); print('locked', flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "locked"
        proc = _cli("run", "--out", str(out), "--overwrite", "--quiet")
        assert proc.returncode == 2 and "is in use by another run" in proc.stderr and "Traceback" not in proc.stderr
    finally:
        holder.kill()
        holder.wait()
    simulate(_small(), out=out, overwrite=True)  # a killed holder leaves no stale lock


def test_overwrite_refuses_files_no_run_wrote_and_deletes_nothing(tmp_path):
    # a directory of the user's with names a run uses (a "reference" folder, a figure), but no run in it
    out = tmp_path / "project"
    (out / "reference").mkdir(parents=True)
    (out / "reference" / "measurements.csv").write_text("data\n")
    (out / "records.png").write_bytes(b"my own figure")
    before = sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    with pytest.raises(RunDirError, match=r"cannot overwrite .*project: it holds records\.png, reference but no run"):
        simulate(_small(), out=out, overwrite=True)
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.name != ".lock") == before
    assert (out / "reference" / "measurements.csv").read_text() == "data\n"


def test_overwrite_of_a_run_refuses_a_file_the_run_did_not_write(tmp_path):
    out = tmp_path / "r"
    simulate(_small(), out=out)
    (out / "verify.csv").write_text("a table of mine\n")  # not written by this run (it was no verification)
    (out / "verify.png").write_bytes(b"my figure")  # nor this: a verification records its figure in the ledger
    (out / "reference").mkdir()  # nor this folder: it holds no run
    with pytest.raises(RunDirError, match=r"verify\.csv is not one of the files the run in .* wrote"):
        simulate(_small(), out=out, overwrite=True)
    assert (out / "verify.csv").read_text() == "a table of mine\n" and (out / "reference").is_dir()
    (out / "verify.csv").unlink()
    with pytest.raises(RunDirError, match=r"verify\.png is not one of the files the run in .* wrote"):
        simulate(_small(), out=out, overwrite=True)
    (out / "verify.png").unlink()
    with pytest.raises(RunDirError, match=r"reference is not a run directory this package wrote"):
        simulate(_small(), out=out, overwrite=True)
    (out / "reference").rmdir()
    assert simulate(_small(), out=out, overwrite=True).steps == load_run(out).steps  # the run's own files go


def test_a_deleted_snapshot_is_named_by_load_run_and_resume(tmp_path):
    out = tmp_path / "r"
    simulate(_small({"t_end": 0.1}), out=out)
    gone = out / "snapshots" / "step_0000002.npz"
    gone.unlink()  # load_run would hand out the next snapshot for t = 0.02
    for read in (lambda: load_run(out), lambda: simulate(_small({"t_end": 0.1}), out=out, resume=True)):
        with pytest.raises(RunDirError, match=r"step_0000002\.npz is recorded in .*metadata\.json but missing"):
            read()


def test_on_finish_runs_while_the_run_directory_is_still_locked(tmp_path):
    # the CLI draws its figures here: another run cannot take the directory over in between
    out, seen = tmp_path / "r", []

    def other_run(run):
        with pytest.raises(RunDirError, match=r"in use by another run"):
            simulate(_small(), out=out, overwrite=True)
        seen.append(run.t)

    simulate(_small(), out=out, on_finish=other_run)
    assert seen == [pytest.approx(0.05)]
    simulate(_small(), out=out, overwrite=True)  # released afterwards


def test_cli_rerun_resume_and_overwrite(tmp_path, capsys):
    out = tmp_path / "r"
    scene = tmp_path / "s.toml"
    scene.write_text(
        'name = "s"\ngamma = 1.0\nt_end = 0.05\n[v]\nL = 2.0\nn = 41\n[initial]\nkind = "gaussians"\n'
        "amplitudes = [1.0]\nrates = [2.0]\ncentres = [0.0]\n[time]\ndt = 0.01\n"
    )
    run = ["run", str(scene), "--out", str(out), "--quiet"]
    assert main(run) == 0
    assert main(run) == 2 and "already holds a run" in capsys.readouterr().err
    assert main([*run, "--overwrite"]) == 0
    assert main([*run, "--resume"]) == 0  # an ended run: nothing left to do
    capsys.readouterr()
    scene.write_text(scene.read_text().replace("gamma = 1.0", "gamma = 1.5"))
    assert main([*run, "--resume"]) == 2 and "gamma: 1.0 -> 1.5" in capsys.readouterr().err
    assert main(["run", str(scene), "--out", str(tmp_path / "no"), "--resume"]) == 2
    assert "nothing to resume" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse: the two exclude each other
        main([*run, "--resume", "--overwrite"])


# --- damaged files ------------------------------------------------------------------------------


def test_damaged_checkpoint_or_snapshot_is_named_on_resume(tmp_path, capsys):
    out = tmp_path / "r"
    simulate(_small(), out=out)
    ck = out / "checkpoint.npz"
    good = ck.read_bytes()
    ck.write_bytes(good[: len(good) // 3])
    with pytest.raises(RunDirError, match=rf"checkpoint {ck} is corrupted or truncated"):
        simulate(_small(), out=out, resume=True)
    assert main(["run", "--out", str(out), "--resume", "--quiet"]) == 2  # the default scene: the same refusal
    assert f"checkpoint {ck} is corrupted" in capsys.readouterr().err
    ck.write_bytes(b"PK not really")
    with pytest.raises(RunDirError, match=rf"checkpoint {ck} is corrupted or truncated \(not an \.npz archive\)"):
        simulate(_small(), out=out, resume=True)
    ck.write_bytes(good)
    snap = out / "snapshots" / "step_0000002.npz"
    snap.write_bytes(snap.read_bytes()[:100])
    with pytest.raises(RunDirError, match=rf"snapshot {snap} is corrupted or truncated"):
        simulate(_small(), out=out, resume=True)
    with pytest.raises(RunDirError, match=rf"snapshot {snap} is corrupted or truncated"):
        load_run(out)


# --- interruptions ------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def long_scene(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "interrupt_me.toml"
    path.write_text(LONG_TOML)
    return path, simulate(load_scene(path))


def _assert_same_run(a, b):
    assert a.t == b.t and a.verdict == b.verdict
    assert np.array_equal(a.f, b.f) and np.array_equal(a.vgrid.points, b.vgrid.points)
    pd.testing.assert_frame_equal(a.diagnostics, b.diagnostics, check_exact=True)
    assert [s["step"] for s in a.snapshots] == [s["step"] for s in b.snapshots]
    for s, r in zip(a.snapshots, b.snapshots, strict=True):
        assert np.array_equal(s["f"], r["f"]) and np.array_equal(s["v"], r["v"])


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupted_run_checkpoints_says_how_to_resume_and_resumes_bit_for_bit(tmp_path, long_scene, signum):
    scene_file, fresh = long_scene
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONUNBUFFERED="1", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "jko_cvx.cli", "run", str(scene_file), "--out", str(out), "--quiet"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    first = out / "snapshots" / "step_0000020.npz"
    deadline = time.time() + 120
    while not first.exists() and time.time() < deadline and proc.poll() is None:
        time.sleep(0.01)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "Traceback" not in err and f"interrupted ({signal.Signals(signum).name})" in err
    step = int(np.load(out / "checkpoint.npz")["step"])
    assert 20 <= step < 800, "interrupted mid-way (checkpoint_every is larger than the run: this is the signal's)"
    assert f"at step {step}," in err and not (out / "verdict.json").exists()
    command = re.search(r"Resume with:\n\s+(.*)", err).group(1)
    assert command == shlex.join(["jko-cvx", "run", str(scene_file), "--out", str(out), "--resume"])
    assert main([*shlex.split(command)[1:], "--quiet"]) == 0
    _assert_same_run(load_run(out), fresh)


def test_a_run_written_before_a_scene_key_was_added_still_loads_and_an_edited_one_does_not(tmp_path, monkeypatch):
    """A version without ``refine.v.junction`` wrote scene.json and its fingerprint without that key; read now, the
    key takes its default (the run loads, the scene is the one that ran).  A record edited beyond that (a value
    changed, digests and all) is still refused."""
    from jko_cvx.scene.model import Scene, shipped_scene

    plain = Scene.to_dict

    def without_junction(self):
        d = plain(self)
        d["refine"]["v"].pop("junction")
        return d

    monkeypatch.setattr(Scene, "to_dict", without_junction)
    simulate(shipped_scene("tab_bu_g1", {"v.n": 41, "t_end": 0.03}), out=tmp_path / "old")
    assert "junction" not in json.loads((tmp_path / "old" / "scene.json").read_text())["refine"]["v"]
    monkeypatch.setattr(Scene, "to_dict", plain)
    run = load_run(tmp_path / "old")
    assert run.scene.refine.v.junction == "paper" and run.scene.v.n == 41
    # the same record with a value changed is no earlier version's: refused, even with its digest made to agree
    record = json.loads((tmp_path / "old" / "scene.json").read_text())
    record["collision"]["beta"] = 7000.0
    (tmp_path / "old" / "scene.json").write_text(json.dumps(record))
    with pytest.raises(RunDirError, match="does not rebuild the scene"):
        load_run(tmp_path / "old")
