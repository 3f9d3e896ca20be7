"""Probe the scene and CLI misuse classes: does each give a clear error naming the key?

Each class is a small scene (or command line) with one mistake.  It is run as
``python -m jko_cvx.cli ...`` in a fresh directory against a source tree (default: this
checkout), and counted *clear* when the command exits non-zero within the time limit,
prints no traceback, names the offending key (the leaf name is enough) or path, and
has written no file (no run directory).

    python studies/misuse_probe.py                         # this checkout
    python studies/misuse_probe.py --before OLD_TREE       # and an older tree, side by side

writes ``studies/results/misuse_scene_cli.{csv,md}`` (the table of docs/guides/bad_input.md).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
TIMEOUT = 40.0

BASE = """name = "probe"
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

[collision]
method = "newton"
beta = 1000.0
fisher = "log"

[stop]
eps_v = 1e-4

[output]
every = 1
checkpoint_every = 1
"""


def _scene(**edits: str) -> str:
    """BASE with lines replaced (``old=new`` pairs given as a dict) or appended (key ``_add``)."""
    text = BASE
    for old, new in edits.items():
        if old == "_add":
            continue
        assert old in text, old
        text = text.replace(old, new, 1)
    return text + edits.get("_add", "")


def _scalar_section(name: str, value: str) -> str:
    """BASE with the table ``[name]`` replaced by a top-level scalar ``name = value``."""
    text = re.sub(rf"\n\[{name}\]\n(?:[^\[\n][^\n]*\n)*", "\n", BASE)
    return f"{name} = {value}\n" + text


CONIC = {'method = "newton"': 'method = "conic"', 'fisher = "log"': 'fisher = "perspective"'}

# class, what is wrong, the key or path the message must name, the scene text (or None), extra CLI args
CASES: list[tuple[str, str, str, str | None, list[str]]] = [
    ("typo top-level key", "gama = 1.0", "gama", _scene(**{"gamma = 1.0": "gamma = 1.0\ngama = 1.0"}), []),
    ("typo in [v]", "v.nn = 41", "nn", _scene(**{"n = 21": "n = 21\nnn = 41"}), []),
    (
        "typo in [x]",
        "x.conserve_moments = false",
        "conserve_moments",
        _scene(_add="\n[x]\nL = 2.0\nn = 11\nconserve_moments = false\n"),
        [],
    ),
    ("typo in [time]", "time.dtt = 0.001", "dtt", _scene(**{"dt = 0.01": "dt = 0.01\ndtt = 0.001"}), []),
    ("typo in [stop]", "stop.eps_vv = 0.1", "eps_vv", _scene(**{"eps_v = 1e-4": "eps_v = 1e-4\neps_vv = 0.1"}), []),
    (
        "typo in [collision]",
        "collision.betaa = 30",
        "betaa",
        _scene(**{"beta = 1000.0": "beta = 1000.0\nbetaa = 30.0"}),
        [],
    ),
    ("typo in [output]", "output.evry = 5", "evry", _scene(**{"every = 1": "every = 1\nevry = 5"}), []),
    ("typo in [refine.v]", "refine.v.delta_0 = 0.3", "delta_0", _scene(_add="\n[refine.v]\ndelta_0 = 0.3\n"), []),
    ("unknown [refine] axis", "[refine.w]", "refine.w", _scene(_add="\n[refine.w]\ndelta = 0.3\n"), []),
    ("typo in [initial]", "initial.rate", "rate", _scene(**{"rates = [2.0]": "rate = [2.0]"}), []),
    (
        "typo in collision.options",
        "collision.options.tolerance",
        "tolerance",
        _scene(**{'fisher = "log"': 'fisher = "log"\noptions = { tolerance = 1e-9 }'}),
        [],
    ),
    ("section as a scalar", 'collision = "newton"', "collision", _scalar_section("collision", '"newton"'), []),
    ("section as a scalar", "stop = 1e-3", "stop", _scalar_section("stop", "1e-3"), []),
    (
        "options as a scalar",
        "collision.options = 5",
        "options",
        _scene(**{'fisher = "log"': 'fisher = "log"\noptions = 5'}),
        [],
    ),
    ("wrong type (string for int)", 'v.n = "21"', "n", _scene(**{"n = 21": 'n = "21"'}), []),
    ("wrong type (float for int)", "v.n = 21.5", "n", _scene(**{"n = 21": "n = 21.5"}), []),
    ("wrong type (bool for int)", "output.every = true", "every", _scene(**{"every = 1": "every = true"}), []),
    (
        "wrong type (int for bool)",
        "collision.conserve_momentum = 1",
        "conserve_momentum",
        _scene(**{'fisher = "log"': 'fisher = "log"\nconserve_momentum = 1'}),
        [],
    ),
    ("bad enum", 'collision.fisher = "fisher"', "fisher", _scene(**{'fisher = "log"': 'fisher = "fisher"'}), []),
    ("bad enum", 'time.policy = "adaptive"', "policy", _scene(**{"dt = 0.01": 'dt = 0.01\npolicy = "adaptive"'}), []),
    ("bad enum", 'initial.kind = "gauss"', "kind", _scene(**{'kind = "gaussians"': 'kind = "gauss"'}), []),
    (
        "incompatible method and fisher",
        'method = "conic", fisher = "log"',
        "fisher",
        _scene(**{'method = "newton"': 'method = "conic"'}),
        [],
    ),
    ("out of range", "refine.v.delta = 1.0", "delta", _scene(_add="\n[refine.v]\ndelta = 1.0\n"), []),
    ("out of range", "collision.beta = -30", "beta", _scene(**{"beta = 1000.0": "beta = -30.0"}), []),
    ("out of range", "collision.beta = 1e-300", "beta", _scene(**{"beta = 1000.0": "beta = 1e-300"}), []),
    ("out of range", "stop.eps_v = -1", "eps_v", _scene(**{"eps_v = 1e-4": "eps_v = -1.0"}), []),
    ("not a number", "gamma = nan", "gamma", _scene(**{"gamma = 1.0": "gamma = nan"}), []),
    ("overflowing kernel", "gamma = 1e300", "gamma", _scene(**{"gamma = 1.0": "gamma = 1e300"}), []),
    (
        "lists of different lengths",
        "initial.rates = [2.0, 3.0]",
        "rates",
        _scene(**{"rates = [2.0]": "rates = [2.0, 3.0]"}),
        [],
    ),
    (
        "snapshot time beyond t_end",
        "output.times = [1.0]",
        "times",
        _scene(**{"every = 1": "every = 1\ntimes = [1.0]"}),
        [],
    ),
    (
        "x threshold without an x-grid",
        "stop.eps_x = 1e-3",
        "eps_x",
        _scene(**{"eps_v = 1e-4": "eps_v = 1e-4\neps_x = 1e-3"}),
        [],
    ),
    (
        "name with a path",
        'name = "../../escape"',
        "name",
        _scene(**{'name = "probe"': 'name = "../../escape"'}),
        ["--quiet"],
    ),
    (
        "name with a leading dot",
        'name = ".hidden"',
        "name",
        _scene(**{'name = "probe"': 'name = ".hidden"'}),
        ["--quiet"],
    ),
    ("huge grid", "v.n = 10**7", "n", _scene(**{"n = 21": "n = 10000000"}), []),
    ("tiny time step", "time.dt = 1e-300", "dt", _scene(**{"dt = 0.01": "dt = 1e-300"}), []),
    (
        "file-writing solver option",
        "solver_options.write_data_filename",
        "write_data_filename",
        _scene(
            **CONIC,
            **{
                "beta = 1000.0": 'beta = 1000.0\noptions = { solver = "SCS", '
                'solver_options = { write_data_filename = "leak.txt" } }'
            },
        ),
        [],
    ),
    (
        "file-writing solver option",
        "solver_options.log_csv_filename",
        "log_csv_filename",
        _scene(
            **CONIC,
            **{
                "beta = 1000.0": 'beta = 1000.0\noptions = { solver = "SCS", '
                'solver_options = { log_csv_filename = "leak.csv" } }'
            },
        ),
        [],
    ),
    ("nesting", "an array nested 5000 deep", "scene.toml", "x = " + "[" * 5000 + "]" * 5000 + "\n" + BASE, []),
    (
        "nesting",
        "an inline table nested 3000 deep",
        "scene.toml",
        "x = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n" + BASE,
        [],
    ),
    ("float range", "v.L = 1e308", "L", _scene(**{"L = 2.0": "L = 1e308"}), []),
    ("float range", "x.L = 1e-200", "L", _scene(_add="\n[x]\nL = 1e-200\nn = 8\n"), []),
    (
        "underflow",
        "initial.amplitudes = [1e-320]",
        "amplitudes",
        _scene(**{"amplitudes = [1.0]": "amplitudes = [1e-320]"}),
        [],
    ),
    (
        "log Fisher zeros",
        "initial.rates = [1e6] (f0 = 0 off one point)",
        "fisher",
        _scene(**{"rates = [2.0]": "rates = [1e6]"}),
        [],
    ),
    ("directory as the scene", "jko-cvx run DIR", "DIR", None, ["run", "DIR"]),
    ("missing scene file", "jko-cvx run missing.toml", "missing.toml", None, ["run", "missing.toml"]),
    ("scene not TOML", "jko-cvx run notes.toml (not TOML)", "notes.toml", None, ["run", "notes.toml"]),
    ("bad CLI number", "jko-cvx solve --n 2", "n", None, ["solve", "--n", "2"]),
    (
        "bad CLI number",
        "jko-cvx reproduce explicit --workers 0",
        "workers",
        None,
        ["reproduce", "explicit", "--workers", "0", "--out", "rep"],
    ),
    ("bad CLI number", "jko-cvx compare --t -1 SCENE", "t", None, ["compare", "scene.toml", "--t", "-1"]),
    (
        "threshold the initial grid meets",
        "stop.eps_v = 0.5 (dv = 0.2)",
        "eps_v",
        _scene(**{"eps_v = 1e-4": "eps_v = 0.5"}),
        [],
    ),
    ("fixed step longer than the run", "time.dt = 0x10", "dt", _scene(**{"dt = 0.01": "dt = 0x10"}), []),
    (
        "overlapping overrides",
        "--set v.n=31 --set v={L=2.0,n=41}",
        "v.n",
        BASE,
        ["--set", "v.n=31", "--set", "v={L=2.0,n=41}", "--out", "out"],
    ),
]


def _probe(tree: Path, text: str | None, args: list[str]) -> tuple[int | None, str, bool, bool]:
    """Run one case in a fresh directory: exit code (None on time-out), output, traceback shown, files written."""
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp) / "a" / "b" / "c"
        cwd.mkdir(parents=True)
        (cwd / "DIR").mkdir()
        (cwd / "notes.toml").write_text("this is = not [toml\n")
        (cwd / "scene.toml").write_text(BASE)
        if text is not None:
            (cwd / "scene.toml").write_text(text)
            # the name cases use the default run directory runs/<name>
            args = ["run", "scene.toml", "--quiet", *(args or ["--out", "out"])]
        env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
        before = set(Path(tmp).rglob("*"))
        try:
            proc = subprocess.run(
                [sys.executable, "-m", "jko_cvx.cli", *args],
                cwd=cwd,
                env=env,
                capture_output=True,
                text=True,
                timeout=TIMEOUT,
            )
        except subprocess.TimeoutExpired:
            return None, f"still running after {TIMEOUT:g} s", False, set(Path(tmp).rglob("*")) != before
        out = (proc.stderr.strip() or proc.stdout.strip()).splitlines()
        shown = out[-1] if out else ""
        return proc.returncode, shown, "Traceback" in proc.stderr, set(Path(tmp).rglob("*")) != before


def _clear(rc: int | None, message: str, traceback: bool, wrote: bool, key: str) -> bool:
    return rc not in (None, 0) and not traceback and not wrote and key.split(".")[-1] in message


def probe(tree: Path) -> pd.DataFrame:
    rows = []
    for cls, what, key, text, args in CASES:
        rc, message, tb, wrote = _probe(tree, text, args)
        outcome = "timed out" if rc is None else ("exit 0 (accepted)" if rc == 0 else f"exit {rc}")
        if tb:
            outcome += ", traceback"
        if wrote:
            outcome += ", wrote files"
        rows.append(
            {
                "class": cls,
                "input": what,
                "key": key,
                "clear": _clear(rc, message, tb, wrote, key),
                "outcome": outcome,
                "message": message[:240],
            }
        )
        print(f"{rows[-1]['clear']!s:5} {what}: {outcome}: {message[:120]}", flush=True)
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", type=Path, default=None, help="an older source tree to probe as well")
    parser.add_argument("--out", type=Path, default=ROOT / "studies" / "results")
    args = parser.parse_args()
    after = probe(ROOT)
    table = after.rename(columns={"clear": "clear (now)", "outcome": "outcome (now)", "message": "message (now)"})
    if args.before is not None:
        before = probe(args.before.resolve())
        table.insert(4, "clear (before)", before["clear"])
        table.insert(5, "outcome (before)", before["outcome"])
        table["message (before)"] = before["message"]
    args.out.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out / "misuse_scene_cli.csv", index=False)
    n = len(table)
    counts = f"clear errors naming the key: {int(table['clear (now)'].sum())} of {n} now"
    if args.before is not None:
        counts += f", {int(table['clear (before)'].sum())} of {n} before"
    md = table.drop(columns=[c for c in table.columns if c.startswith("message (before)")])
    (args.out / "misuse_scene_cli.md").write_text(
        "# Scene and CLI misuse classes (`python studies/misuse_probe.py`)\n\n"
        + counts
        + ".\n\n"
        + md.to_markdown(index=False)
        + "\n"
    )
    print(counts)


if __name__ == "__main__":
    main()
