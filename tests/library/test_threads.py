"""Thread control (jko_cvx.threads): settings, the BLAS limit, and work split across slices."""

import threading

import numpy as np
import pytest
from threadpoolctl import threadpool_info

from jko_cvx import CollisionProblem, Grid, PowerKernel
from jko_cvx.collision.newton import solve_newton
from jko_cvx.threads import (
    BLAS_THREADS_ENV,
    THREADS_ENV,
    blas_limits,
    blas_threads,
    map_chunks,
    slice_workers,
    thread_environment,
)


def _blas_counts() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_defaults(monkeypatch):
    monkeypatch.delenv(BLAS_THREADS_ENV, raising=False)
    monkeypatch.delenv(THREADS_ENV, raising=False)
    assert blas_threads() == 1
    # one thread across slices: only LAPACK releases the GIL, and two threads were slower in wall time
    # than one on 12 of 13 batches measured on 2 cores (studies/bench_slice_threads.py)
    assert slice_workers() == 1
    monkeypatch.setenv(BLAS_THREADS_ENV, "0")  # BLAS keeps its own threads: no threads on top
    assert blas_threads() == 0 and slice_workers() == 1


def test_the_recorded_thread_environment_names_every_setting(monkeypatch):
    monkeypatch.setenv(BLAS_THREADS_ENV, "1")
    monkeypatch.setenv(THREADS_ENV, "2")
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    text = thread_environment()
    assert text.startswith("JKO_CVX_BLAS_THREADS=1, JKO_CVX_THREADS=2, OPENBLAS_NUM_THREADS=")
    assert "MKL_NUM_THREADS=unset" in text
    assert text.endswith("; BLAS threads [1] inside solves, 2 slice threads")  # what the libraries report


@pytest.mark.parametrize("name, value", [(BLAS_THREADS_ENV, "-1"), (BLAS_THREADS_ENV, "two"), (THREADS_ENV, "0")])
def test_bad_settings_are_named(monkeypatch, name, value):
    monkeypatch.setenv(name, value)
    with pytest.raises(ValueError, match=f"environment variable {name} must be an integer >= "):
        map_chunks(lambda start, stop: None, 4)  # reads both settings


def test_blas_limit_holds_inside_and_is_restored(monkeypatch):
    monkeypatch.setenv(BLAS_THREADS_ENV, "1")
    with blas_limits():
        before = _blas_counts()
        with blas_limits():  # re-entrant
            assert _blas_counts() == [1] * len(before)
    assert before == [1] * len(before)
    with blas_limits():
        pass
    monkeypatch.setenv(BLAS_THREADS_ENV, "0")
    outside = _blas_counts()
    with blas_limits():
        assert _blas_counts() == outside  # 0: left alone


def test_map_chunks_covers_every_item_once_in_threads(monkeypatch):
    monkeypatch.setenv(THREADS_ENV, "3")
    seen = np.zeros(100, dtype=int)
    chunks, names = [], set()

    def work(a, b):
        seen[a:b] += 1
        chunks.append((a, b))
        names.add(threading.current_thread().name)
        map_chunks(lambda c, d: names.add("nested-" + threading.current_thread().name), 4)  # runs inline

    map_chunks(work, 100)
    assert np.all(seen == 1) and len(chunks) == 3
    assert names and all(n.startswith(("jko_cvx", "nested-jko_cvx")) for n in names)


def test_map_chunks_propagates_errors_and_errstate(monkeypatch):
    monkeypatch.setenv(THREADS_ENV, "2")

    def fail(a, b):
        raise RuntimeError(f"chunk {a}:{b}")

    with pytest.raises(RuntimeError, match="chunk"):
        map_chunks(fail, 10)

    def divide(a, b):
        np.ones(1) / np.zeros(1)

    with np.errstate(divide="raise"), pytest.raises(FloatingPointError):
        map_chunks(divide, 10)


@pytest.mark.parametrize("gamma, n", [(1.5, 81), (3.0, 81), (1.5, 321)])  # dense, exact O(N), certified CG
def test_results_do_not_depend_on_the_slice_threads(monkeypatch, gamma, n):
    """Bitwise: each slice is solved by the same operations in any thread (BLAS threads may change rounding)."""
    v = np.linspace(-3, 3, n)
    F = np.stack([np.exp(-2 * (v - c) ** 2) + 1e-6 for c in np.linspace(-0.5, 0.5, 40)])
    P = CollisionProblem(Grid(v), PowerKernel(gamma), F, 0.05, beta=100.0, fisher="log")
    runs = []
    for threads, blas in (("1", "1"), ("3", "1"), ("2", "1")):
        monkeypatch.setenv(THREADS_ENV, threads)
        monkeypatch.setenv(BLAS_THREADS_ENV, blas)
        runs.append(solve_newton(P, tol=1e-10))
    for r in runs[1:]:
        assert np.array_equal(r.f, runs[0].f) and list(r.status) == list(runs[0].status)


def test_a_library_at_another_thread_count_is_limited_inside_and_set_back(monkeypatch):
    from threadpoolctl import threadpool_limits

    monkeypatch.setenv(BLAS_THREADS_ENV, "1")
    with threadpool_limits(limits=2, user_api="blas"):
        outside = _blas_counts()
        with blas_limits():
            assert _blas_counts() == [1] * len(outside)
        assert _blas_counts() == outside
    monkeypatch.setenv(BLAS_THREADS_ENV, "2")
    with threadpool_limits(limits=1, user_api="blas"):
        with blas_limits():
            inside = _blas_counts()
        assert _blas_counts() == [1] * len(inside)
