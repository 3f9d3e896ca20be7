"""A sweep on local worker processes started from a script: the ``if __name__ == "__main__":`` guard.

Workers started with ``spawn`` (a local Dask cluster; a process pool under that start method)
import the main script again; a sweep called from its unguarded top level would start again in
every worker, which used to take the cluster down with a page of nanny tracebacks.  The scripts
here are run as ``python script.py``, as a user would.
"""

import subprocess
import sys
import textwrap

import pytest

from jko_cvx.studies.sweep import _guarded_lines

POINT_FUNCTION = "from jko_cvx.studies.reproduce.blowup_tables import blowup_time\n"
SWEEP = (
    'run_sweep(blowup_time, [{"data": "g1", "eps_v": 1e-3, "dt": dt} for dt in (0.02, 0.01)], "cache", '
    'executor="{executor}", workers=2, progress=False)'
)


def _script(tmp_path, body: str, executor: str = "dask") -> subprocess.CompletedProcess:
    path = tmp_path / "sweep_script.py"
    text = POINT_FUNCTION + "from jko_cvx.studies.sweep import run_sweep\n" + textwrap.dedent(body)
    path.write_text(text.replace("SWEEP", SWEEP.replace("{executor}", executor)))
    return subprocess.run([sys.executable, str(path)], cwd=tmp_path, capture_output=True, text=True, timeout=300)


def _refused(proc: subprocess.CompletedProcess, tmp_path, line: int) -> None:
    assert proc.returncode == 1, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("RuntimeError: ") and 'if __name__ == "__main__":' in last, proc.stderr
    assert f"sweep_script.py again, running its top-level code: line {line}," in last
    assert "Nanny" not in proc.stderr and "bootstrapping" not in proc.stderr  # refused before any worker started
    assert not (tmp_path / "cache").exists()  # and before any file was written


def test_an_unguarded_dask_sweep_in_a_script_is_refused_before_any_work(tmp_path):
    pytest.importorskip("distributed")
    _refused(_script(tmp_path, "print(SWEEP)\n"), tmp_path, line=3)


def test_an_unguarded_call_of_main_is_refused_too(tmp_path):
    pytest.importorskip("distributed")
    body = """
    def main():
        print(SWEEP)


    main()
    """
    _refused(_script(tmp_path, body), tmp_path, line=8)


def test_an_unguarded_process_pool_under_spawn_is_refused(tmp_path):
    body = """
    import multiprocessing

    multiprocessing.set_start_method("spawn")
    print(SWEEP)
    """
    _refused(_script(tmp_path, body, executor="process"), tmp_path, line=7)


def test_the_guarded_script_runs_on_a_local_dask_cluster(tmp_path):
    pytest.importorskip("distributed")
    body = """
    def main():
        table = SWEEP
        assert list(table.dt) == [0.02, 0.01] and table.T_b.notna().all() and not table.cached.any()
        print("swept", len(table))


    if __name__ == "__main__":
        main()
    """
    proc = _script(tmp_path, body)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == "swept 2"
    assert len(list((tmp_path / "cache").glob("*.json"))) == 2


def test_the_guard_is_found_in_either_order_and_only_outside_functions():
    source = textwrap.dedent(
        """
        import os
        if "__main__" == __name__:
            os.getcwd()
        def f():
            if __name__ == "__main__":
                pass
        if __name__ != "__main__":
            pass
        try:
            if __name__ == "__main__" and os.name:
                os.getcwd()
        finally:
            pass
        """
    )
    assert _guarded_lines(source) == [(3, 4), (11, 12)]
