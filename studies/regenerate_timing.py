"""How long regenerating the paper's numerical section takes (issue 15, item 5).

Runs ``jko-cvx reproduce NAME --fresh`` for every entry of
:data:`jko_cvx.studies.reproduce.REPRODUCTIONS` (full forms unless ``--quick``), one after another,
each in its own process, into ``SCRATCH/reproduce`` (the shipped results are not touched), and
records per entry the wall time, the CPU time of the process and its pool workers
(``RUSAGE_CHILDREN``), the exit status and the 1-minute load average before and after.
``--fresh`` ignores every sweep cache: the times are those of a first regeneration.

A row is appended to the CSV as soon as its entry finishes, together with the package's
code hash: a killed run resumes where it stopped (entries already timed with the same code
are skipped; ``--again`` times them anew).  The Markdown report sums the entries and
compares the total with the goal of 20 minutes on 2 cores.

``--section`` times ``jko-cvx reproduce section --fresh`` instead: every entry in one process
sharing one pool (:mod:`jko_cvx.studies.reproduce.section`), the way to regenerate the whole section;
it writes ``regenerate_timing_section.{csv,md}`` (per entry: when it started and finished in
the shared run) beside the entry-by-entry timing.

Run: ``python studies/regenerate_timing.py [--workers 2] [--entries a b ...] [--quick] [--section]``;
writes ``studies/results/regenerate_timing{,_quick}{,_section}.{csv,md}``.  BLAS threads: the package's
default (``JKO_CVX_BLAS_THREADS`` = 1 inside every solve); the environment is recorded.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd

from jko_cvx.studies.reproduce import REPRODUCTIONS
from jko_cvx.studies.sweep import code_identity
from jko_cvx.threads import THREAD_ENV_KEYS

RESULTS = Path(__file__).parent / "results"
GOAL_S = 20 * 60
"""The issue's goal for the whole section on 2 cores."""
_ENV_KEYS = THREAD_ENV_KEYS


def _children_cpu() -> float:
    use = resource.getrusage(resource.RUSAGE_CHILDREN)
    return use.ru_utime + use.ru_stime


def run_timed(cmd: list[str], **run_kwargs) -> tuple[subprocess.CompletedProcess, dict]:
    """Run ``cmd`` in a fresh process: its result, and wall seconds, the CPU seconds of the process
    and its children (``RUSAGE_CHILDREN``), the exit status and the 1-minute load before and after."""
    load0, cpu0, t0 = os.getloadavg()[0], _children_cpu(), time.perf_counter()
    proc = subprocess.run(cmd, check=False, **run_kwargs)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    timing = {"wall_s": wall, "cpu_s": cpu, "returncode": proc.returncode, "load_before": load0,
              "load_after": os.getloadavg()[0]}  # fmt: skip
    return proc, timing


def time_entry(name: str, out: Path, workers: int, quick: bool) -> dict:
    """Run one entry in a fresh process; wall and CPU seconds, exit status, load averages."""
    cmd = [sys.executable, "-m", "jko_cvx.cli", "reproduce", name, "--fresh", "--out", str(out)]
    cmd += ["--workers", str(workers)] + (["--quick"] if quick else [])
    proc, timing = run_timed(cmd, capture_output=True, text=True)
    tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] if proc.returncode else []
    return {
        "entry": name,
        "wall_s": timing["wall_s"],
        "cpu_s": timing["cpu_s"],
        "returncode": proc.returncode,
        "error": tail[0][:200] if tail else "",
        "load_before": timing["load_before"],
        "load_after": timing["load_after"],
        "workers": workers,
        "finished": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
    }


def _report(df: pd.DataFrame, path: Path, quick: bool, whole: bool = True) -> None:
    ok = df[df.returncode == 0]
    missing = [e for e in REPRODUCTIONS if e not in set(ok.entry)]  # the goal is for the whole section
    total = ok.wall_s.sum()
    env = {k: os.environ.get(k, "unset") for k in _ENV_KEYS}
    lines = [
        f"# Regenerating the numerical section ({'quick' if quick else 'full'} forms)",
        "",
        f"Every entry of `jko-cvx reproduce`, one after another, each in a fresh process with `--fresh` "
        f"(no sweep cache) and `--workers {int(df.workers.iloc[0])}`, on this 2-core machine; "
        f"thread environment: {', '.join(f'{k}={v}' for k, v in env.items())}.",
        "",
        df.to_markdown(index=False, floatfmt=".4g"),
        "",
        f"**Total wall time {total:.0f} s ({total / 60:.1f} min) over {len(ok)} of the section's "
        f"{len(REPRODUCTIONS)} entries; "
        f"CPU {ok.cpu_s.sum():.0f} s.**  Goal: {GOAL_S / 60:.0f} min: "
        + ("not met." if total > GOAL_S else "open (entries missing)." if missing else "met.")
        + (f"  Not timed (or failed): {', '.join(missing)}." if missing else "")
        if whole
        else f"**Wall time {total:.0f} s over these {len(ok)} entries; CPU {ok.cpu_s.sum():.0f} s** (a separate "
        "timing of some entries: the section's total is in `regenerate_timing.md`).",
        "",
    ]
    path.write_text("\n".join(lines))


def time_section(scratch: Path, workers: int, quick: bool) -> int:
    """``jko-cvx reproduce section --fresh`` in one process: its own record plus wall, CPU and load."""
    out = scratch / "reproduce"
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "jko_cvx.cli", "reproduce", "section", "--fresh", "--out", str(out)]
    cmd += ["--workers", str(workers)] + (["--quick"] if quick else [])
    proc, timing = run_timed(cmd)
    wall, cpu, load0, load1 = (timing[k] for k in ("wall_s", "cpu_s", "load_before", "load_after"))
    entries = pd.read_csv(out / "section.csv")
    stem = "regenerate_timing" + ("_quick" if quick else "") + "_section"
    entries.to_csv(RESULTS / f"{stem}.csv", index=False)
    env = {k: os.environ.get(k, "unset") for k in _ENV_KEYS}
    ok = int((entries.status == "ok").sum())
    verdict = "not met" if wall > GOAL_S or ok < len(entries) else "met"
    lines = [
        f"# Regenerating the numerical section in one run ({'quick' if quick else 'full'} forms)",
        "",
        f"`jko-cvx reproduce section --fresh --workers {workers}`: every entry of the section in one process, "
        f"sharing one pool of {workers} workers (entries start longest first), on this "
        f"2-core machine; thread environment: {', '.join(f'{k}={v}' for k, v in env.items())}; code "
        f"{code_identity(main)['package_sha256'][:12]}; 1-minute load {load0:.2f} before, {load1:.2f} after; "
        f"finished {datetime.now(UTC).strftime('%Y-%m-%d %H:%M UTC')}.",
        "",
        entries.to_markdown(index=False, floatfmt=".1f"),
        "",
        f"**Total wall time {wall:.0f} s ({wall / 60:.1f} min) for {ok} of {len(entries)} entries; CPU "
        f"{cpu:.0f} s; exit status {proc.returncode}.**  Goal: {GOAL_S / 60:.0f} min: {verdict}.",
        "",
    ]
    (RESULTS / f"{stem}.md").write_text("\n".join(lines))
    print((RESULTS / f"{stem}.md").read_text())
    return proc.returncode


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--entries", nargs="+", choices=sorted(REPRODUCTIONS), default=None)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--again", action="store_true", help="time entries already in the CSV again")
    parser.add_argument("--scratch", type=Path, default=None, help="output directory (default: a temporary one)")
    parser.add_argument("--tag", default="", help="suffix of the result files (a separate timing of some entries)")
    parser.add_argument("--section", action="store_true", help="time `jko-cvx reproduce section` (one run)")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    if args.section:
        if args.entries or args.again or args.tag:
            parser.error("--section times the whole section: no --entries, --again or --tag")
        return time_section(args.scratch or Path(tempfile.mkdtemp(prefix="jko_cvx_section_")), args.workers, args.quick)
    entries = args.entries or list(REPRODUCTIONS)
    stem = "regenerate_timing" + ("_quick" if args.quick else "") + (f"_{args.tag}" if args.tag else "")
    csv = RESULTS / f"{stem}.csv"
    code = code_identity(main)["package_sha256"]
    done = pd.read_csv(csv) if csv.exists() else pd.DataFrame()
    if len(done):
        # rows of other code are stale: dropped, never mixed with this code's
        done = done[(done.package_sha256 == code) & ~(args.again & done.entry.isin(entries))]
    scratch = args.scratch or Path(tempfile.mkdtemp(prefix="jko_cvx_regenerate_"))
    out = scratch / "reproduce"
    out.mkdir(parents=True, exist_ok=True)
    for name in entries:
        if len(done) and ((done.entry == name) & (done.returncode == 0)).any():
            continue
        print(f"{name} ...", flush=True)
        row = {**time_entry(name, out, args.workers, args.quick), "package_sha256": code}
        print(f"  {row['wall_s']:.1f} s wall, {row['cpu_s']:.1f} s CPU, exit {row['returncode']}", flush=True)
        done = pd.concat([done[done.entry != name] if len(done) else done, pd.DataFrame([row])], ignore_index=True)
        done.to_csv(csv, index=False)  # after every entry: a killed run loses nothing
    order = {e: i for i, e in enumerate(REPRODUCTIONS)}
    done = done.sort_values("entry", key=lambda s: s.map(order)).reset_index(drop=True)
    done.to_csv(csv, index=False)
    _report(done, RESULTS / f"{stem}.md", args.quick, whole=not args.tag)
    print((RESULTS / f"{stem}.md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
