"""Run data that cannot be silently tampered with, nothing written outside the run directory,
an overwrite that is all or nothing, stray temporary files removed, modes from the umask."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

import jko_cvx.engine._rundir as rundir_module
from jko_cvx import load_run
from jko_cvx.cli import main
from jko_cvx.engine._state import file_sha256
from jko_cvx.engine.errors import RunDirError
from jko_cvx.engine.loop import simulate
from jko_cvx.scene import scene_from_dict

from .test_rundir import SMALL


@pytest.fixture
def run_dir(tmp_path):
    out = tmp_path / "run"
    simulate(scene_from_dict(SMALL), out=out, progress=False)
    return out


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _edit_npz(path: Path, **changes) -> None:
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    for k, fn in changes.items():
        arrays[k] = fn(arrays[k])
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def _forge_digest(root: Path, name: str) -> None:
    """What a deliberate edit would do: recompute the digest the ledger records."""
    meta = json.loads((root / "metadata.json").read_text())
    meta["digests"][name] = [file_sha256(root / name)]
    (root / "metadata.json").write_text(json.dumps(meta))


EDITS = {
    "scaled by 1.01": {"f": lambda f: f * 1.01},
    "negated": {"f": lambda f: -f},
    "NaN": {"f": lambda f: np.where(np.arange(f.size).reshape(f.shape) == 3, np.nan, f)},
    "rewound to step 3": {"t": lambda t: np.array(0.03), "step": lambda s: np.array(3)},
}


def _marked(folder: Path) -> Path:
    """``folder`` made as an overwrite makes ``.replaced``: with the mark written before any move."""
    (folder / "snapshots").mkdir(parents=True)
    (folder / rundir_module._ASIDE_MARK).write_text("moved aside")
    return folder


@pytest.mark.parametrize("edit", EDITS)
@pytest.mark.parametrize("forged", [False, True], ids=["digest kept", "digest recomputed"])
def test_an_edited_checkpoint_is_refused_on_resume_and_by_load_run(run_dir, edit, forged):
    ck = run_dir / "checkpoint.npz"
    _edit_npz(ck, **EDITS[edit])
    if forged:
        _forge_digest(run_dir, "checkpoint.npz")
    why = "does not hold a state this run reached" if forged else "has changed since the run wrote it"
    with pytest.raises(RunDirError, match=rf"{ck}.*{why}"):
        simulate(scene_from_dict(SMALL), out=run_dir, resume=True, progress=False)
    with pytest.raises(RunDirError, match=rf"{ck}.*{why}"):
        load_run(run_dir)


def test_an_edited_snapshot_or_diagnostics_file_is_refused_by_load_run(run_dir):
    snap = run_dir / "snapshots" / "step_0000002.npz"
    original = snap.read_bytes()
    _edit_npz(snap, f=lambda f: f * 2)
    with pytest.raises(RunDirError, match=rf"{snap} has changed since the run wrote it"):
        load_run(run_dir)
    snap.write_bytes(original)
    load_run(run_dir)  # restored: accepted again
    diag = run_dir / "diagnostics.csv"
    diag.write_text(diag.read_text().replace("0.01", "0.02"))
    with pytest.raises(RunDirError, match=rf"{diag} has changed"):
        load_run(run_dir)


@pytest.mark.parametrize(
    "name, how",
    [("scene.json", "edited"), ("diagnostics.csv", "edited"), ("verdict.json", "edited"), ("scene.json", "removed")],
)
def test_resume_checks_every_run_file_before_a_step(run_dir, name, how, monkeypatch):
    """A resume vouches for the whole directory, not only the checkpoint: an edited scene.json, diagnostics.csv or
    verdict.json, or a removed scene.json, is refused before any step, not found later by load_run (a missing
    diagnostics.csv or verdict.json is no tampering: the resumed run writes them)."""
    path = run_dir / name
    if how == "edited":
        path.write_text(path.read_text().replace("0", "1", 1))
    else:
        path.unlink()
    stepped = []
    monkeypatch.setattr(rundir_module.RunDir, "save_state", lambda *a, **k: stepped.append(1))
    why = "has changed since the run wrote it" if how == "edited" else "is missing"
    with pytest.raises(RunDirError, match=rf"{path}.*{why}"):
        simulate(scene_from_dict(SMALL), out=run_dir, resume=True, progress=False)
    assert not stepped


def test_a_snapshot_the_run_did_not_write_is_refused(run_dir):
    shutil.copy(run_dir / "snapshots" / "step_0000002.npz", run_dir / "snapshots" / "step_0000003.npz")
    with pytest.raises(RunDirError, match=r"step_0000003\.npz is not one of the files this run wrote"):
        load_run(run_dir)


def test_a_run_without_digests_is_refused(run_dir):
    meta = json.loads((run_dir / "metadata.json").read_text())
    del meta["digests"]
    (run_dir / "metadata.json").write_text(json.dumps(meta))
    for call in (lambda: load_run(run_dir), lambda: simulate(scene_from_dict(SMALL), out=run_dir, resume=True)):
        with pytest.raises(RunDirError, match="records no file digests"):
            call()


def test_a_run_killed_between_recording_a_digest_and_the_rename_still_resumes(run_dir):
    """The ledger records the new file's digest before the rename: a kill in between leaves the
    old file in place, which the ledger still accepts (and the next write settles)."""
    meta = json.loads((run_dir / "metadata.json").read_text())
    meta["digests"]["checkpoint.npz"] = ["0" * 64, *meta["digests"]["checkpoint.npz"]]
    (run_dir / "metadata.json").write_text(json.dumps(meta))
    simulate(scene_from_dict(SMALL), out=run_dir, resume=True, progress=False)
    assert len(json.loads((run_dir / "metadata.json").read_text())["digests"]["checkpoint.npz"]) == 1


def test_a_planted_lock_link_is_not_followed(tmp_path):
    target = tmp_path / "precious.txt"
    target.write_text("keep me")
    out = tmp_path / "run"
    out.mkdir()
    (out / ".lock").symlink_to(target)
    with pytest.raises(RunDirError, match=r"\.lock is a symbolic link"):
        simulate(scene_from_dict(SMALL), out=out, progress=False)
    assert target.read_text() == "keep me"
    assert (out / ".lock").is_symlink() and not (out / "scene.json").exists()


@pytest.mark.parametrize("entry", ["snapshots", "checkpoint.npz", "scene.json"])
def test_a_planted_link_in_a_run_is_refused_before_anything_is_deleted(run_dir, tmp_path, entry):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    source = run_dir / entry
    moved = elsewhere / entry
    shutil.move(source, moved)
    source.symlink_to(moved)
    before, before_run = _files(elsewhere), _files(run_dir)
    with pytest.raises(RunDirError, match=rf"{entry} is a symbolic link"):
        simulate(scene_from_dict(SMALL), out=run_dir, overwrite=True, progress=False)
    with pytest.raises(RunDirError, match=rf"{entry} is a symbolic link"):
        load_run(run_dir)
    assert _files(elsewhere) == before and _files(run_dir) == before_run


def test_an_empty_out_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="out must name a run directory"):
        simulate(scene_from_dict(SMALL), out="", progress=False)
    with pytest.raises(SystemExit) as exit_:
        main(["run", "--out", "", "--quiet"])
    assert exit_.value.code == 2 and "--out: must name a directory" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_failed_overwrite_leaves_the_old_run_intact(run_dir, monkeypatch):
    before = _files(run_dir)

    def broken(scene, provenance):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(rundir_module, "_metadata", broken)
    with pytest.raises(OSError, match="No space left"):
        simulate(scene_from_dict({**SMALL, "t_end": 0.03}), out=run_dir, overwrite=True, progress=False)
    after = _files(run_dir)
    after.pop(".lock", None), before.pop(".lock", None)
    assert after == before
    load_run(run_dir)


def test_an_overwrite_whose_move_fails_puts_back_what_it_moved(run_dir, monkeypatch):
    before = _files(run_dir)
    real, calls = os.replace, []

    def flaky(src, dst):
        calls.append(src)
        if len(calls) == 4:
            raise PermissionError(13, "Permission denied")
        return real(src, dst)

    monkeypatch.setattr(rundir_module.os, "replace", flaky)
    with pytest.raises(RunDirError, match="the old run is left as it was"):
        simulate(scene_from_dict({**SMALL, "t_end": 0.03}), out=run_dir, overwrite=True, progress=False)
    monkeypatch.undo()
    after = _files(run_dir)
    after.pop(".lock", None), before.pop(".lock", None)
    assert after == before and not (run_dir / ".replaced").exists()


def test_an_overwrite_killed_within_its_move_keeps_the_files_it_had_not_moved(run_dir):
    """A kill after the overwrite moved some of the old run's files aside: the next open puts those back and keeps
    the ones still in place (they are the old run's, not the new one's)."""
    before = _files(run_dir)
    aside = _marked(run_dir / ".replaced")
    os.replace(run_dir / "scene.json", aside / "scene.json")  # the first rename of the move, then the kill
    with pytest.raises(RunDirError, match="already holds a run"):
        simulate(scene_from_dict(SMALL), out=run_dir, progress=False)
    after = _files(run_dir)
    after.pop(".lock", None), before.pop(".lock", None)
    assert after == before and not aside.exists()
    load_run(run_dir)


def test_a_replaced_folder_of_the_users_deletes_nothing(tmp_path):
    """DIR/.replaced that holds no run this package moved aside: the open is refused and no file is touched."""
    out = tmp_path / "ud"
    (out / ".replaced").mkdir(parents=True)
    (out / ".replaced" / "scene.json").write_text("{}")  # not empty (an empty one is a kill before the mark)
    (out / "reference").mkdir()
    (out / "reference" / "data.txt").write_text("precious")
    (out / "records.png").write_text("mine")
    before = _files(out)
    with pytest.raises(RunDirError, match=r"\.replaced is not a folder this package made"):
        simulate(scene_from_dict(SMALL), out=out, progress=False)
    after = _files(out)
    after.pop(".lock", None)
    assert after == before and (out / ".replaced").is_dir()


@pytest.mark.parametrize("name", [".replaced", ".replaced.done"])
def test_a_folder_of_the_users_beside_a_run_touches_neither(run_dir, name):
    """A user's own .replaced (or .replaced.done) beside a finished run, holding files with run names: every open
    is refused and neither the run nor the user's files change."""
    mine = run_dir / name
    mine.mkdir()
    (mine / "diagnostics.csv").write_text("my own table")
    (mine / "notes.txt").write_text("my notes")
    before = _files(run_dir)
    for call in (
        lambda: simulate(scene_from_dict(SMALL), out=run_dir, resume=True, progress=False),
        lambda: simulate(scene_from_dict(SMALL), out=run_dir, overwrite=True, progress=False),
    ):
        with pytest.raises(RunDirError, match="is not a folder this package made"):
            call()
    after = _files(run_dir)
    after.pop(".lock", None), before.pop(".lock", None)
    assert after == before


def test_an_overwrite_killed_while_deleting_the_old_run_is_finished_on_the_next_open(run_dir):
    """The old run is renamed to .replaced.done (one step) and emptied with its mark last: a kill midway leaves a
    marked folder, which the next open deletes; the new run beside it is untouched."""
    diagnostics = (run_dir / "diagnostics.csv").read_bytes()
    done = _marked(run_dir / ".replaced.done")
    (done / "checkpoint.npz").write_bytes(b"the old run's, half deleted")
    simulate(scene_from_dict(SMALL), out=run_dir, resume=True, progress=False)  # a finished run: nothing to step
    assert not done.exists() and (run_dir / "diagnostics.csv").read_bytes() == diagnostics
    load_run(run_dir)


def test_an_overwrite_leaves_no_folder_of_the_old_run(run_dir):
    simulate(scene_from_dict({**SMALL, "t_end": 0.03}), out=run_dir, overwrite=True, progress=False)
    assert not any(p.name.startswith(".replaced") for p in run_dir.iterdir())
    load_run(run_dir)


def test_an_overwrite_killed_midway_is_put_back_on_the_next_open(run_dir):
    before = _files(run_dir)
    aside = _marked(run_dir / ".replaced")
    for p in sorted(run_dir.rglob("*")):  # the state a kill leaves: old run aside, the new one begun
        if p.is_file() and ".replaced" not in p.parts and p.name not in (".lock", rundir_module._ASIDE_MARK):
            os.replace(p, aside / p.relative_to(run_dir))
    (run_dir / "scene.json").write_text("{}")
    with pytest.raises(RunDirError, match="an overwrite of it was interrupted"):
        load_run(run_dir)
    with pytest.raises(RunDirError, match="already holds a run"):
        simulate(scene_from_dict(SMALL), out=run_dir, progress=False)
    after = _files(run_dir)
    after.pop(".lock", None), before.pop(".lock", None)
    assert after == before
    load_run(run_dir)


def test_stray_temporary_files_of_a_killed_write_are_removed(run_dir):
    strays = [
        run_dir / ".checkpoint.npz.jko_tmp.ab12cd34",
        run_dir / "snapshots" / ".step_0000004.npz.jko_tmp.x_y9zq0w",
    ]
    keep = [
        run_dir / ".notes.txt.jko_tmp.abcdefgh",
        run_dir / "snapshots" / "mine.txt",
        run_dir / ".checkpoint.npz.ab12cd34",
    ]
    for p in strays + keep:
        p.write_text("partial")
    simulate(scene_from_dict(SMALL), out=run_dir, resume=True, progress=False)
    assert not any(p.exists() for p in strays) and all(p.exists() for p in keep)


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_run_files_follow_the_umask(tmp_path, umask):
    old = os.umask(umask)
    try:
        simulate(scene_from_dict(SMALL), out=tmp_path / "run", progress=False)
    finally:
        os.umask(old)
    modes = {p.name: p.stat().st_mode & 0o777 for p in (tmp_path / "run").rglob("*") if p.is_file()}
    assert set(modes.values()) == {0o666 & ~umask}, modes


@pytest.mark.parametrize("name", ["metadata.json", "scene.json", "verdict.json"])
def test_a_json_file_nested_thousands_deep_is_a_run_dir_error(run_dir, name):
    (run_dir / name).write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(RunDirError, match=name.replace(".", r"\.")):
        load_run(run_dir)


@pytest.mark.parametrize(
    "error",
    [OSError(27, "File too large"), OSError(28, "No space left on device"), PermissionError(13, "Permission denied")],
    ids=["EFBIG", "ENOSPC", "EACCES"],
)
def test_a_write_that_fails_names_the_run_file_not_a_temporary_one(run_dir, monkeypatch, capsys, error):
    """A full disk or an unwritable run directory: exit 2, one line naming the file in the run
    directory (the temporary file beside it is an implementation detail, and is removed)."""
    import jko_cvx.engine._state as state_module

    real = np.savez

    def failing_savez(fh, **arrays):
        if "f" in arrays and "t" in arrays and "rows" in arrays:  # the checkpoint
            raise error
        real(fh, **arrays)

    monkeypatch.setattr(state_module.np, "savez", failing_savez)
    toml = run_dir.parent / "small.toml"
    from .test_interrupt_anywhere import _toml

    toml.write_text(_toml(SMALL))
    assert main(["run", str(toml), "--out", str(run_dir), "--overwrite", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"cannot write {run_dir / 'checkpoint.npz'}" in err[0] and error.strerror in err[0]
    assert not [p.name for p in run_dir.iterdir() if p.name.startswith(".checkpoint.npz.")]


def test_a_finished_run_reads_back_whatever_the_size_limits_here(run_dir, monkeypatch):
    """The size limits guard a run's start; reading back what a run wrote does not depend on this machine's
    JKO_CVX_MAX_GIB or JKO_CVX_THREADS (the conic estimate grows with the slice threads)."""
    monkeypatch.setenv("JKO_CVX_MAX_GIB", "1e-9")
    monkeypatch.setenv("JKO_CVX_THREADS", "64")
    assert load_run(run_dir).steps > 0


def test_an_empty_replaced_folder_of_the_users_is_refused_not_deleted(run_dir):
    """The overwrite renames .replaced into place already marked, so an unmarked one, even empty, is the user's."""
    (run_dir / ".replaced" / "snapshots").mkdir(parents=True)
    with pytest.raises(RunDirError, match="is not a folder this package made"):
        simulate(scene_from_dict(SMALL), out=run_dir, resume=True, progress=False)
    with pytest.raises(RunDirError, match="is not a folder this package made"):
        load_run(run_dir)
    assert (run_dir / ".replaced" / "snapshots").is_dir()


def test_what_a_kill_before_the_aside_folder_was_renamed_leaves_is_removed(run_dir):
    made = run_dir / ".replaced.tmpab12cd34"
    _marked(made)
    simulate(scene_from_dict(SMALL), out=run_dir, resume=True, progress=False)
    assert not made.exists()


def test_load_run_names_an_interrupted_overwrite_that_moved_scene_json_aside(run_dir):
    aside = _marked(run_dir / ".replaced")
    os.replace(run_dir / "scene.json", aside / "scene.json")
    with pytest.raises(RunDirError, match="an overwrite of it was interrupted"):
        load_run(run_dir)


def _user_files(folder: Path) -> dict[str, bytes | None]:
    """Every entry of ``folder`` with its bytes (None for a folder)."""
    return {p.relative_to(folder).as_posix(): (p.read_bytes() if p.is_file() else None) for p in folder.rglob("*")}


def test_a_refused_run_leaves_a_directory_of_the_users_exactly_as_it_was(tmp_path, capsys):
    """Names that look like the package's (a lock, a temporary file, the aside folder's temporary name) in a directory
    that never held a run: the refused command neither truncates, deletes nor creates anything there."""
    out = tmp_path / "mine"
    out.mkdir()
    (out / "diagnostics.csv").write_text("my own table\n")  # a run-like name: the run is refused
    (out / ".diagnostics.csv.20240101").write_text("a dated backup\n")  # 8 characters, as mkstemp's names
    (out / ".replaced.tmp_notes").mkdir()  # an empty folder under the aside folder's temporary prefix
    before = _user_files(out)
    assert main(["run", "--quiet", "--set", "t_end=0.02", "--set", "v.n=21", "--out", str(out), "--overwrite"]) == 2
    assert "no run this package wrote" in capsys.readouterr().err
    lock = _user_files(out).pop(".lock")  # the lock it took, never unlinked (a waiting process holds the file)
    assert lock is not None and lock.isdigit()
    assert {k: v for k, v in _user_files(out).items() if k != ".lock"} == before
    (out / ".lock").unlink()
    (out / ".lock").write_text("team lock: do not touch\n")  # not a process id: not the package's lock
    before = _user_files(out)
    assert main(["run", "--quiet", "--set", "t_end=0.02", "--set", "v.n=21", "--out", str(out), "--overwrite"]) == 2
    assert "is not the lock of a run of this package" in capsys.readouterr().err
    assert _user_files(out) == before


def test_a_run_beside_files_that_look_temporary_keeps_them(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / ".diagnostics.csv.20240101").write_text("a dated backup\n")
    (out / ".records.png.abcd1234").write_text("not a figure of ours\n")
    simulate(scene_from_dict(SMALL), out=out, progress=False)
    assert (out / ".diagnostics.csv.20240101").read_text() == "a dated backup\n"
    assert (out / ".records.png.abcd1234").exists()


def test_a_figure_left_half_written_by_a_kill_is_removed_on_the_next_start(run_dir):
    stale = run_dir / ".records.png.jko_tmp.ab12cd34"  # what atomic_write names it
    stale.write_bytes(b"\x89PNG half")
    simulate(scene_from_dict(SMALL), out=run_dir, resume=True, progress=False)
    assert not stale.exists()
