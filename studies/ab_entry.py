"""One ``jko-cvx reproduce`` entry from two checkouts, interleaved: the speed-up of a change, side by side.

The machine's speed drifts between sessions (and within one), so two regeneration timings
taken on different days do not measure a change of code.  This runs
``jko-cvx reproduce ENTRY --fresh --workers W`` from an old and a new checkout alternately
(old, new, old, new, ...), each in a fresh process with the checkout's package first on
``PYTHONPATH``, and records each run's wall time and the CPU time of the process and its
pool (``RUSAGE_CHILDREN``), with the 1-minute load.

Run: ``python studies/ab_entry.py OLD_TREE NEW_TREE [--entry gk2_bu] [--rounds 2]``; appends
to ``studies/results/ab_entry.csv`` (the checkouts' commits recorded).  BLAS threads: the
package default (1 inside every solve).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from datetime import UTC, datetime
from pathlib import Path

import pandas as pd
from regenerate_timing import run_timed

RESULTS = Path(__file__).parent / "results"


def _commit(tree: Path) -> str:
    out = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True)
    return out.stdout.strip() or "unknown"


def run_once(tree: Path, entry: str, workers: int) -> dict:
    """``jko-cvx reproduce ENTRY --fresh`` from ``tree``: wall and CPU seconds, exit status, loads."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    with tempfile.TemporaryDirectory(prefix="jko_cvx_ab_") as out:
        cmd = [sys.executable, "-m", "jko_cvx.cli", "reproduce", entry, "--fresh", "--workers", str(workers)]
        _, timing = run_timed([*cmd, "--out", out], capture_output=True, text=True, env=env, cwd=out)
    return timing


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("old", type=Path, help="checkout of the old code")
    ap.add_argument("new", type=Path, help="checkout of the new code")
    ap.add_argument("--entry", default="gk2_bu")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.workers < 1:
        ap.error("--rounds and --workers must be >= 1")
    for tree in (args.old, args.new):
        if not (tree / "jko_cvx" / "__init__.py").is_file():
            ap.error(f"{tree} is not a checkout of jko_cvx (no jko_cvx/__init__.py)")
    csv = RESULTS / "ab_entry.csv"
    before = pd.read_csv(csv) if csv.exists() else pd.DataFrame()
    rows = []
    for r in range(args.rounds):
        for side, tree in (("old", args.old), ("new", args.new)):
            row = {"entry": args.entry, "round": r, "side": side, "commit": _commit(tree), **run_once(tree, args.entry,
                   args.workers), "finished": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")}  # fmt: skip
            print(row, flush=True)
            rows.append(row)
            pd.concat([before, pd.DataFrame(rows)], ignore_index=True).to_csv(csv, index=False)  # after every run
    return 0 if all(row["returncode"] == 0 for row in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
