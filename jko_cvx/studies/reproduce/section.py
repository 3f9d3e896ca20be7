"""``jko-cvx reproduce section``: every entry of the paper's numerical section in one run.

Run one entry after another, each with its own pool, and the cores idle whenever an entry
has fewer points left than workers (a long point at the end of a sweep, a serial entry, a
report being drawn), and every entry pays for starting its own pool.  Here the entries run
in threads of one process that share one pool of worker processes: each entry submits its
sweep points to the shared pool as soon as it starts, so the pool always has work queued,
and the entries start in the order of their measured cost (longest first, see
:data:`SECTION`), so the long points are not left for the end.

The entries' own code (reading the sweep results, tables, figures, the runs some entries do
outside a sweep) runs one entry at a time: an entry holds a lock except while it waits for
its points (:func:`jko_cvx.studies.sweep.run_sweep` releases it there), so matplotlib and the
entries' files see no concurrency they were not written for.  Results do not depend on this:
a sweep point is a deterministic function of its parameters wherever it runs (the sweep's
tests check serial, process and Dask runs give identical tables), and the entries write
the same files as ``jko-cvx reproduce NAME`` does, one by one.

Entries that read another entry's files wait for it (:data:`NEEDS`).  A point that two entries
share (the same function, code and parameters: ``gk2_bu``'s runs are four of ``tab_g2bu``'s and
``g2bu_records``' one, ``tab_bu``'s are a block of the beta scan's, ``ibu_panels``' is ``ibu``'s)
runs once (:func:`jko_cvx.studies.sweep.shared_points`).  A failing entry is recorded and the others
go on; entries that need it are skipped.  ``section.{csv,md}`` record, per entry, when it started
and finished, and the total wall and CPU time, with the code's provenance.
"""

from __future__ import annotations

import os
import resource
import threading
import time
import traceback
from concurrent.futures import Executor, ProcessPoolExecutor
from contextlib import ExitStack
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pandas as pd

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce import REPRODUCTIONS
from jko_cvx.studies.sweep import check_main_guard, code_provenance, holding, shared_points

__all__ = ["NEEDS", "SECTION", "reproduce_section"]

SECTION = (
    "inhom_gamma1p5",
    "tab_bu_beta_scan",
    "tab_g2bu",
    "tab_g2bu_control",
    "criterion_control",
    "gk1_records",
    "gk2_bu",
    "inhom_gamma3",
    "gk3_panels",
    "tab_bu",
    "property_budget",
    "g2bu_records",
    "tab_bu_tb2",
    "ibu_panels",
    "ibu",
    "fisher_width",
    "tab_bu_traces",
    "explicit",
    "explicit_figures",
    "explicit2_sketch",
    "gk1_final",
    "mesh_maps",
    "g2bu_loglog",
    "discrimination",
)
"""The entries of the paper's numerical section, in the order they start: by CPU time, longest first
(measured one entry at a time on 2 cores: ``inhom_gamma1p5``
first, the entries of a few seconds last), then the entries that read others' files (an entry starts after
the one before it has, so these come last).  ``grid_convergence``
(the study the paper lacks, 41 minutes on its own) is not part of the section: run it by name; nor is
``g3_dt_probe`` (the gamma = 3 runs in the grid and in dt: hours on one core, its table's ``seconds``), nor
``conclusions``, which reads its files and those of the paper-variants study script, nor
``inhom_gamma1p5_events``, which reads its files and those of ``inhom_gamma1p5``."""

NEEDS: dict[str, tuple[str, ...]] = {
    "g2bu_loglog": ("tab_g2bu",),  # reads tab_g2bu.csv
    "discrimination": ("tab_bu", "tab_bu_tb2", "tab_g2bu", "tab_bu_beta_scan"),  # reads their CSVs
}
"""The entries each entry reads files of (it starts after they have finished)."""


class _Entry:
    """One entry's thread: waits for the entries it needs and for its turn, then runs holding the lock."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.finished = threading.Event()
        self.released = threading.Event()  # the entry has submitted its first points (or finished)
        self.row: dict[str, Any] = {"entry": name, "status": "not started", "error": ""}


def _run_entry(
    entry: _Entry, before: _Entry | None, needs: list[_Entry], lock: threading.Lock, t0: float, call: dict,
    progress: bool,
) -> None:  # fmt: skip
    try:
        for other in needs:
            other.finished.wait()
        failed = [o.name for o in needs if o.row["status"] != "ok"]
        if failed:
            entry.row.update(status="skipped", error=f"needs {', '.join(failed)}, which did not finish")
            return
        if before is not None:
            before.released.wait()  # start in SECTION order: the pool's queue follows it
        with holding(lock, on_release=entry.released.set):
            entry.row["started_s"] = time.perf_counter() - t0
            REPRODUCTIONS[entry.name](**call)
        entry.row.update(status="ok")
    except Exception as exc:  # recorded; the other entries go on
        entry.row.update(status="failed", error=f"{type(exc).__name__}: {exc}")
        traceback.print_exc()
    finally:
        entry.row["finished_s"] = time.perf_counter() - t0
        if "started_s" in entry.row:
            entry.row["wall_s"] = entry.row["finished_s"] - entry.row["started_s"]
        entry.released.set()
        entry.finished.set()
        if progress:
            _print_row(entry.row)


def _cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def reproduce_section(
    out: Path,
    quick: bool = False,
    executor: str | Executor = "process",
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    fresh: bool = False,
    audit: int = 0,
    entries: tuple[str, ...] | None = None,
) -> pd.DataFrame:
    """Run every entry of :data:`SECTION` (or ``entries``, in SECTION's order) into ``out``, on one shared pool.

    Parameters
    ----------
    out : Path
        Output directory of every entry (as ``jko-cvx reproduce NAME --out out``).
    quick : bool
        The entries' quick forms.
    executor : {"process", "serial", "dask"} or Executor
        ``"process"``: one process pool of ``workers`` shared by every entry; ``"serial"``: the
        entries one after another, their points in this process; ``"dask"`` or ``scheduler``:
        every entry sends its points to the Dask cluster (a local one of ``workers`` is
        started for ``"dask"``); an Executor instance is shared as it is.
    workers : int, optional
        Worker processes (default: the CPU count).
    progress : bool
        Print a line as each entry finishes.
    fresh : bool
        Ignore the sweep caches (``--fresh``).
    audit : int
        Recompute this many cached points of each sweep and compare them with the cache
        (``--audit K``; see :func:`jko_cvx.studies.sweep.run_sweep`).
    entries : tuple of str, optional
        A subset of :data:`SECTION`; an entry that needs one left out reads its files from ``out``.
        Default: every entry.

    Returns
    -------
    pandas.DataFrame
        Per entry: status (ok, failed, skipped), error, start, finish and wall seconds
        (from the section's start); also written to ``section.{csv,md}`` in ``out``.
        ``RuntimeError`` after the run (and the files) if any entry did not finish.
    """
    names = SECTION if entries is None else tuple(entries)
    unknown = [n for n in names if n not in SECTION]
    if unknown:
        raise ValueError(f"entries must be entries of the section {SECTION}, got {unknown}")
    names = tuple(n for n in SECTION if n in names)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if isinstance(executor, str) and executor not in ("process", "serial", "dask"):
        raise ValueError(f"executor must be 'process', 'serial', 'dask' or an Executor, got {executor!r}")
    if scheduler is None and isinstance(executor, str):
        check_main_guard(executor)  # its pool is started here, not by run_sweep
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0, cpu0 = time.perf_counter(), _cpu_seconds()
    started = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    with ExitStack() as stack:
        shared: str | Executor = executor
        if scheduler is None and executor == "dask":
            try:
                from distributed import LocalCluster
            except ImportError as exc:  # optional extra
                raise ImportError('Dask sweeps need the optional extra: pip install "jko_cvx[dask]"') from exc

            cluster = stack.enter_context(
                LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True)
            )
            scheduler = cluster.scheduler_address
        elif scheduler is None and executor == "process":
            shared = stack.enter_context(ProcessPoolExecutor(max_workers=workers))
        if not isinstance(shared, str):
            stack.enter_context(shared_points())  # a point two entries share runs once
        call = {"out": out, "quick": quick, "executor": shared, "scheduler": scheduler, "workers": workers}
        call.update(progress=False, fresh=fresh, **({"audit": audit} if audit else {}))
        threads = executor != "serial" or scheduler is not None
        state = {n: _Entry(n) for n in names}
        lock = threading.Lock()
        runners = []
        for i, name in enumerate(names):
            before = state[names[i - 1]] if i else None
            needs = [state[n] for n in NEEDS.get(name, ()) if n in state]
            args = (state[name], before, needs, lock, t0, {**call}, progress)
            if threads:
                runners.append(threading.Thread(target=_run_entry, args=args, name=f"section-{name}", daemon=True))
                runners[-1].start()
            else:
                _run_entry(*args)
        for runner in runners:
            runner.join()
    wall, cpu = time.perf_counter() - t0, _cpu_seconds() - cpu0
    df = pd.DataFrame([state[n].row for n in names])
    _write(out, df, wall, cpu, started, workers, quick, fresh, executor if isinstance(executor, str) else "executor")
    bad = df[df.status != "ok"]
    if len(bad):
        raise RuntimeError(f"{len(bad)} of {len(df)} entries did not finish: {', '.join(bad.entry)} (see section.md)")
    return df


_PRINT = threading.Lock()


def _print_row(row: dict[str, Any]) -> None:
    wall = f"{row['wall_s']:.1f} s" if "wall_s" in row else "-"
    with _PRINT:
        print(f"  {row['entry']}: {row['status']} ({wall}, done at {row.get('finished_s', float('nan')):.0f} s)"
              + (f": {row['error']}" if row["error"] else ""), flush=True)  # fmt: skip


def _write(out: Path, df: pd.DataFrame, wall: float, cpu: float, started: str, workers, quick, fresh, how) -> None:
    prov = code_provenance(reproduce_section)
    df.to_csv(out / "section.csv", index=False)
    record_csv(out / "section.csv")
    modified = " (jko_cvx modified)" if prov["jko_cvx_modified"] else ""
    lines = [
        f"# The numerical section in one run ({'quick' if quick else 'full'} forms)",
        "",
        f"`jko-cvx reproduce section`: {len(df)} entries started {started}, executor {how}, "
        f"{workers or os.cpu_count()} workers{', fresh (no sweep cache)' if fresh else ''}; code: commit "
        f"{str(prov['git_commit'])[:12]}{modified}, package sha256 {prov['package_sha256'][:12]}.",
        "",
        df.to_markdown(index=False, floatfmt=".1f"),
        "",
        f"**Wall time {wall:.0f} s ({wall / 60:.1f} min); CPU {cpu:.0f} s** (this process and its "
        "pool's workers; a Dask cluster's CPU is not counted).",
        "",
    ]
    write_markdown(out / "section.md", "\n".join(lines))
