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

A script that starts local worker processes needs the ``if __name__ == "__main__":`` guard.
A local Dask cluster starts its workers with the ``spawn`` method (the Dask setting
``distributed.worker.multiprocessing-method``), and so does a process pool where ``spawn`` or
``forkserver`` is the start method (macOS, Windows; Linux from Python 3.14): each worker
imports the main script again, so a call at its top level would start the sweep again in
every worker.  :func:`run_sweep` refuses such a call before any work, with a
``RuntimeError`` naming the script's line (:func:`check_main_guard`)::

    from jko_cvx.studies.sweep import run_sweep

    def main():
        run_sweep(func, points, "cache", executor="dask", workers=2)

    if __name__ == "__main__":  # the workers import this file without running main()
        main()

Interactive sessions, notebooks and ``python -c`` have no main script to import again.

The cache serves no result of code other than what its key names.  A point's key (:func:`point_key`) covers the point
(NumPy numbers as the Python numbers of their kind), the function's qualified name, the source
of the module that defines it, the package version and a hash of every file of the package
(its modules and the shipped scenes, :func:`jko_cvx.environment.code_fingerprint`): after any
change of code or shipped data, old entries are simply not found (and the point runs again).
Functions whose results that key cannot pin are refused before any point runs: lambdas (two in
one module share a name), closures and functions defined inside functions (the values they were
made with are not in the source) and callable objects such as ``functools.partial``, and so is a point function
whose file no longer holds the code that runs (edited after its module was imported).  Code in neither the
function's module nor the package (a helper module of the caller's that it imports) is not in the key: a
point function that "depends on nothing else" keeps such code in its module.  Each entry records its key and
a SHA-256 digest of its content; an entry that does not parse, records another key or
point, or fails its digest (truncated, tampered with) is recomputed with a
:class:`StaleCacheWarning` naming the file.  ``fresh=True`` (``jko-cvx reproduce --fresh``)
ignores the cache and recomputes every point.

Digests catch accidents (a truncated write, an edited file, an entry of older code); they do
not stop a deliberate forgery, whose author can recompute the digest too.  For that,
``audit=K`` (``jko-cvx reproduce NAME --audit K``) recomputes K randomly chosen cached points
and compares each result with its entry bit for bit (measured wall times excepted:
:data:`TIMING_KEY`); any mismatch raises :class:`CacheAuditError` naming the files and the
keys that differ, and nothing is served.
"""

from __future__ import annotations

import ast
import hashlib
import inspect
import json
import linecache
import multiprocessing
import os
import random
import re
import secrets
import sys
import tempfile
import threading
import types
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

import pandas as pd

from jko_cvx.environment import CodeChangedError, code_fingerprint, git_state, library_versions

__all__ = [
    "TIMING_KEY",
    "CacheAuditError",
    "StaleCacheWarning",
    "cached_entries",
    "check_main_guard",
    "code_identity",
    "holding",
    "point_key",
    "run_sweep",
    "shared_points",
]


TIMING_KEY = re.compile(r"seconds|wall|speed-up|.+_s|.+_seconds")
"""Result keys that hold a measured wall time (or a ratio of two): an audit does not compare them."""


class CacheAuditError(ValueError):
    """A cached result that recomputing its point does not reproduce (see ``run_sweep(audit=...)``)."""


class StaleCacheWarning(UserWarning):
    """A cache entry that could not be trusted (unreadable, another key, a bad digest): recomputed."""


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _module_source(func: Callable[..., Any]) -> str:
    """The source of the module defining ``func`` (its helpers change the results too); the function's own
    source where the module has none.  ValueError where that source no longer compiles to the functions
    running (the file was edited after the module was imported)."""
    module = sys.modules.get(getattr(func, "__module__", ""), None)
    for obj in (module, func):
        try:
            source = inspect.getsource(obj)
        except (OSError, TypeError):
            continue
        _check_running(func)
        return source
    raise TypeError(f"cannot read the source of {func!r}: sweeps cache only functions defined in source files")


def _code_shape(code: types.CodeType) -> tuple[Any, ...]:
    """What a code object computes, line numbers left out (an edit that only moves code changes no result)."""
    consts = tuple(
        _code_shape(c) if isinstance(c, types.CodeType)
        else repr(sorted(c, key=repr)) if isinstance(c, frozenset)  # printed in the string-hash seed's order
        else repr(c)
        for c in code.co_consts
    )  # fmt: skip
    return code.co_code, consts, code.co_names, code.co_varnames, code.co_freevars, code.co_cellvars


def _check_running(func: Callable[..., Any]) -> None:
    """ValueError unless the file ``func`` was defined in (read now) compiles to the code of ``func`` that runs: the
    key must name the code that computes the results it stores.  The whole file is compiled: a function compiled
    alone is compiled differently (its module's imports and future statements shape its bytecode)."""
    filename = func.__code__.co_filename
    linecache.checkcache(filename)
    source = "".join(linecache.getlines(filename))
    if not source:  # no file (defined in an interactive session): its source is the function's own, read above
        return
    compiled: dict[str, list[tuple[Any, ...]]] = {}  # a name defined twice has two codes
    todo = [compile(source, filename, "exec", dont_inherit=True)]
    while todo:
        code = todo.pop()
        compiled.setdefault(code.co_qualname, []).append(_code_shape(code))
        todo.extend(c for c in code.co_consts if isinstance(c, types.CodeType))
    # the point function itself (the module's other functions may be rewritten on import, as pytest's asserts)
    if _code_shape(func.__code__) not in compiled.get(func.__code__.co_qualname, ()):
        raise ValueError(
            f"{filename} changed since {func.__module__} was imported ({func.__qualname__} runs other code than the "
            "file holds now): a cached result would be keyed by code that did not compute it; restart Python to "
            "sweep the edited code"
        )


def _check_cacheable(func: Callable[..., Any]) -> None:
    """TypeError / ValueError unless ``func``'s results are determined by what :func:`code_identity` records: a
    function defined with ``def`` at module level, whose behaviour its module's source fixes (no lambda: two in one
    module share a name; no function defined inside another, nor a closure: the values it was made with are not in
    its source; no ``functools.partial`` or other callable object)."""
    if not isinstance(func, types.FunctionType):
        raise TypeError(
            f"func must be a function defined with def (at module level), got {type(func).__module__}."
            f"{type(func).__qualname__}: its results could not be keyed by its source; pass the arguments it fixes "
            "in the points instead"
        )
    if func.__name__ == "<lambda>":
        raise ValueError(
            f"func is a lambda ({func.__qualname__} in {func.__module__}): lambdas of one module share a name, so "
            "the cache could serve one's results for another; define it with def"
        )
    if "<locals>" in func.__qualname__ and not func.__closure__:
        raise ValueError(
            f"func {func.__qualname__} is defined inside a function: the values it was made with (default "
            "arguments, globals of the call) are not in its module's source, so the cache could serve results of "
            "other values; define it at module level and pass them in the points"
        )
    if func.__closure__:
        raise ValueError(
            f"func {func.__qualname__} captures values ({', '.join(func.__code__.co_freevars)}) that its source does "
            "not fix, so the cache could serve results of other values; pass them in the points instead"
        )


def code_identity(func: Callable[..., Any]) -> dict[str, str]:
    """What the results of ``func`` depend on besides the point: name, module source, package version and code,
    and the versions of Python and the numerical libraries (:func:`~jko_cvx.environment.library_versions`).

    Raises TypeError or ValueError for a function whose results these do not determine (a lambda, a closure,
    a ``functools.partial`` or other callable object)."""
    _check_cacheable(func)
    return {
        "func": f"{func.__module__}.{func.__qualname__}",
        "module_sha256": _sha(_module_source(func)),
        **_package_identity(),
    }


def _package_identity() -> dict[str, str]:
    """The part of :func:`code_identity` that is not the function's: the package's version and code, the libraries."""
    from jko_cvx._version import __version__

    return {"package_version": __version__, "package_sha256": code_fingerprint(), "libraries": library_versions()}


def code_provenance(func: Callable[..., Any]) -> dict[str, Any]:
    """:func:`code_identity` plus the git commit of the checkout the package sits in and whether
    its ``jko_cvx`` files differ from that commit (``None`` and ``None`` outside a git checkout).

    For study scripts that record which code produced a result file; take it before the run,
    so that a file edited meanwhile cannot change the record.
    """
    commit, modified = git_state()
    return {
        **code_identity(func),
        "git_commit": commit,
        "jko_cvx_modified": modified,
    }


def _plain(obj: Any) -> Any:
    """A NumPy scalar as the Python number of its kind (``np.int64(5)`` is 5, not 5.0: the key tells the types
    apart as JSON does), anything else JSON cannot write refused."""
    import numpy as np

    if isinstance(obj, np.generic) and isinstance(obj, np.number | np.bool_):
        return obj.item()
    raise TypeError(f"a point or result holds {obj!r} ({type(obj).__name__}): only numbers, strings, bools, None, "
                    "lists and dicts are keyed and cached")  # fmt: skip


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, default=_plain)


def point_key(func: Callable[..., Any], point: Mapping[str, Any]) -> str:
    """Cache key of ``func`` at ``point``: SHA-256 of :func:`code_identity` and the point's canonical JSON."""
    return _key(code_identity(func), point)


def _key(identity: Mapping[str, str], point: Mapping[str, Any]) -> str:
    return _sha(_canonical({"code": dict(identity), "point": dict(point)}))[:32]


def _entry(key: str, point: Mapping[str, Any], result: Mapping[str, Any]) -> str:
    """The JSON text of a cache entry; ``digest`` covers key, point and result."""
    body = {"key": key, "point": dict(point), "result": dict(result)}
    return json.dumps({**body, "digest": _sha(_canonical(body))}, default=_plain)


def _read_entry(path: Path, key: str, point: Mapping[str, Any]) -> dict | None:
    """The cached result at ``path``, or None (with a warning naming the file) if it cannot be trusted."""
    try:
        entry = json.loads(path.read_text())
        body = {k: entry[k] for k in ("key", "point", "result")}
        problem = (
            "records another key"
            if body["key"] != key
            else "records another point"
            if _canonical(body["point"]) != _canonical(dict(point))
            else "fails its digest (edited or corrupted)"
            if entry.get("digest") != _sha(_canonical(body))
            else None
        )
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, RecursionError) as exc:
        problem = f"does not parse ({type(exc).__name__}: {exc})"
    if problem is None:
        return entry["result"]
    warnings.warn(f"sweep cache entry {path} {problem}; recomputing the point", StaleCacheWarning, stacklevel=4)
    return None


def cached_entries(cache_dir: str | Path) -> list[tuple[dict, dict]]:
    """Every (point, result) in ``cache_dir``, whatever code wrote it, each entry's digest checked.

    For reports built from a stopped sweep's cache,
    which must state the code the entries came from themselves: the key, which covers the
    code, is not compared here.  Raises ``ValueError`` naming an entry that does not parse
    or fails its digest (edited or truncated) rather than leaving it out.
    """
    entries = []
    for path in sorted(Path(cache_dir).glob("*.json")):
        try:
            entry = json.loads(path.read_text())
            body = {k: entry[k] for k in ("key", "point", "result")}
        except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, RecursionError) as exc:
            raise ValueError(f"cache entry {path} does not parse ({type(exc).__name__}: {exc})") from None
        if entry.get("digest") != _sha(_canonical(body)):
            raise ValueError(f"cache entry {path} fails its digest: refusing to report from it")
        entries.append((body["point"], body["result"]))
    return entries


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _read_cache(cache: Path, points: Mapping[str, Mapping[str, Any]]) -> dict[str, dict]:
    """The trusted cached results of ``points`` (by key); damaged entries are left out with a warning."""
    results = {}
    for key, point in points.items():
        path = cache / f"{key}.json"
        if path.exists():
            result = _read_entry(path, key, point)
            if result is not None:
                results[key] = result
    return results


def _call(func: Callable[..., dict], point: dict, identity: Mapping[str, str] | None = None) -> dict:
    """``func(**point)``, in a worker or here; with ``identity`` (the :func:`code_identity` the point's key was made
    of), checked before and after against the code that runs it: a worker imports its own copy of the code."""
    if identity is not None:
        _check_identity(func, identity)
    result = func(**point)
    if identity is not None:
        _check_identity(func, identity)
    return result


def _check_identity(func: Callable[..., Any], identity: Mapping[str, str]) -> None:
    """CodeChangedError unless the code here is the code ``identity`` names (see :func:`_call`)."""
    here = _package_identity()
    try:
        here["module_sha256"] = _sha(_module_source(func))
    except TypeError:  # a function sent by value (Dask's cloudpickle): its code is the parent's own
        pass
    differ = sorted(k for k, v in here.items() if identity.get(k) != v)
    if differ:
        raise CodeChangedError(
            f"the code computing a point of {identity.get('func')} is not the code its cache key names "
            f"({', '.join(differ)} differ): a file changed during the sweep, or a worker runs another installation; "
            "restart the sweep"
        )


_HELD = threading.local()


@contextmanager
def holding(lock: threading.Lock, on_release: Callable[[], None] | None = None) -> Iterator[None]:
    """Hold ``lock`` in this block, except while :func:`run_sweep` waits for its points.

    Lets several callers share one pool (``jko-cvx reproduce section``): each runs its own
    code holding the lock, one at a time, and lets the others run while its points are
    computed.  ``on_release`` is called each time the lock is let go for a wait.
    """
    lock.acquire()
    _HELD.lock, _HELD.on_release = lock, on_release
    try:
        yield
    finally:
        _HELD.lock = _HELD.on_release = None
        lock.release()


_SHARED: dict[str, Future] | None = None
_SHARED_LOCK = threading.Lock()


@contextmanager
def shared_points() -> Iterator[None]:
    """Within the block, a point that another :func:`run_sweep` call has already submitted is not
    submitted again: the call takes that call's future.

    For callers that share one Executor (``jko-cvx reproduce section``: ``gk2_bu``'s runs are
    four of ``tab_g2bu``'s, ``tab_bu``'s are a block of the beta scan's).  A point's key
    (:func:`point_key`) covers the function, the source of its module, the package's code and
    the parameters, and a point is a deterministic function of them, so its result is the
    same whichever call computed it; each call still writes it into its own cache.
    """
    global _SHARED
    with _SHARED_LOCK:
        if _SHARED is not None:
            raise RuntimeError("shared_points blocks do not nest")
        _SHARED = {}
    try:
        yield
    finally:
        with _SHARED_LOCK:
            _SHARED = None


def _submit(pool: Executor, func: Callable[..., dict], key: str, point: dict, identity: Mapping[str, str]) -> Future:
    """``pool.submit`` of one point, or the future of the same point already submitted (:func:`shared_points`)."""
    with _SHARED_LOCK:
        if _SHARED is None:
            return pool.submit(_call, func, point, identity)
        fut = _SHARED.get(key)
        if fut is None:
            fut = _SHARED[key] = pool.submit(_call, func, point, identity)
        return fut


@contextmanager
def _lock_released() -> Iterator[None]:
    """Release the lock of :func:`holding` (if this thread holds one) for the block."""
    lock = getattr(_HELD, "lock", None)
    if lock is None:
        yield
        return
    lock.release()
    if _HELD.on_release is not None:
        _HELD.on_release()
    try:
        yield
    finally:
        lock.acquire()


def run_sweep(
    func: Callable[..., dict],
    points: Iterable[Mapping[str, Any]],
    cache_dir: str | Path,
    executor: str | Executor = "process",
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    desc: str = "sweep",
    fresh: bool = False,
    audit: int = 0,
    audit_seed: int | None = None,
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
        Where the missing points run (see the module docstring).  ``"dask"`` (and
        ``"process"`` under the ``spawn`` or ``forkserver`` start method) called from a script
        needs the script's ``if __name__ == "__main__":`` guard (:func:`check_main_guard`).
    scheduler : str, optional
        Address of a Dask scheduler; overrides ``executor``.
    workers : int, optional
        Worker count for the local pool or cluster (default: the CPU count).
    progress : bool, default True
        Show a tqdm progress bar of points done (cached points count as done).
    desc : str, default "sweep"
        Label of the progress bar.
    fresh : bool, default False
        Ignore the cache: compute every point and overwrite its entry.
    audit : int, default 0
        Recompute this many randomly chosen cached points (all of them if fewer) and compare
        their results with the cache bit for bit, keys matching :data:`TIMING_KEY` excepted;
        a mismatch raises :class:`CacheAuditError` and no table is returned.  A line on
        stderr reports what was audited and the seed.
    audit_seed : int, optional
        Seed of the choice of audited points (default: a fresh random seed, reported).

    Returns
    -------
    pandas.DataFrame
        The point's parameters followed by its results, plus ``cached`` (True where the
        result was read from the cache rather than computed in this call).

    Raises
    ------
    RuntimeError
        Local worker processes would import the main script again and rerun this call (no
        ``if __name__ == "__main__":`` guard around it; see :func:`check_main_guard`);
        raised before any point runs or any file is written.
    """
    if not callable(func):
        raise TypeError(f"func must be callable, got {type(func).__name__}")
    _check_cacheable(func)
    points = _checked_points(points)
    if isinstance(executor, str) and executor not in ("process", "serial", "dask"):
        raise ValueError(f"executor must be 'process', 'serial', 'dask' or an Executor, got {executor!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if not isinstance(fresh, bool):
        raise TypeError(f"fresh must be a bool, got {fresh!r}")
    if isinstance(audit, bool) or not isinstance(audit, int) or audit < 0:
        raise ValueError(f"audit must be an integer >= 0 (cached points to recompute), got {audit!r}")
    if audit_seed is not None and (isinstance(audit_seed, bool) or not isinstance(audit_seed, int)):
        raise TypeError(f"audit_seed must be None or an integer, got {audit_seed!r}")
    if scheduler is None and isinstance(executor, str):
        check_main_guard(executor)
    identity = code_identity(func)  # once: it reads and compiles the module and hashes the package
    keys = [_key(identity, p) for p in points]
    cache = Path(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    results = {} if fresh else _read_cache(cache, dict(zip(keys, points, strict=True)))
    cached = set(results)
    todo = {k: p for k, p in zip(keys, points, strict=True) if k not in results}
    seed = secrets.randbits(32) if audit_seed is None else audit_seed
    audited = random.Random(seed).sample(sorted(cached), min(audit, len(cached))) if audit else []
    recomputed: dict[str, dict] = {}
    points_by_key = dict(zip(keys, points, strict=True))

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(set(keys)), initial=len(cached), desc=desc, unit="pt")

    def store(key: str, result: dict) -> None:
        if not isinstance(result, dict):
            raise TypeError(f"{func.__qualname__} must return a dict, got {type(result).__name__}")
        if key in cached:  # an audited point: compared, never written over its entry
            recomputed[key] = result
            return
        _write_atomic(cache / f"{key}.json", _entry(key, todo[key], result))
        results[key] = result
        if bar is not None:
            bar.update(1)

    work = {**todo, **{k: points_by_key[k] for k in audited}}
    try:
        if work and (executor == "serial" and scheduler is None):
            for key, point in work.items():
                store(key, _call(func, point, identity))
        elif work:
            with ExitStack() as stack:
                pool = _open_executor(stack, executor, scheduler, workers)
                futures: dict[Future, str] = {_submit(pool, func, k, p, identity): k for k, p in work.items()}
                with _lock_released():  # other holders of a shared pool run meanwhile (holding)
                    for fut in as_completed(futures):
                        store(futures[fut], fut.result())
    finally:
        if bar is not None:
            bar.close()
    if audit:
        _check_audit(cache, results, recomputed, audited, len(cached), seed)
    rows = [{**p, **results[k], "cached": k in cached} for k, p in zip(keys, points, strict=True)]
    return pd.DataFrame(rows)


def _check_audit(
    cache: Path, results: dict[str, dict], recomputed: dict[str, dict], audited: list[str], n_cached: int, seed: int
) -> None:
    """Compare the recomputed results of the audited keys with their cache entries; raise on any difference."""
    bad = []
    for key in audited:
        old, new = results[key], recomputed[key]
        names = sorted(set(old) | set(new))
        differ = [n for n in names if not TIMING_KEY.fullmatch(n) and _canonical(old.get(n)) != _canonical(new.get(n))]
        if differ:
            shown = ", ".join(f"{n}: cached {old.get(n)!r}, recomputed {new.get(n)!r}" for n in differ[:3])
            bad.append(f"{cache / (key + '.json')} ({shown}{', ...' if len(differ) > 3 else ''})")
    if bad:
        raise CacheAuditError(
            f"audit of {cache}: {len(bad)} of {len(audited)} recomputed points differ from the cache "
            f"(seed {seed}): " + "; ".join(bad) + ". Refusing to report from it; rerun with fresh=True (--fresh)"
        )
    print(
        f"audit of {cache}: {len(audited)} of {n_cached} cached points recomputed, identical bit for bit "
        f"(wall times excepted; seed {seed})",
        file=sys.stderr,
    )


def _checked_points(points: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The points as dicts; ``TypeError`` naming the first that is not a mapping or not JSON."""
    out = []
    for i, p in enumerate(points):
        if not isinstance(p, Mapping):
            raise TypeError(f"points must be an iterable of mappings (dicts of parameters), got points[{i}] = {p!r}")
        try:
            _canonical(dict(p))
        except (TypeError, ValueError) as exc:
            raise TypeError(f"points[{i}] = {p!r} is not JSON-serialisable ({exc}): a cache key needs JSON") from None
        out.append(dict(p))
    return out


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


def _start_method(executor: str) -> str | None:
    """How the local workers of ``executor`` are started (None: no local worker processes)."""
    if executor == "dask":
        try:
            import dask
            import distributed  # noqa: F401  (registers the distributed.* configuration defaults)
        except ImportError:  # run_sweep names the missing extra when it opens the cluster
            return None

        return str(dask.config.get("distributed.worker.multiprocessing-method"))
    if executor == "process":  # the context a ProcessPoolExecutor takes, without fixing it
        return multiprocessing.get_start_method(allow_none=True) or multiprocessing.get_all_start_methods()[0]
    return None


def _reimported_main() -> str | None:
    """The file a ``spawn`` / ``forkserver`` worker imports again as the main module, or None.

    As :mod:`multiprocessing` decides: none for an interactive session, a notebook or
    ``python -c`` (no ``__main__.__file__``) or for ``python -m pkg`` (a ``__main__`` module).
    """
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    spec = getattr(main, "__spec__", None)
    if path is None or (spec is not None and spec.name.rpartition(".")[2] == "__main__"):
        return None
    return os.path.realpath(path)


def _is_main_test(node: ast.AST) -> bool:
    """Whether an ``if`` test contains ``__name__ == "__main__"`` (either order)."""
    for cmp in ast.walk(node):
        if isinstance(cmp, ast.Compare) and len(cmp.ops) == 1 and isinstance(cmp.ops[0], ast.Eq):
            sides = [cmp.left, *cmp.comparators]
            names = {s.id for s in sides if isinstance(s, ast.Name)}
            consts = {s.value for s in sides if isinstance(s, ast.Constant)}
            if names == {"__name__"} and consts == {"__main__"}:
                return True
    return False


def _guarded_lines(source: str) -> list[tuple[int, int]]:
    """Line ranges of the bodies of ``if __name__ == "__main__":`` blocks outside any function or class."""
    ranges = []

    def visit(nodes) -> None:
        for node in nodes:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                continue
            if isinstance(node, ast.If) and _is_main_test(node.test):
                ranges.append((node.lineno, node.end_lineno or node.lineno))
                continue
            for field in ("body", "orelse", "finalbody", "handlers"):
                visit(getattr(node, field, []))

    visit(ast.parse(source).body)
    return ranges


def check_main_guard(executor: str) -> None:
    """Refuse to start local worker processes from a main script's unguarded top-level code.

    A local Dask cluster (``executor="dask"``) starts its workers with the ``spawn`` method,
    a process pool with the platform's start method (``fork`` on Linux up to Python 3.13,
    ``spawn`` on macOS and Windows, ``forkserver`` on Linux from 3.14).  Under ``spawn`` and
    ``forkserver`` every worker imports the main script again, as ``__mp_main__``, running
    its top-level code: a sweep called there, outside an ``if __name__ == "__main__":`` block,
    would start again in each worker, which fails while bootstrapping and takes the cluster
    down with a page of tracebacks.  This finds the main script's top-level line on the call
    stack and raises before any work when it lies outside such a block.

    Raises
    ------
    RuntimeError
        Naming the script and line and the way out: the ``if __name__ == "__main__":``
        guard, or ``scheduler=`` (a running cluster) or ``executor="serial"``.
    """
    method = _start_method(executor)
    main = _reimported_main() if method in ("spawn", "forkserver") else None
    if main is None:
        return
    frame = inspect.currentframe()
    while frame is not None:
        code = frame.f_code
        if code.co_name == "<module>" and frame.f_globals.get("__name__") == "__main__":
            if os.path.realpath(code.co_filename) == main:
                break
        frame = frame.f_back
    if frame is None:
        return
    line = frame.f_lineno
    try:
        source = Path(main).read_text()
        guarded = _guarded_lines(source)
    except (OSError, UnicodeDecodeError, SyntaxError, ValueError):
        return  # a main script that cannot be read back: nothing to judge it by
    if any(lo <= line <= hi for lo, hi in guarded):
        return
    raise RuntimeError(
        f'executor="{executor}" starts local worker processes with the {method!r} method, and each imports the '
        f"main script {main} again, running its top-level code: line {line}, outside an "
        f'`if __name__ == "__main__":` block, would start this sweep again in every worker.  Put the script\'s '
        f'top-level code under `if __name__ == "__main__":` (or run the sweep with scheduler= the address of a '
        f'running Dask cluster, or executor="serial")'
    )
