"""Tests for gaps the mutation study (``studies/mutation.py``, round 2) found: each one fails on the
mutation named in its docstring.  Oracles: the paper's LaTeX, exact invariants, planted answers."""

import re

import numpy as np
import pandas as pd
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision

from ..paper_tex import blowup_table, paper_available, paper_source


def test_reproduction_and_study_names_are_wired_to_their_functions():
    """Mutations ``reproductions-registry``, ``studies-registry``: a name wired to another entry."""
    from jko_cvx.studies.reproduce import REPRODUCTIONS
    from jko_cvx.studies.solvers import STUDIES

    for name, func in REPRODUCTIONS.items():
        assert func.__name__ == f"reproduce_{name}", name
    for name, func in STUDIES.items():
        assert func.__name__ == name, name


def test_pareto_front_keeps_exactly_the_points_no_faster_point_beats():
    """Mutation ``pareto-sorted-by-error``: the front must be walked in order of time."""
    from jko_cvx.studies.solvers.figures import pareto_front

    t = np.array([3.0, 1.0, 2.0, 4.0, 5.0])
    e = np.array([0.5, 2.0, 1.0, 0.7, 0.1])
    # (4, 0.7) is beaten by the faster (3, 0.5); every other point is better than all faster ones
    assert pareto_front(t, e) == ([1.0, 2.0, 3.0, 5.0], [2.0, 1.0, 0.5, 0.1])


def test_gamma1p5_sweep_point_is_n_by_n():
    """Mutation ``gamma1p5-x-n-ignored`` (the default n = 121 is the shipped x.n, so only other n show it)."""
    from jko_cvx.studies.reproduce.gamma1p5 import gamma1p5_scene

    for case in ("before", "after"):
        scene = gamma1p5_scene(case, 41)
        assert (scene.x.n, scene.v.n) == (41, 41)


def test_an_unshipped_lambda_has_strength_lambda_over_2_like_the_shipped_ones():
    """Mutation ``inhom-strength-lambda``: eqn:gke's collision term is lambda/2 Q(f, f)."""
    from jko_cvx.studies.reproduce.inhomogeneous import inhomogeneous_scene

    assert inhomogeneous_scene(4.0).strength == 2.0  # shipped TOML
    assert inhomogeneous_scene(3.0).strength == 1.5  # built by the override


def test_gk1_records_run_with_the_policy_they_name(monkeypatch):
    """Mutation ``records-reset-not-halving``: the halving_reset records ran with the fixed step."""
    from jko_cvx.studies.reproduce import records

    class Built(Exception):
        pass

    def capture(scene, **kwargs):
        raise Built(scene)

    monkeypatch.setattr(records, "simulate", capture)
    for policy in ("fixed", "halving", "halving_reset"):
        with pytest.raises(Built) as caught:
            records.record_run("g1", 0.5, policy, 0.1)
        scene = caught.value.args[0]
        assert scene.time.policy == policy
        assert (scene.collision.method == "sqp") == (policy != "fixed")  # the halving runs use the paper's SQP


@pytest.mark.skipif(not paper_available(), reason="the paper's LaTeX is not available")
def test_gk1_final_scene_has_the_captions_map_parameters():
    """Mutation ``gk1-final-map-params``: delta and delta0 read from fig:gk1_final's caption."""
    from jko_cvx.studies.reproduce.gk1_final import gk1_final_scene

    tex = paper_source()
    caption = tex[: tex.index(r"\label{fig:gk1_final}")].rsplit(r"\caption{", 1)[1]
    delta = float(re.search(r"\\delta=([0-9.]+)", caption).group(1))
    delta0 = float(re.search(r"\\delta_0 = ([0-9.]+)", caption).group(1))
    spec = gk1_final_scene().refine.v
    assert (spec.delta, spec.delta0) == (delta, delta0)


@pytest.mark.skipif(not paper_available(), reason="the paper's LaTeX is not available")
def test_beta_scan_puts_the_papers_entry_of_each_dt_beside_ours(monkeypatch, tmp_path):
    """Mutation ``beta-scan-paper-column``: the paper's number comes from its LaTeX table here."""
    from jko_cvx.studies.reproduce import beta_scan

    def sweep(func, points, *args, **kwargs):  # planted results: no runs (one run per column of eps_v)
        rows = []
        for p in points:
            n = len(p["eps_v"])
            rows.append({**p, "T_b": [0.5] * n, "steps": [1] * n, "failed_steps": [0] * n, "seconds": 0.0})
        return pd.DataFrame(rows)

    monkeypatch.setattr(beta_scan, "run_sweep", sweep)
    beta_scan.reproduce_tab_bu_beta_scan(tmp_path, quick=True)
    df = pd.read_csv(tmp_path / "tab_bu_beta_scan.csv")
    table = blowup_table("tab:bu")
    assert df["dt"].nunique() > 1
    for row in df.itertuples():
        key = next(k for k in table if k[0] == row.data and np.isclose(k[1], row.eps_v) and k[2] == row.dt)
        assert row.paper == table[key]


def test_fisher_width_error_is_relative_so_equal_for_every_width_without_fisher():
    """Mutation ``fisher-width-absolute``.  Without the Fisher term the problem on [-8w, 8w] is the
    width-1 problem rescaled (W = |v|: W' * f scales with the mass, d/dv with 1/w), so the relative
    L1 error is the same for every width and the absolute one scales with w."""
    from jko_cvx.studies.reproduce.fisher_width import fisher_width_error

    wide, narrow = fisher_width_error(0.5, np.inf, "log"), fisher_width_error(0.125, np.inf, "log")
    assert wide["completed"] and narrow["completed"]
    assert 1e-4 < wide["error"] < 0.1
    assert narrow["error"] == pytest.approx(wide["error"], rel=1e-4)


def test_g2bu_loglog_plots_every_lambda_of_the_table_once(tmp_path):
    """Mutation ``panels-loglog-finest``: the lambda sweep is complete on the coarsest grid only."""
    from jko_cvx.studies.reproduce.panels import reproduce_g2bu_loglog

    table = pd.DataFrame(
        {
            "lambda": [100.0, 200.0, 310.0, 310.0],
            "n_v": [101, 101, 101, 201],
            "log ratio at T_b": [0.9, 0.8, 0.7, 0.71],
            "infinite-mass ratio 2/(lambda rho0 T)": [1.2, 0.9, 0.6, 0.6],
        }
    )
    table.to_csv(tmp_path / "tab_g2bu.csv", index=False)
    df = reproduce_g2bu_loglog(tmp_path)
    assert df["lambda"].tolist() == [100.0, 200.0, 310.0]
    assert (tmp_path / "g2bu_loglog.png").stat().st_size > 0


def test_the_extremes_matrix_calls_a_planted_liar_silently_wrong():
    """Mutation ``extremes-kkt-unchecked``: the matrix recomputes the residual whatever the status says."""
    from jko_cvx.studies.solvers.extremes import ExtremeCase, extremes_matrix

    grid = Grid.uniform(-2.0, 2.0, 41)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.01, beta=3.0)
    liar_opts = {"tol": 1e-2, "kkt_tol": 0.5}
    liar = solve_collision(prob, method="sqp", **liar_opts)
    assert liar.success and float(prob.kkt_residual(liar.f, liar.m).total) > 1e-6  # the plant
    solvers = {"liar": ("sqp", liar_opts), "newton": ("newton", {"tol": 1e-12})}
    df = extremes_matrix([ExtremeCase("planted", lambda: prob)], solvers).set_index("solver")
    assert df.loc["liar", "outcome"] == "silently wrong"
    assert df.loc["newton", "outcome"] == "certified"


def test_the_osqp_subproblem_gives_the_banded_sqp_iterates():
    """Mutation ``sqp-osqp-q-sign``: with the floor inactive both QP solvers solve the same
    subproblem, so the SQP runs agree (to OSQP's tolerance) and both end certified."""
    grid = Grid.uniform(-2.0, 2.0, 41)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.01, beta=3.0)
    banded = solve_collision(prob, method="sqp", qp="banded")
    osqp = solve_collision(prob, method="sqp", qp="osqp")
    assert banded.success and osqp.success
    assert np.abs(osqp.f - banded.f).max() < 1e-6 * banded.f.max()

