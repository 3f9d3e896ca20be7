"""The sweep runner: the same results on every executor, and resume after a kill."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from jko_cvx.reproduce.blowup_tables import blowup_time
from jko_cvx.sweep import point_key, run_sweep

POINTS = [{"data": d, "eps_v": 1e-3, "dt": dt} for d in ("g1", "g3") for dt in (0.02, 0.01)]
COLUMNS = ["data", "eps_v", "dt", "T_b", "steps", "failed_steps"]


def test_serial_process_pool_and_dask_give_identical_tables(tmp_path):
    serial = run_sweep(blowup_time, POINTS, tmp_path / "serial", executor="serial", progress=False)
    pool = run_sweep(blowup_time, POINTS, tmp_path / "pool", executor="process", workers=2, progress=False)
    assert not serial.cached.any() and not pool.cached.any()
    assert serial[COLUMNS].equals(pool[COLUMNS])
    pytest.importorskip("distributed")
    dask = run_sweep(blowup_time, POINTS, tmp_path / "dask", executor="dask", workers=2, progress=False)
    assert serial[COLUMNS].equals(dask[COLUMNS])
    # g3 blows up four times earlier than g1 (exact T = 0.125 and 0.5): the points differ
    assert serial.T_b.iloc[2] < serial.T_b.iloc[0] / 2
    again = run_sweep(blowup_time, POINTS, tmp_path / "serial", executor="serial", progress=False)
    assert again.cached.all() and again[COLUMNS].equals(serial[COLUMNS])


_SCRIPT = """
import sys
from jko_cvx.reproduce.blowup_tables import blowup_time
from jko_cvx.sweep import run_sweep
points = [{"data": "g1", "eps_v": 1e-3, "dt": dt} for dt in (0.0025, 0.002, 0.0015, 0.00125, 0.001, 0.00075)]
run_sweep(blowup_time, points, sys.argv[1], executor="serial", progress=False)
"""


def test_killed_sweep_recomputes_only_missing_points(tmp_path):
    cache = tmp_path / "cache"
    proc = subprocess.Popen([sys.executable, "-c", _SCRIPT, str(cache)], stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None and len(list(cache.glob("*.json"))) < 2:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = {p.stem for p in cache.glob("*.json")}
    points = [{"data": "g1", "eps_v": 1e-3, "dt": dt} for dt in (0.0025, 0.002, 0.0015, 0.00125, 0.001, 0.00075)]
    assert 0 < len(done) < len(points), "the sweep must have been killed mid-way"
    assert not any(name.startswith(".") for name in os.listdir(cache) if name.endswith(".json"))
    resumed = run_sweep(blowup_time, points, cache, executor="serial", progress=False)
    keys = [point_key(blowup_time, p) for p in points]
    assert list(resumed.cached) == [k in done for k in keys]  # only the missing points ran
    fresh = run_sweep(blowup_time, points, tmp_path / "fresh", executor="serial", progress=False)
    assert resumed[["T_b", "steps"]].equals(fresh[["T_b", "steps"]])
    stored = json.loads((cache / f"{keys[0]}.json").read_text())
    assert stored["point"] == points[0] and np.isfinite(stored["result"]["T_b"])


def test_sweep_validates_its_arguments(tmp_path):
    with pytest.raises(ValueError, match="executor must be"):
        run_sweep(blowup_time, POINTS, tmp_path, executor="threads")
    with pytest.raises(ValueError, match="workers must be an integer >= 1"):
        run_sweep(blowup_time, POINTS, tmp_path, workers=0)
