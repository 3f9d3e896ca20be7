"""``PeriodicGrid.vacuum_coordinate``: the sparse-table window maximum is bitwise the neighbour loop it replaced."""

from __future__ import annotations

import numpy as np
import pytest

from jko_cvx.grid import PeriodicGrid


def _vacuum_coordinate_reference(grid: PeriodicGrid, lines, reach: float):
    """The neighbour-by-neighbour loop, verbatim from the version before the sparse table."""
    f = np.asarray(lines, dtype=float)
    x, n, P = grid.points, grid.n, grid.period
    window_max = f.copy()
    idx = np.arange(n)
    for d in range(1, n // 2 + 1):
        inside = False
        for step in (d, -d):
            pos = idx + step
            within = np.abs(x[pos % n] + P * (pos // n) - x) <= reach
            if within.any():
                inside = True
                window_max = np.maximum(window_max, np.where(within, np.roll(f, -step, axis=-1), 0.0))
        if not inside:
            break
    i = np.argmin(window_max, axis=-1)
    cut = x[i][..., None]
    near_cut = np.take_along_axis(window_max, i[..., None], axis=-1)[..., 0]
    return np.mod(x - cut, P), near_cut


def _mapped_grid(rng, n: int, period: float) -> PeriodicGrid:
    """Cells spread over three decades, clustered like the two-bump maps' grids."""
    widths = 10.0 ** rng.uniform(-3, 0, n)
    edges = np.concatenate([[0.0], np.cumsum(widths)]) * period / widths.sum() - period / 2
    return PeriodicGrid(0.5 * (edges[:-1] + edges[1:]), period)


@pytest.mark.parametrize("n", [3, 4, 7, 64, 121])
def test_window_maximum_is_bitwise_the_neighbour_loop(n):
    rng = np.random.default_rng(n)
    grid = _mapped_grid(rng, n, 10.0)
    lines = rng.exponential(size=(5, n)) * (rng.uniform(size=(5, n)) < 0.6)  # zeros: vacuum
    lines[1] = -np.abs(lines[1])  # negative values: where the loop compared with 0, so must we
    lines[2, : n // 2] = 0.0
    spacing = np.diff(np.sort(grid.points)).max() if n > 1 else 1.0
    for reach in (0.0, 1e-4, 0.3 * spacing, 2 * spacing, 3.0, 7.0, 40.0):
        xi, near = grid.vacuum_coordinate(lines, reach)
        xi_ref, near_ref = _vacuum_coordinate_reference(grid, lines, reach)
        assert np.array_equal(xi.view(np.int64), xi_ref.view(np.int64))
        assert np.array_equal(near, near_ref)


def test_window_maximum_on_a_batch_of_lines_and_nan():
    rng = np.random.default_rng(11)
    grid = _mapped_grid(rng, 81, 10.0)
    lines = rng.exponential(size=(3, 4, 81))
    lines[0, 1, 5] = np.nan
    reach = 2 * float(np.diff(grid.points).max())
    xi, near = grid.vacuum_coordinate(lines, reach)
    xi_ref, near_ref = _vacuum_coordinate_reference(grid, lines, reach)
    assert np.array_equal(xi, xi_ref) and np.array_equal(near, near_ref, equal_nan=True)


def test_neighbours_that_are_not_a_run_are_taken_one_by_one(monkeypatch):
    """Rounding could make a point's neighbours in reach skip one; such a window is maximised neighbour by
    neighbour (forced here through the table of neighbours in reach)."""
    rng = np.random.default_rng(4)
    grid = _mapped_grid(rng, 9, 10.0)
    lines = rng.exponential(size=(3, 9))
    within = np.zeros((2, 3, 9), dtype=bool)
    within[:, 0] = True
    within[0, 2, 4] = True  # point 4 sees 1 and 3 places ahead but not 2: not a run
    within[1, 1, 6] = True  # point 6 sees 2 places behind and 1, a run
    monkeypatch.setattr(PeriodicGrid, "_reach_table", lambda self, reach: (within, np.zeros(9, dtype=bool)))
    got = grid._window_max(lines, 1.0)
    want = np.maximum(np.maximum(lines, np.roll(lines, -1, axis=-1)), np.roll(lines, 1, axis=-1))
    want[:, 4] = lines[:, [3, 4, 5, 7]].max(axis=-1)
    want[:, 6] = lines[:, [4, 5, 6, 7]].max(axis=-1)
    assert np.array_equal(got, want)
