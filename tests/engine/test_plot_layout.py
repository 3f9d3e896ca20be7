"""The run figures' fixed margins hold their labels: nothing drawn is cut at the canvas edge, and no
y-axis label or tick label of one panel runs into another panel."""

import pytest

from jko_cvx.engine.loop import simulate
from jko_cvx.engine.plot import _run_figures
from jko_cvx.scene import shipped_scene


def _check_layout(fig):
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    r = canvas.get_renderer()
    page = fig.bbox
    for a in fig.axes:
        bb = a.get_tightbbox(r)  # what is drawn: tick labels in view, axis labels, title, legend
        assert page.x0 - 0.5 <= bb.x0 and bb.x1 <= page.x1 + 0.5, (a, bb, page)
        assert page.y0 - 0.5 <= bb.y0 and bb.y1 <= page.y1 + 0.5, (a, bb, page)
        ylabels = a.yaxis.get_tightbbox(r)
        for other in fig.axes:
            if other is not a and ylabels is not None:
                assert not ylabels.overlaps(other.bbox), (a, other)


@pytest.mark.parametrize(
    ("name", "over"),
    [
        ("tab_bu_g1", {"time.dt": 0.02}),  # blow-up: two-line title with the fit, error bar, the exact law
        ("inhom_gamma1p5_before", {"v.n": 21, "x.n": 21, "t_end": 0.02, "output.times": []}),  # colorbar panel
        # the longest records label: both spacings and the spread
        ("inhom_gamma1p5_before", {"v.n": 21, "x.n": 21, "t_end": 0.02, "output.times": [], "stop.spread_v": 0.05}),
    ],
)
def test_the_run_figures_keep_every_label_on_the_canvas(name, over):
    run = simulate(shipped_scene(name, over))
    for fig in _run_figures(run):
        _check_layout(fig)
