"""A reproduction's figure leaves the caller's matplotlib backend alone.

``matplotlib.use("Agg")`` inside a library call switches the backend of the whole process: in a
notebook, every later ``plt.show()`` then shows nothing (found by the paper_table tutorial).
"""

import matplotlib
import pandas as pd
import pytest

from jko_cvx.studies.reproduce import blowup_tables


@pytest.fixture
def svg_backend():
    before = matplotlib.get_backend()
    matplotlib.use("svg")  # a backend other than the Agg the figures once forced
    yield
    matplotlib.use(before)


def test_the_tab_bu_figure_keeps_the_callers_backend(tmp_path, svg_backend):
    df = pd.DataFrame({"data": "g1", "eps_v": 1e-3, "dt": [0.02, 0.01], "T_b": [0.46, 0.45], "paper": [0.48, 0.48]})
    path = tmp_path / "tab_bu.png"
    blowup_tables._figure(df, path)
    assert matplotlib.get_backend() == "svg"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_the_studies_figures_are_pyplot_free(tmp_path, svg_backend):
    import matplotlib.pyplot as plt

    from jko_cvx.studies.solvers.figures import finish_figure, pyplot

    before = plt.get_fignums()
    headless = pyplot()
    fig, axes = headless.subplots(1, 2, figsize=(4, 2), squeeze=False)
    axes[0, 0].plot([0, 1], [0, 1], label="a", color=headless.cm.tab20(0))
    finish_figure(fig, axes.ravel(), tmp_path / "f.png")
    assert matplotlib.get_backend() == "svg" and plt.get_fignums() == before
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_no_module_of_the_package_switches_the_backend():
    from pathlib import Path

    import jko_cvx

    root = Path(jko_cvx.__file__).parent
    offenders = [str(p.relative_to(root)) for p in root.rglob("*.py") if "matplotlib.use(" in p.read_text()]
    assert not offenders, offenders
