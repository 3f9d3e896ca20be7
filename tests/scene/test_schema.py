"""The scene schema: strict tables, ranges at and around every bound, names, paths, limits, options."""

import copy
import dataclasses
import importlib.util
import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from jko_cvx.scene.initial import GaussiansInitial
from jko_cvx.scene.limits import Limits, estimate_size
from jko_cvx.scene.model import (
    Scene,
    SceneError,
    load_scene,
    scene_from_dict,
    shipped_scene,
    shipped_scene_names,
    with_overrides,
)
from jko_cvx.scene.options import METHOD_OPTIONS

ROOT = Path(__file__).parents[2]
SCENES = ROOT / "jko_cvx" / "scene" / "shipped"

# Every value distinct from every other, so that a key read into the wrong field fails.
BASE = {
    "name": "base",
    "gamma": 1.25,
    "strength": 0.75,
    "t_end": 0.2,
    "v": {"L": 2.5, "n": 23},
    "x": {"L": 3.5, "n": 19, "conserve_moment": False},
    "initial": {"kind": "gaussians", "amplitudes": [1.5], "rates": [2.25], "centres": [0.125]},
    "time": {"policy": "halving", "dt": 0.05, "eps_t": 1e-4, "halve_on": "max_iterations"},
    "refine": {
        "concentration_set": "quadrant",
        "v": {"bumps": 2, "delta0": 0.3, "delta": 0.6, "tol": 0.15},
        "x": {"bumps": 1, "delta0": 0.35, "delta": 0.65, "tol": 0.05},
    },
    "collision": {"method": "newton", "beta": 700.0, "fisher": "log", "conserve_momentum": False},
    "stop": {"eps_v": 2e-4, "eps_x": 3e-4, "spread_v": 0.04, "on_solver_failure": False},
    "output": {"every": 7, "times": [0.15, 0.05], "checkpoint_every": 9},
}


def _set(dotted, value, base=BASE):
    return with_overrides(base, {dotted: value})


def test_base_scene_maps_every_key_to_its_field():
    s = scene_from_dict(BASE)
    assert (s.name, s.gamma, s.strength, s.t_end) == ("base", 1.25, 0.75, 0.2)
    assert (s.v.L, s.v.n, s.x.L, s.x.n, s.x.conserve_moment) == (2.5, 23, 3.5, 19, False)
    assert s.initial == GaussiansInitial(amplitudes=(1.5,), rates=(2.25,), centres=(0.125,))
    assert s.initial.kind == "gaussians"
    assert (s.time.policy, s.time.dt, s.time.eps_t, s.time.halve_on) == ("halving", 0.05, 1e-4, "max_iterations")
    assert s.refine.concentration_set == "quadrant"
    assert (s.refine.v.bumps, s.refine.v.delta0, s.refine.v.delta, s.refine.v.tol) == (2, 0.3, 0.6, 0.15)
    assert (s.refine.x.bumps, s.refine.x.delta0, s.refine.x.delta, s.refine.x.tol) == (1, 0.35, 0.65, 0.05)
    assert (s.collision.method, s.collision.beta, s.collision.problem_fisher, s.collision.conserve_momentum) == (
        "newton",
        700.0,
        "log",
        False,
    )
    assert (s.stop.eps_v, s.stop.eps_x, s.stop.spread_v, s.stop.on_solver_failure) == (2e-4, 3e-4, 0.04, False)
    assert (s.output.every, s.output.times, s.output.checkpoint_every) == (7, (0.05, 0.15), 9)


# (dotted key, how to read it back, accepted values, refused values): at and around each bound
BOUNDS = [
    ("gamma", lambda s: s.gamma, [1e-6, 3.0], [0.0, -1e-9, math.nan, math.inf, 1e-320, 1e300]),
    ("strength", lambda s: s.strength, [1e-9, 155.0], [0.0, -1e-9, math.inf]),
    ("t_end", lambda s: s.t_end, [0.15, 4.0], [0.0, -1e-9, math.inf]),
    ("v.L", lambda s: s.v.L, [1e-3, 5.0], [0.0, -1e-9, math.inf]),
    ("v.n", lambda s: s.v.n, [3, 4], [2, 0, -3]),
    ("x.L", lambda s: s.x.L, [1e-3, 5.0], [0.0, -1e-9]),
    ("x.n", lambda s: s.x.n, [3, 4], [2, 0]),
    ("time.dt", lambda s: s.time.dt, [2e-4, 0.5], [0.0, -1e-9, math.inf, math.nan]),
    ("time.eps_t", lambda s: s.time.eps_t, [1e-12, 0.0499], [0.0, -1e-9, 0.05, 0.06]),  # halving: eps_t < dt
    ("refine.v.delta0", lambda s: s.refine.v.delta0, [1e-9, 0.999999], [0.0, 1.0, -1e-9, 1.000001]),
    ("refine.v.delta", lambda s: s.refine.v.delta, [1e-9, 0.999999], [0.0, 1.0, -1e-9, 1.000001]),
    ("refine.x.delta0", lambda s: s.refine.x.delta0, [1e-9, 0.999999], [0.0, 1.0]),
    ("refine.x.delta", lambda s: s.refine.x.delta, [1e-9, 0.999999], [0.0, 1.0]),
    ("refine.v.tol", lambda s: s.refine.v.tol, [0.0, 0.999999], [1.0, -1e-9]),
    ("refine.v.bumps", lambda s: s.refine.v.bumps, [1, 2], [0, 3]),
    ("collision.beta", lambda s: s.collision.beta, [math.inf, 1e-3, 1e300], [0.0, -1.0, -math.inf, math.nan, 1e-300]),
    ("stop.eps_v", lambda s: s.stop.eps_v, [0.0, 1e-12], [-1e-12, math.inf, math.nan]),
    ("stop.eps_x", lambda s: s.stop.eps_x, [0.0, 1e-12], [-1e-12, math.inf]),
    ("stop.spread_v", lambda s: s.stop.spread_v, [0.0, 1e-12], [-1e-12, math.inf]),
    ("output.every", lambda s: s.output.every, [1, 2], [0, -1]),
    ("output.checkpoint_every", lambda s: s.output.checkpoint_every, [1, 2], [0, -1]),
    ("output.times", lambda s: s.output.times, [[0.0, 0.2], []], [[-1e-9], [0.2 * (1 + 1e-9)], [math.nan]]),
    ("initial.rates", lambda s: s.initial.rates, [[1e-9], [40.0]], [[0.0], [-1e-9], [math.inf]]),
    ("initial.amplitudes", lambda s: s.initial.amplitudes, [[1e-9], [2.0]], [[0.0], [-1e-9]]),
]


@pytest.mark.parametrize("dotted, read, good, bad", BOUNDS, ids=[b[0] for b in BOUNDS])
def test_each_bound_accepts_inside_and_refuses_outside_naming_the_key(dotted, read, good, bad):
    for val in good:
        s = scene_from_dict(_set(dotted, val))
        got = read(s)
        want = tuple(sorted(val)) if dotted == "output.times" else tuple(val) if isinstance(val, list) else val
        assert got == want or (isinstance(want, float) and got == pytest.approx(want, rel=0, abs=0)), (dotted, val)
    for val in bad:
        with pytest.raises(SceneError, match=re.escape(dotted)):
            scene_from_dict(_set(dotted, val))


@pytest.mark.parametrize(
    "dotted, typo, suggestion",
    [
        ("", "gama", "gamma"),
        ("v", "nn", "v.n"),
        ("x", "conserve_moments", "x.conserve_moment"),
        ("initial", "rate", "initial.rates"),
        ("time", "dtt", "time.dt"),
        ("refine", "vv", None),
        ("refine.v", "delta_0", "refine.v.delta0"),
        ("refine.x", "tols", "refine.x.tol"),
        ("collision", "betaa", "collision.beta"),
        ("collision.options", "tols", "collision.options.tol"),
        ("stop", "eps_vv", "stop.eps_v"),
        ("output", "evry", "output.every"),
    ],
)
def test_unknown_key_in_every_table_is_named_with_the_closest_valid_one(dotted, typo, suggestion):
    d = copy.deepcopy(BASE)
    d["collision"]["options"] = {"tol": 1e-9}
    node = d
    for part in filter(None, dotted.split(".")):
        node = node[part]
    node[typo] = node.get(typo, 1)
    full = f"{dotted}.{typo}" if dotted else typo
    msg = f"did you mean '{suggestion}'" if suggestion else "allowed"
    with pytest.raises(SceneError, match=rf"\['{full}'\].*{msg}"):
        scene_from_dict(d)


def test_solver_options_typo_is_named_with_the_closest_valid_one():
    d = _set("collision", {"method": "conic", "fisher": "perspective", "options": {"solver_options": {"eps_abss": 1}}})
    with pytest.raises(SceneError, match=r"collision\.options\.solver_options\.eps_abss.*tol_gap_abs|CLARABEL"):
        scene_from_dict(d)


@pytest.mark.parametrize(
    "dotted, value",
    [
        ("v", 5),
        ("x", "grid"),
        ("initial", "gaussians"),
        ("time", 0.01),
        ("refine", 1),
        ("refine.v", 0.5),
        ("collision", "newton"),
        ("collision.options", 5),
        ("stop", 1e-3),
        ("output", [1, 2]),
    ],
)
def test_a_section_given_as_a_scalar_is_refused_naming_it(dotted, value):
    with pytest.raises(SceneError, match=re.escape(dotted) + " must be a table"):
        scene_from_dict(_set(dotted, value))


def test_the_document_itself_must_be_a_table():
    with pytest.raises(SceneError, match="scene must be a table"):
        scene_from_dict([1, 2])


@pytest.mark.parametrize(
    "dotted, value, kind",
    [
        ("x.conserve_moment", 1, "bool"),
        ("collision.conserve_momentum", "true", "bool"),
        ("stop.on_solver_failure", 0, "bool"),
        ("v.n", 23.0, "int"),
        ("v.n", True, "int"),
        ("output.every", False, "int"),
        ("gamma", True, "float"),
        ("gamma", "1.0", "float"),
        ("name", 5, "str"),
        ("collision.method", 1, "str"),
    ],
)
def test_types_are_checked_and_bools_are_real_bools(dotted, value, kind):
    with pytest.raises(SceneError, match=re.escape(dotted) + f" must be of type {kind}"):
        scene_from_dict(_set(dotted, value))


@pytest.mark.parametrize(
    "dotted, value",
    [
        ("collision.method", "Newton"),
        ("collision.fisher", "fisher"),
        ("time.policy", "adaptive"),
        ("time.halve_on", "e_f"),
        ("refine.concentration_set", "paper"),
        ("collision.options.safeguard", "literal"),
        ("initial.kind", "gauss"),
        ("refine.v.bumps", 3),
    ],
)
def test_enumerations_are_closed(dotted, value):
    d = _set("collision.method", "sqp", _set("collision.conserve_momentum", None)) if "safeguard" in dotted else BASE
    with pytest.raises(SceneError, match=re.escape(dotted) + " must be one of"):
        scene_from_dict(_set(dotted, value, d))


@pytest.mark.parametrize(
    "dotted, allowed",
    [
        ("time.halve_on", "['any_failure', 'max_iterations']"),
        ("refine.concentration_set", "['projections', 'quadrant']"),
    ],
)
def test_paper_switches_name_their_allowed_values_and_default_to_the_shipped_rule(dotted, allowed):
    with pytest.raises(SceneError, match=re.escape(f"{dotted} must be one of {allowed}, got 'paper'")):
        scene_from_dict(_set(dotted, "paper"))
    plain = scene_from_dict(_set("refine.concentration_set", None, _set("time.halve_on", None)))
    assert (plain.time.halve_on, plain.refine.concentration_set) == ("any_failure", "projections")


@pytest.mark.parametrize("name", ["a", "tab_bu_g1", "run-2.v3", "A.B_c-1", "x" * 128])
def test_plain_file_names_are_accepted(name):
    assert scene_from_dict(_set("name", name)).name == name


@pytest.mark.parametrize("name", ["", "../../x", "a/b", "a\\b", ".hidden", "..", "a..b", "a b", "x" * 129, "é"])
def test_names_that_are_not_plain_file_names_are_refused(name):
    with pytest.raises(SceneError, match="name must be a plain file name"):
        scene_from_dict(_set("name", name))


@pytest.mark.parametrize(
    "changes, match",
    [
        ({"collision": {"method": "conic", "fisher": "log"}}, "collision.fisher"),
        ({"collision": {"method": "sqp", "conserve_momentum": True}}, "collision.conserve_momentum"),
        ({"x": None, "refine": {"x": {}}}, r"refine\.x needs an \[x\] grid"),
        ({"x": None, "refine": None, "stop": {"eps_x": 1e-3}}, r"stop\.eps_x needs an \[x\] grid"),
        ({"x": None, "refine": None, "initial": {"kind": "gamma2", "a": 1.0, "b": 2.0, "x1": 0.1}}, r"\[x\] grid"),
        ({"initial": {"kind": "gaussians", "amplitudes": [1.0, 2.0], "rates": [2.0], "centres": [0.0]}}, "same length"),
        ({"initial": {"kind": "gaussians", "amplitudes": [0.0], "rates": [2.0], "centres": [0.0]}}, "no mass"),
        ({"initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [1e4], "centres": [1e3]}}, "f0 is zero"),
        ({"initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0]}}, "initial.centres is required"),
        ({"initial": {"amplitudes": [1.0]}}, "initial.kind is required"),
        ({"gamma": 40.0, "v": {"L": 1e9, "n": 5}}, "gamma = 40 makes the kernel"),
        ({"time.policy": "fixed", "time.halve_on": "max_iterations"}, r"time\.halve_on = 'max_iterations' needs"),
        ({"time.policy": "cfl", "time.halve_on": "max_iterations"}, r"time\.halve_on .* never halves"),
        ({"x": None, "refine.x": None}, r"refine\.concentration_set .*\[x\] grid"),
        ({"refine.v": None, "refine.x": None}, r"needs \[refine\.v\] or \[refine\.x\]"),
    ],
)
def test_inconsistent_combinations_are_refused(changes, match):
    d = with_overrides(BASE, changes)
    with pytest.raises(SceneError, match=match):
        scene_from_dict(d)


# --- solver options: an allow-list per method, nothing that writes files ------------------


@pytest.mark.parametrize("option", ["write_data_filename", "log_csv_filename"])
def test_file_writing_solver_options_are_refused_naming_the_key(option):
    opts = {"solver": "SCS", "solver_options": {option: "/tmp/leak"}}
    d = _set("collision", {"method": "conic", "fisher": "perspective", "options": opts})
    with pytest.raises(SceneError, match=rf"collision\.options\.solver_options\.{option}.*write files"):
        scene_from_dict(d)


@pytest.mark.parametrize(
    "method, options, match",
    [
        ("newton", {"m0": [0.0]}, r"collision\.options\.m0"),
        ("sqp", {"callback": "print"}, r"collision\.options\.callback"),
        ("newton", {"tol": 2.0}, r"collision\.options\.tol must be in \(0, 1\)"),
        ("newton", {"max_iter": 0}, r"collision\.options\.max_iter must be an integer >= 1"),
        ("newton", {"check_convexity": "no"}, r"collision\.options\.check_convexity must be of type bool"),
        ("sqp", {"step": 1.5}, r"collision\.options\.step must be in \(0, 1\]"),
        ("conic", {"solver": "GUROBI"}, r"collision\.options\.solver must be one of"),
        ("conic", {"solver_options": {"max_iter": 0.5}}, r"solver_options\.max_iter must be of type int"),
        ("conic", {"solver_options": 5}, r"collision\.options\.solver_options must be a table"),
    ],
)
def test_solver_options_are_checked_before_the_run(method, options, match):
    fisher = "perspective" if method == "conic" else "log"
    d = _set("collision", {"method": method, "fisher": fisher, "options": options})
    with pytest.raises(SceneError, match=match):
        scene_from_dict(d)


def test_allowed_solver_options_reach_the_scene_unchanged():
    d = _set("collision", {"method": "newton", "fisher": "log", "options": {"tol": 1e-9, "max_iter": 40}})
    assert scene_from_dict(d).collision.options == {"tol": 1e-9, "max_iter": 40}
    opts = {"solver": "CLARABEL", "tol": 1e-8, "solver_options": {"max_iter": 300, "time_limit": 60.0}}
    d = _set("collision", {"method": "conic", "fisher": "perspective", "options": opts})
    assert scene_from_dict(d).collision.options == opts


def test_allow_list_names_options_of_the_solvers():
    """Every allowed option is a keyword of the method, or refused with a clear error where this version lacks it."""
    import inspect

    from jko_cvx.collision.solve import METHODS

    for method, allowed in METHOD_OPTIONS.items():
        params = inspect.signature(METHODS[method]).parameters
        assert "callback" not in allowed and "m0" not in allowed
        for name, rule in allowed.items():
            if name in params:
                continue
            value = {"float": 0.5, "int": 1, "bool": True, "str": (rule.choices or ("x",))[0], "table": {}}[rule.kind]
            fisher = "perspective" if method == "conic" else "log"
            d = _set("collision", {"method": method, "fisher": fisher, "options": {name: value}})
            with pytest.raises(SceneError, match=rf"collision\.options\.{name} is not an option of method"):
                scene_from_dict(d)


# --- paths, shipped scenes, overrides ------------------------------------------------------


def test_a_directory_or_missing_file_as_the_scene_is_named(tmp_path):
    with pytest.raises(SceneError, match=rf"{tmp_path.name}' is a directory"):
        load_scene(tmp_path)
    with pytest.raises(SceneError, match=r"scene file not found: .*nothere\.toml"):
        load_scene(tmp_path / "nothere.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("gamma = [1\n")
    with pytest.raises(SceneError, match=r"bad\.toml' is not valid TOML"):
        load_scene(bad)
    bad.write_bytes(b"\xff\xfe gamma = 1\n")
    with pytest.raises(SceneError, match=r"bad\.toml' is not UTF-8 text"):
        load_scene(bad)


def test_shipped_scenes_are_package_data_and_load_by_name():
    files = sorted(p.stem for p in SCENES.glob("*.toml"))
    assert shipped_scene_names() == files and len(files) >= 13
    for name in files:
        assert shipped_scene(name) == load_scene(SCENES / f"{name}.toml") == load_scene(name)
        assert shipped_scene(name).name == name
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "shipped/*.toml" in pyproject["tool"]["setuptools"]["package-data"]["jko_cvx.scene"]
    with pytest.raises(SceneError, match="no shipped scene 'tab_bu_g9'"):
        shipped_scene("tab_bu_g9")


def test_overrides_set_dotted_keys_and_are_validated_like_the_file():
    s = shipped_scene("tab_bu_g1", {"time.dt": 0.005, "stop.eps_v": 1e-5, "refine.v.delta0": 0.25, "x": None})
    assert (s.time.dt, s.stop.eps_v, s.refine.v.delta0) == (0.005, 1e-5, 0.25)
    assert shipped_scene("tab_bu_g1").time.dt == 0.01  # the file is not changed
    with pytest.raises(SceneError, match=r"unknown key\(s\) \['time\.dtt'\]"):
        shipped_scene("tab_bu_g1", {"time.dtt": 0.005})
    with pytest.raises(SceneError, match=r"override 'gamma\.x': gamma is not a table"):
        shipped_scene("tab_bu_g1", {"gamma.x": 1.0})


@pytest.mark.parametrize(
    "overrides",
    [{"v.n": 61, "v": {"L": 2.0, "n": 41}}, {"v": {"L": 2.0, "n": 41}, "v.n": 61},
     {"refine.v.delta": 0.3, "refine.v": {"bumps": 1}}, {"refine": {"v": {"bumps": 1}}, "refine.v.delta": 0.3}],
)  # fmt: skip
def test_overrides_of_a_table_and_of_one_of_its_keys_are_refused(overrides):
    # one would silently drop the other, whichever order they come in
    a, b = sorted(overrides, key=len)
    with pytest.raises(SceneError, match=rf"overrides '{re.escape(a)}' and '{re.escape(b)}' overlap"):
        shipped_scene("tab_bu_g1", overrides)
    with pytest.raises(SceneError, match=rf"overrides '{re.escape(a)}' and '{re.escape(b)}' overlap"):
        shipped_scene("tab_bu_g1").replace(overrides)  # Scene.replace as well


def test_to_dict_is_canonical_sorted_and_complete():
    s = scene_from_dict(BASE)
    d = s.to_dict()
    assert set(d) == {f.name for f in dataclasses.fields(Scene)}
    assert json.dumps(d) == json.dumps(d, sort_keys=True)
    assert list(d["refine"]["v"]) == sorted(d["refine"]["v"]) and list(d["initial"]) == sorted(d["initial"])
    assert scene_from_dict(d) == s and scene_from_dict(json.loads(json.dumps(d))) == s
    # the same scene written in another order, with defaults spelled out, gives the same dict
    shuffled = {k: BASE[k] for k in reversed(list(BASE))}
    shuffled = with_overrides(shuffled, {"description": "", "collision.options": {}})
    assert scene_from_dict(shuffled).to_dict() == d
    minimal = {k: BASE[k] for k in ("gamma", "t_end", "v", "initial")} | {"time": {"dt": 0.05}}
    full = scene_from_dict(minimal).to_dict()
    assert full["stop"]["eps_v"] == 0.0 and full["output"]["every"] == 10
    assert full["collision"]["fisher"] == "perspective" and full["collision"]["beta"] == math.inf
    assert "x" not in full and full["refine"] == {"concentration_set": "projections"}
    assert scene_from_dict(full) == scene_from_dict(minimal)


# --- size limits ---------------------------------------------------------------------------


def test_huge_grid_and_tiny_step_are_refused_before_anything_is_built():
    with pytest.raises(SceneError, match=r"v\.n = 10000000.* needs an estimated .* TiB.*JKO_CVX_MAX_GIB"):
        scene_from_dict(_set("v.n", 10**7))
    with pytest.raises(SceneError, match=r"time\.dt = 1e-300 .* 2e\+299 steps.*JKO_CVX_MAX_STEPS"):
        scene_from_dict(_set("time", {"dt": 1e-300}))


def test_limits_hold_at_and_around_the_bound(monkeypatch):
    s = scene_from_dict(BASE)
    est = estimate_size(s)
    assert est.steps == 4  # t_end / dt = 0.2 / 0.05
    scene_from_dict(BASE, Limits(max_steps=4))
    with pytest.raises(SceneError, match="about 4 steps, above the limit of 3"):
        scene_from_dict(BASE, Limits(max_steps=3))
    gib = est.bytes / 2**30
    scene_from_dict(BASE, Limits(max_gib=gib))
    with pytest.raises(SceneError, match="needs an estimated"):
        scene_from_dict(BASE, Limits(max_gib=gib * (1 - 1e-9)))
    tiny = _set("time", {"dt": 1e-6})  # 2e5 steps
    monkeypatch.setenv("JKO_CVX_MAX_STEPS", "1e5")
    with pytest.raises(SceneError, match="above the limit of 1e"):
        scene_from_dict(tiny)
    monkeypatch.setenv("JKO_CVX_MAX_STEPS", "3e5")
    assert scene_from_dict(tiny).time.dt == 1e-6
    monkeypatch.setenv("JKO_CVX_MAX_STEPS", "many")
    with pytest.raises(SceneError, match="JKO_CVX_MAX_STEPS must be a number > 0, got 'many'"):
        scene_from_dict(BASE)


def test_cfl_step_estimate_uses_the_grid():
    s = scene_from_dict(_set("time", {"policy": "cfl", "dt": 0.05}))
    # dt = min(0.05, 0.9 dv / L_v, 0.9 dx / L_x): dv = 5/22, dx = 7/19
    dt = min(0.05, 0.9 * (5 / 22) / 2.5, 0.9 * (7 / 19) / 3.5)
    assert estimate_size(s).steps == math.ceil(0.2 / dt)


# --- the CLI: one line, exit 2, nothing written --------------------------------------------


def _probe_cases():
    spec = importlib.util.spec_from_file_location("misuse_probe", ROOT / "studies" / "misuse_probe.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.CASES


@pytest.mark.parametrize("case", _probe_cases(), ids=lambda c: c[1])
def test_every_misuse_class_gives_one_line_naming_the_key_and_writes_nothing(case, tmp_path, monkeypatch, capsys):
    from jko_cvx.cli import main

    _, _, key, text, args = case
    monkeypatch.chdir(tmp_path)
    (tmp_path / "DIR").mkdir()
    (tmp_path / "notes.toml").write_text("this is = not [toml\n")
    (tmp_path / "scene.toml").write_text(text or "")
    if text is None and args[0] == "compare":
        (tmp_path / "scene.toml").write_text(_probe_base())
    argv = args if text is None else ["run", "scene.toml", "--quiet", *(args or ["--out", "out"])]
    before = set(tmp_path.rglob("*"))
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's own errors
        rc = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and key.split(".")[-1] in err[-1], err
    assert "Traceback" not in "\n".join(err)
    assert set(tmp_path.rglob("*")) == before  # no run directory, no file written


def _probe_base():
    spec = importlib.util.spec_from_file_location("misuse_probe", ROOT / "studies" / "misuse_probe.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.BASE


def test_initial_density_of_the_base_scene_is_positive():
    s = scene_from_dict(BASE)
    f0 = s.initial_density(s.xgrid(), s.vgrid())
    assert f0.shape == (19, 23) and np.all(f0 > 0)


def test_memory_estimate_counts_dense_hessians_only_where_newton_forms_them():
    """gamma = 3 uses the structured O(N) Newton solve (no per-slice dense Hessian): the 1025 x 1025 step of
    studies/results/bench_scale.md (0.57 GiB measured) passes the default limit; gamma = 3/2 still counts
    one dense Hessian per slice and is refused."""
    from jko_cvx.scene.model import shipped_scene

    big = {"v.n": 1025, "x.n": 1025}
    assert shipped_scene("inhom_gamma3_lambda4", big).v.n == 1025
    with pytest.raises(SceneError, match="JKO_CVX_MAX_GIB"):
        shipped_scene("inhom_gamma1p5_before", big)


def test_typos_in_several_tables_are_named_in_one_error():
    """One pass over the file finds every unknown key: each table's message, in one error."""
    import tomllib

    from jko_cvx.scene.model import default_scene, scene_from_dict

    d = default_scene().to_dict()
    d["v"]["nn"] = d["v"].pop("n")  # a misspelt required key: reported as the typo, not as missing
    d["stop"]["eps_vv"] = 1e-3
    d["refine"]["v"]["delta_0"] = 0.3
    d["initial"]["rate"] = [2.0]
    d["gama"] = 1.0
    with pytest.raises(SceneError) as info:
        scene_from_dict(d)
    msg = str(info.value)
    for dotted, hint in [("gama", "gamma"), ("v.nn", "v.n"), ("stop.eps_vv", "stop.eps_v"),
                         ("refine.v.delta_0", "refine.v.delta0"), ("initial.rate", "initial.rates")]:  # fmt: skip
        assert f"'{dotted}'" in msg and f"did you mean '{hint}'?" in msg, (dotted, msg)
    # one table's unknown keys: the message check_known gives alone, unchanged
    one = tomllib.loads('gamma = 1.0\nt_end = 1.0\n[v]\nL = 2.0\nnn = 21\n[initial]\nkind = "gaussians"\n'
                        'amplitudes = [1.0]\nrates = [2.0]\ncentres = [0.0]\n[time]\ndt = 0.01\n')  # fmt: skip
    with pytest.raises(SceneError, match=r"^unknown key\(s\) \['v.nn'\] in \[v\] \(did you mean 'v.n'\?\); allowed: "):
        scene_from_dict(one)


def test_a_list_entry_out_of_range_is_named_with_the_range():
    with pytest.raises(SceneError, match=r"initial\.amplitudes\[1\] must be a finite number >= 0, got -0\.5"):
        shipped_scene("tab_bu_g1", {"initial.amplitudes": [1.0, -0.5], "initial.rates": [2.0, 2.0],
                                    "initial.centres": [0.0, 0.5]})  # fmt: skip
    with pytest.raises(SceneError, match=r"must be a non-empty list of numbers, each a finite number >= 0, got \[\]"):
        shipped_scene("tab_bu_g1", {"initial.amplitudes": []})


def test_the_memory_estimate_holds_what_the_cvxpy_methods_allocate(monkeypatch):
    """conic holds hundreds of N_v^2 doubles per slice it solves (measured: 515 at gamma = 3, 775 at gamma = 2.5,
    78-110 at gamma = 1, 1.5, 2, 4); the estimate must not be Newton's 4 N_v^2 for it, and scales with the slices
    solved at once."""

    def dense(method, gamma, threads=1):
        monkeypatch.setenv("JKO_CVX_THREADS", str(threads))
        over = {"collision": {"method": method, "fisher": "perspective"}, "gamma": gamma, "v": {"L": 2.5, "n": 600}}
        doc = {**BASE, **over}
        return estimate_size(scene_from_dict(doc, Limits(max_gib=1e9))).dense_bytes / (8 * 600**2)

    assert dense("newton", 3.0) == 4
    assert dense("conic", 3.0) >= 515 + 4 and dense("conic", 2.5) >= 775 + 4
    for gamma in (1.0, 1.5, 2.0, 4.0):
        assert 110 + 4 <= dense("conic", gamma) < 515
    assert dense("nlp", 3.0) >= 48
    # the slices solved at once: the slice threads (at most the x-grid's 19 slices)
    assert dense("conic", 3.0, threads=2) - 4 == 2 * (dense("conic", 3.0) - 4)
    assert dense("conic", 3.0, threads=64) - 4 == 19 * (dense("conic", 3.0) - 4)
