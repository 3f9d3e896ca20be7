"""What makes the first step fail from the scene's data alone is refused at load, naming the key,
before any file is written."""

import pytest

from jko_cvx.cli import main
from jko_cvx.engine.loop import simulate
from jko_cvx.scene import SceneError, scene_from_dict, with_overrides

BASE = {
    "name": "base",
    "gamma": 1.0,
    "t_end": 0.02,
    "v": {"L": 2.0, "n": 41},
    "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
    "time": {"dt": 0.01},
    "collision": {"beta": 100.0, "fisher": "log"},
}


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"initial.rates": [1e6]}, r"collision\.fisher = 'log' f0 must be > 0 at every grid point .* 0 at 40 of 41"),
        ({"initial.rates": [400.0]}, r"collision\.fisher = 'log' f0 must be > 0"),
        ({"initial.amplitudes": [1e-320]}, r"initial: max f0 = .* below the smallest normal float"),
        ({"initial.amplitudes": [1e308], "initial.rates": [0.01]}, r"initial: the mass of f0 .* overflows"),
        ({"initial.amplitudes": [1e300]}, r"initial: the mass of f0 .* overflows"),
    ],
)
def test_a_first_step_that_must_fail_is_refused_at_load(tmp_path, overrides, message):
    doc = with_overrides(BASE, overrides)
    with pytest.raises(SceneError, match=message):
        scene_from_dict(doc)
    # the same through the CLI: exit 2, the message, and no run directory
    toml = tmp_path / "s.toml"
    lines = [
        'name = "s"', "gamma = 1.0", "t_end = 0.02",
        "[v]", "L = 2.0", "n = 41",
        "[initial]", 'kind = "gaussians"',
        f"amplitudes = {doc['initial']['amplitudes']}", f"rates = {doc['initial']['rates']}", "centres = [0.0]",
        "[time]", "dt = 0.01", "[collision]", "beta = 100.0", 'fisher = "log"',
    ]  # fmt: skip
    toml.write_text("\n".join(lines) + "\n")
    assert main(["run", str(toml), "--out", str(tmp_path / "run"), "--quiet"]) == 2
    assert not (tmp_path / "run").exists()


def test_the_same_data_with_the_perspective_form_is_not_refused():
    """Zeros are admissible where the Fisher term is the perspective cone (or absent): the conic
    reference steps from them (Newton's barrier-free start cannot, and says so in its status)."""
    for fisher in ("perspective", "none"):
        scene_from_dict(with_overrides(BASE, {"initial.rates": [400.0], "collision.fisher": fisher}))
    conic = {"initial.rates": [400.0], "collision.fisher": "perspective", "collision.method": "conic"}
    run = simulate(scene_from_dict(with_overrides(BASE, conic)))
    assert run.verdict.certified and run.steps == 2 and not run.diagnostics.failed.any()


def test_a_threshold_the_initial_grid_already_meets_is_refused_before_writing(tmp_path):
    # min dv of the initial (refined) grid is 0.05 on 41 points: eps_v = 0.06 would "detect" a blow-up at the first
    # step with no concentration at all
    scene = scene_from_dict(with_overrides(BASE, {"refine": {"v": {"bumps": 1}}, "stop.eps_v": 0.06}))
    with pytest.raises(SceneError, match=r"stop\.eps_v = 0\.06 is not below the smallest spacing of the v-grid the "
                                         r"run starts on \(0\.05\)"):  # fmt: skip
        simulate(scene, out=tmp_path / "run")
    assert not (tmp_path / "run").exists()
    simulate(scene.replace({"stop.eps_v": 0.04}))  # below it: a threshold the run must reach


def test_a_scene_built_in_code_is_validated_before_writing(tmp_path):
    import dataclasses

    scene = scene_from_dict(BASE)
    for bad, key in ((dataclasses.replace(scene, strength=float("inf")), "strength"),
                     (dataclasses.replace(scene, t_end=-1.0), "t_end")):  # fmt: skip
        with pytest.raises(SceneError, match=key):
            simulate(bad, out=tmp_path / "run")
        assert not (tmp_path / "run").exists()


def test_a_fixed_step_longer_than_the_run_is_refused():
    # --set time.dt=0x10 is the TOML integer 16: one clipped step of t_end would run instead of the step asked for
    with pytest.raises(SceneError, match=r"time\.dt = 16 is larger than t_end = 0\.02 with time\.policy = 'fixed'"):
        scene_from_dict(with_overrides(BASE, {"time.dt": 16}))
    scene_from_dict(with_overrides(BASE, {"time.dt": 0.02}))  # one whole step is fine


@pytest.mark.parametrize("strength, dt", [(1e308, 0.01), (1e300, 1e3), (3e299, 1.0)])
def test_an_interaction_weight_that_overflows_is_refused_at_load(strength, dt):
    """dt * strength * W(v) must be finite on the grid (the energy term of every step): refused naming both keys."""
    doc = with_overrides(BASE, {"strength": strength, "time.dt": dt, "t_end": max(dt, 0.02)})
    with pytest.raises(SceneError, match=r"strength = .* time\.dt = .* overflows"):
        scene_from_dict(doc)
    scene_from_dict(with_overrides(BASE, {"strength": 1e6}))  # large, not overflowing: accepted
