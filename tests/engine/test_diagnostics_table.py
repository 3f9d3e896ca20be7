"""A run's diagnostics without pandas: ``diagnostics.csv`` and ``Run.column`` give, bit for bit, what
pandas gives for the same records (compared in this process), and the default ``jko-cvx run`` (and
``import jko_cvx``) never imports pandas."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from jko_cvx.engine._table import column, csv_text
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.run import load_run
from jko_cvx.scene import scene_from_dict

HOM = {
    "name": "table_hom",
    "gamma": 1.0,
    "t_end": 0.05,
    "v": {"L": 2.0, "n": 41},
    "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
    "time": {"dt": 0.01},
    "refine": {"v": {}},
    "stop": {"eps_v": 1e-4},
}
INHOM = {**HOM, "name": "table_inhom", "gamma": 3.0, "strength": 2.0, "x": {"L": 1.0, "n": 8}, "v": {"L": 2.0, "n": 21},
         "initial": {"kind": "two_bump_phase", "a": 6.0, "b": 6.0, "c": 0.5, "d": 0.5}, "refine": {}}  # fmt: skip
ORDER2 = {**HOM, "name": "table_order2", "time": {"dt": 0.01, "order": 2}}  # a time_error column with numbers


def _same_column(ours: np.ndarray, theirs: np.ndarray) -> bool:
    if ours.dtype != theirs.dtype:
        return False
    if ours.dtype.kind == "f":
        return np.array_equal(ours, theirs, equal_nan=True) and np.array_equal(np.signbit(ours), np.signbit(theirs))
    if ours.dtype == object:
        return all(a is b or a == b for a, b in zip(ours, theirs, strict=True))
    return np.array_equal(ours, theirs)


def _random_rows(rng: np.random.Generator) -> list[dict]:
    """Records with every kind of cell: integers (Python, NumPy), floats over the whole range (subnormal,
    the largest, -0.0, inf, NaN), None, absent keys, NumPy floats, booleans and text (pandas' cases)."""
    specials = [np.inf, -np.inf, -0.0, 0.0, 5e-324, 1e16, 1e-5, 0.1, 1.7976931348623157e308, 123456789012345.0]
    rows = []
    for _ in range(int(rng.integers(1, 6))):
        row = {}
        for name in ("step", "t", "max_f", "min_dx", "flag"):
            k = int(rng.integers(0, 12))
            if k == 0:
                continue  # the key absent from this record
            row[name] = [
                None,
                int(rng.integers(-(10**12), 10**12)),
                float("nan"),
                float(rng.choice(specials)),
                np.float64(rng.standard_normal()),
                np.int64(rng.integers(0, 100)),
                bool(rng.integers(0, 2)),
                "text, with a comma",
            ][k - 1] if k <= 8 else float(rng.standard_normal() * 10.0 ** rng.integers(-300, 300))  # fmt: skip
        rows.append(row)
    return rows


def test_the_csv_and_the_columns_are_pandas_on_every_kind_of_record():
    rng = np.random.default_rng(20261207)
    compared = 0
    for _ in range(1500):
        rows = _random_rows(rng)
        if not any(rows):
            continue
        assert csv_text(rows) == pd.DataFrame(rows).to_csv(index=False), rows
        table = pd.DataFrame(rows)
        for name in table.columns:
            assert _same_column(column(rows, name), table[name].to_numpy()), (name, rows)
            compared += 1
    assert compared > 3000


@pytest.mark.parametrize("scene", [HOM, INHOM, ORDER2], ids=lambda s: s["name"])
def test_a_run_writes_and_reads_its_diagnostics_as_pandas_would(scene, tmp_path):
    run = simulate(scene_from_dict(scene), out=tmp_path / "run")
    rows = json.loads(str(np.load(tmp_path / "run" / "checkpoint.npz")["rows"]))
    assert (tmp_path / "run" / "diagnostics.csv").read_text() == pd.DataFrame(rows).to_csv(index=False)
    back = load_run(tmp_path / "run")
    for r in (run, back):
        columns = [r.column(name) for name in pd.DataFrame(rows).columns]  # before the table is built
        table = r.diagnostics
        assert list(table.columns) == list(pd.DataFrame(rows).columns)
        for name, values in zip(table.columns, columns, strict=True):
            assert _same_column(values, table[name].to_numpy()), name
    assert run.steps == back.steps == int(rows[-1]["step"])
    if scene is ORDER2:
        assert np.isfinite(run.column("time_error")[1:]).all() and "time error" in run.records_line()


def test_a_column_of_a_changed_table_is_the_changed_one_and_an_unknown_name_is_named():
    run = simulate(scene_from_dict(HOM))
    run.diagnostics["max_f"] = 2.0 * run.diagnostics["max_f"]
    assert np.array_equal(run.column("max_f"), run.diagnostics["max_f"].to_numpy())
    fresh = simulate(scene_from_dict(HOM))
    for r in (run, fresh):
        with pytest.raises(KeyError, match=r"no diagnostics column 'maxf'.*max_f"):
            r.column("maxf")


def test_the_default_run_and_the_package_import_no_pandas(tmp_path):
    code = f"""
import sys
import jko_cvx
assert "pandas" not in sys.modules, "import jko_cvx imported pandas"
from jko_cvx.cli import main
assert main(["run", "--out", {str(tmp_path / "run")!r}, "--quiet"]) == 0
assert "pandas" not in sys.modules, "the default run imported pandas"
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert {"diagnostics.csv", "records.png", "solution.png"} <= {p.name for p in (tmp_path / "run").iterdir()}
