"""One options dataclass per collision method, and the scene allow-list derived from it.

Each method's options dataclass (``jko_cvx.collision.solve.OPTIONS``) has one field per keyword
option of its solver, with the solver's default; the scene allow-list
(``jko_cvx.scene.options.METHOD_OPTIONS``) holds exactly its scene-settable fields with their
ranges and choices; and at every bound of every such field (just inside, at, just outside,
the wrong type) the scene parser and ``solve_collision`` accept and refuse the same values.
"""

import contextlib
import dataclasses
import inspect
import io
import math

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, solve_collision
from jko_cvx.collision.nlp import nlp_available
from jko_cvx.collision.options import Spec, scene_specs
from jko_cvx.collision.solve import METHODS, OPTIONS
from jko_cvx.scene.options import METHOD_OPTIONS, parse_options
from jko_cvx.scene.schema import SceneError

# Options that are data but not on the scene allow-list (a decision, not an oversight of this test).
NOT_FOR_SCENES_BY_CHOICE = {"conic": {"accept_inaccurate"}}
# Options the probes override to keep each accepted solve to a few iterations.
FAST = {"sqp": {"max_iter": 2}, "newton": {"max_iter": 2}, "conic": {"max_passes": 1}, "nlp": {"max_iter": 2}}


def _fields(method):
    return {f.name: f for f in dataclasses.fields(OPTIONS[method])}


@pytest.mark.parametrize("method", sorted(METHODS))
def test_the_options_dataclass_has_the_solvers_keyword_options_and_defaults(method):
    params = inspect.signature(METHODS[method]).parameters.values()
    params = {p.name: p.default for p in params if p.kind is p.KEYWORD_ONLY}
    fields = _fields(method)
    assert set(fields) == set(params)
    for name, f in fields.items():
        assert f.default == params[name], name


@pytest.mark.parametrize("method", sorted(METHODS))
def test_the_scene_allow_list_is_the_scene_fields_with_their_ranges(method):
    specs = scene_specs(OPTIONS[method])
    assert set(METHOD_OPTIONS[method]) == set(specs)
    for name, spec in specs.items():
        rule = METHOD_OPTIONS[method][name]
        assert (rule.kind, rule.lo, rule.hi, rule.lo_open, rule.hi_open, rule.choices) == (
            spec.kind, spec.lo, spec.hi, spec.lo_open, spec.hi_open, spec.choices,
        ), name  # fmt: skip
    # what a scene may not set: callables and warm starts always, the rest by a recorded choice
    others = {name for name, f in _fields(method).items() if not f.metadata["spec"].scene}
    code = {name for name in others if _fields(method)[name].metadata["spec"].kind in ("callable", "array")}
    assert others - code == NOT_FOR_SCENES_BY_CHOICE.get(method, set())
    assert not any("file" in name for name in specs)


def _probes(spec: Spec) -> list:
    """Values at, inside and outside every bound of ``spec``, and values of the wrong type."""
    if spec.kind in ("float", "int"):
        out = [True, "1"]
        for b in (spec.lo, spec.hi):
            if b is not None:
                if spec.kind == "int":
                    out += [int(b) - 1, int(b), int(b) + 1, float(b)]
                else:
                    out += [b, math.nextafter(b, -math.inf), math.nextafter(b, math.inf), b - 1, b + 1, int(b)]
        if spec.kind == "float":
            out += [math.nan, math.inf, -math.inf] + ([1e300] if spec.hi is None else [])
        return out
    if spec.kind == "bool":
        return [True, False, 1, 0, "true"]
    if spec.kind == "str":
        return [*spec.choices, *(c.lower() if c.isupper() else c.upper() for c in spec.choices), "x", 1]
    assert spec.kind == "table"
    return [{}, 5, []]


def _scene_accepts(method, name, value):
    try:
        parse_options(method, {name: value})
    except SceneError:
        return False
    return True


def _solver_accepts(method, name, value, problem):
    options = {**FAST[method], name: value}
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            solve_collision(problem, method, **options)
    except (ValueError, TypeError):
        return False
    return True


@pytest.mark.parametrize("method", sorted(METHODS))
def test_scene_and_solver_accept_and_refuse_the_same_values_at_every_bound(method):
    if method == "nlp" and not nlp_available():
        pytest.skip("needs cyipopt")
    grid = Grid.uniform(-2.0, 2.0, 15)
    problem = CollisionProblem(grid, PowerKernel(1.0), np.exp(-2 * grid.points**2), dt=0.01, beta=10.0)
    checked = 0
    for name, spec in scene_specs(OPTIONS[method]).items():
        for value in _probes(spec):
            scene, solver = _scene_accepts(method, name, value), _solver_accepts(method, name, value, problem)
            assert scene == solver, f"{method}.{name} = {value!r}: scene {scene}, solver {solver}"
            checked += scene
    assert checked >= len(scene_specs(OPTIONS[method]))  # every option accepts something
