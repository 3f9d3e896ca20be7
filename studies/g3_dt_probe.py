"""Extend the shipped gamma = 3 table case by case: ``python studies/g3_dt_probe.py --cases CASE ...``.

The study is ``jko-cvx reproduce g3_dt_probe`` (:mod:`jko_cvx.studies.reproduce.dt_probe`: the runs, the report,
the figure); its full form takes many hours on one core, so the shipped
``studies/results/reproduce/g3_dt_probe.{csv,md,png}`` were assembled by this driver over several sessions: it
runs the given cases with the same :func:`~jko_cvx.studies.reproduce.dt_probe.probe_run`, writes the CSV after
every run (a killed probe keeps what it ran), skips a case already in the CSV from the same commit, replaces
one from another commit, and rewrites the report from every row (each row names the commit that ran it).
Default cases: the entry's full form.  A case is ``lam:n:dt[:order[:key=value,...]]`` (order 1 or 2, default
1; keys of :data:`~jko_cvx.studies.reproduce.dt_probe.VARIANT_KEYS`).  ``--run-dir DIR`` runs each case in
``DIR/<case>/``, a run directory checkpointed every step: a case longer than a session is continued where it
stopped by the same command under the same code (a worktree at the same commit), bit for bit.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from jko_cvx.environment import environment, environment_line, record_csv, write_markdown
from jko_cvx.studies.reproduce.dt_probe import (
    FULL_CASES,
    parse_variant,
    probe_figure,
    probe_report,
    probe_rows,
    probe_run,
    variant_key,
)

OUT = Path(__file__).parent / "results" / "reproduce"  # evidence of the conclusions table
CSV = OUT / "g3_dt_probe.csv"
KEY = ("lambda", "n", "dt", "time_order")  # and the variant, by what it changes (variant_key)


def parse_case(text: str) -> tuple[float, int, float, int, str]:
    """``lam:n:dt[:order[:key=value,...]]`` (order 1 or 2, default 1), checked before any run."""
    parts = text.split(":")
    if len(parts) not in (3, 4, 5):
        raise ValueError(f"a case is lam:n:dt[:order[:key=value,...]], got {text!r}")
    lam, n, dt = float(parts[0]), int(parts[1]), float(parts[2])
    order = int(parts[3]) if len(parts) >= 4 else 1
    if lam not in (4.0, 10.0):
        raise ValueError(f"lambda must be 4 or 10 (the shipped scenes), got {parts[0]!r}")
    if not (n >= 3 and dt > 0 and order in (1, 2)):
        raise ValueError(f"need n >= 3, dt > 0 and order 1 or 2, got {text!r}")
    variant = parts[4] if len(parts) == 5 else ""
    parse_variant(variant)  # checked here, before any run
    return lam, n, dt, order, variant


def case_dir(lam: float, n: int, dt: float, order: int, variant: str) -> str:
    """The case's run directory name: ``lam10_n481_dt0.00625_o1`` (and the variant, characters other than letters,
    digits, ``.`` and ``-`` as ``_``)."""
    name = f"lam{lam:g}_n{n}_dt{dt:g}_o{order}"
    if variant:
        name += "_" + "".join(c if c.isalnum() or c in ".-" else "_" for c in variant)
    return name


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cases", nargs="*", default=None, help="lam:n:dt[:order[:variant]] (default: the full form)")
    parser.add_argument("--run-dir", type=Path, default=None, help="checkpoint each case in DIR/<case>/, continued")
    args = parser.parse_args(argv)
    cases = FULL_CASES if args.cases is None else [parse_case(c) for c in args.cases]
    commit = environment().get("git_commit")
    done = probe_rows(pd.read_csv(CSV)) if CSV.exists() else pd.DataFrame()
    rows = done.to_dict("records")

    def key(r: dict) -> tuple:  # the variant by what it changes, not by its spelling
        return (*(r[k] for k in KEY), variant_key(r["variant"]))

    for lam, n, dt, order, variant in cases:
        case = (lam, n, dt, order, variant_key(variant))
        if any(key(r) == case and r.get("commit") == commit for r in rows):
            continue
        rows = [r for r in rows if key(r) != case]
        out = None if args.run_dir is None else args.run_dir / case_dir(lam, n, dt, order, variant)
        row = {**probe_run(lam, n, dt, order, variant, out=out), "commit": commit}
        rows.append(row)
        print(
            f"lambda {lam:g} n {n} dt {dt:g} order {order} {variant}: peak max f {row['max_f_peak']:.4g}, min dx "
            f"{row['min_dx']:.3g}, {row['reason']}, {row['blowup_kind']} ({row['seconds']:.0f} s)",
            flush=True,
        )
        df = pd.DataFrame(rows)
        df.to_csv(CSV, index=False)  # after every run: a killed probe keeps what it ran
        record_csv(CSV)
    df = pd.DataFrame(rows)
    write_markdown(OUT / "g3_dt_probe.md", probe_report(df))
    probe_figure(df, OUT / "g3_dt_probe.png")
    print(environment_line())


if __name__ == "__main__":
    main()
