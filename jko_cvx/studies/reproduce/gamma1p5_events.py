"""Blow-up or collapse: what the velocity spread does after it falls below the threshold (``sec:sp_inhom_gamma_1p5``).

A blow-up in v sends the smallest local velocity spread sigma_v to 0 and keeps it there; a
collapse that reverses lets it grow again.  :func:`spread_event` names the event of one run
from its record of sigma_v against t: the first time it falls below the threshold
:data:`~jko_cvx.studies.reproduce.gamma1p5.COLLAPSE_SPREAD`, its smallest recorded value and
when, and whether it comes back above the threshold (``"collapse at t = t_c, reversed by
t = t_r"``), stays below with the run still on it (``"collapse at t = t_c, not reversed by
t = t_end"``), or was not followed past the threshold (a run stopped there).

``jko-cvx reproduce inhom_gamma1p5_events`` reads the shipped records of every gamma = 3/2 grid,
``inhom_gamma1p5_resolution.csv`` (41^2-121^2 mapped and the uniform reference, run past the
collapse) and ``grid_convergence.csv`` (121^2-481^2 mapped and uniform, stopped at it), and
writes ``inhom_gamma1p5_events.{csv,md,png}``.  The resolution file holds sigma_v at
t = 0.2, 0.4, 0.6, at the threshold crossing and at the run's end (and, from the sweep of
:func:`~jko_cvx.studies.reproduce.gamma1p5.reproduce_inhom_gamma1p5` on, the exact minimum
and return time of the whole record): a minimum read off these samples is an upper bound
of the record's, and a return time the first sample back above the threshold.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.gamma1p5 import (
    COLLAPSE_SPREAD,
    MEETING_TIME,
    SPREAD_TIMES,
    UNIFORM,
    spread_event,
)
from jko_cvx.studies.solvers.figures import finish_figure, pyplot

__all__ = ["EVENT_FILES", "events", "reproduce_inhom_gamma1p5_events"]

EVENT_FILES = ("inhom_gamma1p5_resolution.csv", "grid_convergence.csv")
"""The files :func:`events` reads: the sweep run past the collapse, and the grid study stopped at it."""

_BELOW = f"t(sigma_v < {COLLAPSE_SPREAD:g})"


def _num(r: pd.Series, key: str) -> float:
    return float(r[key]) if key in r and pd.notna(r[key]) else float("nan")


def _resolution_event(r: pd.Series, uniform_t_end: float) -> dict[str, Any]:
    """One row of ``inhom_gamma1p5_resolution.csv``: its samples of sigma_v, and the exact columns where present."""
    t_end = _num(r, "t (end)")
    if np.isnan(t_end):  # files written before the column: the run ended at T_b, or at the uniform reference's t_end
        t_end = r.T_b if pd.notna(r.T_b) else uniform_t_end
    t = [tk for tk in SPREAD_TIMES if pd.notna(r.get(f"sigma_v(t={tk:g})"))]
    samples = [(tk, float(r[f"sigma_v(t={tk:g})"])) for tk in t]
    if not np.isnan(_num(r, "t(min sigma_v)")):
        samples.append((_num(r, "t(min sigma_v)"), _num(r, "min sigma_v")))
    samples.append((float(t_end), float(r["sigma_v (end)"])))
    times, sigma = zip(*sorted(samples), strict=True)
    return spread_event(
        list(times), list(sigma), t_below=_num(r, _BELOW), t_back=_num(r, f"t(sigma_v back >= {COLLAPSE_SPREAD:g})")
    )


def _convergence_event(r: pd.Series) -> dict[str, Any]:
    """One gamma = 3/2 row of ``grid_convergence.csv`` (stopped at the collapse, the paper's criterion or t_end)."""
    cols = [c for c in r.index if c.startswith("sigma_v(t=")]
    samples = [(float(c[len("sigma_v(t=") : -1]), float(r[c])) for c in cols if pd.notna(r[c])]
    samples.append((float(r["t stop"]), float(r["sigma_v (stop)"])))
    times, sigma = zip(*sorted(samples), strict=True)
    stopped = pd.notna(r[_BELOW]) and np.isclose(r[_BELOW], r["t stop"])
    return spread_event(list(times), list(sigma), t_below=_num(r, _BELOW), followed=not stopped)


def events(root: Path, uniform_t_end: float = UNIFORM[2]) -> pd.DataFrame:
    """The event of every gamma = 3/2 run in the files :data:`EVENT_FILES` under ``root``, one row per run.

    ``uniform_t_end``: the end of the uniform reference runs, for resolution files that do not
    record it (those the shipped sweep wrote: :data:`~jko_cvx.studies.reproduce.gamma1p5.UNIFORM`).
    """
    root = Path(root)
    missing = [name for name in EVENT_FILES if not (root / name).is_file()]
    if missing:
        raise FileNotFoundError(f"out: reproduce inhom_gamma1p5_events reads {missing} in {root}; run those entries")
    res = pd.read_csv(root / EVENT_FILES[0])
    conv = pd.read_csv(root / EVENT_FILES[1])
    conv = conv[conv.case.isin(res.case.unique())] if "case" in conv else conv.iloc[0:0]
    rows = []
    for _, r in res.iterrows():
        grid = str(r.grid) if str(r.grid).endswith("uniform") else f"{r.grid} mapped"
        source = EVENT_FILES[0]
        rows.append(
            {"case": r.case, "lambda": r["lambda"], "grid": grid, **_resolution_event(r, uniform_t_end), "file": source}
        )
    for _, r in conv.iterrows():
        grid = f"{int(r.n)} x {int(r.n)} {r.grid}"
        source = EVENT_FILES[1]
        rows.append({"case": r.case, "lambda": r["lambda"], "grid": grid, **_convergence_event(r), "file": source})
    return pd.DataFrame(rows)


def _figure(df: pd.DataFrame, samples: dict[int, tuple[list[float], list[float]]], path: Path) -> None:
    """sigma_v against t (the recorded samples) per grid and case, with the threshold and the meeting time."""
    plt = pyplot()
    cases = list(dict.fromkeys(df.case))
    fig, axes = plt.subplots(1, len(cases), figsize=(6.4 * len(cases), 7.0), squeeze=False)
    for ax, case in zip(axes[0], cases, strict=True):
        for i, (k, r) in enumerate(df[df.case == case].iterrows()):
            t, s = samples[k]
            style = "--" if "uniform" in r.grid else "-"
            ax.semilogy(t, s, style, marker="o", ms=3, color=plt.cm.tab20(i % 20), label=f"{r.grid}: {r.event}")
        ax.axhline(COLLAPSE_SPREAD, color="k", lw=1, label=f"threshold sigma_v = {COLLAPSE_SPREAD:g}")
        ax.axvline(MEETING_TIME, color="k", ls=":", lw=1, label="bumps meet (c/d)")
        ax.set_title(
            f"{case}, lambda = {df[df.case == case]['lambda'].iloc[0]:g}: sigma_v (recorded samples)", fontsize=9
        )
        ax.set_xlabel("t")
        ax.set_ylabel("sigma_v")
    finish_figure(fig, axes[0], path, fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.12))


def reproduce_inhom_gamma1p5_events(out: Path, quick: bool = False, **_sweep_opts: Any) -> pd.DataFrame:
    """Write ``inhom_gamma1p5_events.{csv,md,png}`` in ``out`` from the files there (:func:`events`).

    ``quick`` changes nothing: no run is made.
    """
    out = Path(out)
    df = events(out)
    samples = {k: (r["sample t"], r["sample sigma_v"]) for k, r in df.iterrows()}
    table = df.drop(columns=["sample t", "sample sigma_v"])
    table.to_csv(out / "inhom_gamma1p5_events.csv", index=False)
    record_csv(out / "inhom_gamma1p5_events.csv")
    followed = table[table.followed & table["t below"].notna()]
    counts = []
    for kind in ("mapped", "uniform"):
        runs = followed[followed.grid.str.endswith(kind)]
        counts.append(f"{int(runs['t back above'].notna().sum())} of {len(runs)} {kind}")
    write_markdown(
        out / "inhom_gamma1p5_events.md",
        "# sec:sp_inhom_gamma_1p5: blow-up or collapse\n\n"
        f"What the smallest local velocity spread sigma_v does after it falls below {COLLAPSE_SPREAD:g}, "
        "on every gamma = 3/2 grid the result files hold.  A blow-up in v keeps sigma_v at 0; a "
        "collapse that comes back above the threshold is not a blow-up.  The minimum and the return "
        "are read off the recorded samples (t = "
        + ", ".join(f"{tk:g}" for tk in SPREAD_TIMES)
        + ", the end of the run, and the exact minimum where the file has it): a sampled minimum "
        "is an upper bound of the record's.  Runs stopped at the threshold (the grid study) were "
        "not followed past it.\n\n"
        f"Of the runs that fell below the threshold and were followed past it, {' and '.join(counts)} come back "
        "above it before their end (on the mapped grids: T_b of the paper's criterion).\n\n"
        + table.to_markdown(index=False, floatfmt=".4g")
        + "\n",
    )
    _figure(df, samples, out / "inhom_gamma1p5_events.png")
    return table
