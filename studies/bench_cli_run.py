"""CPU time of the default ``jko-cvx run``: a baseline commit against this tree, side by side.

Each round runs, in fresh interpreters and interleaved, the baseline (exported with
``git archive`` and imported as ``jko_cvx_base``, as in ``studies/newton_single_call.py``) and
this tree: the whole command (``main(["run", "--out", DIR])`` on the built-in default scene, its
figures included) and the interpreter with the command's imports alone.  CPU time is the child
processes' user + system time (``resource.getrusage``), median over ``--repeats`` rounds, in
the package's default thread setting (recorded).  Both versions' modules are compiled to bytecode
first (``compileall``), as ``pip install`` does: an interpreter that may not write bytecode
(``PYTHONDONTWRITEBYTECODE``) would otherwise compile every module of the package on every run.
The package's target for the whole command is 2 s.

Run::

    OPENBLAS_NUM_THREADS=1 python studies/bench_cli_run.py --base f0dcb29

Writes ``studies/results/bench_cli_run.{csv,md}`` with the environment.
"""

from __future__ import annotations

import argparse
import compileall
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
from newton_single_call import import_baseline, tree_label

import jko_cvx
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.threads import thread_environment

RESULTS = Path(__file__).parent / "results"
TARGET_S = 2.0
WARM = "jko-cvx run, compiled Newton"
COLD = "jko-cvx run, compiled Newton, cold cache"


def _child_cpu(code: str, path: str, env: dict[str, str] | None = None) -> float:
    """User + system CPU seconds of ``python -c code`` with ``path`` first on sys.path (and ``env`` added)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    script = f"import sys; sys.path.insert(0, {path!r}); {code}"
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, env={**os.environ, **(env or {})})
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _compiled_run(out: Path) -> str:
    """The code of ``jko-cvx run --out OUT --set collision.options.compiled=true`` (this tree)."""
    args = ["run", "--out", str(out), "--set", "collision.options.compiled=true"]
    return f"from jko_cvx.cli import main; main({args!r})"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="baseline commit")
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--cold-repeats", type=int, default=3, help="rounds that also time a cold numba cache (~30 s each)")
    args = ap.parse_args(argv)
    times: dict[tuple[str, str], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "base"
        import_baseline(args.base, folder)
        for package in (folder / "jko_cvx_base", Path(jko_cvx.__file__).parent):  # as pip install does
            if not compileall.compile_dir(package, quiet=1):
                raise SystemExit(f"compileall failed on {package}")
        sides = {"base": ("jko_cvx_base", str(folder)), "tree": ("jko_cvx", "")}
        _child_cpu(_compiled_run(Path(tmp) / "warm"), "")  # compile into the on-disk cache (not timed)
        for r in range(args.repeats):
            for side, (pkg, path) in sides.items():
                out = Path(tmp) / f"{side}{r}"
                run = f"from {pkg}.cli import main; main(['run', '--out', {str(out)!r}])"
                times.setdefault((side, "jko-cvx run"), []).append(_child_cpu(run, path))
                times.setdefault((side, "imports"), []).append(_child_cpu(f"import {pkg}.cli, {pkg}.engine.plot", path))
            # this tree with Newton's compiled iteration: its cache warm (above), and cold (an empty cache directory)
            compiled = [(WARM, f"warm{r}", None)]
            if r < args.cold_repeats:
                compiled.append((COLD, f"cold{r}", {"NUMBA_CACHE_DIR": str(Path(tmp) / f"numba{r}")}))
            for what, name, env in compiled:
                times.setdefault(("tree", what), []).append(_child_cpu(_compiled_run(Path(tmp) / name), "", env))
            print(f"round {r + 1}/{args.repeats}", flush=True)
    rows = []
    for what in ("jko-cvx run", "imports", WARM, COLD):
        base = statistics.median(times[("base", what)]) if ("base", what) in times else float("nan")
        tree = statistics.median(times[("tree", what)])
        rows.append({"what": what, "base_cpu_s": base, "tree_cpu_s": tree, "tree/base": tree / base,
                     "tree_min_s": min(times[("tree", what)]), "tree_max_s": max(times[("tree", what)])})  # fmt: skip
    df = pd.DataFrame(rows)
    print(df.to_string(index=False))
    out = RESULTS / "bench_cli_run.csv"
    df.to_csv(out, index=False)
    record_csv(out)
    run_s = float(df.tree_cpu_s[0])
    write_markdown(
        RESULTS / "bench_cli_run.md",
        "# CPU time of the default `jko-cvx run`\n\n"
        f"Baseline {args.base}, tree {tree_label()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.  "
        f"Threads: {thread_environment()}.  User + system CPU seconds of a fresh interpreter, median of "
        f"{args.repeats} rounds ({args.cold_repeats} for the cold cache) with the versions interleaved: the whole "
        "command on the built-in default scene (simulation, run directory, figures), and the interpreter with the "
        "command's imports alone, both "
        "versions' modules compiled to bytecode first, as `pip install` does (PYTHONDONTWRITEBYTECODE="
        f"{os.environ.get('PYTHONDONTWRITEBYTECODE', 'unset')} here).  Each side "
        "runs its own version's default scene (`jko_cvx.default_scene`; it may differ between the versions).  "
        "This tree also runs the command with `--set collision.options.compiled=true` (Newton's compiled "
        "iteration, numba): with its on-disk cache warm, and cold (an empty `NUMBA_CACHE_DIR`: the first use on "
        "a machine, which compiles).  "
        f"Target: under {TARGET_S:g} s for the whole command ({'met' if run_s < TARGET_S else 'not met'}: "
        f"{run_s:.2f} s).\n\n" + df.to_markdown(index=False, floatfmt=".3g") + "\n",
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
