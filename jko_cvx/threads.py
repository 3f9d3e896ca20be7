"""Thread control: BLAS threads for the per-slice factorisations, and threads across slices.

A batched collision step solves one small linear system per slice and per Newton
iteration.  OpenBLAS's default (one thread per core inside every call) is the wrong
parallelism for that: each call is too small to share, and with another busy process on
the machine the threads spin and wait for each other (measured on 2 cores with one busy
process: a 240 x 240 Cholesky 6.3 ms with the default threads against 1.05 ms with one;
batched Newton at N_v = 481 several times slower: the thread benchmark of the results pages).
The package therefore

* limits BLAS/LAPACK to :func:`blas_threads` threads (default 1) around its batched
  linear algebra (:func:`blas_limits`, threadpoolctl), and
* can run the slices' factorisations in :func:`slice_workers` threads instead
  (:func:`map_chunks`: contiguous chunks of slices; the LAPACK routines called there release
  the GIL, the NumPy code around them does not).  One thread is the default: the chained
  LAPACK calls leave a chunk's Python and NumPy work larger than its LAPACK work, and two
  threads were slower in wall time than one on 12 of 13 batches measured on 2 cores, 4-44 %
  (the benchmark of slice threads on the results pages: gamma 1 to 4, N_v 121 to 961, 32 and
  121 slices, the dense Cholesky included; the 13th, gamma = 1, 1 % faster).

Settings (environment variables, read at every call, so a process may change them):

``JKO_CVX_BLAS_THREADS``
    BLAS threads inside the batched linear algebra: an integer >= 0 (default 1); 0 leaves
    the BLAS library's own setting alone (OpenBLAS: one thread per core, or
    ``OPENBLAS_NUM_THREADS``).
``JKO_CVX_THREADS``
    Threads across slices: an integer >= 1 (default 1).  Keep ``JKO_CVX_BLAS_THREADS``
    times this within the usable cores.

Results do not depend on ``JKO_CVX_THREADS``: each slice is solved by the same sequence of
operations whatever thread runs it (tested bitwise).  The BLAS thread count can change the
rounding of matrix products (a product split between threads is summed in other blocks;
measured: 8e-15 in f), as it always could; with the default of one BLAS thread they do not
depend on the number of cores.
"""

from __future__ import annotations

import functools
import itertools
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import ParamSpec, TypeVar

import numpy as np

__all__ = [
    "BLAS_THREADS_ENV",
    "THREADS_ENV",
    "THREAD_ENV_KEYS",
    "blas_limited",
    "blas_limits",
    "blas_threads",
    "map_chunks",
    "slice_workers",
    "thread_environment",
    "usable_cores",
]

P = ParamSpec("P")
R = TypeVar("R")

BLAS_THREADS_ENV = "JKO_CVX_BLAS_THREADS"
THREADS_ENV = "JKO_CVX_THREADS"
# The variables a timing depends on: the package's own and the BLAS libraries'.
THREAD_ENV_KEYS = (BLAS_THREADS_ENV, THREADS_ENV, "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

_state = threading.local()  # depth of blas_limits, and whether this thread is a slice worker
_lock = threading.Lock()
_blas_libraries: list | None = None  # threadpoolctl's BLAS library controllers
_pool: ThreadPoolExecutor | None = None
_pool_size = 0


def _env_int(name: str, default: int, least: int) -> int:
    raw = os.environ.get(name, "").strip()
    if not raw:
        return default
    try:
        value = int(raw)
    except ValueError:
        value = least - 1
    if value < least:
        raise ValueError(f"environment variable {name} must be an integer >= {least}, got {raw!r}")
    return value


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform reports it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def blas_threads() -> int:
    """BLAS threads inside the batched linear algebra (``JKO_CVX_BLAS_THREADS``, default 1; 0: library's own)."""
    return _env_int(BLAS_THREADS_ENV, 1, 0)


def slice_workers() -> int:
    """Threads across slices (``JKO_CVX_THREADS``, default 1)."""
    return _env_int(THREADS_ENV, 1, 1)


class _BlasLimit:
    """The context manager :func:`blas_limits` returns (a class: a solve pays no generator's setup)."""

    __slots__ = ("changed", "entered")

    def __enter__(self) -> None:
        self.changed: list = []
        self.entered = False
        if getattr(_state, "depth", 0) or getattr(_state, "worker", False):
            return  # the outer block (or the pool's caller) has set the limit
        limit = blas_threads()
        if limit == 0:
            return
        changed = [(lib, n) for lib in _blas_controllers() if (n := lib.get_num_threads()) is not None and n != limit]
        _state.depth = 1
        self.entered = True
        try:
            for lib, n in changed:
                lib.set_num_threads(limit)
                self.changed.append((lib, n))  # set back on exit, each library that was set
        except BaseException:
            self.__exit__(None, None, None)
            raise

    def __exit__(self, *exc: object) -> None:
        if not self.entered:
            return
        try:
            for lib, n in self.changed:
                lib.set_num_threads(n)
        finally:
            _state.depth = 0


def blas_limits() -> _BlasLimit:
    """Limit BLAS to :func:`blas_threads` threads inside the ``with`` block (re-entrant; 0: no limit).

    The BLAS libraries are those loaded at the first use (NumPy's and SciPy's OpenBLAS), found
    once by threadpoolctl.  Only a library whose thread count differs from the limit is set, and
    set back on exit: a few microseconds where the limit holds already (``OPENBLAS_NUM_THREADS=1``),
    two native calls per library otherwise -- a single small solve pays nothing like threadpoolctl's
    full ``limit`` (about 100 us, which reads every library's information twice).
    """
    return _BlasLimit()


def _blas_controllers() -> list:
    """threadpoolctl's controllers of the BLAS libraries loaded at the first call (built once)."""
    global _blas_libraries
    if _blas_libraries is None:
        from threadpoolctl import ThreadpoolController

        with _lock:
            if _blas_libraries is None:
                _blas_libraries = ThreadpoolController().select(user_api="blas").lib_controllers
    return _blas_libraries


def thread_environment() -> str:
    """The thread setting a timing was taken under, for a benchmark's record.

    The variables of ``THREAD_ENV_KEYS`` (``unset`` where absent), the BLAS threads the
    loaded libraries report inside :func:`blas_limits` (where every solve runs) and the
    slice threads, e.g. ``"JKO_CVX_BLAS_THREADS=unset, ..., OPENBLAS_NUM_THREADS=1; BLAS
    threads [1] inside solves, 1 slice threads"``.
    """
    from threadpoolctl import threadpool_info

    env = ", ".join(f"{k}={os.environ.get(k, 'unset')}" for k in THREAD_ENV_KEYS)
    with blas_limits():
        counts = sorted({lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"})
    return f"{env}; BLAS threads {counts} inside solves, {slice_workers()} slice threads"


def blas_limited(func: Callable[P, R]) -> Callable[P, R]:
    """Decorator: run ``func`` inside :func:`blas_limits`."""

    @functools.wraps(func)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> R:
        if getattr(_state, "depth", 0) or getattr(_state, "worker", False):
            return func(*args, **kwargs)  # inside a limit already: blas_limits would do nothing
        with blas_limits():
            return func(*args, **kwargs)

    return wrapper


def _with_errstate(err: dict, func: Callable[[int, int], None], a: int, b: int) -> None:
    with np.errstate(**err):
        func(a, b)


def _mark_worker() -> None:
    _state.worker = True


def _executor(workers: int) -> ThreadPoolExecutor:
    """The shared pool, rebuilt only when the setting changes."""
    global _pool, _pool_size
    with _lock:
        if _pool is None or _pool_size != workers:
            if _pool is not None:
                _pool.shutdown(wait=False)
            _pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="jko_cvx", initializer=_mark_worker)
            _pool_size = workers
        return _pool


def map_chunks(func: Callable[[int, int], None], n: int, min_chunk: int = 1, align: int = 1) -> None:
    """Call ``func(start, stop)`` on contiguous chunks covering ``range(n)``, in :func:`slice_workers` threads.

    ``func`` writes its results into arrays owned by the caller (disjoint rows per chunk).
    Chunk boundaries are multiples of ``align``, so that a ``func`` working in blocks of
    ``align`` items from ``start`` sees the same blocks whatever the number of threads
    (results that depend on a block's width, such as a matrix product's rounding, then do
    not depend on the thread setting).
    Runs inline when one worker suffices (one worker, fewer than ``2 * min_chunk`` items,
    or a call from inside a worker: no nested pools).  The BLAS limit of
    :func:`blas_limits` holds in the workers (threadpoolctl's limit is process-wide).
    Exceptions raised by ``func`` propagate; the workers run under the caller's NumPy error
    state.
    """
    size = slice_workers()
    workers = 1 if getattr(_state, "worker", False) else min(size, n // max(min_chunk, 1))
    with blas_limits():
        if workers <= 1:
            if n:
                func(0, n)
            return
        step = max(align, 1)
        bounds = sorted({min(n, -(-(n * i // workers) // step) * step) for i in range(workers + 1)})
        pool = _executor(size)
        err = np.geterr()  # NumPy's error state is per thread: the workers take the caller's
        futures = [pool.submit(_with_errstate, err, func, a, b) for a, b in itertools.pairwise(bounds)]
        for fut in futures:
            fut.result()
