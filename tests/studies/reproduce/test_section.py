"""``jko-cvx reproduce section``: the entries share one pool, overlap while they wait, and give the
results they give one by one; dependents wait, failures are recorded and refused."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

from jko_cvx.studies.reproduce import REPRODUCTIONS, section
from jko_cvx.studies.sweep import holding, run_sweep


def square_point(x: float, pause: float = 0.0, marks: str = "") -> dict:
    """A sweep point (module level: picklable for the process pool); leaves a file in ``marks`` per call."""
    time.sleep(pause)
    if marks:
        Path(marks, f"{x}-{os.getpid()}-{time.perf_counter_ns()}").touch()
    return {"y": x * x + 0.1}


def _fake_entry(name: str, pause: float, log: list):
    def entry(out: Path, quick: bool = False, **sweep_opts) -> pd.DataFrame:
        log.append((name, "start", time.perf_counter()))
        points = [{"x": float(i), "pause": pause} for i in range(4)]
        df = run_sweep(square_point, points, Path(out) / "cache" / name, desc=name, **sweep_opts)
        df.to_csv(Path(out) / f"{name}.csv", index=False)
        log.append((name, "end", time.perf_counter()))
        return df

    return entry


def _total(log: list):
    """An entry that reads every other entry's file."""

    def entry(out: Path, quick: bool = False, **sweep_opts) -> pd.DataFrame:
        log.append(("total", "start", time.perf_counter()))
        total = sum(pd.read_csv(Path(out) / f"{n}.csv").y.sum() for n in ("alpha", "beta", "gamma"))
        (Path(out) / "total.md").write_text(f"total {total!r}\n")
        return pd.DataFrame()

    return entry


@pytest.fixture
def fake_section(monkeypatch):
    log: list = []
    monkeypatch.setattr(section, "SECTION", ("alpha", "beta", "gamma", "total"))
    monkeypatch.setattr(section, "NEEDS", {"gamma": ("alpha",), "total": ("alpha", "beta", "gamma")})
    for name, pause in (("alpha", 0.4), ("beta", 0.05), ("gamma", 0.0)):
        monkeypatch.setitem(REPRODUCTIONS, name, _fake_entry(name, pause, log))
    monkeypatch.setitem(REPRODUCTIONS, "total", _total(log))
    return log


def test_entries_share_the_pool_overlap_and_match_the_serial_run(fake_section, tmp_path):
    log = fake_section
    df = section.reproduce_section(tmp_path / "pool", workers=2, progress=False)
    assert list(df.entry) == ["alpha", "beta", "gamma", "total"] and (df.status == "ok").all()
    when = {(name, what): t for name, what, t in log}
    # beta starts while alpha waits for its points (the lock is let go during the wait) ...
    assert when["beta", "start"] < when["alpha", "end"]
    # ... gamma (needs alpha) and total (needs everything) only after what they read
    assert when["gamma", "start"] > when["alpha", "end"]
    assert when["total", "start"] > max(when["alpha", "end"], when["beta", "end"], when["gamma", "end"])
    log.clear()
    section.reproduce_section(tmp_path / "serial", executor="serial", progress=False)
    for name in ("alpha.csv", "beta.csv", "gamma.csv", "total.md"):
        a, b = (tmp_path / "pool" / name).read_bytes(), (tmp_path / "serial" / name).read_bytes()
        assert a == b, name
    record = pd.read_csv(tmp_path / "pool" / "section.csv")
    assert (record.wall_s > 0).all() and (record.finished_s >= record.started_s).all()
    assert "Wall time" in (tmp_path / "pool" / "section.md").read_text()


def test_a_failing_entry_skips_its_dependents_and_the_run_says_so(fake_section, monkeypatch, tmp_path):
    def broken(out, quick=False, **sweep_opts):
        raise ValueError("this entry is broken")

    monkeypatch.setitem(REPRODUCTIONS, "alpha", broken)
    with pytest.raises(RuntimeError, match="3 of 4 entries did not finish: alpha, gamma, total"):
        section.reproduce_section(tmp_path, workers=2, progress=False)
    record = pd.read_csv(tmp_path / "section.csv").set_index("entry")
    assert record.loc["alpha", "status"] == "failed" and "this entry is broken" in record.loc["alpha", "error"]
    assert record.loc["beta", "status"] == "ok"
    assert record.loc["gamma", "status"] == "skipped" and "alpha" in record.loc["gamma", "error"]


def test_bad_arguments_are_refused_before_any_work(tmp_path):
    with pytest.raises(ValueError, match="entries must be entries of the section"):
        section.reproduce_section(tmp_path, entries=("tab_bu", "no_such_entry"))
    with pytest.raises(ValueError, match="workers must be an integer >= 1"):
        section.reproduce_section(tmp_path, workers=0)
    with pytest.raises(ValueError, match="executor must be"):
        section.reproduce_section(tmp_path, executor="threads")
    assert not list(tmp_path.iterdir())


def test_the_section_is_every_entry_but_the_grid_convergence_studies():
    # grid_convergence and g3_dt_probe are long studies of their own; conclusions reads its files and
    # paper_variants.py's, inhom_gamma1p5_events its files and inhom_gamma1p5's
    own = {"grid_convergence", "g3_dt_probe", "conclusions", "inhom_gamma1p5_events"}
    assert set(section.SECTION) == set(REPRODUCTIONS) - own
    assert "summary" not in section.SECTION and len(set(section.SECTION)) == len(section.SECTION)
    for name, needs in section.NEEDS.items():
        assert all(section.SECTION.index(n) < section.SECTION.index(name) for n in needs)


def test_holding_lets_go_only_while_a_sweep_waits(tmp_path):
    lock = threading.Lock()
    released = []
    with holding(lock, on_release=lambda: released.append(lock.locked())):
        assert lock.locked()
        run_sweep(square_point, [{"x": 1.0}], tmp_path, executor="process", workers=1, progress=False)
        assert lock.locked()
    assert released == [False] and not lock.locked()


def test_the_quick_section_runs_every_entry(fake_section, tmp_path):
    df = section.reproduce_section(tmp_path, quick=True, workers=1, progress=False)
    assert list(df.entry) == ["alpha", "beta", "gamma", "total"] and (df.status == "ok").all()
    assert not (tmp_path / "summary.md").exists()


def test_a_point_two_entries_share_runs_once(monkeypatch, tmp_path):
    """gk2_bu's runs are tab_g2bu's: in one section run the shared pool computes such a point once, and
    each entry still gets it (and caches it), also with --fresh."""
    marks = tmp_path / "marks"
    marks.mkdir()

    def entry(name, xs):
        def run(out, quick=False, **sweep_opts):
            points = [{"x": x, "pause": 0.2, "marks": str(marks)} for x in xs]
            df = run_sweep(square_point, points, Path(out) / "cache" / name, desc=name, **sweep_opts)
            df.to_csv(Path(out) / f"{name}.csv", index=False)

        return run

    monkeypatch.setattr(section, "SECTION", ("first", "second"))
    monkeypatch.setattr(section, "NEEDS", {})
    monkeypatch.setitem(REPRODUCTIONS, "first", entry("first", [1.0, 2.0, 3.0]))
    monkeypatch.setitem(REPRODUCTIONS, "second", entry("second", [2.0, 3.0, 4.0]))
    before = os.environ.get("JKO_CVX_THREADS")
    section.reproduce_section(tmp_path / "out", workers=2, progress=False, fresh=True)
    runs = sorted(float(p.name.split("-")[0]) for p in marks.iterdir())
    assert runs == [1.0, 2.0, 3.0, 4.0]
    second = pd.read_csv(tmp_path / "out" / "second.csv")
    assert list(second.y) == [x * x + 0.1 for x in (2.0, 3.0, 4.0)]
    assert len(list((tmp_path / "out" / "cache" / "second").glob("*.json"))) == 3
    assert os.environ.get("JKO_CVX_THREADS") == before  # the section leaves the thread setting alone


def test_shared_points_blocks_do_not_nest():
    from jko_cvx.studies.sweep import shared_points

    with shared_points(), pytest.raises(RuntimeError, match="do not nest"), shared_points():
        pass
