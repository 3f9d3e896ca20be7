"""``studies/bench_collision.py`` writes every table the solver guide quotes, with the run's provenance."""

import pandas as pd
import pytest

from tests.studies.scripts import load_study_script

pytest.importorskip("cyipopt")



def _bench():
    return load_study_script("bench_collision.py")


def test_a_small_run_writes_the_csv_and_the_report_with_its_provenance(tmp_path, monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    out = tmp_path / "bench_collision.csv"
    _bench().main(["--sizes", "21", "--repeats", "1", "--no-newton", "--out", str(out)])
    df = pd.read_csv(out)
    assert sorted(zip(df.fisher, df.method, strict=True)) == sorted(
        [("perspective", m) for m in ("conic", "sqp", "newton", "newton_compiled", "nlp")]
        + [("log", m) for m in ("sqp", "newton", "newton_compiled", "nlp")]
    )
    assert (df.status == "CONVERGED").all() and (df.kkt_residual <= 1e-6).all()  # certified, re-checked
    report = out.with_suffix(".md").read_text()
    assert "OPENBLAS_NUM_THREADS=1" in report and "BLAS threads [1]" in report
    assert "code " in report and "UTC" in report and "1-minute load" in report
    assert "perspective: conic / newton (medians per solve): N = 21:" in report
    assert "log: newton / newton_compiled (medians per solve): N = 21:" in report
    assert not (tmp_path / "bench_newton.csv").exists()  # --no-newton: the second part is not run


@pytest.mark.parametrize("argv", [["--repeats", "0"], ["--sizes", "3"]])
def test_bad_arguments_are_refused_before_any_solve(tmp_path, argv, capsys):
    with pytest.raises(SystemExit):
        _bench().main([*argv, "--out", str(tmp_path / "b.csv")])
    assert "--repeats must be >= 1" in capsys.readouterr().err
    assert not (tmp_path / "b.csv").exists()
