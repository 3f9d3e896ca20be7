"""The solver studies of issue 6: work-precision, cost growth, the extremes matrix.

Checks on the studies' own outputs against exact solutions and invariants (timings are
printed by the studies, never asserted).
"""

import numpy as np
import pandas as pd
import pytest

from jko_cvx.studies.solvers import extremes_matrix, work_precision_run
from jko_cvx.studies.solvers.cost import cost_growth, fit_exponent
from jko_cvx.studies.solvers.extremes import _PACKAGE, default_solvers, extreme_cases
from jko_cvx.studies.solvers.workprecision import run_point


def test_whole_run_error_is_first_order_in_dt_and_the_fisher_bias_shows(tmp_path):
    """Quick work-precision run: Newton's L1 error against the Burgers solution falls like dt
    (dt = 0.04 -> 0.01: ratio 4.2 measured), and beta = 3 adds a bias that beta = inf does not."""
    df = work_precision_run(tmp_path, quick=True, progress=False)
    assert (tmp_path / "work_precision_run.md").exists() and (tmp_path / "work_precision_run.png").exists()
    bias = df[df.sweep == "bias"].set_index(["beta", "dt"]).error
    ratio = bias[(np.inf, 0.04)] / bias[(np.inf, 0.01)]
    assert 3.0 <= ratio <= 5.5, ratio
    assert bias[(3.0, 0.01)] > 3 * bias[(np.inf, 0.01)]
    newton = df[(df.family == "newton") & np.isfinite(df.error)]
    assert len(newton) == len(df[df.family == "newton"])  # every Newton run certified to the end


def test_run_point_matches_the_gamma2_linear_solution():
    out = run_point("newton", 2.0, 121, 0.01, np.inf, 1e-8)
    assert out["failed_step"] == -1 and out["steps"] == 50
    assert out["error"] < 0.015  # measured 0.0094 at N = 121 (first order in dt)


def test_fit_exponent_recovers_a_power_law():
    n = np.array([31, 61, 121, 241, 481])
    assert fit_exponent(n, 3e-6 * n**1.5) == pytest.approx(1.5)
    assert np.isnan(fit_exponent(n[:2], n[:2] * 1.0))  # fewer than two sizes >= 121


_SUBSET = (
    "vacuum tails 1e-30, beta=inf",
    "dt=1, gamma=1.5",
    "spacing ratio 1e4, gamma=1",
    "beta=0.1",
    "right before blow-up (g1, t = 0.49)",
)


def _ci_solvers():
    """Every solver of the matrix with its iteration budget cut (the full budgets take ~4 min here)."""
    solvers = dict(default_solvers())
    solvers["sqp:banded"] = ("sqp", {"max_iter": 2000})
    solvers["sqp:osqp"] = ("sqp", {"qp": "osqp", "max_iter": 10})
    for label, (method, opts) in list(solvers.items()):
        if method == "conic":  # at most 10 convex-concave passes
            solvers[label] = (method, {**opts, "max_passes": 10})
    if "conic:SCS" in solvers:
        solvers["conic:SCS"][1]["solver_options"] = {"max_iters": 1000}
    return solvers


def test_extremes_subset_has_no_silently_wrong_outcome():
    """A representative subset of the matrix (the full one: ``jko-cvx study extremes``)."""
    cases = [c for c in extreme_cases() if c.name in _SUBSET]
    assert len(cases) == len(_SUBSET)
    df = extremes_matrix(cases=cases, solvers=_ci_solvers())
    assert set(df.solver) == set(default_solvers())
    assert not (df.outcome == "silently wrong").any(), df[df.outcome == "silently wrong"].to_string()
    flagged = df[df.outcome == "flagged"]
    assert flagged.status.ne("CONVERGED").all() and flagged.message.str.len().gt(0).all()
    # Newton at the study engine's tolerance certifies every case the conic reference certifies
    ok = df[df.outcome.str.startswith("certified")]
    assert set(ok[ok.solver == "conic:CLARABEL"].case) <= set(ok[ok.solver == "newton:tol=1e-8"].case)
    assert set(_PACKAGE) <= set(df.solver)
    if "nlp" in df.solver.values:  # IPOPT certifies every case of the subset (measured; the SQP none)
        assert set(ok[ok.solver == "nlp"].case) == set(_SUBSET)


@pytest.mark.slow
def test_cost_growth_quick(tmp_path):
    tables = cost_growth(tmp_path, quick=True)
    step = tables["step"]
    assert isinstance(step, pd.DataFrame) and (step.status == "CONVERGED").all()
    assert (tmp_path / "cost_growth.md").exists() and (tmp_path / "cost_growth.png").exists()
    head = (tmp_path / "cost_growth.md").read_text().split("\n\n")[1]  # the run's record
    assert " UTC on " in head and "(quick form)" in head and "threads: JKO_CVX_BLAS_THREADS=" in head
    assert "1-minute load" in head and "medians of 2 repeats" in head


def test_study_command_writes_its_tables(tmp_path, capsys):
    from jko_cvx.cli import main

    assert main(["study", "work_precision_run", "--quick", "--out", str(tmp_path)]) == 0
    assert "Regularisation bias" in capsys.readouterr().out
    assert (tmp_path / "work_precision_run.csv").exists()
    with pytest.raises(SystemExit):
        main(["study", "no_such_study"])
