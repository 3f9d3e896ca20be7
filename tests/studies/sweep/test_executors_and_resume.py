"""The sweep runner: the same results on every executor, and resume after a kill."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from jko_cvx.studies.reproduce.blowup_tables import blowup_time
from jko_cvx.studies.sweep import cached_entries, point_key, run_sweep

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
from jko_cvx.studies.reproduce.blowup_tables import blowup_time
from jko_cvx.studies.sweep import run_sweep
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


# --- the cache cannot serve stale results -------------------------------------------------

_MODULE = '''
def double(a):
    return {{"y": a * {factor}}}


def triple(a):
    return {{"y": a * 3}}
'''


def _point_module(path, name, factor):
    """Write and import a module of point functions (a fresh module object each time)."""
    import importlib.util

    file = path / f"{name}.py"
    file.write_text(_MODULE.format(factor=factor))
    spec = importlib.util.spec_from_file_location(name, file)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def test_changed_point_function_is_recomputed(tmp_path):
    points = [{"a": 1.0}, {"a": 2.0}]
    original = _point_module(tmp_path, "pts_changed", "2")
    first = run_sweep(original.double, points, tmp_path / "c", "serial", progress=False)
    assert list(first.y) == [2.0, 4.0]
    edited = _point_module(tmp_path, "pts_changed", "2 + 100")  # same name and point, new code
    again = run_sweep(edited.double, points, tmp_path / "c", "serial", progress=False)
    assert not again.cached.any() and list(again.y) == [102.0, 104.0]
    assert run_sweep(edited.double, points, tmp_path / "c", "serial", progress=False).cached.all()


def test_a_module_edited_after_import_is_refused_not_keyed_by_its_new_source(tmp_path):
    """The running code is the imported one; its file now holds other code: a result computed now and stored under
    the file's key would be served to the edited code later."""
    running = _point_module(tmp_path, "pts_edited", "2")
    (tmp_path / "pts_edited.py").write_text(_MODULE.format(factor="2 + 100"))  # an editor saves; no re-import
    with pytest.raises(ValueError, match=r"pts_edited\.py changed since pts_edited was imported"):
        run_sweep(running.double, [{"a": 1.0}], tmp_path / "c", "serial", progress=False)
    assert not (tmp_path / "c").exists() or not any((tmp_path / "c").iterdir())
    # a change that moves code without changing it (a comment above) is the same code
    (tmp_path / "pts_edited.py").write_text("# a comment\n" + _MODULE.format(factor="2"))
    assert list(run_sweep(running.double, [{"a": 1.0}], tmp_path / "c", "serial", progress=False).y) == [2.0]


_SELF_EDITING = """
from pathlib import Path


def point(a):
    if a == 2.0:  # an editor saves the module while the sweep runs
        Path(__file__).write_text(Path(__file__).read_text().replace("a * 2", "a * 3"))
    return {"y": a * 2}
"""


def test_a_module_edited_while_its_sweep_runs_stores_nothing_after_the_edit(tmp_path):
    import importlib.util

    file = tmp_path / "pts_during.py"
    file.write_text(_SELF_EDITING)
    spec = importlib.util.spec_from_file_location("pts_during", file)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["pts_during"] = mod
    spec.loader.exec_module(mod)
    with pytest.raises(ValueError, match=r"pts_during\.py changed since pts_during was imported"):
        run_sweep(mod.point, [{"a": 1.0}, {"a": 2.0}, {"a": 3.0}], tmp_path / "c", "serial", progress=False)
    stored = [json.loads(p.read_text())["point"] for p in (tmp_path / "c").glob("*.json")]
    assert stored == [{"a": 1.0}]  # the point computed before the edit, under the key of the code that ran


def test_two_functions_at_one_point_have_distinct_keys(tmp_path):
    mod = _point_module(tmp_path, "pts_two", "2")
    assert point_key(mod.double, {"a": 1.0}) != point_key(mod.triple, {"a": 1.0})
    both = [run_sweep(f, [{"a": 1.0}], tmp_path / "c", "serial", progress=False) for f in (mod.double, mod.triple)]
    assert [b.y.iloc[0] for b in both] == [2.0, 3.0] and not both[1].cached.any()


def test_the_package_hash_covers_every_module_of_the_package():
    import jko_cvx
    from jko_cvx.environment import package_files

    root = Path(jko_cvx.__file__).resolve().parent
    assert set(root.rglob("*.py")) <= set(package_files())
    assert {root / "grid.py", root / "collision" / "newton.py", root / "engine" / "loop.py"} <= set(package_files())


def test_key_covers_package_code_and_version(tmp_path, monkeypatch):
    import jko_cvx._version
    import jko_cvx.studies.sweep as sweep

    mod = _point_module(tmp_path, "pts_pkg", "2")
    key = point_key(mod.double, {"a": 1.0})
    monkeypatch.setattr(sweep, "code_fingerprint", lambda: "another package source")
    assert point_key(mod.double, {"a": 1.0}) != key
    monkeypatch.undo()
    monkeypatch.setattr(jko_cvx._version, "__version__", "9.9.9")
    assert point_key(mod.double, {"a": 1.0}) != key


@pytest.mark.parametrize(
    "damage, reason",
    [
        (lambda text: text.replace('"y": 2.0', '"y": 5.0'), "fails its digest"),
        (lambda text: text[: len(text) // 2], "does not parse"),
        (lambda text: "", "does not parse"),
        (lambda text: json.dumps({**json.loads(text), "key": "0" * 32}), "records another key"),
        (lambda text: json.dumps({**json.loads(text), "point": {"a": 7.0}}), "records another point"),
    ],
)
def test_damaged_entry_is_recomputed_with_a_warning_naming_the_file(tmp_path, damage, reason):
    from jko_cvx.studies.sweep import StaleCacheWarning

    mod = _point_module(tmp_path, "pts_damaged", "2")
    run_sweep(mod.double, [{"a": 1.0}], tmp_path / "c", "serial", progress=False)
    entry = tmp_path / "c" / f"{point_key(mod.double, {'a': 1.0})}.json"
    entry.write_text(damage(entry.read_text()))
    with pytest.warns(StaleCacheWarning, match=rf"{entry.name}.*{reason}"):
        again = run_sweep(mod.double, [{"a": 1.0}], tmp_path / "c", "serial", progress=False)
    assert not again.cached.any() and again.y.iloc[0] == 2.0
    assert run_sweep(mod.double, [{"a": 1.0}], tmp_path / "c", "serial", progress=False).cached.all()  # repaired


def test_fresh_recomputes_every_point(tmp_path):
    mod = _point_module(tmp_path, "pts_fresh", "2")
    run_sweep(mod.double, [{"a": 1.0}, {"a": 2.0}], tmp_path / "c", "serial", progress=False)
    again = run_sweep(mod.double, [{"a": 1.0}, {"a": 2.0}], tmp_path / "c", "serial", progress=False, fresh=True)
    assert not again.cached.any() and list(again.y) == [2.0, 4.0]
    with pytest.raises(TypeError, match="fresh must be a bool"):
        run_sweep(mod.double, [{"a": 1.0}], tmp_path / "c", "serial", progress=False, fresh="yes")


def test_cached_entries_returns_every_point_and_refuses_a_damaged_entry(tmp_path):
    mod = _point_module(tmp_path, "pts_entries", "2")
    run_sweep(mod.double, [{"a": 1.0}, {"a": 3.0}], tmp_path / "c", "serial", progress=False)
    assert sorted((p["a"], r["y"]) for p, r in cached_entries(tmp_path / "c")) == [(1.0, 2.0), (3.0, 6.0)]
    path = sorted((tmp_path / "c").glob("*.json"))[0]
    entry = json.loads(path.read_text())
    entry["result"]["y"] += 1.0
    path.write_text(json.dumps(entry))
    with pytest.raises(ValueError, match="fails its digest"):
        cached_entries(tmp_path / "c")
    path.write_text("{not json")
    with pytest.raises(ValueError, match="does not parse"):
        cached_entries(tmp_path / "c")


def test_code_provenance_adds_the_checkouts_commit_to_the_code_identity():
    import re
    import subprocess
    from pathlib import Path

    from jko_cvx.studies.sweep import code_identity, code_provenance

    prov = code_provenance(code_identity)
    assert {k: prov[k] for k in code_identity(code_identity)} == code_identity(code_identity)
    root = Path(__file__).resolve().parents[3]
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, cwd=root)
    if head.returncode == 0:  # a git checkout (CI's clone is one)
        assert prov["git_commit"] == head.stdout.strip() and re.fullmatch(r"[0-9a-f]{40}", prov["git_commit"])
        dirty = subprocess.run(["git", "status", "--porcelain", "jko_cvx"], capture_output=True, text=True, cwd=root)
        assert prov["jko_cvx_modified"] == bool(dirty.stdout.strip())
    else:
        assert prov["git_commit"] is None


def test_the_code_fingerprint_covers_the_shipped_scenes():
    # shipped_scene() reads these files: an edited one changes what a cached point computed
    import jko_cvx
    from jko_cvx.environment import package_files

    root = Path(jko_cvx.__file__).resolve().parent
    assert root / "scene" / "shipped" / "tab_bu_g1.toml" in package_files()
    assert not [p for p in package_files() if "__pycache__" in p.parts or p.suffix in (".pyc", ".pyo")]


def test_lambdas_closures_and_partials_are_refused_before_any_point_runs(tmp_path):
    import functools

    def make(k):
        return lambda a: {"y": k * a}

    def scaled(a, k):
        return {"y": k * a}

    for func, match in (
        (lambda a: {"y": a}, r"a lambda"),
        (make(10), r"a lambda"),
        (_closure(3), r"captures values \(k\)"),
        (functools.partial(scaled, k=2), r"func must be a function defined with def .*functools\.partial"),
        (_with_default(3), r"defined inside a function"),
    ):
        with pytest.raises((TypeError, ValueError), match=match):
            run_sweep(func, [{"a": 1.0}], tmp_path / "c", "serial", progress=False)
    assert not (tmp_path / "c").exists()


def _with_default(k):
    def times(a, k=k):  # the value is captured as a default, not a cell
        return {"y": k * a}

    return times


def _closure(k):
    def times(a):
        return {"y": k * a}

    return times


def test_numpy_and_python_numbers_of_other_types_get_other_keys(tmp_path):
    mod = _point_module(tmp_path, "pts_types", "2")
    assert point_key(mod.double, {"a": np.int64(5)}) == point_key(mod.double, {"a": 5})
    assert point_key(mod.double, {"a": np.int64(5)}) != point_key(mod.double, {"a": 5.0})
    assert point_key(mod.double, {"a": np.float64(5.0)}) == point_key(mod.double, {"a": 5.0})
    assert point_key(mod.double, {"a": np.bool_(True)}) == point_key(mod.double, {"a": True}) != point_key(
        mod.double, {"a": 1}
    )


def test_an_editor_file_beside_the_modules_is_no_change_of_code():
    import jko_cvx
    from jko_cvx.environment import package_files

    root = Path(jko_cvx.__file__).resolve().parent
    assert all(p.suffix in (".py", ".toml") for p in package_files())
    assert {root / "grid.py", root / "scene" / "shipped" / "tab_bu_g1.toml"} <= set(package_files())


def test_a_cached_result_is_keyed_by_the_numerical_libraries_too(monkeypatch):
    """After an upgrade of NumPy, SciPy, CVXPY, Clarabel, a solver (OSQP, SCS, ECOS, IPOPT), numba or Python a
    cached result is computed again: the key holds their versions, not only the package's code."""
    import platform

    import jko_cvx.studies.sweep as sweep
    from jko_cvx.environment import PACKAGES, installed_version

    ident = sweep.code_identity(blowup_time)
    libraries = ident["libraries"]
    for name in (*PACKAGES, "osqp", "scs", "ecos", "cyipopt-wheels", "numba"):
        assert f"{name} {installed_version(name)}" in libraries
    assert f"python {platform.python_version()}" in libraries
    before = point_key(blowup_time, {"n": 41})
    monkeypatch.setattr(sweep, "library_versions", lambda: libraries.replace("clarabel", "clarabel-upgraded"))
    assert point_key(blowup_time, {"n": 41}) != before
