"""Python API misuse: each bad argument is refused before any work, naming the argument.

The classes here are those ``studies/misuse_api_probe.py`` found unclear on main before the
fixes (each of these tests fails there); the probe's table is in docs/guides/bad_input.md.
"""

from __future__ import annotations

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.engine.loop import simulate
from jko_cvx.evolve import evolve_fixed_grid
from jko_cvx.finite_volume import Cells, evolve_finite_volume
from jko_cvx.grid import PeriodicGrid
from jko_cvx.mesh.remapping import remap
from jko_cvx.scene.model import default_scene
from jko_cvx.studies.sweep import run_sweep
from jko_cvx.transport import transport_step

GRID = Grid.uniform(-2.0, 2.0, 21)
K = PowerKernel(1.0)
F = np.exp(-2 * GRID.points**2)


def test_grid_uniform_names_n_and_the_ends():
    with pytest.raises(ValueError, match=r"\bn must be an integer"):
        Grid.uniform(0.0, 1.0, None)
    with pytest.raises(ValueError, match=r"a and b must be"):
        Grid.uniform("0", 1.0, 5)
    with pytest.raises(ValueError, match=r"half_width must be"):
        PeriodicGrid.uniform("1", 5)
    with pytest.raises(ValueError, match=r"\bn must be an integer"):
        PeriodicGrid.uniform(1.0, None)


def test_evolve_fixed_grid_checks_before_stepping():
    with pytest.raises(ValueError, match="t_end"):
        evolve_fixed_grid(GRID, K, F, 0.01, "1")
    with pytest.raises(ValueError, match=r"f0 .*finite"):
        evolve_fixed_grid(GRID, K, np.where(GRID.points > 1, np.nan, F), 0.01, 0.05)
    with pytest.raises(ValueError, match=r"f0 must have shape \(21,\)"):
        evolve_fixed_grid(GRID, K, np.stack([F, F]), 0.01, 0.02)
    with pytest.raises(TypeError, match="stop_on_failure"):
        evolve_fixed_grid(GRID, K, F, 0.01, 0.02, stop_on_failure="no")
    with pytest.raises(TypeError, match="progress"):
        evolve_fixed_grid(GRID, K, F, 0.01, 0.02, progress="no")


def test_evolve_fixed_grid_refuses_an_absurd_step_count():
    # 5e298 steps: refused at once (it looped for ever before), naming dt and the limit
    with pytest.raises(ValueError, match=r"dt = 1e-300 .* steps.*JKO_CVX_MAX_STEPS"):
        evolve_fixed_grid(GRID, K, F, 1e-300, 0.05)


def test_evolve_finite_volume_names_non_numbers():
    cells = Cells(-2.0, 2.0, 20)
    with pytest.raises(ValueError, match="strength"):
        evolve_finite_volume(cells, K, np.ones(20), 0.1, strength="a")
    with pytest.raises(ValueError, match="max_steps"):
        evolve_finite_volume(cells, K, np.ones(20), 0.1, max_steps="x")
    with pytest.raises(ValueError, match="max_steps"):
        evolve_finite_volume(cells, K, np.ones(20), 0.1, max_steps=0)


def test_simulate_needs_a_scene(tmp_path):
    with pytest.raises(TypeError, match=r"scene must be a jko_cvx.scene.Scene .*load_scene"):
        simulate("scene.toml")
    with pytest.raises(TypeError, match="resume"):
        simulate(default_scene(), out=tmp_path / "run", resume="yes")
    assert not (tmp_path / "run").exists()


def _square(a):  # a sweep point function with source (run_sweep keys on it)
    return {"b": a * a}


def test_run_sweep_checks_the_points(tmp_path):
    with pytest.raises(TypeError, match=r"points must be .*mappings.*points\[0\]"):
        run_sweep(_square, [1, 2], tmp_path / "c", executor="serial", progress=False)
    with pytest.raises(TypeError, match=r"points\[0\] .*JSON"):
        run_sweep(_square, [{"a": object()}], tmp_path / "c", executor="serial", progress=False)
    assert not (tmp_path / "c").exists()


def test_remap_checks_its_arguments():
    new = Grid.uniform(-1.0, 1.0, 11)
    with pytest.raises(TypeError, match="old"):
        remap(GRID.points, F, new)
    with pytest.raises(TypeError, match="new"):
        remap(GRID, F, new.points)
    with pytest.raises(ValueError, match=r"\bf must be finite"):
        remap(GRID, np.where(GRID.points > 1, np.nan, F), new)
    with pytest.raises(ValueError, match="floor"):
        remap(GRID, F, new, floor=-1.0)


def test_transport_step_checks_its_arguments():
    xg = PeriodicGrid.uniform(1.0, 8)
    f = np.ones((8, 21))
    with pytest.raises(TypeError, match="xgrid"):
        transport_step(xg.points, GRID.points, f, 0.01)
    with pytest.raises(ValueError, match=r"\bf must be finite"):
        transport_step(xg, GRID.points, np.where(f > 0, np.nan, f), 0.01)
    with pytest.raises(ValueError, match="floor"):
        transport_step(xg, GRID.points, f, 0.01, floor=-1.0)


def test_conic_refuses_file_writing_solver_options(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    prob = CollisionProblem(GRID, K, F, 0.01, beta=10.0)
    for key in ("write_data_filename", "log_csv_filename"):
        with pytest.raises(ValueError, match=f"solver_options.*{key}"):
            solve_collision(prob, "conic", solver="SCS", solver_options={key: "leak.txt"})
    assert list(tmp_path.iterdir()) == []
