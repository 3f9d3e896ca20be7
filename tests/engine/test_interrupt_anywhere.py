"""SIGINT at any moment of ``jko-cvx``: exit status 130 and a hint, never a traceback, and no
half-written figure."""

from __future__ import annotations

import json

import pytest

import jko_cvx.engine.plot as plot_module
import jko_cvx.scene.model as scene_model
from jko_cvx import load_run
from jko_cvx.cli import main
from jko_cvx.scene import scene_from_dict

from .test_rundir import SMALL


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "small.toml"
    scene_from_dict(SMALL)  # the document is a valid scene
    path.write_text(_toml(SMALL))
    return path


def _toml(doc: dict, prefix: str = "") -> str:
    scalars = {k: v for k, v in doc.items() if not isinstance(v, dict)}
    lines = [f"[{prefix}]"] if prefix and scalars else []
    lines += [f"{k} = {json.dumps(v)}" for k, v in scalars.items()]
    for k, v in doc.items():
        if isinstance(v, dict):
            lines.append(_toml(v, f"{prefix}.{k}" if prefix else k))
    return "\n".join(lines) + "\n"


def _interrupt(*args, **kwargs):
    raise KeyboardInterrupt


def test_sigint_while_the_figures_are_drawn_exits_130_with_the_run_complete(tmp_path, scene_file, monkeypatch, capsys):
    monkeypatch.setattr(plot_module, "save_figures", _interrupt)
    out = tmp_path / "run"
    assert main(["run", str(scene_file), "--out", str(out), "--quiet"]) == 130
    err = capsys.readouterr().err
    assert "interrupted while drawing the figures" in err and "--resume" in err
    assert load_run(out).verdict.stop is not None  # the run itself is whole and verified
    monkeypatch.undo()
    assert main(["run", str(scene_file), "--out", str(out), "--resume", "--quiet"]) == 0
    assert (out / "solution.png").stat().st_size > 0 and (out / "records.png").stat().st_size > 0


def test_sigint_while_loading_the_scene_exits_130(tmp_path, scene_file, monkeypatch, capsys):
    monkeypatch.setattr(scene_model, "load_scene", _interrupt)
    assert main(["run", str(scene_file), "--out", str(tmp_path / "run"), "--quiet"]) == 130
    assert "interrupted" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_a_figure_interrupted_mid_write_leaves_no_truncated_file(tmp_path, scene_file, monkeypatch):
    from matplotlib.figure import Figure

    out = tmp_path / "run"
    assert main(["run", str(scene_file), "--out", str(out), "--quiet"]) == 0
    before = (out / "solution.png").read_bytes()

    def half_then_interrupt(self, fname, **kwargs):
        with open(fname, "wb") as fh:
            fh.write(b"\x89PNG half")
        raise KeyboardInterrupt

    monkeypatch.setattr(Figure, "savefig", half_then_interrupt)
    assert main(["run", str(scene_file), "--out", str(out), "--resume", "--quiet"]) == 130
    assert (out / "solution.png").read_bytes() == before
    assert not [p.name for p in out.iterdir() if p.name.startswith(".solution.png.")]
