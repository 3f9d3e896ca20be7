"""``jko-cvx reproduce g3_dt_probe``: the gamma = 3 runs in the grid and in dt (quick form), and its report."""

import pandas as pd
import pytest

from jko_cvx.studies.reproduce import REPRODUCTIONS
from jko_cvx.studies.reproduce.dt_probe import (
    FULL_CASES,
    QUICK_CASES,
    missing_cases,
    parse_variant,
    probe_report,
)


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("g3")
    table = REPRODUCTIONS["g3_dt_probe"](out, quick=True, workers=1, progress=False)
    return out, table


def test_the_quick_form_writes_every_case_and_every_section(quick):
    out, table = quick
    written = pd.read_csv(out / "g3_dt_probe.csv").fillna({"variant": ""})
    cases = {(r["lambda"], r["n"], r["dt"], r["time_order"], r["variant"]) for _, r in written.iterrows()}
    assert cases == set(QUICK_CASES) and len(written) == len(table)
    assert (written.steps >= 4).all() and (written.max_f_peak > 0).all() and written.commit.notna().all()
    report = (out / "g3_dt_probe.md").read_text()
    sections = (
        "## Each grid and order against dt",
        "## Each dt against the grid",
        "## The two orders at one dt: which is right",
        "## Controls: what else changes with dt",
    )
    assert all(section in report for section in sections)
    assert "Every case of the form has a row." in report and "(quick form)" in report
    assert "to t_end = 0.4 with the step dt = 0.1, 0.05" in report and (written.t_end == 0.4).all()
    assert (out / "g3_dt_probe.png").stat().st_size > 0


def test_the_report_names_the_cases_of_the_form_without_a_row(quick):
    _, table = quick
    dropped = table.iloc[1:]
    assert missing_cases(dropped, QUICK_CASES) == [QUICK_CASES[0]]
    assert str(QUICK_CASES[0]) in probe_report(dropped, cases=QUICK_CASES)


def test_the_full_form_halves_dt_three_times_on_every_grid_up_to_481():
    for lam in (4.0, 10.0):
        for n in (121, 241, 481):
            dts = {dt for (la, nn, dt, order, v) in FULL_CASES if (la, nn, order, v) == (lam, n, 1, "")}
            assert {0.05, 0.025, 0.0125, 0.00625} <= dts


def test_a_variant_key_outside_the_controls_or_set_twice_is_refused():
    assert parse_variant("collision.beta=1e5,refine.v.tol=0.1") == {"collision.beta": 1e5, "refine.v.tol": 0.1}
    with pytest.raises(ValueError, match="variant key"):
        parse_variant("time.dt=0.1")
    with pytest.raises(ValueError, match="twice"):
        parse_variant("collision.beta=1e5,collision.beta=10")


def test_a_variant_is_matched_by_what_it_changes_not_by_its_spelling():
    base = {"n": 61, "dt": 0.05, "time_order": 1, "max_f_peak": 2.6, "t_peak": 1.9, "lambda": 4.0}
    rows = pd.DataFrame([{**base, "variant": "collision.beta=100000"}, {**base, "variant": ""}])
    cases = ((4.0, 61, 0.05, 1, "collision.beta=1e5"), (4.0, 61, 0.05, 1, ""))
    assert missing_cases(rows, cases) == []
    swapped = pd.DataFrame([{**base, "variant": "refine.v.tol=0.1,refine.x.tol=0.1"}])
    assert missing_cases(swapped, ((4.0, 61, 0.05, 1, "refine.x.tol=0.1,refine.v.tol=0.1"),)) == []


def test_a_case_in_a_run_directory_continues_from_its_checkpoint_to_the_row_of_an_uninterrupted_run(tmp_path):
    """The probe's long cases outlast a session: run in a directory, a killed case continues bit for bit."""
    from jko_cvx.engine import RunDirError
    from jko_cvx.engine.loop import simulate
    from jko_cvx.engine.trackers import Tracker
    from jko_cvx.scene.model import shipped_scene
    from jko_cvx.studies.reproduce.dt_probe import probe_run

    case = (10.0, 15, 0.1, 1, "")
    whole = probe_run(*case, t_end=0.5)

    class Killed(Exception):
        pass

    class KillAtStep3(Tracker):
        def handle(self, state, step):
            if state.step == 3:
                raise Killed

    out = tmp_path / "case"
    scene = shipped_scene("inhom_gamma3_lambda10", {"v.n": 15, "x.n": 15, "time.dt": 0.1, "time.order": 1,
                                                     "t_end": 0.5, "output.checkpoint_every": 1})  # fmt: skip
    with pytest.raises(Killed):
        simulate(scene, out=out, observers=lambda rd: [KillAtStep3()])
    assert (out / "checkpoint.npz").exists() and not (out / "verdict.json").exists()
    continued = probe_run(*case, t_end=0.5, out=out)
    read_back = probe_run(*case, t_end=0.5, out=out)  # an ended run is read back, not run again
    for row in (continued, read_back):
        assert {k: v for k, v in row.items() if k != "seconds"} == {k: v for k, v in whole.items() if k != "seconds"}
    assert read_back["seconds"] == continued["seconds"] > 0
    with pytest.raises(RunDirError, match="not of the case"):
        probe_run(10.0, 15, 0.05, 1, "", t_end=0.5, out=out)


def test_an_ended_case_of_other_code_is_refused_not_read_back_under_this_commit(tmp_path, monkeypatch):
    """The driver labels each row with this code's commit: an ended run another code made must not get that label."""
    import jko_cvx.studies.reproduce.dt_probe as dt_probe
    from jko_cvx.engine import RunDirError

    out = tmp_path / "case"
    dt_probe.probe_run(10.0, 15, 0.1, 1, "", t_end=0.2, out=out)  # ended: verdict.json written
    monkeypatch.setattr(dt_probe, "code_fingerprint", lambda: "0" * 64)  # as if the package were edited since
    with pytest.raises(RunDirError, match="other jko_cvx code"):
        dt_probe.probe_run(10.0, 15, 0.1, 1, "", t_end=0.2, out=out)
