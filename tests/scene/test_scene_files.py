"""Reading a scene file: whatever its bytes, a SceneError naming the file (never a traceback),
and a byte-order mark is not part of the document."""

from __future__ import annotations

import pytest

from jko_cvx.cli import main
from jko_cvx.scene import SceneError, load_scene
from jko_cvx.scene.model import MAX_SCENE_BYTES

TEXT = """name = "s"
gamma = 1.0
t_end = 0.02

[v]
L = 2.0
n = 21

[initial]
kind = "gaussians"
amplitudes = [1.0]
rates = [2.0]
centres = [0.0]

[time]
dt = 0.01
"""


def test_a_utf8_byte_order_mark_is_read_as_the_same_scene(tmp_path):
    plain, bom = tmp_path / "plain.toml", tmp_path / "bom.toml"
    plain.write_text(TEXT)
    bom.write_bytes(b"\xef\xbb\xbf" + TEXT.encode())
    assert load_scene(bom).to_dict() == load_scene(plain).to_dict()


@pytest.mark.parametrize(
    "content, message",
    [
        (("x = " + "[" * 5000 + "]" * 5000 + "\n" + TEXT).encode(), "nested too deeply"),
        (("x = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n" + TEXT).encode(), "nested too deeply"),
        (b'name = "\xff"\n', "is not UTF-8 text"),
        (b"#" * (MAX_SCENE_BYTES + 1), f"larger than {MAX_SCENE_BYTES} bytes"),
        (b"\xef\xbb\xbf[v\n", "is not valid TOML"),
    ],
)
def test_bad_bytes_are_a_scene_error_naming_the_file(tmp_path, content, message):
    path = tmp_path / "bad.toml"
    path.write_bytes(content)
    with pytest.raises(SceneError, match=message) as info:
        load_scene(path)
    assert "bad.toml" in str(info.value)
    assert main(["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]) == 2
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("table", ["v", "x"])
@pytest.mark.parametrize("half_width", [1e308, 1e151, 1e-200])
def test_a_half_width_whose_square_leaves_the_float_range_is_named(tmp_path, table, half_width):
    if table == "v":
        text = TEXT.replace("L = 2.0", f"L = {half_width!r}")
    else:
        text = TEXT + f"\n[x]\nL = {half_width!r}\nn = 8\n"
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(SceneError, match=rf"^{table}\.L must be a number in \[1e-150, 1e150\]"):
        load_scene(path)


@pytest.mark.parametrize(
    ("table", "half_width", "n"), [("x", 1e-150, 9), ("x", 1e-120, 9), ("x", 1e140, 8), ("v", 1e-95, 21)]
)
def test_a_grid_spacing_whose_cube_leaves_the_float_range_is_refused_before_anything_is_written(
    tmp_path, table, half_width, n
):
    """Half-widths inside their own range whose spacing 2 L / n cubes out of the floats: the cubic interpolation
    of the transport (NaN at x.L = 1e-150) and the moments (overflow at x.L = 1e140) would fail mid-run."""
    if table == "v":
        text = TEXT.replace("L = 2.0", f"L = {half_width!r}").replace("n = 21", f"n = {n}")
    else:
        text = TEXT + f"\n[x]\nL = {half_width!r}\nn = {n}\n"
    path = tmp_path / "s.toml"
    path.write_text(text)
    with pytest.raises(
        SceneError, match=rf"^{table}\.L = .* with {table}\.n = {n}: the grid spacing 2 L / n = .* \[1e-90, 1e90\]"
    ):
        load_scene(path)
