"""The state of the time loop, and its files: the checkpoint and the snapshots.

:class:`RunState` holds everything the loop needs to continue (time, step, f, both grids, the
extents the refined grids were built for, the diagnostics rows and the verdict), so a run
continued from a checkpoint reproduces the uninterrupted run bit for bit.  Every file is
written atomically (a temporary file renamed over the old one, with the permissions the umask
gives); a file that does not read back (truncated, corrupted, not ours) raises
:class:`RunDirError` naming it.

A run directory's :class:`Ledger` records the SHA-256 of every file the run writes in
``metadata.json``, before the file is renamed into place, and checks it when the file is read
back; :meth:`RunState.check` checks a state's invariants (finite, non-negative f, its mass and
maximum those of the last diagnostics row, t and step those of that row, time increasing along
the rows).  Threat model: the digests catch accidents (a file edited, replaced, copied from
another run or left from older code); they do not stop a deliberate forger who recomputes
them, which the invariants partly do and ``jko-cvx reproduce NAME --audit K`` (recomputing
cached points) is for.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import os
import re
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jko_cvx.diagnostics import diagnostics
from jko_cvx.engine.errors import RunDirError
from jko_cvx.engine.verdict import Verdict
from jko_cvx.grid import Grid, PeriodicGrid

__all__ = ["Ledger", "RunState", "read_snapshot", "write_snapshot"]


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


TEMP_FILE = re.compile(r"\.(?P<name>.+)\.jko_tmp\.[a-z0-9_]{8}")
"""The name :func:`atomic_write` gives its temporary file beside ``name`` (``tempfile.mkstemp``)."""


def atomic_write(path: Path, write: Callable[[str], None], before_replace: Callable[[str], None] | None = None) -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it over ``path``.

    The file gets mode ``0o666 & ~umask``, like any file the process creates (``mkstemp``
    alone gives 0o600).  ``before_replace(tmp)``, when given, runs after the file is complete
    and before it replaces ``path`` (a :class:`Ledger` records its digest there).  An OSError
    names ``path``, not the temporary file.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        # a name no file of the user's has (a dated backup ".diagnostics.csv.20240101" is not ours to remove)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.jko_tmp.")
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write {path}: {exc.strerror}") from None
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())
        if before_replace is not None:
            before_replace(tmp)
        os.replace(tmp, path)
    except OSError as exc:
        raise OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _npz_writer(arrays: dict[str, Any]) -> Callable[[str], None]:
    def w(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    return w


def save_npz(path: Path, **arrays) -> None:
    atomic_write(path, _npz_writer(arrays))


def save_text(path: Path, text: str) -> None:
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))


def file_sha256(path: str | Path) -> str:
    """SHA-256 (hex) of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


class Ledger:
    """The digests of a run directory's files, kept in its ``metadata.json``.

    ``metadata["digests"]`` maps each file's path relative to the directory to the digests it
    may have: one, or two while a write is under way (the new file's digest is recorded before
    the rename that puts it in place, so a run killed in between leaves a file the ledger still
    accepts; once the rename is done the entry is settled to the new digest alone).
    ``metadata.json`` itself is written atomically and is not in the ledger.
    """

    def __init__(self, root: Path, metadata: dict[str, Any]) -> None:
        self.root = root
        self.metadata = metadata
        self.metadata.setdefault("digests", {})

    @property
    def digests(self) -> dict[str, list[str]]:
        return self.metadata["digests"]

    @classmethod
    def read(cls, root: Path) -> Ledger:
        """The ledger of the run in ``root``; RunDirError when metadata.json is missing, damaged or has none."""
        path = root / "metadata.json"
        try:
            metadata = json.loads(path.read_text())
        except FileNotFoundError:
            raise RunDirError(f"{path} does not exist: {root} holds no run this jko_cvx wrote") from None
        except (OSError, ValueError, RecursionError) as exc:
            raise RunDirError(f"{path} does not read ({type(exc).__name__}: {exc})") from None
        digests = metadata.get("digests") if isinstance(metadata, dict) else None
        if not isinstance(digests, dict) or not all(
            isinstance(v, list) and all(isinstance(d, str) for d in v) for v in digests.values()
        ):
            raise RunDirError(
                f"{path} records no file digests (an earlier jko_cvx wrote it, or it was edited): the run's files "
                "cannot be checked; start the run again with --overwrite"
            )
        return cls(root, metadata)

    def _save(self) -> None:
        save_text(self.root / "metadata.json", json.dumps(self.metadata, indent=2))

    def append(self, key: str, entry: dict[str, Any]) -> None:
        """Append ``entry`` to the list ``metadata[key]`` and write ``metadata.json`` (atomically)."""
        self.metadata.setdefault(key, []).append(entry)
        self._save()

    def _name(self, path: Path) -> str:
        return path.relative_to(self.root).as_posix()

    def write(self, path: Path, write: Callable[[str], None]) -> None:
        """Write ``path`` atomically (:func:`atomic_write`), its digest recorded before it is put in place."""
        name = self._name(path)

        def record(tmp: str) -> None:
            self.digests[name] = [file_sha256(tmp), *self.digests.get(name, [])[:1]]
            self._save()

        atomic_write(path, write, record)
        if len(self.digests[name]) > 1:
            self.digests[name] = self.digests[name][:1]
            self._save()

    def save_npz(self, path: Path, **arrays) -> None:
        self.write(path, _npz_writer(arrays))

    def save_text(self, path: Path, text: str) -> None:
        self.write(path, lambda tmp: Path(tmp).write_text(text))

    def forget(self, path: Path) -> None:
        """Drop a file's entry (the file is being removed)."""
        if self.digests.pop(self._name(path), None) is not None:
            self._save()

    def verify(self, path: Path) -> None:
        """RunDirError, naming the file, unless ``path``'s digest is one the ledger recorded for it."""
        name = self._name(path)
        if name not in self.digests:
            raise RunDirError(
                f"{path} is not one of the files this run wrote (metadata.json records no digest of it); "
                "it was added or copied from elsewhere: remove it, or start the run again with --overwrite"
            )
        try:
            actual = file_sha256(path)
        except OSError as exc:
            raise RunDirError(f"{path} does not read ({exc.strerror or exc})") from None
        if actual not in self.digests[name]:
            raise RunDirError(
                f"{path} has changed since the run wrote it (SHA-256 {actual[:12]}..., metadata.json records "
                f"{self.digests[name][0][:12]}...): it was edited, replaced or damaged, and is not used; "
                "restore it, or start the run again with --overwrite"
            )


# what a damaged .npz raises while it is opened or read
# RecursionError: json.loads of a document nested thousands deep
_READ_ERRORS = (OSError, EOFError, KeyError, ValueError, TypeError, RecursionError, zipfile.BadZipFile)


def read_npz(path: Path, what: str, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """All arrays of ``path`` (which must hold ``keys``), read eagerly so damage shows here, not later."""
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise RunDirError(f"{what} {path} does not exist") from None
    except _READ_ERRORS as exc:
        # np.load reads a file that is no archive at all as a pickle, which it refuses
        why = "not an .npz archive" if "pickle" in str(exc) else f"{type(exc).__name__}: {exc}"
        raise RunDirError(f"{what} {path} is corrupted or truncated ({why})") from None
    missing = [k for k in keys if k not in data]
    if missing:
        raise RunDirError(f"{what} {path} is not a jko_cvx {what}: it lacks {missing}")
    return data


def write_snapshot(
    path: Path | None,
    step: int,
    t: float,
    xgrid,
    vgrid: Grid,
    f: np.ndarray,
    save: Callable[..., None] = save_npz,
) -> dict[str, Any]:
    """The snapshot record ``{step, t, v, f[, x]}`` (copies), also written to ``path`` when given
    (by ``save(path, **record)``: a run directory's :meth:`Ledger.save_npz`)."""
    snap = {"step": step, "t": t, "v": vgrid.points.copy(), "f": f.copy()}
    if xgrid is not None:
        snap["x"] = xgrid.points.copy()
    if path is not None:
        save(path, **snap)
    return snap


def read_snapshot(path: Path) -> dict[str, Any]:
    """A snapshot file as written by :func:`write_snapshot` (step an int and t a float, as in memory)."""
    snap = read_npz(path, "snapshot", ("step", "t", "v", "f"))
    try:
        return {**snap, "step": int(snap["step"]), "t": float(snap["t"])}
    except (TypeError, ValueError) as exc:
        raise RunDirError(f"snapshot {path} is not a jko_cvx snapshot ({exc})") from None


_CHECKPOINT_KEYS = ("t", "step", "f", "v", "x", "rows", "verdict", "v_params", "x_params", "seconds")


@dataclass
class RunState:
    """Everything the time loop carries from one step to the next.

    ``rows`` are the diagnostics records (one per accepted step, from step 0); ``seconds`` the
    time spent so far in collision, transport and refinement and the loop's ``wall`` time, up to the
    last accepted step and summed over every call that ran the loop (``resume``);
    ``v_params`` / ``x_params`` the extents of the concentration sets the refined grids were
    built for (None on a fixed grid, or before the first refinement).
    """

    t: float
    step: int
    f: np.ndarray
    vgrid: Grid
    xgrid: PeriodicGrid | None
    v_params: np.ndarray | None
    x_params: np.ndarray | None
    rows: list[dict[str, Any]]
    verdict: Verdict
    seconds: dict[str, float] = field(
        default_factory=lambda: dict.fromkeys(("wall", "collision", "transport", "refine"), 0.0)
    )

    def done(self, t_end: float) -> bool:
        """A blow-up rule fired, or ``t_end`` is reached (to rounding in t)."""
        return self.verdict.stop.blowup or self.t >= t_end * (1 - 1e-12)

    def save(self, path: Path, provenance: dict[str, str], save: Callable[..., None] = save_npz) -> None:
        """Write the checkpoint (``provenance``: the scene fingerprint, package version and code fingerprint, as
        strings) with ``save(path, **arrays)`` (a run directory's :meth:`Ledger.save_npz`)."""
        save(
            path,
            v_params=np.array([]) if self.v_params is None else self.v_params,
            x_params=np.array([]) if self.x_params is None else self.x_params,
            t=self.t,
            step=self.step,
            f=self.f,
            v=self.vgrid.points,
            x=np.array([]) if self.xgrid is None else self.xgrid.points,
            rows=json.dumps(self.rows),
            verdict=json.dumps(self.verdict.to_dict()),
            seconds=json.dumps(self.seconds),
            **{k: np.array(v) for k, v in provenance.items()},
        )

    @classmethod
    def load(cls, path: Path, x_period: float | None) -> tuple[RunState, dict[str, str]]:
        """Read a checkpoint: the state, and the provenance recorded with it (``code_sha256`` absent where an
        earlier jko_cvx wrote the checkpoint: :class:`~jko_cvx.engine._rundir.RunDir` refuses to resume it).

        ``x_period`` is the scene's x-period (None for a homogeneous scene).
        """
        ck = read_npz(path, "checkpoint", _CHECKPOINT_KEYS)
        if "scene_sha256" not in ck or "jko_cvx" not in ck:
            raise RunDirError(
                f"checkpoint {path} records no scene fingerprint or package version (an earlier jko_cvx wrote it): "
                "it cannot be checked against the scene; start the run again with --overwrite"
            )
        try:
            v, x, f = ck["v"], ck["x"], ck["f"]
            shape = (v.size,) if x_period is None else (x.size, v.size)
            if f.shape != shape:
                raise ValueError(f"f has shape {f.shape}, the grids in it need {shape}")
            state = cls(
                t=float(ck["t"]),
                step=int(ck["step"]),
                f=f,
                vgrid=Grid(v),
                xgrid=None if x_period is None else PeriodicGrid(x, x_period),
                v_params=ck["v_params"] if ck["v_params"].size else None,
                x_params=ck["x_params"] if ck["x_params"].size else None,
                rows=json.loads(str(ck["rows"])),
                verdict=Verdict.from_dict(json.loads(str(ck["verdict"]))),
                seconds={k: float(x) for k, x in json.loads(str(ck["seconds"])).items()},
            )
        except _READ_ERRORS as exc:
            raise RunDirError(f"checkpoint {path} does not hold a valid run state ({exc})") from None
        provenance = {k: str(ck[k]) for k in ("scene_sha256", "jko_cvx", "code_sha256") if k in ck}
        return state, provenance

    def check(self, path: Path) -> None:
        """RunDirError naming ``path`` (the file the state was read from) unless the state is one a run
        could have reached: f finite and non-negative, rows numbered from step 0 with time increasing,
        and the last row the diagnostics of this f at this t and step (mass to 1e-12, max f exactly)."""

        def refuse(why: str) -> None:
            raise RunDirError(f"{path} does not hold a state this run reached ({why}); it is not used")

        if not np.all(np.isfinite(self.f)):
            refuse("f is not finite")
        if np.any(self.f < 0):
            refuse(f"f is negative (min {self.f.min():.3g})")
        if not self.rows:
            refuse("no diagnostics rows")
        try:
            steps = [int(r["step"]) for r in self.rows]
            times = [float(r["t"]) for r in self.rows]
            last_mass, last_max = float(self.rows[-1]["mass"]), float(self.rows[-1]["max_f"])
        except (KeyError, TypeError, ValueError) as exc:
            refuse(f"its diagnostics rows lack {exc}")
        if steps != list(range(len(steps))):
            refuse("its diagnostics rows are not numbered 0, 1, 2, ...")
        if any(b <= a for a, b in itertools.pairwise(times)):
            refuse("time does not increase along its diagnostics rows")
        if self.step != steps[-1] or self.t != times[-1]:
            refuse(
                f"t = {self.t!r}, step {self.step} are not those of its last diagnostics row "
                f"(t = {times[-1]!r}, step {steps[-1]})"
            )
        d = diagnostics(self.vgrid, self.f, self.xgrid)
        if not (math.isclose(d["mass"], last_mass, rel_tol=1e-12, abs_tol=0.0) and d["max_f"] == last_max):
            refuse(
                f"the mass / max f of its f ({d['mass']!r} / {d['max_f']!r}) are not those its last diagnostics "
                f"row records ({last_mass!r} / {last_max!r})"
            )
