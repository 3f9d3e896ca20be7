"""The uniform (map-free) references of ``grid_convergence`` rerun on today's code.

The shipped grid-convergence report (``results/reproduce/grid_convergence.md``) was run on
one frozen code (commit fd12f88), whose uniform references had no v-floor: on a fixed
v-grid the collision drains the edge lines in v, and the 481 x 481 lambda = 5 reference
stopped on an uncertified solve (``results/grid_convergence_failure_no_floor.json``).  The
references now keep the floor of the paper's every-step v-remap (``v.floor_every_step``).
This script reruns the six uniform gamma = 3/2 points (both cases, n = 121, 241, 481) on
today's code, as the sweep's own points (:func:`jko_cvx.reproduce.grid_convergence.grid_point`,
cached per point and code), and writes them beside the frozen report's values, so the two
codes are never mixed in one table column:

    python studies/grid_convergence_uniform.py [--workers 2]

writes ``results/reproduce/grid_convergence_uniform_today.{csv,md}`` (with the package hash and
git commit that ran them).  About 6 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from jko_cvx.reproduce.gamma1p5 import COLLAPSE_SPREAD
from jko_cvx.reproduce.grid_convergence import _gamma1p5_rows, _points, convergence, grid_point
from jko_cvx.sweep import code_provenance, run_sweep

RESULTS = Path(__file__).parent / "results" / "reproduce"
FROZEN = RESULTS / "grid_convergence.csv"
COLLAPSE = f"t(sigma_v < {COLLAPSE_SPREAD:g})"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=RESULTS / "cache" / "grid_convergence_uniform_today")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")

    code = code_provenance(grid_point)
    points = [p for p in _points(quick=False) if p["study"] == "gamma1p5" and p["grid"] == "uniform"]
    runs = run_sweep(grid_point, points, args.cache, workers=args.workers, desc="uniform references")
    today = _gamma1p5_rows(runs)  # the rows carry their point's keys
    frozen = pd.read_csv(FROZEN)
    frozen = frozen[frozen.grid == "uniform"].set_index(["case", "n"])
    table = today[["case", "lambda", "n", "stop", "t stop", COLLAPSE, "steps", "failed slices", "seconds"]].copy()
    table["frozen code: stop"] = [frozen.loc[(c, n), "stop"] for c, n in zip(table.case, table.n, strict=True)]
    table[f"frozen code: {COLLAPSE}"] = [frozen.loc[(c, n), COLLAPSE] for c, n in zip(table.case, table.n, strict=True)]
    table = table.sort_values(["case", "n"], ascending=[False, True]).reset_index(drop=True)
    table.to_csv(RESULTS / "grid_convergence_uniform_today.csv", index=False)
    lines = [
        "# grid_convergence: the uniform references on today's code",
        "",
        f"Code: package sha256 {code['package_sha256'][:16]}..., git commit {(code['git_commit'] or 'unknown')[:12]}"
        + (" (jko_cvx modified)" if code["jko_cvx_modified"] else "")
        + "; the frozen columns are the shipped report's (commit fd12f88, no v-floor on the fixed grid).",
        "",
        table.to_markdown(index=False, floatfmt=".4g"),
        "",
    ]
    for case, rows in table.groupby("case", sort=False):
        if rows[COLLAPSE].notna().all() and len(rows) >= 3:
            c = convergence(rows[COLLAPSE].tolist())
            lines.append(
                f"- {case}: collapse times {', '.join(f'{x:.3f}' for x in rows[COLLAPSE])} on n = "
                f"{', '.join(str(int(n)) for n in rows.n)}; successive differences {c['d1']:.4f}, {c['d2']:.4f}"
                + (f", observed order {c['order']:.2f}" if c["order"] == c["order"] else "")
            )
    (RESULTS / "grid_convergence_uniform_today.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
