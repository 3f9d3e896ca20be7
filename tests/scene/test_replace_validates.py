"""Scene.replace validates the scene it returns: a change that is fine alone but inconsistent with the
rest of the scene is refused at once, naming the key, not at the first solve after files are written."""

from __future__ import annotations

import pytest

from jko_cvx.engine.loop import simulate
from jko_cvx.scene import SceneError, default_scene, shipped_scene


def test_switching_to_the_sqp_keeps_no_momentum_constraint_it_cannot_honour(tmp_path):
    s = shipped_scene("tab_bu_g1")  # Newton, momentum constraint on
    needs = r'collision\.conserve_momentum = true needs collision\.method = "newton", "conic" or "nlp"'
    with pytest.raises(SceneError, match=needs):
        s.replace({"collision.method": "sqp"})
    ok = s.replace({"collision.method": "sqp", "collision.conserve_momentum": False, "t_end": 0.02})
    assert ok.collision.method == "sqp"
    run = simulate(ok, out=tmp_path / "run", progress=False)
    assert run.t == pytest.approx(0.02)


def test_options_of_one_method_are_refused_for_another():
    s = default_scene().replace({"collision.options": {"max_iter": 50}})  # a Newton option
    with pytest.raises(SceneError, match=r"collision\.options"):
        s.replace({"collision.method": "conic", "collision.fisher": "perspective"})


@pytest.mark.parametrize(
    "changes, key", [({"v.n": "41"}, "v.n"), ({"time.dt": -1.0}, "time.dt"), ({"gamma": True}, "gamma")]
)
def test_a_bad_value_is_named(changes, key):
    with pytest.raises(SceneError, match=key.replace(".", r"\.")):
        default_scene().replace(changes)


def test_a_valid_replace_equals_the_scene_loaded_with_the_same_overrides():
    from jko_cvx.scene import scene_from_dict, with_overrides

    s = default_scene()
    changes = {"v.n": 41, "time.dt": 0.02, "t_end": 0.1}
    assert s.replace(changes) == scene_from_dict(with_overrides(s.to_dict(), changes))


def test_a_scene_changed_in_code_runs_in_the_loaders_form_and_reads_back(tmp_path):
    """replace (and a scene built with dataclasses.replace) gives the scene the loader would: the run's scene.json
    rebuilds it, so load_run reads the run back instead of calling it tampered."""
    import dataclasses

    from jko_cvx import load_run

    base = shipped_scene("tab_bu_g1", {"v.n": 41, "t_end": 0.05})
    changed = base.replace({"output.times": (0.03, 0.01)})
    assert changed.output.times == (0.01, 0.03)
    simulate(changed, out=tmp_path / "a", progress=False)
    assert load_run(tmp_path / "a").scene == changed
    by_hand = dataclasses.replace(base, output=dataclasses.replace(base.output, times=(0.03, 0.01)))
    simulate(by_hand, out=tmp_path / "b", progress=False)
    assert load_run(tmp_path / "b").scene.output.times == (0.01, 0.03)


def test_a_table_of_the_callers_own_class_survives_replace_and_simulate():
    """A subclass of the initial datum's class (its own density) is the caller's physics: replace and simulate
    keep it (rebuilding the table from the loader would swap it for the stock class without a word)."""
    import dataclasses

    import numpy as np

    base = shipped_scene("tab_bu_g1", {"v.n": 41, "t_end": 0.02})

    @dataclasses.dataclass(frozen=True)
    class Heavier(type(base.initial)):
        def density(self, xgrid, vgrid):
            return 2.0 * super().density(xgrid, vgrid)

    mine = dataclasses.replace(base, initial=Heavier(**{f.name: getattr(base.initial, f.name)
                                                        for f in dataclasses.fields(base.initial)}))  # fmt: skip
    assert type(mine.replace({"t_end": 0.01}).initial) is Heavier
    run = simulate(mine, progress=False)
    stock = simulate(base, progress=False)
    assert np.isclose(run.diagnostics.max_f.iloc[0], 2 * stock.diagnostics.max_f.iloc[0], rtol=1e-12)


def test_tables_of_the_callers_class_get_the_loaders_values_at_every_level(tmp_path):
    """A subclass (methods only) of a table, at the top or nested (refine.v), keeps its class and gets the loader's
    values: its run's scene.json rebuilds the same fingerprint, so load_run reads it back."""
    import dataclasses

    from jko_cvx import load_run

    base = shipped_scene("tab_bu_g1", {"v.n": 21, "t_end": 0.05})

    def subclass(obj):
        cls = dataclasses.dataclass(frozen=True)(type("Mine", (type(obj),), {}))
        return cls(**{f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)})

    out = dataclasses.replace(subclass(base.output), times=(0.04, 0.02))
    refine = dataclasses.replace(base.refine, v=subclass(base.refine.v))
    mine = dataclasses.replace(base, output=out, refine=refine)
    normal = mine.replace({})
    assert type(normal.output) is type(out) and normal.output.times == (0.02, 0.04)
    assert type(normal.refine.v) is type(refine.v)
    simulate(mine, out=tmp_path / "r", progress=False)
    assert load_run(tmp_path / "r").scene.output.times == (0.02, 0.04)
