"""The Python API refuses what it cannot use with the argument named, as the files and the CLI do."""

import json
import os

import pytest

from jko_cvx import default_scene, load_run, load_scene, shipped_scene, simulate
from jko_cvx.cli import main
from jko_cvx.engine._state import file_sha256
from jko_cvx.engine.errors import RunDirError
from jko_cvx.scene import SceneError, scene_from_dict


def test_overrides_limits_and_flags_of_the_wrong_kind_are_named():
    with pytest.raises(TypeError, match="overrides must be a mapping of dotted scene keys"):
        shipped_scene("tab_bu_g1", [("v.n", 41)])
    with pytest.raises(TypeError, match="overrides must be a mapping"):
        default_scene("t_end=0.1")
    with pytest.raises(TypeError, match=r"limits must be a jko_cvx\.scene\.limits\.Limits or None, got str"):
        scene_from_dict(default_scene().to_dict(), limits="x")
    with pytest.raises(TypeError, match="allow_partial must be True or False"):
        load_run(".", allow_partial="yes")
    with pytest.raises(SceneError, match="replace: the scene has no key 'gama'"):
        default_scene().replace({"gama": 1.0})


def test_a_scene_path_that_is_not_a_regular_file_is_refused_without_reading_it(tmp_path):
    fifo = tmp_path / "scene.toml"
    os.mkfifo(fifo)  # reading it would block until a writer comes
    with pytest.raises(SceneError, match="is not a regular file"):
        load_scene(fifo)


def test_set_on_the_default_scene_is_checked_against_the_limits_as_it_runs(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("JKO_CVX_MAX_STEPS", "5")
    assert main(["run", "--set", "t_end=0.03", "--out", str(tmp_path / "r"), "--quiet"]) == 0  # 3 steps
    assert main(["run", "--out", str(tmp_path / "s"), "--quiet"]) == 2  # the default's 100 steps
    assert "JKO_CVX_MAX_STEPS" in capsys.readouterr().err and not (tmp_path / "s").exists()


def test_resume_refuses_a_scene_json_that_is_not_the_checkpoints_scene(tmp_path):
    """A scene.json replaced together with its digest (a deliberate edit): load_run refuses it, and so must resume,
    before the run continues under a record that names another scene."""
    scene = default_scene({"t_end": 0.03, "v.n": 41})
    out = tmp_path / "r"
    simulate(scene, out=out)
    (out / "verdict.json").unlink()  # as if interrupted
    meta = json.loads((out / "metadata.json").read_text())
    meta["digests"].pop("verdict.json", None)
    record = json.loads((out / "scene.json").read_text())
    (out / "scene.json").write_text(json.dumps({**record, "gamma": 1.5}, indent=2))
    meta["digests"]["scene.json"] = [file_sha256(out / "scene.json")]
    (out / "metadata.json").write_text(json.dumps(meta))
    with pytest.raises(RunDirError, match="does not record the scene the checkpoint was made from"):
        simulate(scene, out=out, resume=True)
