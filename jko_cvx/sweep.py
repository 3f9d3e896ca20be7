"""Parameter sweeps: pure point functions on any executor, cached per point on disk.

A sweep is a list of parameter points (dicts of JSON-serialisable values) and a
module-level function ``func(**point) -> dict`` that depends on nothing else.  Each point's
result is written atomically to ``cache_dir/<hash>.json`` as soon as it arrives, so a
killed sweep resumes by computing only the points without a file.  Points run on any
:class:`concurrent.futures.Executor`:

* ``executor="serial"``: in this process, in order (debugging, tests);
* ``executor="process"`` (default): a local :class:`~concurrent.futures.ProcessPoolExecutor`;
* ``executor="dask"``: a local Dask cluster (``distributed.LocalCluster``);
* ``scheduler="tcp://host:8786"``: an existing Dask cluster, through
  ``distributed.Client(scheduler).get_executor()``;
* or an ``Executor`` instance.

Dask is optional (``pip install "jko_cvx[dask]"``).  Results do not depend on where a point
ran: the point functions are deterministic, and the test suite checks that serial, process
pool and Dask runs give identical tables.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import pandas as pd

__all__ = ["point_key", "run_sweep"]


def point_key(func: Callable[..., Any], point: Mapping[str, Any]) -> str:
    """Stable cache key of ``func`` at ``point``: SHA-256 of its qualified name and the canonical JSON."""
    name = f"{func.__module__}.{func.__qualname__}"
    text = json.dumps({"func": name, "point": dict(point)}, sort_keys=True, default=float)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _call(func: Callable[..., dict], point: dict) -> dict:
    return func(**point)


def run_sweep(
    func: Callable[..., dict],
    points: Iterable[Mapping[str, Any]],
    cache_dir: str | Path,
    executor: str | Executor = "process",
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    desc: str = "sweep",
) -> pd.DataFrame:
    """Evaluate ``func(**point)`` at every point, reusing cached results; one row per point.

    Parameters
    ----------
    func : callable
        A module-level (picklable) function of the point's keys returning a dict of results.
    points : iterable of dict
        The parameter points, JSON-serialisable.  Their order is the order of the rows.
    cache_dir : str or Path
        Directory of per-point result files (created if missing).
    executor : {"process", "serial", "dask"} or Executor, default "process"
        Where the missing points run (see the module docstring).
    scheduler : str, optional
        Address of a Dask scheduler; overrides ``executor``.
    workers : int, optional
        Worker count for the local pool or cluster (default: the CPU count).
    progress : bool, default True
        Show a tqdm progress bar of points done (cached points count as done).

    Returns
    -------
    pandas.DataFrame
        The point's parameters followed by its results, plus ``cached`` (True where the
        result was read from the cache rather than computed in this call).
    """
    points = [dict(p) for p in points]
    if not callable(func):
        raise TypeError(f"func must be callable, got {type(func).__name__}")
    if isinstance(executor, str) and executor not in ("process", "serial", "dask"):
        raise ValueError(f"executor must be 'process', 'serial', 'dask' or an Executor, got {executor!r}")
    if workers is not None and (not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    cache = Path(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    keys = [point_key(func, p) for p in points]
    results: dict[str, dict] = {}
    for key in set(keys):
        path = cache / f"{key}.json"
        if path.exists():
            results[key] = json.loads(path.read_text())["result"]
    cached = set(results)
    todo = {k: p for k, p in zip(keys, points, strict=True) if k not in results}

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(set(keys)), initial=len(cached), desc=desc, unit="pt")

    def store(key: str, result: dict) -> None:
        if not isinstance(result, dict):
            raise TypeError(f"{func.__qualname__} must return a dict, got {type(result).__name__}")
        _write_atomic(cache / f"{key}.json", json.dumps({"point": todo[key], "result": result}, default=float))
        results[key] = result
        if bar is not None:
            bar.update(1)

    try:
        if todo and (executor == "serial" and scheduler is None):
            for key, point in todo.items():
                store(key, _call(func, point))
        elif todo:
            with ExitStack() as stack:
                pool = _open_executor(stack, executor, scheduler, workers)
                futures: dict[Future, str] = {pool.submit(_call, func, p): k for k, p in todo.items()}
                for fut in as_completed(futures):
                    store(futures[fut], fut.result())
    finally:
        if bar is not None:
            bar.close()
    rows = [{**p, **results[k], "cached": k in cached} for k, p in zip(keys, points, strict=True)]
    return pd.DataFrame(rows)


def _open_executor(stack: ExitStack, executor, scheduler: str | None, workers: int | None) -> Executor:
    if scheduler is not None or executor == "dask":
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:  # optional extra
            raise ImportError('Dask sweeps need the optional extra: pip install "jko_cvx[dask]"') from exc
        if scheduler is not None:
            client = stack.enter_context(Client(scheduler))
        else:
            cluster = stack.enter_context(
                LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True)
            )
            client = stack.enter_context(Client(cluster))
        return client.get_executor()
    if executor == "process":
        return stack.enter_context(ProcessPoolExecutor(max_workers=workers))
    if isinstance(executor, Executor):
        return executor
    raise ValueError(f"executor must be 'process', 'serial', 'dask' or an Executor, got {executor!r}")
