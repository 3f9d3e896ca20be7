"""The trajectory part of a verification: the whole scene run again with the reference method.

``verify(scene, trajectory=True)`` runs ``scene`` a second time with ``collision.method``
replaced by the reference (and ``collision.options`` by the reference's options), into
``DIR/reference/`` under the run-directory rules, and compares the two runs:

* the stop reason (:class:`~jko_cvx.engine.verdict.StopReason`, the rule, not its value);
* T_b: with blow-up in both, they agree when :math:`|T_b - T_b^{\\rm ref}|` is at most one step
  (the larger of the two runs' last dt), the resolution of a mesh criterion that fires on a step;
* max f(t): the relative difference :math:`|\\max f(t) - \\max f^{\\rm ref}(t)| / \\max f^{\\rm ref}(t)`.

How times are matched: a time of the tested run is *common* when the reference run has a time
within :data:`MATCH` times the smaller dt of the two (fixed dt and the same step halvings give
every step; different halvings give the times both grids share).  Only common times are judged,
against the verification's tolerance (:data:`~jko_cvx.engine.verify.SAFETY` x the reference's
accuracy in f).  At the other tested times within both runs' span the reference's max f is
interpolated linearly in t and shown (column ``matched`` = False) but not judged: its
interpolation error is :math:`O(dt^2 \\, |\\partial_t^2 \\max f|)`, unrelated to the solvers.
The per-step tolerance is a tolerance on one step; along a run the two answers' errors add up and
are amplified near blow-up, so a trajectory that differs where every step agrees says the
scene is sensitive there, not that a solve is wrong.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from jko_cvx.engine.run import Run
from jko_cvx.engine.verdict import run_failure

MATCH = 1e-6
"""Two times are the same when they differ by at most this many of the smaller step (rounding)."""
TRAJECTORY_COLUMNS = ("t", "max_f", "max_f_ref", "dmax_f", "matched", "outcome")
"""The columns of ``trajectory.csv``."""


@dataclass
class TrajectoryComparison:
    """Two runs of one scene compared: the table of max f(t) and the verdict's trajectory part."""

    table: pd.DataFrame
    stop: str
    stop_ref: str
    T_b: float | None
    T_b_ref: float | None
    tolerance: float
    agree: bool
    text: str


def _t_b(run: Run) -> float | None:
    return run.verdict.T_b if run.verdict.blowup else None


def compare_trajectories(run: Run, ref: Run, tolerance: float) -> TrajectoryComparison:
    """Compare ``run`` with ``ref`` (the same scene under the reference method); module docstring."""
    d, r = run.diagnostics, ref.diagnostics
    t, mf = d["t"].to_numpy(float), d["max_f"].to_numpy(float)
    tr, mfr = r["t"].to_numpy(float), r["max_f"].to_numpy(float)
    dts = np.concatenate([d["dt"].to_numpy(float), r["dt"].to_numpy(float)])
    dt_min = float(np.min(dts[dts > 0], initial=np.inf))
    dt_min = dt_min if np.isfinite(dt_min) else 1.0
    slack = MATCH * dt_min  # sums of dt differ in the last bits: 10 x 0.005 ends below 0.05
    inside = (t >= tr[0] - slack) & (t <= tr[-1] + slack) if len(tr) else np.zeros(len(t), bool)
    t, mf = t[inside], mf[inside]
    nearest = np.clip(np.searchsorted(tr, t), 0, max(len(tr) - 1, 0))
    prev = np.clip(nearest - 1, 0, None)
    closest = np.where(np.abs(tr[prev] - t) < np.abs(tr[nearest] - t), prev, nearest) if len(tr) else nearest
    matched = np.abs(tr[closest] - t) <= slack if len(tr) else np.zeros(len(t), bool)
    ref_at = np.where(matched, mfr[closest] if len(tr) else np.nan, np.interp(t, tr, mfr) if len(tr) else np.nan)
    with np.errstate(all="ignore"):
        dmax = np.abs(mf - ref_at) / np.abs(ref_at)
    dmax = np.where(np.isfinite(dmax), dmax, np.inf)
    outcome = np.where(~matched, "not judged", np.where(dmax <= tolerance, "agree", "differ"))
    table = pd.DataFrame({"t": t, "max_f": mf, "max_f_ref": ref_at, "dmax_f": dmax, "matched": matched,
                          "outcome": outcome}, columns=list(TRAJECTORY_COLUMNS))  # fmt: skip
    stop, stop_ref = run.verdict.stop.name, ref.verdict.stop.name
    T_b, T_b_ref = _t_b(run), _t_b(ref)
    problems = []
    # a reference carried on from failed solves is no reference from its first one on: those times, and its stop
    # when that comes later, are not judged (never counted as agreement); before it the comparison stands
    failure = run_failure(ref.verdict)
    if failure is None:
        if stop != stop_ref:
            problems.append(
                f"the runs stop for different reasons ({run.verdict.reason}; reference: {ref.verdict.reason})"
            )
        if (T_b is None) != (T_b_ref is None):
            problems.append(f"T_b {_fmt(T_b)} against the reference's {_fmt(T_b_ref)}")
        elif T_b is not None and T_b_ref is not None:
            step = max(float(d["dt"].iloc[-1]), float(r["dt"].iloc[-1]))
            if abs(T_b - T_b_ref) > step * (1 + MATCH):
                problems.append(
                    f"T_b {T_b:.6g} against the reference's {T_b_ref:.6g}, more than one step ({step:.3g}) apart"
                )
    else:  # the stop is not judged, nor anything from the reference's first uncertified state on (or its T_b)
        first = ref.verdict.first_uncertified_t if ref.verdict.first_uncertified_t is not None else ref.verdict.T_b
        cut = math.inf if first is None else float(first)
        late = table["matched"].to_numpy() & (table["t"].to_numpy() >= cut - slack)
        table.loc[late, "outcome"] = "not judged"
        table.loc[late, "matched"] = False
    judged = table[table["matched"]]
    bad = judged[judged["outcome"] == "differ"]
    if len(bad):
        row = bad.iloc[0]
        problems.append(
            f"max f parts first at t = {row['t']:.6g} ({row['max_f']:.6g} against {row['max_f_ref']:.6g}, relative "
            f"{row['dmax_f']:.2e} > tolerance {tolerance:.1e}; {len(bad)} of {len(judged)} common times)"
        )
    if len(judged) == 0:
        problems.append("the runs share no time to compare max f at")
    worst = float(judged["dmax_f"].max()) if len(judged) else math.nan
    if problems:
        text = "trajectory differs: " + "; ".join(problems)
    elif failure is not None:
        text = (
            f"trajectory agrees where the reference is certified: max f within {tolerance:.1e} at all {len(judged)} "
            f"common times before t = {cut:.6g} (max relative difference {worst:.2e}); the reference run is not "
            f"certified from there ({failure}): later times and the stop (T_b {_fmt(T_b)} against the reference's "
            f"{_fmt(T_b_ref)}) are not judged"
        )
    else:
        text = (
            f"trajectory agrees: same stop ({stop}), T_b {_fmt(T_b)} and {_fmt(T_b_ref)}, max f within {tolerance:.1e} "
            f"at all {len(judged)} common times (max relative difference {worst:.2e})"
        )
    return TrajectoryComparison(table, stop, stop_ref, T_b, T_b_ref, tolerance, not problems, text)


def _fmt(T_b: float | None) -> str:
    return "none (no blow-up)" if T_b is None else f"{T_b:.6g}"
