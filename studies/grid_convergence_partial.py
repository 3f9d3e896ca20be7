"""The grid-convergence report from the points a stopped ``jko-cvx reproduce grid_convergence`` finished.

The full sweep (:mod:`jko_cvx.reproduce.grid_convergence`) needs more machine time than one
session on 2 cores has: the mapped 481 x 481 gamma = 3/2 runs and the tab:g2bu runs at
N_v = 801 take hours.  This script builds the same tables, report and figure from the
points that finished (the sweep writes each point's result to its cache as soon as it
arrives), lists the points that did not, and records which code computed them:

    python studies/grid_convergence_partial.py --cache OUT/cache/grid_convergence \\
        --provenance "commit fd12f88" --out studies/results/reproduce

Each cache entry's digest is checked (an edited or truncated entry is refused); entries of
points outside the sweep are ignored.  A complete sweep needs no script: the entry's own
command writes the report.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pandas as pd

from jko_cvx.reproduce.grid_convergence import _points, write_report
from jko_cvx.sweep import cached_entries


def _canonical(point: dict) -> str:
    return json.dumps(point, sort_keys=True, default=float)


def read_points(cache: Path) -> dict[str, dict]:
    """Every cache entry (digest checked by :func:`jko_cvx.sweep.cached_entries`), by its point's JSON."""
    return {_canonical(point): {**point, **result} for point, result in cached_entries(cache)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache", type=Path, required=True, help="the sweep's cache directory")
    parser.add_argument("--provenance", required=True, help="the code that ran the points (e.g. a commit)")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--wall", type=float, default=float("nan"), help="the stopped sweep's wall seconds")
    parser.add_argument("--quick", action="store_true", help="the points of the quick form")
    args = parser.parse_args(argv)
    if not args.cache.is_dir():
        parser.error(f"--cache {args.cache} is not a directory")
    found = read_points(args.cache)
    points = _points(quick=args.quick)
    done = [found[_canonical(p)] for p in points if _canonical(p) in found]
    missing = [p for p in points if _canonical(p) not in found]
    if not done:
        parser.error(f"no finished point of the sweep in {args.cache}")
    args.out.mkdir(parents=True, exist_ok=True)
    write_report(pd.DataFrame(done), args.out, wall=args.wall, provenance=args.provenance, missing=missing)
    print(f"{len(done)} of {len(points)} points reported, {len(missing)} missing; wrote {args.out}/grid_convergence*")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
