"""Run directories: provenance, the lock, resume and overwrite rules.

A run directory holds ``scene.json``, ``metadata.json`` (package and solver versions, git
commit, BLAS library, kernel and threads: :func:`jko_cvx.environment.environment`; the scene
fingerprint), ``diagnostics.csv``, ``snapshots/step_*.npz``, ``checkpoint.npz`` and, once
the run has ended, ``verdict.json`` (the CLI adds ``solution.png`` and ``records.png``).

Rules (each refusal is a :class:`~jko_cvx.engine.errors.RunDirError` naming the directory or file):

* a new run refuses a directory that already holds a run, unless ``overwrite``, which moves
  that run's files (and only those) aside into ``DIR/.replaced/`` -- and refuses, deleting nothing,
  where an entry it would remove is not the run's: a directory without a run this package wrote
  (no ``metadata.json`` with digests), a run or verification file the ledger does not record, a
  ``reference`` folder that is no run directory --, writes the new run's
  ``scene.json`` and ``metadata.json``, and only then deletes them: a failed overwrite puts the
  old run back, and one killed meanwhile is put back when the directory is next opened;
* ``resume`` needs a checkpoint, made from the same scene (the SHA-256 of the canonical JSON
  of ``scene.to_dict()``; a refusal names the keys that differ) by the same package version and
  the same code (:func:`~jko_cvx.environment.code_fingerprint`, the SHA-256 of the package's
  files: an edited checkout keeps its version number, and a run continued under other
  code would mix two codes' steps in one record);
* every file the run writes has its SHA-256 recorded in ``metadata.json``
  (:class:`~jko_cvx.engine._state.Ledger`); ``resume`` and :func:`~jko_cvx.engine.run.load_run`
  refuse a file whose digest differs and a state whose invariants fail
  (:meth:`~jko_cvx.engine._state.RunState.check`);
* nothing outside the directory is written, followed or deleted: an entry of the run that is a
  symbolic link (``.lock``, ``snapshots``, any run file) is refused, not followed, and the lock
  is opened with ``O_NOFOLLOW``;
* temporary files a killed write left (``.checkpoint.npz.XXXXXXXX``) are removed on the next open;
* one run at a time: an exclusive, non-blocking ``fcntl.flock`` on ``DIR/.lock``, held
  until the run returns (the kernel drops it when a process dies, so a killed run leaves no
  stale lock).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from jko_cvx._version import __version__
from jko_cvx.engine._state import TEMP_FILE, Ledger, RunState, read_snapshot
from jko_cvx.engine._table import csv_text
from jko_cvx.engine.errors import RunDirError
from jko_cvx.environment import PACKAGES, code_fingerprint, environment
from jko_cvx.scene.model import Scene

__all__ = ["RunDir", "canonical_scene", "flat_scene_record", "read_snapshots", "scene_differences", "scene_fingerprint"]

RUN_FILES = ("scene.json", "metadata.json", "checkpoint.npz", "diagnostics.csv", "verdict.json")
FIGURES = ("solution.png", "records.png")
VERIFY_FILES = ("verify.json", "verify.csv", "verify.md", "verify.png", "trajectory.csv", "reference")
ENTRY_NAMES = (".lock", "snapshots", *RUN_FILES, *FIGURES, *VERIFY_FILES)
"""The names of a run directory's own entries (besides the snapshot files in ``snapshots/``)."""
"""A verification's files beside the run's (:mod:`jko_cvx.engine.verify`; ``reference/`` holds the reference's
run): moved aside by an overwrite too."""
_SNAPSHOT = re.compile(r"step_(\d+)\.npz")
_NUMERIC_ENVIRONMENT = ("python", *PACKAGES, "machine", "cpu", "cpu_count", "blas")
"""The keys of :func:`~jko_cvx.environment.environment` a run's numbers may depend on (a resumed leg records where
they differ from the first leg's)."""
_ASIDE = ".replaced"  # an overwritten run, kept until the new run has started
_DISCARDED = ".replaced.done"  # the same, renamed once the new run has started, while it is deleted
_ASIDE_TMP = ".replaced.tmp"  # the name .replaced is made under, before its mark makes it the package's
_ASIDE_TMP_NAME = re.compile(re.escape(_ASIDE_TMP) + r"[a-z0-9_]{8}")  # tempfile.mkdtemp's names, and no others
_ASIDE_MARK = ".moved_aside_by_jko_cvx"
"""The file that makes ``.replaced`` (and ``.replaced.done``) a folder this package made: written first, deleted
last; a folder of that name without it is the user's, and nothing in or beside it is deleted or restored."""


def canonical_scene(scene: Scene) -> str:
    """The scene as canonical JSON: ``scene.to_dict()`` with sorted keys and no whitespace."""
    return json.dumps(scene.to_dict(), sort_keys=True, separators=(",", ":"), default=str)


def scene_fingerprint(scene: Scene) -> str:
    """SHA-256 (hex) of :func:`canonical_scene`."""
    return record_fingerprint(scene.to_dict())


def record_fingerprint(record: dict[str, Any]) -> str:
    """SHA-256 (hex) of a scene record (``scene.json`` as read) in the canonical JSON of :func:`canonical_scene`."""
    return hashlib.sha256(json.dumps(record, sort_keys=True, separators=(",", ":"), default=str).encode()).hexdigest()


_FLAT_FIELDS = frozenset({"v_L", "v_n", "dt", "policy", "method", "every", "snapshot_times"})


def flat_scene_record(record: Any) -> bool:
    """True for a scene record in the flat field layout of earlier versions (``v_n``, ``dt``, ...)."""
    return isinstance(record, dict) and bool(_FLAT_FIELDS & set(record))


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):  # an empty table has no keys: the same scene as the table left out
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def scene_differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """``"key: old -> new"`` for each dotted key whose value differs between two scene records."""
    a, b = _flatten(old), _flatten(new)
    keys = sorted(k for k in a.keys() | b.keys() if a.get(k, _ABSENT) != b.get(k, _ABSENT))
    return [f"{k}: {a.get(k, _ABSENT)!r} -> {b.get(k, _ABSENT)!r}" for k in keys]


def only_added(old: dict[str, Any], new: dict[str, Any]) -> bool:
    """Every dotted key whose value differs between two scene records is one that ``old`` lacks (a key added to
    the scene since ``old`` was written, at the value ``new`` gives it)."""
    a, b = _flatten(old), _flatten(new)
    return all(k not in a for k in a.keys() | b.keys() if a.get(k, _ABSENT) != b.get(k, _ABSENT))


class _Absent:
    def __repr__(self) -> str:
        return "(absent)"


_ABSENT = _Absent()


def _metadata(scene: Scene, provenance: dict[str, str]) -> dict[str, Any]:
    """What ``metadata.json`` records: the scene, the start time, :func:`jko_cvx.environment.environment`
    (package and library versions, git commit, the BLAS library, its kernel and threads) and the fingerprints of
    ``provenance`` (the run directory's, taken when it was opened: the package is not hashed again)."""
    return {
        **environment(),
        "code_sha256": provenance["code_sha256"],
        "scene_sha256": provenance["scene_sha256"],
        "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "scene": scene.name,
    }


def read_snapshots(path: Path, last_step: int, ledger: Ledger | None = None) -> list[dict[str, Any]]:
    """The snapshot files in ``path/snapshots`` of steps ``<= last_step``, in step order, each checked
    against ``ledger`` when given (a snapshot whose step is not its name's is refused too, and so is one the
    ledger records that is gone: the snapshots asked for by time would silently skip it)."""
    found = []
    for p in (path / "snapshots").glob("step_*.npz"):
        m = _SNAPSHOT.fullmatch(p.name)
        if m and int(m.group(1)) <= last_step:
            found.append((int(m.group(1)), p))
    if ledger is not None:
        present = {p.name for _, p in found}
        for name in sorted(ledger.digests):
            folder, _, file = name.partition("/")
            m = _SNAPSHOT.fullmatch(file)
            if folder == "snapshots" and m and int(m.group(1)) <= last_step and file not in present:
                raise RunDirError(
                    f"{path / name} is recorded in {path / 'metadata.json'} but missing: it was deleted or moved; "
                    "restore it, or start the run again with --overwrite"
                )
    snaps = []
    for step, p in sorted(found):
        if p.is_symlink():
            raise RunDirError(f"{p} is a symbolic link: a run's files are never followed; remove it")
        snap = read_snapshot(p)  # a truncated file is named as such, then its digest is checked
        if ledger is not None:
            ledger.verify(p)
        if snap["step"] != step:
            raise RunDirError(f"snapshot {p} holds step {snap['step']}, not the step its name gives")
        snaps.append(snap)
    return snaps


def _entries(path: Path) -> list[Path]:
    """The entries of a run directory that a run writes or deletes (the lock, run files, figures, snapshots)."""
    names = [path / n for n in ENTRY_NAMES]
    snaps = path / "snapshots"
    if snaps.is_dir() and not snaps.is_symlink():
        names += [p for p in snaps.iterdir() if _SNAPSHOT.fullmatch(p.name)]
    return names


def _foreign_aside(path: Path) -> Path | None:
    """The first of ``DIR/.replaced`` and ``DIR/.replaced.done`` that is not a folder this package made (None: both
    absent or the package's): a link, a file, or a folder without the mark.  ``.replaced`` is renamed into place
    marked; ``.replaced.done`` loses its mark just before its ``rmdir``, so an empty one is the package's."""
    for folder in (path / _ASIDE, path / _DISCARDED):
        if not (folder.exists() or folder.is_symlink()):
            continue
        if folder.is_symlink() or not folder.is_dir():
            return folder
        emptied = folder == path / _DISCARDED and not any(folder.iterdir())
        if not (folder / _ASIDE_MARK).is_file() and not emptied:
            return folder
    return None


def aside_state(path: Path) -> str | None:
    """What an interrupted overwrite left in the run directory ``path``, in words (None: nothing)."""
    foreign = _foreign_aside(path)
    if foreign is not None:
        return (
            f"{foreign} is not a folder this package made (a link, a file, or a folder without its mark "
            f"{_ASIDE_MARK}), so nothing in {path} is deleted or restored, and no run opens here until it is moved away"
        )
    aside, done = path / _ASIDE, path / _DISCARDED
    if aside.is_dir():
        return (
            f"an overwrite of it was interrupted ({aside} holds the old run); opening it again with jko-cvx run "
            "(or simulate) puts the old run back"
        )
    if done.is_dir():
        return (
            f"an overwrite of it was interrupted while deleting the old run ({done}); opening it again with "
            "jko-cvx run (or simulate) finishes that"
        )
    return None


def _only_mark(folder: Path) -> bool:
    """``folder`` holds nothing but the aside mark and an empty ``snapshots/`` (or less)."""
    for p in folder.iterdir():
        mark, snapshots = p == folder / _ASIDE_MARK and p.is_file(), p == folder / "snapshots" and p.is_dir()
        if p.is_symlink() or not (mark or snapshots):
            return False
        if p.is_dir() and any(p.iterdir()):
            return False
    return True


def refuse_links(path: Path) -> None:
    """RunDirError naming the first entry of the run directory ``path`` that is a symbolic link."""
    for p in _entries(path):
        if p.is_symlink():
            raise RunDirError(
                f"{p} is a symbolic link: a run directory's files are never followed (writing or deleting through "
                f"it would reach {os.readlink(p)!r}, outside the run); remove the link"
            )


def _remove_temp_files(path: Path) -> None:
    """Remove temporary files that a killed atomic write left (regular files of our naming only)."""
    for folder, names in ((path, RUN_FILES + VERIFY_FILES + FIGURES), (path / "snapshots", None)):
        if not folder.is_dir() or folder.is_symlink():
            continue
        for p in folder.iterdir():
            m = TEMP_FILE.fullmatch(p.name)
            if not m or p.is_symlink() or not p.is_file():
                continue
            if (names is None and _SNAPSHOT.fullmatch(m["name"])) or (names is not None and m["name"] in names):
                p.unlink()


def check_metadata(ledger: Ledger, recorded: dict[str, str], path: Path) -> None:
    """RunDirError where ``metadata.json`` names another package version, code or scene than the checkpoint
    (``recorded``, whose digest metadata.json holds): an edited metadata.json mislabels the run."""
    for key in ("jko_cvx", "code_sha256", "scene_sha256"):
        if key in recorded and ledger.metadata.get(key) != recorded[key]:
            raise RunDirError(
                f"{path / 'metadata.json'} records {key} = {ledger.metadata.get(key)!r}, but the checkpoint records "
                f"{recorded[key]!r}: metadata.json was edited since the run wrote it, so the run's provenance cannot "
                "be vouched for"
            )


class RunDir:
    """An open run directory: locked, checked, and (on resume) its state and snapshots read.

    Use as a context manager (the lock is released on exit)::

        with RunDir.open(path, scene, resume=False, overwrite=False) as rd:
            rd.state      # the checkpointed RunState on resume, else None
            rd.snapshots  # the snapshots taken up to that state
    """

    def __init__(self, path: Path, scene: Scene) -> None:
        self.path = path
        self.scene = scene
        self.provenance = {
            "scene_sha256": scene_fingerprint(scene), "jko_cvx": __version__, "code_sha256": code_fingerprint(),
        }  # fmt: skip
        self.state: RunState | None = None
        self.snapshots: list[dict[str, Any]] = []
        self.ledger: Ledger | None = None
        self._lock_fd: int | None = None

    @classmethod
    def open(cls, path: str | Path, scene: Scene, *, resume: bool = False, overwrite: bool = False) -> RunDir:
        if resume and overwrite:
            raise ValueError("resume and overwrite exclude each other (resume continues a run, overwrite replaces it)")
        if not isinstance(path, str | os.PathLike) or not str(path).strip():
            raise ValueError(f"out must name a run directory (a non-empty path), got {path!r}")
        rd = cls(Path(path), scene)
        if rd.path.exists() and not rd.path.is_dir():
            raise RunDirError(f"run directory {rd.path} exists and is not a directory")
        if resume and not rd.path.is_dir():
            raise RunDirError(f"nothing to resume: run directory {rd.path} does not exist")
        rd.path.mkdir(parents=True, exist_ok=True)
        refuse_links(rd.path)
        rd._lock()  # never unlinked: a process waiting on the file it opened must lock the one in place
        try:
            rd._restore_aside()
            _remove_temp_files(rd.path)
            rd._resume() if resume else rd._start(overwrite)
        except BaseException:
            rd.close()
            raise
        return rd

    def __enter__(self) -> RunDir:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def checkpoint(self) -> Path:
        return self.path / "checkpoint.npz"

    def snapshot_path(self, step: int) -> Path:
        return self.path / "snapshots" / f"step_{step:07d}.npz"

    def _lock(self) -> None:
        """Take ``DIR/.lock`` (flock) and write this process's id in it."""
        import fcntl

        lock = self.path / ".lock"
        try:  # O_NOFOLLOW: a planted link is refused, never followed (refuse_links names it first)
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666)
        except OSError as exc:
            raise RunDirError(f"cannot open the lock {lock}: {exc.strerror or exc}") from None
        held = os.read(fd, 64).decode(errors="replace").strip()
        if held and not held.isdigit():  # not a process id this package wrote: the user's file, left as it is
            os.close(fd)
            raise RunDirError(
                f"{lock} is not the lock of a run of this package (it holds {held[:30]!r}, not a process id), so "
                "it may be a file of yours and nothing is changed: move it away or choose another --out"
            )
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise RunDirError(
                f"run directory {self.path} is in use by another run (process {held or 'unknown'} holds {lock}); "
                "wait for it to end or choose another --out"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._lock_fd = fd

    def close(self) -> None:
        """Release the lock (closing the descriptor drops the flock)."""
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def _existing(self) -> list[str]:
        names = [n for n in RUN_FILES + FIGURES + VERIFY_FILES if (self.path / n).exists()]
        return names + (["snapshots/"] if (self.path / "snapshots").is_dir() else [])

    def _run_files(self) -> list[Path]:
        """This directory's run files (figures and snapshot files included; nothing else in it)."""
        return [p for p in _entries(self.path) if p.name not in (".lock", "snapshots") and p.exists()]

    def _start(self, overwrite: bool) -> None:
        found = self._existing()
        if found and not overwrite:
            raise RunDirError(
                f"run directory {self.path} already holds a run ({', '.join(found)}): "
                "resume it with --resume (resume=True) or replace it with --overwrite (overwrite=True)"
            )
        if found:
            self._check_replaceable(found)
        moved = self._move_aside() if found else []
        try:
            self.ledger = Ledger(self.path, _metadata(self.scene, self.provenance))
            self.ledger.save_text(self.path / "scene.json", json.dumps(self.scene.to_dict(), indent=2, default=str))
            (self.path / "snapshots").mkdir(exist_ok=True)
        except BaseException:
            for p in (self.path / "scene.json", self.path / "metadata.json"):
                p.unlink(missing_ok=True)
            self._move_back(moved)
            raise
        if moved:
            self._discard_aside()

    def _check_replaceable(self, found: list[str]) -> None:
        """RunDirError unless every entry an overwrite would remove is the old run's own: the directory must hold a
        run this package wrote (``metadata.json`` with its files' digests), each run and verification file one it
        recorded, and ``reference`` a run directory of its own.  The figures (written beside the ledger, unrecorded)
        and the files of ``snapshots/`` named as the run names its snapshots are the run's by name."""
        try:
            recorded = set(Ledger.read(self.path).digests)
        except RunDirError:
            raise RunDirError(
                f"cannot overwrite {self.path}: it holds {', '.join(found)} but no run this package wrote "
                "(metadata.json with the digests of a run's files is missing or unreadable), so these may be files of "
                "yours and nothing is deleted: move them away or choose another --out"
            ) from None
        for p in self._run_files():
            name = p.relative_to(self.path).as_posix()
            if p.name in FIGURES or name == "metadata.json" or name.startswith("snapshots/"):
                continue
            if name == "reference":
                try:
                    inner = set(Ledger.read(p).digests)
                except RunDirError:
                    raise RunDirError(
                        f"cannot overwrite {self.path}: {p} is not a run directory this package wrote (a "
                        "verification's reference run has a metadata.json with its files' digests); nothing is "
                        "deleted: move it away or choose another --out"
                    ) from None
                # the folder goes as a whole: every entry in it must be the reference run's own
                for q in sorted(p.rglob("*")):
                    rel = q.relative_to(p).as_posix()
                    own = (
                        rel in inner
                        or rel in (*FIGURES, "metadata.json", ".lock", "snapshots")
                        or (rel.startswith("snapshots/") and _SNAPSHOT.fullmatch(q.name) is not None)
                        or TEMP_FILE.fullmatch(q.name) is not None
                    )  # (the last: a killed write's temporary file, of this package's naming)
                    if q.is_symlink() or not own:
                        raise RunDirError(
                            f"cannot overwrite {self.path}: {q} is not one of the files the reference run in {p} "
                            "wrote, so it may be a file of yours and nothing is deleted: move it away or choose "
                            "another --out"
                        )
            elif name not in recorded:
                raise RunDirError(
                    f"cannot overwrite {self.path}: {p} is not one of the files the run in {self.path} wrote "
                    "(metadata.json records no digest of it), so it may be a file of yours and nothing is deleted: "
                    "move it away or choose another --out"
                )

    def _move_aside(self) -> list[Path]:
        """Move the old run's files into ``DIR/.replaced/`` (renames in one file system); on failure move
        back what moved and refuse, leaving the old run as it was.  The folder's mark is written before any move."""
        aside = self.path / _ASIDE
        # made under a temporary name, marked, then renamed: a .replaced is never without its mark
        made = Path(tempfile.mkdtemp(prefix=_ASIDE_TMP, dir=self.path))
        (made / _ASIDE_MARK).write_text(f"the run of {self.path} moved aside by an overwrite\n")
        (made / "snapshots").mkdir()
        os.replace(made, aside)
        moved: list[Path] = []
        try:
            for p in self._run_files():
                os.replace(p, aside / p.relative_to(self.path))
                moved.append(p)
        except OSError as exc:
            self._move_back(moved)
            raise RunDirError(
                f"cannot replace the run in {self.path}: moving {p} aside failed ({exc.strerror or exc}); "
                "the old run is left as it was"
            ) from None
        return moved

    def _move_back(self, moved: list[Path]) -> None:
        aside = self.path / _ASIDE
        for p in reversed(moved):
            os.replace(aside / p.relative_to(self.path), p)
        if aside.is_dir():
            self._discard_aside()

    def _discard_aside(self) -> None:
        """Delete ``.replaced``: renamed first (one step), then emptied with its mark last, so that a kill at any
        point leaves either the whole folder or a marked (or empty) ``.replaced.done`` the next open finishes."""
        done = self.path / _DISCARDED
        os.replace(self.path / _ASIDE, done)
        self._finish_discard(done)

    @staticmethod
    def _finish_discard(done: Path) -> None:
        for p in sorted(done.iterdir()):
            if p != done / _ASIDE_MARK:
                shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()
        (done / _ASIDE_MARK).unlink(missing_ok=True)
        done.rmdir()

    def _restore_aside(self) -> None:
        """Finish what an overwrite killed midway left: put back the old run from ``DIR/.replaced/`` (killed before
        the new run had started), or delete ``DIR/.replaced.done/`` (killed while deleting the old run).

        The overwrite marked ``.replaced`` (:data:`_ASIDE_MARK`), renamed the old run's entries into it one by one,
        then wrote the new run's first files: a name in both places is the new run's in DIR (removed) and the old
        run's aside (put back); a name in DIR alone is the old run's, not yet moved when the kill came (kept).  A
        folder of either name that is not this package's (:func:`_foreign_aside`) is refused, and nothing is
        deleted or restored.
        """
        for made in self.path.glob(f"{_ASIDE_TMP}*"):  # killed before the rename: the mark at most, no run file
            if _ASIDE_TMP_NAME.fullmatch(made.name) and made.is_dir() and not made.is_symlink() and _only_mark(made):
                shutil.rmtree(made)
        if _foreign_aside(self.path) is not None:
            raise RunDirError(aside_state(self.path))
        done = self.path / _DISCARDED
        if done.is_dir():
            self._finish_discard(done)
        aside = self.path / _ASIDE
        if not aside.is_dir():
            return
        old = [p for p in _entries(aside) if p.name not in (".lock", "snapshots") and (p.exists() or p.is_symlink())]
        links = [p for p in old if p.is_symlink()]
        if links:
            raise RunDirError(f"{links[0]} is a symbolic link: {aside} is not a directory this package made")
        for p in old:
            target = self.path / p.relative_to(aside)
            if target.is_dir() and not target.is_symlink():  # the new run's entry of that name
                shutil.rmtree(target)
            elif target.exists() or target.is_symlink():
                target.unlink()
            target.parent.mkdir(exist_ok=True)
            os.replace(p, target)
        self._discard_aside()

    def _resume(self) -> None:
        if not self.checkpoint.exists():
            raise RunDirError(f"nothing to resume in {self.path}: it has no checkpoint.npz (run without --resume)")
        self.ledger = Ledger.read(self.path)
        period = None if self.scene.homogeneous else self.scene.xgrid().period
        state, recorded = RunState.load(self.checkpoint, period)  # names a truncated file as such
        self._check_provenance(recorded)
        self.ledger.verify(self.checkpoint)
        # the rest of the run's own files, before any step (load_run would refuse them after the work)
        scene_file = self.path / "scene.json"
        if not scene_file.is_file():
            raise RunDirError(
                f"{scene_file} is missing: {self.path} is not a run this package can vouch for; restore the file, "
                "or start the run again with --overwrite"
            )
        for name in ("scene.json", "diagnostics.csv", "verdict.json"):  # the last two are rewritten, if present
            if (self.path / name).exists():
                self.ledger.verify(self.path / name)
        try:  # as load_run reads it: scene.json must be the scene the checkpoint was made from
            same = record_fingerprint(json.loads(scene_file.read_text())) == recorded["scene_sha256"]
        except (OSError, ValueError, RecursionError):
            same = False
        if not same:
            raise RunDirError(
                f"{scene_file} does not record the scene the checkpoint was made from (its fingerprint differs): "
                "the run cannot be vouched for; start it again with --overwrite"
            )
        state.check(self.checkpoint)
        self.state = state
        self.snapshots = self.read_snapshots(state.step)
        # the same code, maybe not the same numerics: other library versions or another BLAS give numbers that
        # agree within tolerances, not bit for bit; each leg records where its environment differs from the first's
        here = environment()
        differs = {k: [self.ledger.metadata.get(k), here[k]] for k in _NUMERIC_ENVIRONMENT
                   if k in here and self.ledger.metadata.get(k) != here[k]}  # fmt: skip
        leg = {"at_step": state.step, "t": state.t, "started": time.strftime("%Y-%m-%dT%H:%M:%S")}
        self.ledger.append("resumed", {**leg, "environment_differs": differs})

    def _check_provenance(self, recorded: dict[str, str]) -> None:
        check_metadata(self.ledger, recorded, self.path)
        if recorded["scene_sha256"] != self.provenance["scene_sha256"]:
            try:
                old = json.loads((self.path / "scene.json").read_text())
                if flat_scene_record(old):
                    diff = "scene.json records it as flat fields (v_n, dt, ...), the layout of an earlier jko_cvx"
                else:
                    diff = "; ".join(scene_differences(old, json.loads(canonical_scene(self.scene))))
            except (OSError, ValueError, RecursionError) as exc:
                diff = f"the keys cannot be named: scene.json does not read ({exc})"
            raise RunDirError(
                f"cannot resume {self.path}: the scene is not the one its checkpoint was made from ({diff}); "
                "resume with that scene, or start again with --overwrite"
            )
        if recorded["jko_cvx"] != __version__:
            raise RunDirError(
                f"cannot resume {self.path}: its checkpoint was made by jko_cvx {recorded['jko_cvx']}, this is "
                f"{__version__} (a continued run would mix two versions); start again with --overwrite"
            )
        code, here = recorded.get("code_sha256"), self.provenance["code_sha256"]
        if code is None:
            raise RunDirError(
                f"cannot resume {self.path}: its checkpoint records no code fingerprint (an earlier jko_cvx wrote it), "
                "so it cannot be continued under code known to be the same; start again with --overwrite"
            )
        if code != here:
            raise RunDirError(
                f"cannot resume {self.path}: its checkpoint was made by other jko_cvx code of the same version "
                f"(code SHA-256 {code[:12]}... then, {here[:12]}... now: a package file was edited since; a continued "
                "run would mix two codes' steps); start again with --overwrite"
            )

    def read_snapshots(self, last_step: int) -> list[dict[str, Any]]:
        return read_snapshots(self.path, last_step, self.ledger)

    def save_snapshot(self, path: Path, **record: Any) -> None:
        """Write a snapshot file (its digest recorded in the ledger)."""
        self.ledger.save_npz(path, **record)

    def save_state(self, state: RunState) -> None:
        """Write the checkpoint, then diagnostics.csv from its rows."""
        state.save(self.checkpoint, self.provenance, self.ledger.save_npz)
        self.ledger.save_text(self.path / "diagnostics.csv", csv_text(state.rows))

    def write_verdict(self, state: RunState) -> None:
        """verdict.json: the verdict, t, the step count and the timings (its presence marks an ended run)."""
        record = {**state.verdict.to_dict(), "t": state.t, "steps": state.step, "seconds": state.seconds}
        self.ledger.save_text(self.path / "verdict.json", json.dumps(record, indent=2))
