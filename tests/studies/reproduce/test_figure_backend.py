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
