"""The environment a result records: versions, git commit, BLAS library and threads."""

import importlib.metadata
import json
import platform
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from threadpoolctl import threadpool_limits

from jko_cvx.environment import (
    ENVIRONMENT_FILE,
    PACKAGES,
    environment,
    environment_line,
    git_state,
    record_csv,
    write_markdown,
)


def test_the_environment_names_the_versions_python_and_the_blas_threads():
    env = environment()
    assert env["numpy"] == np.__version__ and env["python"] == platform.python_version()
    for name in PACKAGES:
        assert env[name] == importlib.metadata.version(name)
    assert env["blas"], "numpy's BLAS is loaded, threadpoolctl must find it"
    assert all(b["internal_api"] and b["version"] for b in env["blas"])
    with threadpool_limits(limits=1, user_api="blas"):
        assert {b["num_threads"] for b in environment()["blas"]} == {1}  # measured, not a stored setting
    json.dumps(env)  # a result file can hold it
    line = environment_line(env)
    assert f"numpy {np.__version__}" in line and env["blas"][0]["internal_api"] in line


def test_timings_name_the_processor_they_ran_on(monkeypatch):
    """CPU times differ by 1.5x between machines of the same core count: a timing names its processor."""
    env = environment()
    assert isinstance(env["cpu"], str) and env["cpu"].strip() and env["cpu"] == env["cpu"].strip()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():  # Linux: the kernel's name of the first processor
        names = [ln.split(":", 1)[1].strip() for ln in cpuinfo.read_text().splitlines() if ln.startswith("model name")]
        if names:
            assert env["cpu"] == names[0]
    assert f"{env['cpu']}, {env['cpu_count']} CPUs" in environment_line(env)
    older = {k: v for k, v in env.items() if k != "cpu"}  # a record written before the processor was named
    assert f"{env['machine']}, {env['cpu_count']} CPUs" in environment_line(older)


def _git(cwd, *args):
    return subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, check=True).stdout.strip()


def test_git_state_is_the_checkouts_commit_and_whether_it_is_modified(tmp_path):
    assert git_state(tmp_path) == (None, None)  # not a checkout
    _git(tmp_path, "init", "-q")
    (tmp_path / "a.py").write_text("x = 1\n")
    _git(tmp_path, "add", "a.py")
    _git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "a")
    assert git_state(tmp_path) == (_git(tmp_path, "rev-parse", "HEAD"), False)
    (tmp_path / "a.py").write_text("x = 2\n")
    assert git_state(tmp_path)[1] is True


def test_markdown_reports_carry_the_environment_under_their_title(tmp_path):
    env = {**environment(), "numpy": "9.9.9"}
    write_markdown(tmp_path / "r.md", "# Title\n\nbody\n", env)
    lines = (tmp_path / "r.md").read_text().split("\n")
    assert lines[0] == "# Title" and lines[2] == environment_line(env) and "numpy 9.9.9" in lines[2]
    assert lines[3:] == ["", "body", ""]
    write_markdown(tmp_path / "s.md", "no title\n", env)
    assert (tmp_path / "s.md").read_text() == f"{environment_line(env)}\n\nno title\n"


def test_csv_files_have_their_environment_beside_them(tmp_path):
    for name in ("a.csv", "b.csv"):
        pd.DataFrame({"x": [1]}).to_csv(tmp_path / name, index=False)
    record_csv(tmp_path / "a.csv", env={"numpy": "1"})
    record_csv(tmp_path / "b.csv", env={"numpy": "2"})
    record = json.loads((tmp_path / ENVIRONMENT_FILE).read_text())
    assert record["a.csv"]["environment"] == {"numpy": "1"} and record["b.csv"]["environment"] == {"numpy": "2"}
    assert pd.read_csv(tmp_path / "a.csv").x.tolist() == [1]  # the CSV itself stays plain
    with pytest.raises(FileNotFoundError, match=r"paths: .*missing\.csv"):
        record_csv(tmp_path / "missing.csv")
    (tmp_path / ENVIRONMENT_FILE).write_text("{broken")
    with pytest.raises(ValueError, match="does not read as JSON"):
        record_csv(tmp_path / "a.csv")


def test_a_reproduction_records_its_environment_in_each_file(tmp_path):
    from jko_cvx.studies.reproduce import reproduce_mesh_maps

    reproduce_mesh_maps(tmp_path)
    md = (tmp_path / "mesh_maps.md").read_text().split("\n")
    assert md[0].startswith("# ") and md[2].startswith("*Environment: jko_cvx ")
    record = json.loads((tmp_path / ENVIRONMENT_FILE).read_text())
    assert set(record) == {p.name for p in tmp_path.glob("*.csv")}
    assert record["mesh_maps.csv"]["environment"]["blas"]


def test_the_blas_libraries_are_recorded_in_one_order_whatever_the_load_order(monkeypatch):
    """Two processes that loaded the same BLAS libraries in another order record the same environment (a resumed
    run compares them: a reordering is no difference)."""
    import threadpoolctl

    def libs(order):
        base = [{"user_api": "blas", "internal_api": "openblas", "version": v, "architecture": "Haswell",
                 "threading_layer": "pthreads", "num_threads": 1, "filepath": f"/lib/{name}.so"}
                for name, v in (("a", "0.3.30"), ("b", "0.3.31"))]  # fmt: skip
        return base if order else base[::-1]

    seen = []
    for order in (True, False):
        monkeypatch.setattr(threadpoolctl, "threadpool_info", lambda order=order: libs(order))
        seen.append(environment()["blas"])
    assert seen[0] == seen[1] and [b["filepath"] for b in seen[0]] == ["/lib/a.so", "/lib/b.so"]
