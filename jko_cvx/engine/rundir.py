"""Run directories: provenance, the lock, resume and overwrite rules.

A run directory holds ``scene.json``, ``metadata.json`` (package and solver versions, the
scene fingerprint), ``diagnostics.csv``, ``snapshots/step_*.npz``, ``checkpoint.npz`` and, once
the run has ended, ``verdict.json`` (the CLI adds ``solution.png`` and ``records.png``).

Rules (each refusal is a :class:`~jko_cvx.engine.state.RunDirError` naming the directory):

* a new run refuses a directory that already holds a run, unless ``overwrite`` (which
  removes that run's files, and only those);
* ``resume`` needs a checkpoint, made from the same scene (the SHA-256 of the canonical JSON
  of ``scene.to_dict()``; a refusal names the keys that differ) by the same package version;
* one run at a time: an exclusive, non-blocking ``fcntl.flock`` on ``DIR/.lock``, held
  until the run returns (the kernel drops it when a process dies, so a killed run leaves no
  stale lock).
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
import re
import time
from pathlib import Path
from typing import Any

import numpy as np

from jko_cvx._version import __version__
from jko_cvx.engine.state import RunDirError, RunState, read_snapshot, save_text
from jko_cvx.scene.model import Scene

__all__ = ["RunDir", "canonical_scene", "flat_scene_record", "read_snapshots", "scene_differences", "scene_fingerprint"]

RUN_FILES = ("scene.json", "metadata.json", "checkpoint.npz", "diagnostics.csv", "verdict.json")
FIGURES = ("solution.png", "records.png")
_SNAPSHOT = re.compile(r"step_(\d+)\.npz")


def canonical_scene(scene: Scene) -> str:
    """The scene as canonical JSON: ``scene.to_dict()`` with sorted keys and no whitespace."""
    return json.dumps(scene.to_dict(), sort_keys=True, separators=(",", ":"), default=str)


def scene_fingerprint(scene: Scene) -> str:
    """SHA-256 (hex) of :func:`canonical_scene`."""
    return hashlib.sha256(canonical_scene(scene).encode()).hexdigest()


_FLAT_FIELDS = frozenset({"v_L", "v_n", "dt", "policy", "method", "every", "snapshot_times"})


def flat_scene_record(record: Any) -> bool:
    """True for a scene record in the flat field layout of earlier versions (``v_n``, ``dt``, ...)."""
    return isinstance(record, dict) and bool(_FLAT_FIELDS & set(record))


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def scene_differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """``"key: old -> new"`` for each dotted key whose value differs between two scene records."""
    a, b = _flatten(old), _flatten(new)
    keys = sorted(k for k in a.keys() | b.keys() if a.get(k, _ABSENT) != b.get(k, _ABSENT))
    return [f"{k}: {a.get(k, _ABSENT)!r} -> {b.get(k, _ABSENT)!r}" for k in keys]


class _Absent:
    def __repr__(self) -> str:
        return "(absent)"


_ABSENT = _Absent()


def _metadata(scene: Scene) -> dict[str, Any]:
    import clarabel
    import cvxpy
    import scipy

    return {
        "jko_cvx": __version__,
        "scene_sha256": scene_fingerprint(scene),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "cvxpy": cvxpy.__version__,
        "clarabel": getattr(clarabel, "__version__", "unknown"),
        "python": platform.python_version(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "scene": scene.name,
    }


def read_snapshots(path: Path, last_step: int) -> list[dict[str, Any]]:
    """The snapshot files in ``path/snapshots`` of steps ``<= last_step``, in step order."""
    found = []
    for p in (path / "snapshots").glob("step_*.npz"):
        m = _SNAPSHOT.fullmatch(p.name)
        if m and int(m.group(1)) <= last_step:
            found.append((int(m.group(1)), p))
    return [read_snapshot(p) for _, p in sorted(found)]


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
        self.provenance = {"scene_sha256": scene_fingerprint(scene), "jko_cvx": __version__}
        self.state: RunState | None = None
        self.snapshots: list[dict[str, Any]] = []
        self._lock_fd: int | None = None

    @classmethod
    def open(cls, path: str | Path, scene: Scene, *, resume: bool = False, overwrite: bool = False) -> RunDir:
        if resume and overwrite:
            raise ValueError("resume and overwrite exclude each other (resume continues a run, overwrite replaces it)")
        rd = cls(Path(path), scene)
        if rd.path.exists() and not rd.path.is_dir():
            raise RunDirError(f"run directory {rd.path} exists and is not a directory")
        if resume and not rd.path.is_dir():
            raise RunDirError(f"nothing to resume: run directory {rd.path} does not exist")
        rd.path.mkdir(parents=True, exist_ok=True)
        rd._lock()
        try:
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
        import fcntl

        lock = self.path / ".lock"
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise RunDirError(
                f"run directory {self.path} is in use by another run (process {holder} holds {lock}); "
                "wait for it to end or choose another --out"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        self._lock_fd = fd

    def close(self) -> None:
        """Release the lock (closing the descriptor drops the flock)."""
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def _existing(self) -> list[str]:
        names = [n for n in RUN_FILES + FIGURES if (self.path / n).exists()]
        return names + (["snapshots/"] if (self.path / "snapshots").is_dir() else [])

    def _start(self, overwrite: bool) -> None:
        found = self._existing()
        if found and not overwrite:
            raise RunDirError(
                f"run directory {self.path} already holds a run ({', '.join(found)}): "
                "resume it with --resume (resume=True) or replace it with --overwrite (overwrite=True)"
            )
        if found:
            self._remove_run()
        save_text(self.path / "scene.json", json.dumps(self.scene.to_dict(), indent=2, default=str))
        save_text(self.path / "metadata.json", json.dumps(_metadata(self.scene), indent=2))

    def _remove_run(self) -> None:
        """Remove this directory's run files (only those: other files in it are left alone)."""
        for name in RUN_FILES + FIGURES:
            (self.path / name).unlink(missing_ok=True)
        snaps = self.path / "snapshots"
        if snaps.is_dir():
            for p in snaps.iterdir():
                if _SNAPSHOT.fullmatch(p.name):
                    p.unlink()
            if not any(snaps.iterdir()):
                snaps.rmdir()

    def _resume(self) -> None:
        if not self.checkpoint.exists():
            raise RunDirError(f"nothing to resume in {self.path}: it has no checkpoint.npz (run without --resume)")
        period = None if self.scene.homogeneous else self.scene.xgrid().period
        state, recorded = RunState.load(self.checkpoint, period)
        self._check_provenance(recorded)
        self.state = state
        self.snapshots = self.read_snapshots(state.step)

    def _check_provenance(self, recorded: dict[str, str]) -> None:
        if recorded["scene_sha256"] != self.provenance["scene_sha256"]:
            try:
                old = json.loads((self.path / "scene.json").read_text())
                if flat_scene_record(old):
                    diff = "scene.json records it as flat fields (v_n, dt, ...), the layout of an earlier jko_cvx"
                else:
                    diff = "; ".join(scene_differences(old, json.loads(canonical_scene(self.scene))))
            except (OSError, ValueError) as exc:
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

    def read_snapshots(self, last_step: int) -> list[dict[str, Any]]:
        return read_snapshots(self.path, last_step)

    def save_state(self, state: RunState) -> None:
        """Write the checkpoint, then diagnostics.csv from its rows."""
        import pandas as pd

        state.save(self.checkpoint, self.provenance)
        save_text(self.path / "diagnostics.csv", pd.DataFrame(state.rows).to_csv(index=False))

    def write_verdict(self, state: RunState) -> None:
        """verdict.json: the verdict, t, the step count and the timings (its presence marks an ended run)."""
        record = {**state.verdict.to_dict(), "t": state.t, "steps": state.step, "seconds": state.seconds}
        save_text(self.path / "verdict.json", json.dumps(record, indent=2))
