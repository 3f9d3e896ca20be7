"""README.md is a guide whose code runs: the quickstart prints what README says it prints, the
Python example of a scene runs, every command it shows parses, and it stays short."""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from jko_cvx.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()
_FENCE = re.compile(r"^```(\w+)\n(.*?)^```$", re.S | re.M)
BLOCKS = _FENCE.findall(README)


def _blocks(lang: str) -> list[str]:
    return [body for kind, body in BLOCKS if kind == lang]


def test_readme_is_a_short_guide():
    assert len(README.splitlines()) <= 150
    assert README.startswith("# jko_cvx\n\n```bash\npython -m pip install . && jko-cvx run")
    assert 'python -m pip install ".[test]" && python -m pytest' in _blocks("bash")[0]


def test_quickstart_prints_what_the_readme_says(tmp_path, monkeypatch):
    quickstart = _blocks("python")[0]
    monkeypatch.chdir(tmp_path)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(quickstart, "README.md[quickstart]", "exec"), {"__name__": "__main__"})
    assert out.getvalue() == _blocks("text")[0]


def test_the_scene_example_runs(tmp_path, monkeypatch):
    scene_example = _blocks("python")[1]
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__main__"}
    exec(compile(scene_example, "README.md[scene]", "exec"), namespace)
    run = namespace["run"]
    v = run.verdict  # gamma = 1: the exact blow-up time is 1/(2 max f0) = 0.5
    assert v.blowup and abs(v.T_b - 0.5) < 0.05 and v.blowup_kind == "finite_time"
    assert abs(v.T_b_fit - 0.5) <= v.T_b_fit_err
    assert (tmp_path / "runs" / "g1" / "verdict.json").is_file()


@pytest.mark.parametrize(
    "line",
    [ln.split("#")[0].strip() for ln in _blocks("bash")[1].splitlines() if ln.strip().startswith("jko-cvx")],
)
def test_every_command_shown_parses(line):
    argv = shlex.split(line.split(">")[0])[1:]
    build_parser().parse_args(argv)  # argparse exits (SystemExit) on anything it does not know
