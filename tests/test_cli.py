"""The command line on tiny inputs: ``jko-cvx run SCENE`` writes the run of that scene, ``solve`` every method."""

import json

import numpy as np
import pandas as pd

from jko_cvx.cli import main
from jko_cvx.engine.loop import simulate
from jko_cvx.scene.model import load_scene

SCENE = """
name = "cli_tiny"
gamma = 1.0
t_end = 0.06
[v]
L = 2.0
n = 31
[initial]
kind = "gaussians"
amplitudes = [2.0]
rates = [2.0]
centres = [0.3]
[time]
dt = 0.02
[collision]
method = "newton"
beta = 100.0
fisher = "log"
"""


def test_run_command_writes_the_run_of_the_given_scene(tmp_path, capsys):
    path = tmp_path / "cli_tiny.toml"
    path.write_text(SCENE)
    out = tmp_path / "run"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    assert "cli_tiny" in capsys.readouterr().out
    direct = simulate(load_scene(path))
    on_disk = json.loads((out / "verdict.json").read_text())
    assert on_disk["steps"] == 3 and abs(on_disk["t"] - 0.06) < 1e-12
    assert {k: on_disk[k] for k in direct.verdict} == {k: direct.verdict[k] for k in direct.verdict}
    assert np.array_equal(np.load(out / "checkpoint.npz")["f"], direct.f)
    csv = pd.read_csv(out / "diagnostics.csv")
    np.testing.assert_allclose(csv.momentum, direct.diagnostics.momentum, rtol=1e-15)
    assert len(csv) == 4 and csv.momentum.iloc[-1] > 0.1  # the datum's mean velocity 0.3


def test_solve_command_prints_every_method_converged(capsys):
    assert main(["solve", "--n", "31", "--beta", "30"]) == 0
    out = capsys.readouterr().out
    for method in ("conic", "sqp", "newton"):
        assert f"method='{method}', status=CONVERGED" in out


def test_run_command_refuses_to_resume_a_checkpoint_of_another_scene(tmp_path, capsys):
    """--resume on a checkpoint left by another datum (amplitude 2.5 up to t = 0.04) is refused, naming
    what differs, and leaves the checkpoint untouched (issue 14: a resume never mixes two scenes)."""
    path, other = tmp_path / "cli_tiny.toml", tmp_path / "other.toml"
    path.write_text(SCENE)
    other.write_text(SCENE.replace("amplitudes = [2.0]", "amplitudes = [2.5]").replace("t_end = 0.06", "t_end = 0.04"))
    out = tmp_path / "run"
    first = simulate(load_scene(other), out=out)
    before = (out / "checkpoint.npz").read_bytes()
    assert main(["run", str(path), "--out", str(out), "--quiet", "--resume"]) == 2
    err = capsys.readouterr().err
    assert "initial.amplitudes: [2.5] -> [2.0]" in err and "t_end: 0.04 -> 0.06" in err
    assert (out / "checkpoint.npz").read_bytes() == before
    assert int(np.load(out / "checkpoint.npz")["step"]) == len(first.diagnostics) - 1
