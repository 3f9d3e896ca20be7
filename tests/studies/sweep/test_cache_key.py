"""The sweep cache is keyed by the point *and* the function: two functions never share a result."""

from jko_cvx.studies.sweep import point_key, run_sweep


def square(x):
    return {"y": x * x}


def cube(x):
    return {"y": x * x * x}


def test_two_functions_at_the_same_point_have_their_own_cache_entries(tmp_path):
    points = [{"x": 3}]
    assert point_key(square, points[0]) != point_key(cube, points[0])
    first = run_sweep(square, points, tmp_path, executor="serial", progress=False)
    second = run_sweep(cube, points, tmp_path, executor="serial", progress=False)
    assert first.y.tolist() == [9] and not first.cached.any()
    assert second.y.tolist() == [27] and not second.cached.any()
    again = run_sweep(square, points, tmp_path, executor="serial", progress=False)
    assert again.y.tolist() == [9] and again.cached.all()
    assert len(list(tmp_path.glob("*.json"))) == 2


def test_the_key_depends_on_the_values_not_on_the_key_order():
    assert point_key(square, {"x": 1, "z": 2}) == point_key(square, {"z": 2, "x": 1})
    assert point_key(square, {"x": 1}) != point_key(square, {"x": 2})
    assert point_key(square, {"x": 1}) != point_key(square, {"w": 1})
