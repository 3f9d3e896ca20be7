"""A finished run as data: :class:`Run` (what ``simulate`` returns), :func:`load_run`, ``Run.to_xarray``.

``load_run(path)`` rebuilds, from a run directory, the :class:`Run` that ``simulate``
returned when it wrote that directory: the same scene, diagnostics, snapshots, final
state, verdict and timings.

``Run.to_xarray()`` lays the run out as an :class:`xarray.Dataset` (optional extra
``jko_cvx[netcdf]``):

* diagnostics over the dimension ``t`` (one entry per accepted step, from t = 0), one
  variable per column of ``diagnostics.csv`` (``step``, ``dt``, ``mass``, ``min_dv``, ...);
* snapshots over ``(t_snap, ix, iv)`` (homogeneous scenes: ``(t_snap, iv)``), with the grids
  as two-dimensional coordinates ``v(t_snap, iv)`` and ``x(t_snap, ix)``: mesh refinement
  moves the grid points between snapshots, so ``iv`` / ``ix`` are point indices and each
  snapshot carries its own grid (no interpolation); ``step_snap(t_snap)`` is the step number;
* attributes: the scene (canonical JSON) and its SHA-256, the package version, the verdict
  (booleans as 0/1, ``T_b`` NaN without blow-up) and the timings.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from jko_cvx._version import __version__
from jko_cvx.collision._checks import check_bool
from jko_cvx.engine._state import Ledger, RunState, read_npz
from jko_cvx.engine._table import column, unknown_column
from jko_cvx.engine.errors import RunDirError
from jko_cvx.engine.verdict import StopReason, Verdict
from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.limits import Limits
from jko_cvx.scene.model import Scene, scene_from_dict
from jko_cvx.scene.options import RUN_KKT

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["Run", "load_run"]


@dataclass
class Run:
    """The result of :func:`~jko_cvx.engine.loop.simulate` (always returned, also when blow-up stops the run).

    ``diagnostics`` holds one row per accepted step (row 0: the initial state), ``snapshots`` the
    densities at the scene's ``output`` times with their grids, ``f`` the final density on
    ``vgrid`` (and ``xgrid`` for an inhomogeneous scene), ``verdict`` the stopping reason and
    whether the run blew up.  ``diagnostics`` may be given as the table or as the rows the loop
    recorded (a list of dicts, one per row): the run then builds the table on first use, and
    :meth:`column` reads a column without it (the CLI's run imports no pandas).  ``made_by`` names the
    package that computed the run (``jko_cvx``: its version, ``code_sha256``: its code fingerprint), as
    :func:`load_run` reads them from the checkpoint; :meth:`to_xarray` records them, not the exporter's.

    Examples
    --------
    >>> from jko_cvx import shipped_scene, simulate
    >>> run = simulate(shipped_scene("tab_bu_g1", {"v.n": 41, "t_end": 0.05}))
    >>> run.steps, run.blowup, run.f.shape, run.xgrid is None
    (5, False, (41,), True)
    >>> print(run.summary())  # doctest: +ELLIPSIS
    tab_bu_g1: t = 0.05, steps = 5, blow-up = False (direction: none; reached t_end); ...
    >>> run.diagnostics[["t", "mass", "max_f"]].round(2).tail(2)
          t  mass  max_f
    4  0.04  1.25   1.08
    5  0.05  1.25   1.11
    """

    scene: Scene
    diagnostics: pd.DataFrame  # a property (below): the table, built from recorded rows on first use
    snapshots: list[dict[str, Any]]
    f: np.ndarray
    vgrid: Grid
    xgrid: PeriodicGrid | None
    t: float
    verdict: Verdict
    seconds: dict[str, float] = field(default_factory=dict)
    made_by: dict[str, str] = field(default_factory=dict)

    def _get_diagnostics(self) -> pd.DataFrame:
        if self._table is None:
            import pandas as pd

            self._table, self._rows = pd.DataFrame(self._rows), None
        return self._table

    def _set_diagnostics(self, value: pd.DataFrame | Sequence[Mapping[str, Any]]) -> None:
        if isinstance(value, list | tuple) and all(isinstance(r, Mapping) for r in value):
            self._table, self._rows = None, list(value)
            return
        pd = sys.modules.get("pandas")  # a DataFrame comes with pandas imported
        if pd is None or not isinstance(value, pd.DataFrame):
            raise TypeError(
                f"Run: diagnostics must be a pandas.DataFrame or a list of row dicts, got {type(value).__name__}"
            )
        self._table, self._rows = value, None

    def column(self, name: str) -> np.ndarray:
        """The diagnostics column ``name`` as a new array, ``run.diagnostics[name].to_numpy()``.

        Read from the table where it has been built (a change made to it shows), else from the
        recorded rows without building it (no pandas import).  An unknown name raises ``KeyError``
        naming the columns.
        """
        if self._table is not None:
            if name not in self._table:
                raise unknown_column(name, self._table.columns)
            return np.array(self._table[name].to_numpy())
        return column(self._rows, name)

    @property
    def blowup(self) -> bool | None:
        """:attr:`Verdict.blowup`: True (a blow-up rule fired), False (reached ``t_end``, certified), or None
        (undetermined: an uncertified run that no rule stopped, no step accepted, or a run read back before it
        ended)."""
        return self.verdict.blowup

    @property
    def steps(self) -> int:
        """Accepted time steps (the step-0 row of the diagnostics is the initial state, not a step)."""
        return int(self.column("step")[-1])

    @property
    def failed_steps(self) -> int:
        """Steps with a failed collision solve: accepted steps with a failed slice, and the step a
        solver failure stopped the run on (it has no diagnostics row; nor has a first step that failed, NO_STEP)."""
        stopped = self.verdict.stop in (StopReason.SOLVER_FAILURE, StopReason.NO_STEP)
        return int((self.column("failed") > 0).sum()) + int(stopped)

    def snapshots_at(self, times) -> list[dict[str, Any]]:
        """The first snapshot at or after each of ``times`` (distinct; times past the run's end are skipped).

        Exact for the scene's ``output.times``: the run took a snapshot at the first step
        reaching each of them.
        """
        ts = np.array([s["t"] for s in self.snapshots])
        picked = []
        for tk in times:
            later = np.flatnonzero(ts >= tk - 1e-12 * max(tk, 1.0))
            if later.size and int(later[0]) not in picked:
                picked.append(int(later[0]))
        return [self.snapshots[i] for i in sorted(picked)]

    def summary(self) -> str:
        """One line: time reached, steps, verdict."""
        v = self.verdict
        where = ", ".join(k for k in ("B_x", "B_v") if v[k]) or "none"
        if v.e_f and v.B_v and not v.B_x and v.stop in (StopReason.SOLVER_FAILURE, StopReason.EPS_T):
            where = "B_v, which e_f sets as alg:MR_JKO_ver2 does"
        return (
            f"{self.scene.name}: t = {self.t:.6g}, steps = {self.steps}, "
            f"{v.describe()} (direction: {where}; {v.reason})"
            + (f", T_b = {v.T_b:.6g}" if v.blowup else "")
            + (f"; {fit}" if (fit := v.describe_fit()) else "")
            + self._certificate_note()
        )

    def _certificate_note(self) -> str:
        """What the scene's solver options do to the certificate of its steps (``RUN_KKT``): a looser ``kkt_tol``
        (warned), or a Newton ``tol`` above the threshold (steps stop before they can be certified)."""
        c = self.scene.collision
        opts, limit = c.options, RUN_KKT[c.method]
        kkt = opts.get("kkt_tol")
        if kkt is not None and kkt > limit:
            return (
                f" (WARNING: steps certified at collision.options.kkt_tol = {kkt:g}, looser than a run's {limit:g} "
                f"for method {c.method!r}: 'certified' here means a KKT residual up to {kkt:g})"
            )
        tol = opts.get("tol")
        if c.method == "newton" and kkt is None and tol is not None and tol > limit:
            return (
                f" (collision.options.tol = {tol:g} is above the {limit:g} at which a run certifies Newton's steps: "
                "they stop before they can be certified; lower tol, or set collision.options.kkt_tol to loosen the "
                "certificate explicitly)"
            )
        return ""

    def records_line(self) -> str:
        """Conservation and extremes over the run: mass and momentum drift, max f, min dv (min dx)."""
        mass, momentum = self.column("mass"), self.column("momentum")
        return (
            f"mass drift {abs(mass[-1] - mass[0]) / mass[0]:.1e} (relative), "
            f"momentum drift {abs(momentum[-1] - momentum[0]):.1e}, "
            f"max f over the run {_nan_skipped(np.max, self.column('max_f')):.4g}, "
            f"min dv {_nan_skipped(np.min, self.column('min_dv')):.3g}"
            + ("" if self.xgrid is None else f", min dx {_nan_skipped(np.min, self.column('min_dx')):.3g}")
            + _time_error_words(self)
        )

    def to_xarray(self):
        """The run as an :class:`xarray.Dataset` (see the module docstring for the layout)."""
        xr = _require("xarray")
        snaps = [s for i, s in enumerate(self.snapshots) if i == 0 or s["step"] != self.snapshots[i - 1]["step"]]
        d = self.diagnostics
        ds = xr.Dataset(
            {c: ("t", d[c].to_numpy(), {"long_name": c}) for c in d.columns if c != "t"},
            coords={"t": ("t", d["t"].to_numpy(), {"long_name": "time of the step's end (diagnostics)"})},
        )
        f_dims = ("t_snap", "iv") if self.xgrid is None else ("t_snap", "ix", "iv")
        ds["f"] = (f_dims, np.stack([s["f"] for s in snaps]), {"long_name": "f at the grid points"})
        ds = ds.assign_coords(
            t_snap=("t_snap", np.array([float(s["t"]) for s in snaps]), {"long_name": "snapshot time"}),
            step_snap=("t_snap", np.array([int(s["step"]) for s in snaps])),
            v=(("t_snap", "iv"), np.stack([s["v"] for s in snaps]), {"long_name": "velocity grid of the snapshot"}),
        )
        if self.xgrid is not None:
            x = np.stack([s["x"] for s in snaps])
            ds = ds.assign_coords(x=(("t_snap", "ix"), x, {"long_name": "space grid of the snapshot"}))
        ds.attrs = _attrs(self)
        return ds


Run.diagnostics = property(
    Run._get_diagnostics,
    Run._set_diagnostics,
    doc="""One row per accepted step (row 0: the initial state), one column per record of ``diagnostics.csv``:
    a :class:`pandas.DataFrame` (built on first use from the recorded rows, then kept).""",
)


def _floats(values: np.ndarray) -> np.ndarray:
    """A diagnostics column as floats, a missing value (None in a column pandas keeps as objects) as NaN."""
    return np.array([np.nan if v is None else v for v in values], dtype=float)


def _nan_skipped(reduce, values: np.ndarray) -> float:
    """``reduce`` (np.max or np.min) over the values that are not missing (NaN, None), as pandas' ``Series.max``
    / ``min`` skip them; NaN where none is left."""
    x = _floats(values)
    kept = x[~np.isnan(x)]
    return float(reduce(kept)) if kept.size else float("nan")


def _time_error_words(run: Run) -> str:
    """The largest ``time_error`` of a second-order run and its time, as a clause of the records line ("" where
    none was recorded: first-order steps, or a run written before the column)."""
    try:
        err = _floats(run.column("time_error"))
    except KeyError:
        return ""
    if not np.isfinite(err).any():
        return ""
    k = int(np.nanargmax(err))
    return f", first-order local time error up to {err[k]:.2g} of max f (t = {run.column('t')[k]:.4g})"


def _attrs(run: Run) -> dict[str, Any]:
    from jko_cvx.engine._rundir import canonical_scene, scene_fingerprint

    v = run.verdict
    return {
        "scene": canonical_scene(run.scene),
        "scene_sha256": scene_fingerprint(run.scene),
        # the package that computed the run (read back from its checkpoint), not the one exporting it
        "jko_cvx": run.made_by.get("jko_cvx", __version__),
        "code_sha256": run.made_by.get("code_sha256", "not recorded"),
        "t_final": float(run.t),
        "stop": v.stop.name,
        "reason": v.reason,
        # undetermined is no boolean: a 0 there would read as "no blow-up"
        "blowup": "undetermined" if v.blowup is None else int(v.blowup),
        "certified": int(v.certified),
        "T_b": float("nan") if v.T_b is None else float(v.T_b),
        **{k: int(v[k]) for k in ("B_x", "B_v", "e_f")},
        **{f"seconds_{k}": float(s) for k, s in run.seconds.items()},
    }


def _require(module: str):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(
            f"{module} is needed for runs as xarray / netCDF data: install the optional extra "
            "jko_cvx[netcdf] (pip install 'jko_cvx[netcdf]': xarray and h5netcdf)"
        ) from None


def _check_export_target(path: Path) -> None:
    """RunDirError for a target that is a symbolic link (never followed), a directory, or a file of a run directory
    (writing there would destroy the run)."""
    from jko_cvx.engine._rundir import ENTRY_NAMES

    if path.is_symlink():
        raise RunDirError(f"{path} is a symbolic link: an export never writes through one; choose another file")
    if path.is_dir():
        raise RunDirError(f"{path} is a directory: name the netCDF file to write")
    # the folder as it is on disk (a relative path, a linked folder): the file the write would reach
    folder, leaf = path.parent.resolve(), path.parts[-1] if path.parts else ""
    in_run = (folder / "scene.json").exists() and leaf in ENTRY_NAMES
    in_snapshots = folder.parts[-1:] == ("snapshots",) and (folder.parent / "scene.json").exists()
    if in_run or in_snapshots:
        raise RunDirError(
            f"{path} is a file of the run directory {folder.parent if in_snapshots else folder}: exporting there "
            "would destroy the run; choose another file name (a new file beside the run is fine)"
        )


def export_netcdf(run: Run, path: str | Path) -> Path:
    """Write :meth:`Run.to_xarray` to a netCDF-4 file with h5netcdf (extra ``jko_cvx[netcdf]``).

    A target that is a symbolic link, a directory or one of a run directory's own files is refused
    (:class:`~jko_cvx.engine.errors.RunDirError`) before anything is written."""
    path = Path(path)
    _check_export_target(path)
    ds = run.to_xarray()
    _require("h5netcdf")
    ds.to_netcdf(path, engine="h5netcdf")
    return path


def _scene_from_record(record: dict[str, Any], fingerprint: str, where: Path) -> Scene:
    """Rebuild the scene recorded in ``scene.json``; it must reproduce the recorded fingerprint.

    A record written by an earlier version lacks the scene keys added since: rebuilt, they take their defaults
    and the scene's fingerprint is not the recorded one.  Such a record is read when it is itself what the
    fingerprint was taken of (the SHA-256 of its canonical JSON) and the rebuilt scene differs from it only by
    keys the record does not have; any other difference is refused.
    """
    from jko_cvx.engine._rundir import flat_scene_record, only_added, record_fingerprint, scene_fingerprint

    if flat_scene_record(record):
        raise RunDirError(
            f"{where} records the scene as flat fields (v_n, dt, ...), the layout of an earlier jko_cvx; this "
            "version records and reads the TOML-shaped document (v.n, time.dt, ...): run the scene again"
        )
    try:  # a recorded scene is read back, not started: the size limits (which depend on this machine's settings,
        # JKO_CVX_THREADS and JKO_CVX_MAX_GIB) guard a run's start, not reading what a run wrote
        scene = scene_from_dict(record, Limits(math.inf, math.inf))
    except (ValueError, TypeError) as exc:
        raise RunDirError(f"{where} does not rebuild the scene the run's checkpoint was made from ({exc})") from None
    if scene_fingerprint(scene) != fingerprint:
        if not (record_fingerprint(record) == fingerprint and only_added(record, scene.to_dict())):
            raise RunDirError(
                f"{where} does not rebuild the scene the run's checkpoint was made from (fingerprint differs)"
            )
    return scene


def load_run(path: str | Path, *, allow_partial: bool = False) -> Run:
    """The :class:`Run` that :func:`~jko_cvx.engine.loop.simulate` returned when it wrote the run directory ``path``.

    Parameters
    ----------
    path : str or Path
        A run directory (``jko-cvx run --out``, or ``simulate(..., out=path)``).
    allow_partial : bool
        Also load a run that has not ended (no ``verdict.json``: killed or interrupted) as
        it stood at its last checkpoint (its verdict is then provisional: where no rule has fired yet, it
        stops with ``StopReason.NOT_ENDED`` and its blow-up is undetermined, None).

    Raises
    ------
    RunDirError
        ``path`` is not a run directory, a file in it is missing, damaged or changed since the
        run wrote it (its digest is not the one ``metadata.json`` records), the state fails its
        invariants (:meth:`~jko_cvx.engine._state.RunState.check`), an entry is a symbolic link,
        or the run has not ended and ``allow_partial`` is false.

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> from jko_cvx import load_run, shipped_scene, simulate
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     run = simulate(shipped_scene("tab_bu_g1", {"v.n": 41, "t_end": 0.05}), out=Path(tmp) / "run")
    ...     back = load_run(Path(tmp) / "run")
    >>> back.steps, back.t == run.t, bool((back.f == run.f).all()), back.scene == run.scene
    (5, True, True, True)
    """
    check_bool("allow_partial", allow_partial)
    path = Path(path)
    if not path.is_dir():
        raise RunDirError(f"run directory {path} does not exist")
    from jko_cvx.engine._rundir import aside_state, check_metadata, read_snapshots, refuse_links

    interrupted = aside_state(path)  # before the files: an interrupted overwrite may have moved scene.json aside
    if interrupted:
        raise RunDirError(f"{path}: {interrupted}")
    if not (path / "scene.json").exists():
        raise RunDirError(f"{path} is not a run directory: it has no scene.json")
    refuse_links(path)
    ledger = Ledger.read(path)
    try:
        record = json.loads((path / "scene.json").read_text())
    except (OSError, ValueError, RecursionError) as exc:
        raise RunDirError(f"{path / 'scene.json'} does not read ({type(exc).__name__}: {exc})") from None
    ck = path / "checkpoint.npz"
    fingerprint = str(read_npz(ck, "checkpoint", ("scene_sha256",))["scene_sha256"])
    scene = _scene_from_record(record, fingerprint, path / "scene.json")
    state, recorded = RunState.load(ck, None if scene.homogeneous else scene.xgrid().period)
    # the files read whole first (a truncated one is named as such), then each against its digest
    for name in ("scene.json", "checkpoint.npz", "diagnostics.csv", "verdict.json"):
        if name != "verdict.json" or (path / name).exists():
            ledger.verify(path / name)
    state.check(ck)
    check_metadata(ledger, recorded, path)
    verdict_file = path / "verdict.json"
    if verdict_file.exists():
        try:
            json.loads(verdict_file.read_text())["stop"]
        except (OSError, ValueError, KeyError, TypeError, RecursionError) as exc:
            raise RunDirError(f"{verdict_file} does not read ({type(exc).__name__}: {exc})") from None
    elif not allow_partial:
        raise RunDirError(
            f"the run in {path} has not ended (no verdict.json; checkpoint at step {state.step}, t = {state.t:g}): "
            "resume it (jko-cvx run SCENE --out DIR --resume) or pass allow_partial=True"
        )
    else:  # a provisional verdict: no rule has fired yet, which says nothing of the rest of the run
        state.verdict = state.verdict.not_ended(state.t, scene.t_end)
    snaps = read_snapshots(path, state.step, ledger)
    made_by = {k: recorded[k] for k in ("jko_cvx", "code_sha256") if k in recorded}
    return Run(scene, state.rows, snaps, state.f, state.vgrid, state.xgrid, state.t, state.verdict, state.seconds,
               made_by)  # fmt: skip
