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
t = 0.2, 0.4, 0.6 and at the run's end, and the whole record's exact minimum, its time, the
first time below the threshold and the first return above it (files written before those
columns: a minimum read off the samples, an upper bound of the record's).  The minimum need
not come before the return: on some grids sigma_v comes back above the threshold and then
dips a second time, deeper, before T_b (``end / min`` is measured from that deepest point).
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
_BACK = f"t(sigma_v back >= {COLLAPSE_SPREAD:g})"


def _num(r: pd.Series, key: str) -> float:
    return float(r[key]) if key in r and pd.notna(r[key]) else float("nan")


def _resolution_event(r: pd.Series, uniform_t_end: float) -> dict[str, Any]:
    """One row of ``inhom_gamma1p5_resolution.csv``: its samples of sigma_v, and the exact columns where present.

    Where the file has the whole record's columns (minimum, its time, the return above the
    threshold) they decide, and the samples must agree with them: no sample below the
    minimum, none at or above the threshold after the collapse of a run that never comes
    back, the return after the collapse.  A row that disagrees was edited or written by
    other code, and is refused.
    """
    t_end = _num(r, "t (end)")
    if np.isnan(t_end):  # files written before the column: the run ended at T_b, or at the uniform reference's t_end
        t_end = r.T_b if pd.notna(r.T_b) else uniform_t_end
    t = [tk for tk in SPREAD_TIMES if pd.notna(r.get(f"sigma_v(t={tk:g})"))]
    samples = [(tk, float(r[f"sigma_v(t={tk:g})"])) for tk in t]
    samples.append((float(t_end), float(r["sigma_v (end)"])))
    exact = not np.isnan(_num(r, "t(min sigma_v)")) and _BACK in r.index
    t_below, t_back = _num(r, _BELOW), (_num(r, _BACK) if exact else None)
    if exact:
        t_min, s_min = _num(r, "t(min sigma_v)"), _num(r, "min sigma_v")
        where = f"{EVENT_FILES[0]}, {r.case} {r.grid}"
        if not (0.0 <= t_min <= t_end) or any(sk < s_min * (1 - 1e-12) for _, sk in samples):
            raise ValueError(f"{where}: min sigma_v {s_min:g} at t = {t_min:g} disagrees with the samples {samples}")
        if not np.isnan(t_below):
            if t_back is not None and not np.isnan(t_back) and not (t_below < t_back <= t_end):
                raise ValueError(
                    f"{where}: the return t = {t_back:g} is not between the collapse {t_below:g} and the end"
                )
            if (
                t_back is not None
                and np.isnan(t_back)
                and any(tk > t_below and sk >= COLLAPSE_SPREAD for tk, sk in samples)
            ):
                raise ValueError(f"{where}: no return above {COLLAPSE_SPREAD:g} recorded, but a sample is above it")
        samples.append((t_min, s_min))
    times, sigma = zip(*sorted(samples), strict=True)
    return spread_event(list(times), list(sigma), t_below=t_below, t_back=t_back)


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
    second = int((followed["t(min sigma_v)"] > followed["t back above"]).sum())
    write_markdown(
        out / "inhom_gamma1p5_events.md",
        "# sec:sp_inhom_gamma_1p5: blow-up or collapse\n\n"
        f"What the smallest local velocity spread sigma_v does after it falls below {COLLAPSE_SPREAD:g}, "
        "on every gamma = 3/2 grid the result files hold.  A blow-up in v keeps sigma_v at 0; a "
        "collapse that comes back above the threshold is not a blow-up.  The minimum, its time and the "
        "return are the whole record's where the file has them (a minimum read off the samples at t = "
        + ", ".join(f"{tk:g}" for tk in SPREAD_TIMES)
        + " and the end is an upper bound of the record's).  Runs stopped at the threshold (the grid "
        "study) were not followed past it.\n\n"
        f"Of the runs that fell below the threshold and were followed past it, {' and '.join(counts)} come back "
        "above it before their end (on the mapped grids: T_b of the paper's criterion); "
        f"{second} of them dip a second time, deeper, after the return (t(min sigma_v) > t back above).\n\n"
        + table.to_markdown(index=False, floatfmt=".4g")
        + "\n",
    )
    _figure(df, samples, out / "inhom_gamma1p5_events.png")
    return table
