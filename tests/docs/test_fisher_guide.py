"""The Fisher-weight guide's table of shipped scenes is the scenes' own setting."""

import re
from pathlib import Path

from jko_cvx import default_scene, shipped_scene
from jko_cvx.scene import shipped_scene_names

PAGE = Path(__file__).resolve().parents[2] / "docs" / "guides" / "fisher_weight.md"
ROW = re.compile(r"^\| `([a-z0-9_]+)` \| (\w+) \| ([0-9.e+]+|inf) \| (\w+) \|$", re.M)


def test_the_table_lists_every_shipped_scene_as_loaded():
    rows = {name: (fisher, float(beta), method) for name, fisher, beta, method in ROW.findall(PAGE.read_text())}
    assert set(rows) == {"default", *shipped_scene_names()}
    for name, (fisher, beta, method) in rows.items():
        c = (default_scene() if name == "default" else shipped_scene(name)).collision
        assert (fisher, beta, method) == (c.fisher, c.beta, c.method), name
