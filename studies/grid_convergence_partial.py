"""The grid-convergence report from the points a (stopped) ``jko-cvx reproduce grid_convergence`` finished.

The full sweep (:mod:`jko_cvx.studies.reproduce.grid_convergence`) needs more machine time than one
session on 2 cores has: the mapped 481 x 481 gamma = 3/2 runs and the tab:g2bu runs at
N_v = 801 take hours.  This script builds the same tables, report and figure from the
points that finished (the sweep writes each point's result to its cache as soon as it
arrives) and lists the points that did not.

Only entries computed by the code this script runs with are reported: a point's cache key
covers the code (:func:`jko_cvx.studies.sweep.point_key`), so the script looks each point up under
the key the running package gives it, and an entry that another code wrote (or that
belongs to no point of the sweep) is counted and left out -- a report never mixes codes.
To report a sweep that ran in a frozen checkout, run this script with that checkout's
package (``PYTHONPATH=CHECKOUT``).  The report records that code itself
(:func:`jko_cvx.studies.sweep.code_provenance`: commit, package hash); a checkout whose ``jko_cvx``
differs from its commit is refused, since nothing would say which code that was::

    PYTHONPATH=FROZEN python studies/grid_convergence_partial.py \\
        --cache OUT/cache/grid_convergence --note "2 workers beside other jobs" --out studies/results/reproduce

Each entry's digest is checked (an edited or truncated entry is refused).
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import pandas as pd

from jko_cvx.studies.reproduce.grid_convergence import _points, grid_point, write_report
from jko_cvx.studies.sweep import StaleCacheWarning, cached_entries, code_provenance, point_key

# The sweep's own reader of entries under given keys (key, point and digest checked), private
# but present in every package version that wrote such caches: the script must run with the
# frozen checkout's package, so it uses nothing newer.
from jko_cvx.studies.sweep import _read_cache as read_cache


def provenance_text(prov: dict, note: str | None) -> str:
    """The report's statement of the code that computed its points."""
    text = (
        f"commit {str(prov['git_commit'])[:12]}"
        + (" with uncommitted changes to jko_cvx" if prov["jko_cvx_modified"] else "")
        + f", package {prov['package_version']}, package sha256 {prov['package_sha256'][:12]}"
    )
    return text + (f"; {note}" if note else "")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cache", type=Path, required=True, help="the sweep's cache directory")
    parser.add_argument("--note", default=None, help="how the points ran (workers, load), added to the provenance")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--wall", type=float, default=float("nan"), help="the stopped sweep's wall seconds")
    parser.add_argument("--quick", action="store_true", help="the points of the quick form")
    parser.add_argument(
        "--allow-modified",
        action="store_true",
        help="report although jko_cvx differs from its commit (the report then says so; for tests)",
    )
    args = parser.parse_args(argv)
    if not args.cache.is_dir():
        parser.error(f"--cache {args.cache} is not a directory")
    prov = code_provenance(grid_point)
    if prov["jko_cvx_modified"] and not args.allow_modified:
        parser.error(
            f"the running jko_cvx differs from its commit {prov['git_commit']}: commit it, or run from the "
            "frozen checkout that computed the cache (PYTHONPATH=CHECKOUT)"
        )
    total = len(cached_entries(args.cache))  # every entry's digest is checked here (a damaged one is refused)
    points = _points(quick=args.quick)
    keys = {point_key(grid_point, p): p for p in points}
    with warnings.catch_warnings():
        warnings.simplefilter("error", StaleCacheWarning)  # an entry under this code's key that fails: refuse
        found = read_cache(args.cache, keys)
    done = [{**p, **found[k]} for k, p in keys.items() if k in found]
    missing = [p for k, p in keys.items() if k not in found]
    if not done:
        parser.error(
            f"no point of the sweep computed by this code (package sha256 {prov['package_sha256'][:12]}) "
            f"in {args.cache}"
        )
    args.out.mkdir(parents=True, exist_ok=True)
    write_report(
        pd.DataFrame(done), args.out, wall=args.wall, provenance=provenance_text(prov, args.note), missing=missing
    )
    ignored = total - len(done)
    print(
        f"{len(done)} of {len(points)} points reported, {len(missing)} missing; "
        f"{ignored} entr{'y' if ignored == 1 else 'ies'} of other code or other points ignored; "
        f"wrote {args.out}/grid_convergence*"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
