"""The command line on tiny inputs: ``jko-cvx run SCENE`` writes the run of that scene, ``solve`` every method."""

import json
import re

import numpy as np
import pandas as pd
import pytest

from jko_cvx.cli import main
from jko_cvx.engine.loop import simulate
from jko_cvx.scene.model import load_scene, scene_from_dict

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


def test_solve_command_prints_each_answers_error_estimate_in_f(capsys):
    """Beside each certified answer, the a posteriori estimate of its distance in f to the minimiser."""
    assert main(["solve", "--n", "31", "--beta", "30"]) == 0
    out = capsys.readouterr().out
    found = re.findall(r"error in f \(a posteriori estimate, relative to max f\): ([0-9.e+-]+)", out)
    answers = out.count("CollisionResult(")  # conic, sqp, newton, and nlp where IPOPT is installed
    assert answers >= 3 and len(found) == answers and all(float(e) < 1e-6 for e in found), out


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


# ---- what a newcomer reads first: the help of every option, the scene template and key reference ----


def _subcommands(parser=None, prefix=""):
    """``{"solve": parser, ..., "scene template": parser}``: every subcommand, nested ones included."""
    import argparse

    from jko_cvx.cli import build_parser

    out = {}
    for action in (parser or build_parser())._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out[prefix + name] = sub
                out.update(_subcommands(sub, f"{prefix}{name} "))
    return out


def test_every_option_of_every_subcommand_has_help_stating_its_default():
    """Help on every option; where the option has a default (not a flag, not None), the help states it
    (``%(default)s`` or in words: the formatted help must contain the default's text)."""
    import argparse

    missing, no_default = [], []
    for name, parser in _subcommands().items():
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            label = f"jko-cvx {name} {'/'.join(action.option_strings) or action.dest}"
            text = action.help % {**vars(action), "prog": parser.prog} if action.help else ""
            if not text.strip():
                missing.append(label)
                continue
            flag = isinstance(action, argparse._StoreTrueAction | argparse._StoreFalseAction)
            if flag or action.default is None or action.required or not action.option_strings:
                continue
            if str(action.default) not in text and "default" not in text:
                no_default.append(f"{label} (default {action.default!r})")
            elif str(action.default) not in text:
                no_default.append(f"{label} says 'default' but not {action.default!r}")
    assert not missing, f"options without help: {missing}"
    assert not no_default, f"options whose help does not state the default: {no_default}"


def test_solve_and_compare_take_the_problem_options_method_and_fisher():
    subs = _subcommands()
    for name in ("solve", "compare"):
        opts = {o for a in subs[name]._actions for o in a.option_strings}
        assert {"--gamma", "--n", "--L", "--dt", "--beta", "--fisher"} <= opts, name
    assert "--method" in {o for a in subs["solve"]._actions for o in a.option_strings}


def test_solve_method_restricts_the_methods_and_fisher_sets_the_form(capsys):
    assert main(["solve", "--n", "31", "--beta", "30", "--method", "newton", "sqp", "--fisher", "log"]) == 0
    out = capsys.readouterr().out
    assert "fisher='log'" in out.splitlines()[0]
    for method in ("newton", "sqp"):
        assert f"method='{method}', status=CONVERGED" in out
    assert "method='conic'" not in out


def test_solve_refuses_conic_on_the_log_form_naming_the_methods_that_pose_it(capsys):
    assert main(["solve", "--n", "31", "--method", "conic", "--fisher", "log"]) == 2
    err = capsys.readouterr().err
    assert "nlp" in err and "newton" in err and "status=" not in err


def test_scene_template_is_a_scene_run_accepts_as_written(tmp_path, capsys):
    """The printed template (every key, commented) loads with load_scene and runs two steps."""
    for kind in ("homogeneous", "inhomogeneous"):
        assert main(["scene", "template", "--kind", kind]) == 0
        text = capsys.readouterr().out
        path = tmp_path / f"{kind}.toml"
        path.write_text(text)
        scene = load_scene(path)
        assert scene.homogeneous is (kind == "homogeneous")
        short = scene.replace({"t_end": 2 * scene.time.dt, "output.every": 1, "output.checkpoint_every": 1})
        run = simulate(short, out=tmp_path / f"run_{kind}")
        assert run.steps == 2 and run.verdict.certified


def test_scene_template_leaves_resolved_defaults_absent(tmp_path, capsys):
    """The template writes the example scene's own keys, not the values the loader resolved from them: a key
    the example leaves at its default stays commented out, so a newcomer who edits the initial datum keeps
    ``refine.v.centre = "auto"`` (resolved against the new f0) and the method-dependent momentum constraint."""
    import tomllib

    assert main(["scene", "template"]) == 0
    text = capsys.readouterr().out
    doc = tomllib.loads(text)
    assert "centre" not in doc["refine"]["v"] and "conserve_momentum" not in doc["collision"]
    # a name of its own: run as written, it does not take the default scene's run directory
    assert doc["name"] == "my_homogeneous_scene" and "template" in doc["description"]
    doc["initial"]["centres"] = [0.6]
    assert scene_from_dict(doc).refine.v.centre == "follow"  # off-centre f0: the map follows it
    doc["initial"]["centres"] = [0.0]
    doc["collision"]["method"] = "sqp"
    assert scene_from_dict(doc).collision.method == "sqp"  # the paper's SQP without a momentum constraint


def test_scene_template_comments_every_key_with_type_and_default(capsys):
    """Every key of the reference is in the template under its own table, as ``key = value`` or commented
    out (``# key = value``, where the default is absent), right after a comment naming its type, the
    allowed values and the default."""
    import re
    import tomllib

    from jko_cvx.scene.initial import INITIAL_KINDS
    from jko_cvx.scene.model import scene_from_dict
    from jko_cvx.scene.reference import scene_keys

    def load_scene_text(lines):
        return scene_from_dict(tomllib.loads("\n".join(lines)))

    for kind in ("homogeneous", "inhomogeneous"):
        assert main(["scene", "template", "--kind", kind]) == 0
        lines = capsys.readouterr().out.splitlines()
        found, table = set(), ""
        for i, line in enumerate(lines):
            head = re.fullmatch(r"(?:# )?\[([a-z.]+)\]", line)
            if head:  # a table key: its section, under its meaning
                table = head.group(1)
                assert lines[i - 1].startswith("# ") and len(lines[i - 1]) > 4, f"no meaning above {line!r}"
                found.add(table)
                continue
            m = re.match(r"(?:# )?([A-Za-z_0-9]+) = ", line)
            if m and i > 0 and lines[i - 1].startswith("# type:"):
                assert "allowed:" in lines[i - 1] and "default:" in lines[i - 1], lines[i - 1]
                assert lines[i - 2].startswith("# ") and len(lines[i - 2]) > 4, f"no meaning above {line!r}"
                found.add(f"{table}.{m.group(1)}" if table else m.group(1))
        own = {f"initial.{name}" for name in INITIAL_KINDS[load_scene_text(lines).initial.kind].__dataclass_fields__}
        other = {k for k in scene_keys() if k.startswith("initial.") and k != "initial.kind"} - own
        missing = [k for k in scene_keys() if k not in found and k not in other]
        assert not missing, f"{kind}: keys not in the template: {missing}"


def test_scene_keys_prints_every_key_with_type_range_default_and_meaning(capsys):
    from jko_cvx.scene.reference import key_entries, scene_keys

    assert main(["scene", "keys"]) == 0
    out = capsys.readouterr().out
    entries = {e.key: e for e in key_entries()}
    assert set(scene_keys()) <= set(entries)
    rows = {ln.split()[0]: ln for ln in out.splitlines() if ln and not ln.startswith((" ", "-", "key"))}
    for k, e in entries.items():
        assert k in rows, k
        assert e.meaning and e.meaning in out, k
        assert e.type in rows[k] and e.default in rows[k], (k, rows[k])


def test_a_resumed_run_reports_wall_time_over_both_legs(tmp_path, capsys, monkeypatch):
    """Interrupted after a slow first leg (0.3 s per collision solve, imposed), then resumed: the wall
    time printed is the run's over both legs, as for an uninterrupted run: at least the collision time
    (which sums both legs), and the value verdict.json records."""
    import time as _time

    import jko_cvx.engine.loop as loop
    from jko_cvx.engine.loop import Stepper

    from .engine._inject import interrupted_commit

    path = tmp_path / "cli_tiny.toml"
    longer = SCENE.replace("t_end = 0.06", "t_end = 0.1")
    path.write_text(longer.replace("[time]", "[output]\ncheckpoint_every = 1\n[time]"))
    out = tmp_path / "run"
    real_solve = loop.solve_collision

    def slow(problem, **kw):
        _time.sleep(0.3)
        return real_solve(problem, **kw)

    monkeypatch.setattr(loop, "solve_collision", slow)
    monkeypatch.setattr(Stepper, "commit", interrupted_commit(3))
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 130
    monkeypatch.undo()
    capsys.readouterr()
    assert main(["run", str(path), "--out", str(out), "--quiet", "--resume"]) == 0
    text = capsys.readouterr().out
    import re

    wall, coll = (float(x) for x in re.search(r"wall ([\d.]+) s \(collision ([\d.]+) s", text).groups())
    seconds = json.loads((out / "verdict.json").read_text())["seconds"]
    assert coll >= 0.55  # two committed solves of the first leg, 0.3 s each
    assert wall >= coll, text
    assert abs(wall - seconds["wall"]) < 0.01


# ---- --set KEY=VALUE: scene keys overridden from the command line, validated as in a file ----


def test_set_overrides_scene_keys_as_a_file_would(tmp_path, capsys):
    path = tmp_path / "cli_tiny.toml"
    path.write_text(SCENE)
    out = tmp_path / "run"
    argv = ["run", str(path), "--set", "v.n=21", "--set", "t_end=0.04", "--set", "collision.method=sqp",
            "--set", "collision.conserve_momentum=false", "--out", str(out), "--quiet"]  # fmt: skip
    assert main(argv) == 0
    edited = SCENE.replace("n = 31", "n = 21").replace("t_end = 0.06", "t_end = 0.04")
    edited = edited.replace('method = "newton"', 'method = "sqp"\nconserve_momentum = false')
    other = tmp_path / "edited.toml"
    other.write_text(edited)
    direct = simulate(load_scene(other))
    assert json.loads((out / "scene.json").read_text()) == load_scene(other).to_dict()
    assert np.array_equal(np.load(out / "checkpoint.npz")["f"], direct.f)
    # the same overrides resume the run; without them the scene differs and the resume is refused
    assert main([*argv[:-3], "--out", str(out), "--quiet", "--resume"]) == 0
    assert main(["run", str(path), "--out", str(out), "--quiet", "--resume"]) == 2
    assert "v.n: 21 -> 31" in capsys.readouterr().err


def test_the_header_says_what_set_changed_and_escapes_control_characters(tmp_path, capsys):
    """The description is the scene file's words: after --set it may describe another scene, and a control
    character in it (an ANSI escape) must not reach the terminal raw."""
    path = tmp_path / "described.toml"
    path.write_text(SCENE.replace('name = ', 'description = "gamma = 1 \\u001b[2Jcleared"\nname = ', 1))
    argv = ["run", str(path), "--set", "t_end=0.04", "--set", "v.n=21", "--out", str(tmp_path / "r"), "--quiet"]
    assert main(argv) == 0
    header = capsys.readouterr().out.splitlines()[0]
    assert header.endswith("-- gamma = 1 \\x1b[2Jcleared [--set: t_end = 0.04, v.n = 21]"), header
    assert "\x1b" not in header


def test_set_on_the_default_scene_and_a_shipped_one(tmp_path):
    from jko_cvx.cli import _load, _setting

    sets = [_setting("v.n=61"), _setting("stop.eps_v=1e-3"), _setting("collision.beta=inf")]
    scene = _load(None, sets)
    assert (scene.v.n, scene.stop.eps_v, scene.collision.beta) == (61, 1e-3, float("inf"))
    assert _load(None, None) == _load(None, [])
    shipped = _load("tab_bu_g1", [_setting("initial.centres=[0.3]"), _setting('refine.v.centre="follow"')])
    assert shipped.initial.centres == (0.3,) and shipped.refine.v.centre == "follow"


def test_bad_set_values_are_refused_naming_the_key_before_anything_is_written(tmp_path, capsys):
    out = tmp_path / "run"
    cases = {
        "v.nn=41": "did you mean 'v.n'?",  # a misspelt key, as in a file
        "v.n=4 1": "v.n: the value must be a TOML value",  # not a value
        "v.n=41.5": "v.n must be of type int",  # the schema's types
        "gamma=-1": "gamma must be a finite number > 0",  # and ranges
        "=3": "must be KEY=VALUE",
        "v.n": "must be KEY=VALUE",
        "v..n=3": "must be KEY=VALUE",
        # more TOML after the value is not a second override: it is refused, not dropped
        "strength=1.0\nstrength_typo=2.0": "strength: one TOML value, nothing after it",
        "gamma=1.0\n[stop]\neps_v=0.5": "gamma: one TOML value, nothing after it",
    }

    def exit_code(argv):  # argparse's own refusals exit (status 2) instead of returning
        try:
            return main(argv)
        except SystemExit as exc:
            return exc.code

    for arg, message in cases.items():
        assert exit_code(["run", "--set", arg, "--out", str(out), "--quiet"]) == 2, arg
        assert message in capsys.readouterr().err, arg
        assert not out.exists(), arg
    assert main(["run", "--set", "v.n=41", "--set", "v.n=61", "--out", str(out), "--quiet"]) == 2
    assert "--set v.n is given twice" in capsys.readouterr().err and not out.exists()
    assert main(["compare", "--set", "v.n=41"]) == 2
    assert "give a scene" in capsys.readouterr().err


def test_a_closed_pipe_ends_the_command_quietly(monkeypatch, capsys):
    import jko_cvx.cli as cli

    def reader_gone(argv):
        raise BrokenPipeError(32, "Broken pipe")  # what print() raises once `| head` has exited

    monkeypatch.setattr(cli, "_main", reader_gone)
    assert cli.main(["scene", "keys"]) == 141
    assert capsys.readouterr().err == ""


def test_a_misspelt_shipped_scene_name_is_answered_with_the_close_ones(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["run", "inhom_gamma3_lambda44", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "did you mean the shipped scene 'inhom_gamma3_lambda4'" in err and not (tmp_path / "runs").exists()


def test_scene_list_names_every_shipped_scene_with_its_description(capsys):
    from jko_cvx.scene import shipped_scene, shipped_scene_names

    assert main(["scene", "list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(shipped_scene_names())
    for line, name in zip(lines, shipped_scene_names(), strict=True):
        assert line.split()[0] == name and line.endswith(shipped_scene(name).description)


@pytest.mark.parametrize("command", ["solve", "compare"])
def test_a_built_in_problem_too_large_is_refused_naming_n(command, capsys, monkeypatch):
    monkeypatch.setenv("JKO_CVX_MAX_GIB", "1")
    assert main([command, "--n", "30000"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jko-cvx: error: --n = 30000 needs an estimated") and "JKO_CVX_MAX_GIB" in err


def test_running_out_of_memory_is_one_line_not_a_traceback(capsys, monkeypatch):
    import jko_cvx.cli as cli

    def exhausted(*args, **kwargs):
        raise MemoryError("Unable to allocate 6.7 GiB for an array with shape (30000, 30000)")

    monkeypatch.setattr(cli, "solve_collision", exhausted)
    assert main(["solve", "--n", "41", "--method", "newton"]) == 2
    assert "jko-cvx: error: Unable to allocate 6.7 GiB" in capsys.readouterr().err


def test_the_size_check_counts_only_the_methods_that_run(capsys, monkeypatch):
    """conic's blocks (800 N^2 doubles at gamma = 3) do not refuse a Newton-only solve, nor the log form, which
    conic does not pose."""
    monkeypatch.setenv("JKO_CVX_MAX_GIB", "0.1")  # conic at gamma = 3 would need ~0.5 GiB at n = 281
    args = ["--gamma", "3", "--n", "281", "--dt", "0.001"]
    assert main(["solve", *args]) == 2 and "--n = 281 needs an estimated" in capsys.readouterr().err
    assert main(["solve", *args, "--method", "newton"]) == 0
    assert main(["solve", *args, "--fisher", "log", "--method", "newton", "sqp"]) == 0
    capsys.readouterr()
