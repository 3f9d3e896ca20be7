"""The tutorial ``studies/examples/verify_sqp.py`` runs in quick form and says what its docstring says."""

from tests.studies.scripts import load_study_script


def test_the_quick_example_verifies_sqp_and_saves_the_figures(tmp_path):
    mod = load_study_script("examples/verify_sqp.py")
    g1, inhom = mod.main(["--quick", "--out", str(tmp_path)])
    # tab_bu_g1 (gamma = 1): SQP agrees with nlp step by step and along the run, to the blow-up criterion
    assert g1.verified and "trajectory agrees" in g1.verdict, g1.verdict
    assert g1.run.verdict.stop.name == g1.reference_run.verdict.stop.name == "EPS_V"
    assert abs(g1.run.verdict.T_b_fit - 0.5) < 0.03  # the exact blow-up time 1/(2 max f0) = 0.5 (Burgers)
    assert inhom.verified and len(inhom.table) == 3, inhom.verdict  # 3 slices of step 2
    for name in ("verify_sqp_tab_bu_g1.png", "verify_sqp_inhom_gamma3_lambda4.png", "verify_sqp_quick.md"):
        assert (tmp_path / name).stat().st_size > 0
    assert "threads" in (tmp_path / "verify_sqp_quick.md").read_text().splitlines()[2]  # the environment line
