"""The state of the time loop, and its files: the checkpoint and the snapshots.

:class:`RunState` holds everything the loop needs to continue (time, step, f, both grids, the
extents the refined grids were built for, the diagnostics rows and the verdict), so a run
continued from a checkpoint reproduces the uninterrupted run bit for bit.  Every file is
written atomically (a temporary file renamed over the old one); a file that does not read
back (truncated, corrupted, not ours) raises :class:`RunDirError` naming it.
"""

from __future__ import annotations

import json
import os
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jko_cvx.engine.verdict import Verdict
from jko_cvx.grid import Grid, PeriodicGrid

__all__ = ["RunDirError", "RunState", "read_snapshot", "write_snapshot"]


class RunDirError(ValueError):
    """A run directory that cannot be used as asked; the message names the directory or file."""


def atomic_write(path: Path, write: Callable[[str], None]) -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it over ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def save_npz(path: Path, **arrays) -> None:
    def w(tmp: str) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    atomic_write(path, w)


def save_text(path: Path, text: str) -> None:
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))


# what a damaged .npz raises while it is opened or read
_READ_ERRORS = (OSError, EOFError, KeyError, ValueError, TypeError, zipfile.BadZipFile, json.JSONDecodeError)


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


def write_snapshot(path: Path | None, step: int, t: float, xgrid, vgrid: Grid, f: np.ndarray) -> dict[str, Any]:
    """The snapshot record ``{step, t, v, f[, x]}`` (copies), also written to ``path`` when given."""
    snap = {"step": step, "t": t, "v": vgrid.points.copy(), "f": f.copy()}
    if xgrid is not None:
        snap["x"] = xgrid.points.copy()
    if path is not None:
        save_npz(path, **snap)
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
    time spent so far in collision, transport and refinement (over every call that ran the loop);
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
    seconds: dict[str, float] = field(default_factory=lambda: dict.fromkeys(("collision", "transport", "refine"), 0.0))

    def done(self, t_end: float) -> bool:
        """A blow-up rule fired, or ``t_end`` is reached (to rounding in t)."""
        return self.verdict.blowup or self.t >= t_end * (1 - 1e-12)

    def save(self, path: Path, provenance: dict[str, str]) -> None:
        """Write the checkpoint (``provenance``: the scene fingerprint and package version, as strings)."""
        save_npz(
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
        """Read a checkpoint: the state, and the provenance recorded with it.

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
        provenance = {k: str(ck[k]) for k in ("scene_sha256", "jko_cvx")}
        return state, provenance
