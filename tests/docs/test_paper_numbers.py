"""The package's copy of the paper's numbers (jko_cvx.studies.reproduce.paper) against the LaTeX source."""

from jko_cvx.studies.reproduce import paper

from ..paper_tex import blowup_table, g2bu_table, paper_source


def test_tab_bu_is_the_papers():
    tex = blowup_table("tab:bu")
    assert len(tex) == 3 * 5 * 5
    for data, rows in paper.TAB_BU.items():
        for eps, values in rows.items():
            for dt, val in zip(paper.TAB_BU_DT, values, strict=True):
                assert tex[(data, eps, dt)] == val, (data, eps, dt)


def test_tab_bu_tb2_is_the_papers():
    tex = blowup_table("tab:bu_tb2")
    assert len(tex) == 4 * 4
    for eps, values in paper.TAB_BU_TB2["g4"].items():
        for dt, val in zip(paper.TAB_BU_TB2_DT, values, strict=True):
            assert tex[("g4", eps, dt)] == val


def test_tab_g2bu_is_the_papers():
    assert g2bu_table() == {float(k): v for k, v in paper.TAB_G2BU.items()}


def test_exact_blowup_times_are_the_papers():
    tex = paper_source()
    for i, data in enumerate(("g1", "g2", "g3", "g4"), start=1):
        assert f"T_{i}={paper.EXACT_T[data]}" in tex.replace(" ", "").replace("$", "")
