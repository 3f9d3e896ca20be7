"""Figures a reader understands without the code: every axis labelled, the initial datum drawn and named
in the legend, a labelled colorbar, the work-precision figure naming its reference and every marker.

The figure objects are inspected (labels, legend entries, the data of the drawn lines), not pixels.
"""

import numpy as np
import pytest

from jko_cvx.engine.loop import simulate
from jko_cvx.engine.plot import plot_records, plot_solution
from jko_cvx.scene import scene_from_dict

plt = pytest.importorskip("matplotlib.pyplot")

HOM = {
    "name": "fig_hom",
    "gamma": 1.0,
    "t_end": 0.04,
    "v": {"L": 2.0, "n": 41},
    "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
    "time": {"dt": 0.01},
    "refine": {"v": {}},
    "stop": {"eps_v": 1e-4},
}
INHOM = {**HOM, "name": "fig_inhom", "gamma": 3.0, "strength": 2.0, "x": {"L": 1.0, "n": 8}, "v": {"L": 2.0, "n": 21},
         "initial": {"kind": "two_bump_phase", "a": 6.0, "b": 6.0, "c": 0.5, "d": 0.5}, "refine": {}}  # fmt: skip


@pytest.fixture(scope="module")
def runs():
    return {k: simulate(scene_from_dict(d)) for k, d in (("hom", HOM), ("inhom", INHOM))}


def _labels(fig) -> list[str]:
    """The entries of the figure's legends, as a reader sees them."""
    return [t.get_text() for ax in fig.axes if ax.get_legend() is not None for t in ax.get_legend().get_texts()]


@pytest.mark.parametrize("kind", ["hom", "inhom"])
def test_every_records_panel_names_its_quantities(runs, kind):
    fig = plot_records(runs[kind])
    for ax in fig.axes:
        assert ax.get_xlabel().strip() and ax.get_ylabel().strip(), (ax.get_xlabel(), ax.get_ylabel())
        assert "t" in ax.get_xlabel()
    ylabel = " ".join(ax.get_ylabel() for ax in fig.axes)
    assert "dv" in ylabel and "max f" in ylabel and ("dx" in ylabel) is (kind == "inhom")
    plt.close(fig)


def test_homogeneous_solution_draws_the_initial_datum_in_the_legend(runs):
    run = runs["hom"]
    fig = plot_solution(run)
    for ax in fig.axes:
        assert ax.get_xlabel().strip() and ax.get_ylabel().strip()
    main = fig.axes[0]
    lines = {ln.get_label(): ln for ln in main.get_lines()}
    (f0_label,) = [lab for lab in lines if lab.startswith("initial datum")]
    assert any(lab.startswith("f at t =") for lab in lines)
    v, f0 = lines[f0_label].get_data()
    np.testing.assert_allclose(f0, np.exp(-2 * np.asarray(v) ** 2), rtol=1e-12)  # g1 = exp(-2 v^2), independently
    assert f0_label in _labels(fig)
    plt.close(fig)


def test_inhomogeneous_solution_has_a_labelled_colorbar_and_the_initial_datum(runs):
    fig = plot_solution(runs["inhom"])
    main, bar = fig.axes[0], fig.axes[1]
    assert main.get_xlabel() == "x" and main.get_ylabel() == "v"
    assert "f" in bar.get_ylabel(), "the colorbar names the quantity"
    assert any(lab.startswith("initial datum") for lab in _labels(fig))
    plt.close(fig)


def test_work_precision_figure_names_its_reference_and_every_marker(tmp_path):
    from jko_cvx import CollisionProblem, Grid, PowerKernel
    from jko_cvx.studies.compare import Configuration, compare_solvers
    from jko_cvx.studies.solvers.workprecision import _plot

    grid = Grid.uniform(-2.0, 2.0, 21)
    prob = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), 0.01, beta=10.0)
    configs = [Configuration("newton", "newton", f"tol={t:g}", {"tol": t}) for t in (1e-4, 1e-8)]
    configs += [Configuration("sqp:banded", "sqp", "max_iter=2", {"max_iter": 2})]  # not certified: hollow
    df = compare_solvers(prob, configs, repeats=1)
    df.insert(0, "problem", "gamma=1")
    assert not df.certified.all() and df.certified.any()
    fig = _plot(df, "problem", "median_s", "f_error", tmp_path / "wp.png", "one collision step",
                reference=df.attrs["reference"])  # fmt: skip
    assert (tmp_path / "wp.png").stat().st_size > 0
    ax = fig.axes[0]
    assert "reference" in (ax.get_title() + ax.get_ylabel()).lower() and "newton" in ax.get_title() + ax.get_ylabel()
    labels = ax.get_legend_handles_labels()[1]
    assert ax.get_legend() is not None and len(ax.get_legend().get_texts()) == len(labels)
    assert any("certified" in lab and "not" not in lab for lab in labels)
    assert any("not certified" in lab for lab in labels)
    assert all(any(fam in lab for lab in labels) for fam in ("newton", "sqp:banded"))
    # every drawn marker set is in the legend: no line or marker artist without a label
    unlabelled = [ln for ln in ax.get_lines() if ln.get_label().startswith("_") and len(ln.get_xdata())]
    assert not unlabelled, [ln.get_label() for ln in unlabelled]
    plt.close(fig)


@pytest.mark.parametrize("limits", [(1e-5, 1e3), (0.2, 0.9), (3.0, 40.0), (1e-30, 1e30), (0.5, 2.0)])
def test_the_log_tick_labels_read_as_matplotlibs_without_mathtext(limits):
    """The records' log-axis labels are matplotlib's scientific-notation labels in plain Unicode
    (10⁻⁴, 2×10⁻¹): the same text a reader sees, with no mathtext to parse."""
    import matplotlib.ticker as mt

    from jko_cvx.engine import plot

    fig, ax = plt.subplots()
    ax.semilogy(limits, limits)
    ax.set_ylim(*limits)
    ours = plot._use_plain_log_labels(ax.yaxis)
    fig.canvas.draw()
    shown = [t.get_text() for t in ax.yaxis.get_ticklabels() + ax.yaxis.get_ticklabels(minor=True)]
    assert any(shown) and not any("$" in s or "\\" in s for s in shown), shown
    sup = str.maketrans("⁻⁰¹²³⁴⁵⁶⁷⁸⁹", "-0123456789")
    for formatter, which in ((ours[0], ax.yaxis.get_majorticklocs()), (ours[1], ax.yaxis.get_minorticklocs())):
        ref = mt.LogFormatterSciNotation(labelOnlyBase=formatter.labelOnlyBase)
        ref.set_axis(ax.yaxis)
        ref.set_locs(which)
        formatter.set_locs(which)
        for x in which:
            want = ref(x)  # "$\mathdefault{10^{-4}}$", "$\mathdefault{2\times10^{-1}}$", "$\mathdefault{0.5}$" or ""
            got = formatter(x)
            if not want:
                assert got == ""
                continue
            body = want.removeprefix("$\\mathdefault{").removesuffix("}$")
            base, _, exp = body.partition("^{")
            assert got.translate(sup).replace("×", "\\times") == base + exp.removesuffix("}"), (x, want, got)
    plt.close(fig)


def test_the_run_figures_need_neither_pyplot_nor_mathtext(tmp_path):
    """save_figures (the CLI's figures) draws without pyplot, which would choose a backend, and without the
    mathtext parser (a fresh interpreter: this one has pyplot loaded)."""
    import json
    import subprocess
    import sys

    code = f"""
import json, sys
import matplotlib.mathtext as mathtext
def refuse(*args, **kwargs):
    raise AssertionError("a label was parsed as mathtext: " + repr(args[1:2]))
mathtext.MathTextParser.parse = refuse
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.plot import save_figures
from jko_cvx.scene import scene_from_dict
for name, scene in json.loads({json.dumps(json.dumps({"hom": HOM, "inhom": INHOM}))}).items():
    save_figures(simulate(scene_from_dict(scene)), {str(tmp_path)!r})
assert "matplotlib.pyplot" not in sys.modules, "pyplot was imported"
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert {p.name for p in tmp_path.iterdir()} >= {"solution.png", "records.png"}
