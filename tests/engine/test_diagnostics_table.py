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

from .test_figures import HOM, INHOM

ORDER2 = {**HOM, "name": "fig_order2", "time": {"dt": 0.01, "order": 2}}  # a time_error column with numbers


def _same_column(ours: np.ndarray, theirs: np.ndarray) -> bool:
    if ours.dtype != theirs.dtype:
        return False
    if ours.dtype.kind == "f":
        return np.array_equal(ours, theirs, equal_nan=True) and np.array_equal(np.signbit(ours), np.signbit(theirs))
    if ours.dtype == object:
        return all(a is b or a == b for a, b in zip(ours, theirs, strict=True))
    return np.array_equal(ours, theirs)


def _cell(rng: np.random.Generator):
    """A cell of any kind pandas tells apart: integers (Python, int64, other widths, beyond int64), floats over
    the whole range (subnormal, the largest, -0.0, inf, NaN; float64, float32, float16, longdouble), None,
    booleans and text."""
    specials = [np.inf, -np.inf, -0.0, 0.0, 5e-324, 1e16, 1e-5, 0.1, 1.7976931348623157e308, 123456789012345.0]
    k = int(rng.integers(0, 16))
    if k >= 11:
        return float(rng.standard_normal() * 10.0 ** rng.integers(-300, 300))
    return [
        lambda: None,
        lambda: int(rng.integers(-(10**12), 10**12)),
        lambda: float("nan"),
        lambda: float(rng.choice(specials)),
        lambda: np.float64(rng.standard_normal()),
        lambda: np.int64(rng.integers(0, 100)),
        lambda: bool(rng.integers(0, 2)),
        lambda: "text, with a comma",
        lambda: [np.float32(0.1), np.float16(0.5), np.longdouble(0.1)][int(rng.integers(0, 3))],
        lambda: [np.int32(7), np.uint8(3), np.uint64(2**63)][int(rng.integers(0, 3))],
        lambda: [2**63, -(2**63) - 1, 2**64 + 1, 10**400, 2**63 - 1, -(2**63)][int(rng.integers(0, 6))],
    ][k]()


def _random_rows(rng: np.random.Generator) -> list[dict]:
    """Records of one to five columns (keys absent from some records), every cell of any kind (:func:`_cell`)."""
    names = ["step", "t", "max_f", "min_dx", "flag"][: int(rng.integers(1, 6))]
    return [{name: _cell(rng) for name in names if rng.random() > 0.1} for _ in range(int(rng.integers(1, 6)))]


def test_the_csv_and_the_columns_are_pandas_on_every_kind_of_record():
    rng = np.random.default_rng(20261207)
    compared = 0
    for _ in range(3000):
        rows = _random_rows(rng)
        try:
            want = pd.DataFrame(rows).to_csv(index=False)
        except OverflowError:  # pandas' own limit (an integer beyond any dtype beside a float)
            continue
        assert csv_text(iter(rows)) == csv_text(rows) == want, rows
        table = pd.DataFrame(rows)
        for name in table.columns:
            assert _same_column(column(iter(rows), name), table[name].to_numpy()), (name, rows)
            compared += 1
    assert compared > 3000
    for rows in ([{}], [{}, {}], [{"a": 1.0}, {}], [{0: 1.5, "b": 2.0}], [{"a b": 1.0, "c": 2.0}]):
        assert csv_text(rows) == pd.DataFrame(rows).to_csv(index=False), rows


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


def test_a_run_takes_its_table_or_its_rows_and_copies_keep_the_changed_table():
    import copy
    import dataclasses
    import pickle

    run = simulate(scene_from_dict(HOM))
    rows = [dict(r) for r in run.diagnostics.to_dict("records")]
    fields = [getattr(run, f.name) for f in dataclasses.fields(run)]
    assert [f.name for f in dataclasses.fields(run)][1] == "diagnostics"
    for given in (run.diagnostics.copy(), rows):  # positional and keyword, a table or its rows
        for r in (dataclasses.replace(run, diagnostics=given), type(run)(run.scene, given, *fields[2:])):
            assert r.diagnostics.equals(run.diagnostics) and r.steps == run.steps
    with pytest.raises(TypeError, match=r"diagnostics must be a pandas.DataFrame or a list of row dicts, got str"):
        dataclasses.replace(run, diagnostics="step,t\n0,0.0\n")
    run.diagnostics.loc[0, "max_f"] = 7.0  # a change to the table shows in every copy and in the columns
    for r in (dataclasses.replace(run), copy.deepcopy(run), pickle.loads(pickle.dumps(run))):
        assert r.column("max_f")[0] == 7.0 and r.diagnostics["max_f"].iloc[0] == 7.0
    for r in (run, simulate(scene_from_dict(HOM))):  # built or not: a new array, writable
        a = r.column("t")
        a[0] = -1.0
        assert r.column("t")[0] == 0.0


def test_the_records_line_skips_missing_values_as_pandas_does():
    run = simulate(scene_from_dict(HOM))
    d = run.diagnostics
    d.loc[1, "max_f"] = np.nan
    d.loc[2, "min_dv"] = np.nan
    want = f"max f over the run {d.max_f.max():.4g}, min dv {d.min_dv.min():.3g}"
    assert want in run.records_line() and "nan" not in run.records_line()
