"""Tables ``tab:bu`` (g1-g3) and ``tab:bu_tb2`` (g4): numerical blow-up times against eps_v and dt.

Homogeneous gamma = 1 (``sec31``), N_v = 121, mesh refinement delta = delta0 = 0.5, fixed
dt, the run stopped when min dv < eps_v: T_b is that time.  Each (data, eps_v, dt) is one
entry is the run of one (data, eps_v, dt), a pure function of its parameters
(:func:`blowup_time`).  The scenes are the shipped ``jko_cvx/scene/shipped/tab_bu_g*.toml`` with
eps_v, dt, beta and the end time set per entry.  A column of a table (one data, dt and beta,
every eps_v) is one sweep point, :func:`blowup_times`: eps_v only decides when a run stops,
so the run at the smallest eps_v holds the runs at the larger ones as prefixes, and their
entries are read off its records (bitwise those of the separate runs; a third of the
steps of the beta scan).

The paper does not state its Fisher weight.  The log-Fisher term with weight beta bounds
the collapsed bump's width by about ``(dt / (beta^2 M))^(1/3)``, so beta decides whether
the smallest eps_v are reached at all.  Scanned (full table, g1-g3; entries within 0.03 of
the paper's / runs that never fire / the g1 entry at eps_v = 1e-3/16, dt = 0.00125, exact
0.5): beta = 1000: 61 / 7 / 0.5975; 3000: 68 / 3 / 0.51125; 4000: 69 / 0 / 0.5125;
5000: 64 / 0 / 0.5125; 6000: 67 / 1 / 0.49125; 1e4: 58 / 1 / 0.49125; inf: 57 / 12 /
0.495 (the runs that never fire fail to converge after T instead).  ``TAB_BU_BETA = 6000``
is the smallest scanned weight whose smallest-eps_v, smallest-dt g1 entry lies within
0.01 of the exact 0.5.  For g4 (``tab:bu_tb2``, two bumps, two-bump map) a weaker Fisher
term makes the runs fire earlier still (entries within 0.03: 6 of 16 at beta = 1000,
1 of 16 at 6000), so that table keeps ``TAB_BU_TB2_BETA = 1000``.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.blowup import KINDS, extrapolate_thresholds
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.trackers import EpsV
from jko_cvx.engine.verdict import StopReason, Verdict, fit_rows
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.exact import GaussianMixture, blowup_time_gamma1, exact_gamma1
from jko_cvx.grid import Grid
from jko_cvx.mesh.maps import OneBumpMap, TwoBumpMap
from jko_cvx.scene.model import Scene, shipped_scene
from jko_cvx.studies.reproduce import paper
from jko_cvx.studies.reproduce.discrimination import scores, scores_markdown
from jko_cvx.studies.sweep import run_sweep

__all__ = [
    "DATA",
    "FIT_COLUMNS",
    "TAB_BU_BETA",
    "TAB_BU_TB2_BETA",
    "THRESHOLD_COLUMNS",
    "blowup_scene",
    "blowup_time",
    "blowup_times",
    "fit_columns",
    "reproduce_tab_bu",
    "reproduce_tab_bu_tb2",
    "table_entries",
    "table_points",
    "threshold_columns",
    "threshold_limit",
]

DATA = ("g1", "g2", "g3", "g4")
"""The initial data of the tables: the shipped scenes ``tab_bu_g1`` ... ``tab_bu_g4``."""


TAB_BU_BETA = 6000.0
TAB_BU_TB2_BETA = 1000.0


def blowup_scene(
    data: str, eps_v: float, dt: float, beta: float = TAB_BU_BETA, overrides: dict[str, Any] | None = None
) -> Scene:
    """The shipped ``tab_bu_{data}`` scene (g1-g4) at eps_v, dt and log-Fisher weight ``beta``, run to 2 T.

    ``overrides`` sets further dotted keys (:func:`jko_cvx.scene.with_overrides`).
    """
    if data not in DATA:
        raise ValueError(f"data must be one of {list(DATA)}, got {data!r}")
    return shipped_scene(
        f"tab_bu_{data}",
        {
            "t_end": 2 * paper.EXACT_T[data],
            "time.dt": dt,
            "stop.eps_v": eps_v,
            "collision.beta": beta,
            "output.every": 10**6,
            "output.checkpoint_every": 10**6,
            **(overrides or {}),
        },
    )


def blowup_time(data: str, eps_v: float, dt: float, beta: float = TAB_BU_BETA) -> dict[str, Any]:
    """One sweep point: run the scene to blow-up; T_b (NaN if not reached by 2 T), steps, seconds."""
    t0 = time.perf_counter()
    run = simulate(blowup_scene(data, eps_v, dt, beta))
    return {
        "T_b": float(run.verdict["T_b"]) if run.blowup else float("nan"),
        "steps": len(run.diagnostics) - 1,
        "failed_steps": int((run.diagnostics.failed > 0).sum()),
        **fit_columns(run.verdict),
        "seconds": time.perf_counter() - t0,
    }


FIT_COLUMNS = ("T_b_fit", "T_b_fit_err", "blowup_rate", "blowup_kind")
"""The estimate of :mod:`jko_cvx.blowup` beside the paper's T_b (NaN where the fit locates no blow-up time)."""


def fit_columns(v) -> dict[str, Any]:
    """T_b_fit, its error bar, the rate a and the kind of a verdict (or of a fit read as one, :class:`_FitView`)."""

    def num(x):
        return float("nan") if x is None else float(x)

    kind = v.blowup_kind
    return {"T_b_fit": num(v.T_b_fit), "T_b_fit_err": num(v.T_b_fit_err), "blowup_rate": num(v.blowup_rate),
            "blowup_kind": kind}  # fmt: skip


def blowup_times(data: str, eps_v: Sequence[float], dt: float, beta: float = TAB_BU_BETA) -> dict[str, Any]:
    """One sweep point for a column of the tables: :func:`blowup_time` at every threshold of ``eps_v``, from one run.

    eps_v enters a run only through its stopping rule (:class:`~jko_cvx.engine.trackers.EpsV`
    reads the diagnostics row of each accepted step; nothing in a step depends on it).  So
    the run at the smallest threshold passes through every state that the run at a larger
    one passes through, up to where that one stops, and the stop is found in its records
    (:func:`replayed_entry`).  Each entry equals :func:`blowup_time`'s at that eps_v, bit
    for bit (tested).

    Returns
    -------
    dict
        ``eps_v`` (the thresholds, in the order given), ``T_b``, ``steps`` and
        ``failed_steps`` (lists in that order) and ``seconds``, the wall time of the one run.
    """
    eps = [float(e) for e in eps_v]
    if not eps or not all(np.isfinite(e) and e > 0 for e in eps) or len(set(eps)) != len(eps):
        raise ValueError(f"eps_v must be distinct positive finite thresholds (at least one), got {list(eps_v)!r}")
    t0 = time.perf_counter()
    run = simulate(blowup_scene(data, min(eps), dt, beta))
    entries = [replayed_entry(run.diagnostics, run.verdict, e) for e in eps]
    return {
        "eps_v": eps,
        **{key: [entry[key] for entry in entries] for key in ("T_b", "steps", "failed_steps", *FIT_COLUMNS)},
        "seconds": time.perf_counter() - t0,
    }


def replayed_entry(diagnostics: pd.DataFrame, verdict: Verdict, eps_v: float) -> dict[str, Any]:
    """:func:`blowup_time`'s entry at ``eps_v`` from the records of the same scene run at a threshold <= eps_v.

    The time loop tests its stopping rules on the row of each accepted step (not on the
    initial row); the run at ``eps_v`` stops at the first of those rows where min dv <
    eps_v (:meth:`EpsV.fires <jko_cvx.engine.trackers.StopRule.fires>`, the rule itself), unless the
    recorded run stopped first, on another rule or at t_end, which the run at ``eps_v``
    does as well.  ``T_b`` (NaN without blow-up), ``steps`` (accepted steps) and
    ``failed_steps`` (rows with a failed slice) as :func:`blowup_time` counts them.
    """
    rule = EpsV(eps_v)
    rows = diagnostics.to_dict("records")
    for k in range(1, len(rows)):
        if rule.fires(rows[k]) is not None:
            stopped = Verdict().stopped(StopReason.EPS_V, float(rows[k]["t"]), "replayed")
            fit = fit_rows(rows[: k + 1], stopped) if "max_f" in diagnostics else None
            return {
                "T_b": float(rows[k]["t"]),
                "steps": k,
                "failed_steps": int((diagnostics["failed"].iloc[: k + 1] > 0).sum()),
                **(fit_columns(_FitView(fit)) if fit is not None else {}),
            }
    return {
        "T_b": float(verdict["T_b"]) if verdict.blowup else float("nan"),
        "steps": len(rows) - 1,
        "failed_steps": int((diagnostics["failed"] > 0).sum()),
        **(fit_columns(verdict) if "max_f" in diagnostics else {}),
    }


class _FitView:
    """A :class:`~jko_cvx.blowup.BlowupFit` read as a verdict's fit fields."""

    def __init__(self, fit) -> None:
        (self.T_b_fit, self.T_b_fit_err, self.blowup_rate), self.blowup_kind = fit.estimate(), fit.blowup_kind


def mesh_rule_time(data: str, eps_v: float) -> float:
    """When the paper's mesh rule, applied to the *exact* solution, first gives min dv < eps_v.

    The exact solution (Burgers characteristics, :func:`jko_cvx.exact.exact_gamma1`) is
    sampled on a fine uniform grid at times approaching T; the one- or two-bump map of the
    table's scene (delta0 = delta = 0.5, N = 121) is built from it, and the time at which its
    smallest spacing crosses eps_v is interpolated (log spacing against t).  This is the
    blow-up time a solver without discretisation error in t and f would report: it separates
    what the mesh rule measures from what the solver adds.
    """
    ts, spacing = _mesh_rule_curve(data)
    if not spacing.min() < eps_v < spacing.max():
        raise ValueError(f"eps_v = {eps_v!r} outside the computed range [{spacing.min():.3g}, {spacing.max():.3g}]")
    # spacing decreases in t: interpolate t against log spacing, reversed to increase
    return float(np.interp(np.log(eps_v), np.log(spacing[::-1]), ts[::-1]))


@functools.cache
def _mesh_rule_curve(data: str, n_fine: int = 6001, n_times: int = 160) -> tuple[np.ndarray, np.ndarray]:
    scene = blowup_scene(data, 0.0, 0.01)
    p = scene.initial
    f0 = GaussianMixture(list(p.amplitudes), list(p.rates), list(p.centres))
    T = blowup_time_gamma1(f0)
    fine = Grid(np.linspace(-scene.v.L, scene.v.L, n_fine))
    r, n = scene.refine.v, scene.v.n
    cls = OneBumpMap if r.bumps == 1 else TwoBumpMap
    ts = T * (1 - np.geomspace(0.5, 1e-4, n_times))
    spacing = np.array(
        [
            np.diff(cls.from_density(fine, exact_gamma1(f0, t, fine.points), r.delta0, r.delta).grid(n).points).min()
            for t in ts
        ]
    )
    return ts, spacing


def table_points(datas, eps_list, dts, beta: float = TAB_BU_BETA) -> list[dict[str, Any]]:
    """The sweep points of a table: one :func:`blowup_times` point per (data, dt), every eps_v of ``eps_list``.

    beta is part of every point, so cached points of another weight are not reused; two
    tables (``tab_bu`` and the beta scan) ask for the same point in the same form, so that a
    shared pool runs it once (:func:`jko_cvx.studies.sweep.shared_points`).
    """
    return [{"data": d, "eps_v": [float(e) for e in eps_list], "dt": t, "beta": beta} for d in datas for t in dts]


def table_entries(runs: pd.DataFrame) -> pd.DataFrame:
    """One row per (beta, data, eps_v, dt) of the :func:`blowup_times` sweep ``runs``, in the tables' order.

    ``seconds`` and ``cached`` are those of the run the entry was read from.
    """
    rows = [
        {
            "data": r.data,
            "eps_v": e,
            "dt": r.dt,
            "beta": r.beta,
            "T_b": r.T_b[i],
            "steps": r.steps[i],
            "failed_steps": r.failed_steps[i],
            **{k: getattr(r, k)[i] for k in FIT_COLUMNS if hasattr(r, k)},
            "seconds": r.seconds,
            **({"cached": r.cached} if "cached" in runs else {}),
        }
        for r in runs.itertuples(index=False)
        for i, e in enumerate(r.eps_v)
    ]
    entries = pd.DataFrame(rows)
    # the tables' order: beta, data, eps_v, dt, each as first met (the points' order)
    keys = ("beta", "data", "eps_v", "dt")
    rank = {k: {v: i for i, v in enumerate(dict.fromkeys(entries[k]))} for k in keys}
    order = sorted(range(len(entries)), key=lambda j: tuple(rank[k][entries[k].iat[j]] for k in keys))
    return entries.iloc[order].reset_index(drop=True)


def _sweep(points, out: Path, name: str, **sweep_opts) -> pd.DataFrame:
    t0 = time.perf_counter()
    runs = run_sweep(blowup_times, points, out / "cache" / name, desc=name, **sweep_opts)
    wall = time.perf_counter() - t0
    df = table_entries(runs)
    df.attrs["runs"] = len(runs)
    df.attrs["cached_runs"] = int(runs.cached.sum())
    table = paper.TAB_BU if name == "tab_bu" else paper.TAB_BU_TB2
    dts = paper.TAB_BU_DT if name == "tab_bu" else paper.TAB_BU_TB2_DT

    def paper_value(row):
        eps = min(table[row.data], key=lambda e: abs(e - row.eps_v))
        return table[row.data][eps][dts.index(row["dt"])]

    df["paper"] = df.apply(paper_value, axis=1)
    df["exact"] = df.data.map(paper.EXACT_T)
    df["exact + mesh rule"] = [mesh_rule_time(d, e) for d, e in zip(df.data, df.eps_v, strict=True)]
    df["ours_minus_paper"] = df.T_b - df.paper
    df["ours_minus_exact"] = df.T_b - df.exact
    if "T_b_fit" in df:
        df["fit_minus_exact"] = df.T_b_fit - df.exact
    df = threshold_columns(df)
    df.attrs["wall_seconds"] = wall
    return df


THRESHOLD_COLUMNS = ("T_0 (eps_v -> 0)", "T_0 err")
"""The cross-check of T_b_fit: each column's threshold times extrapolated to eps_v -> 0."""


def threshold_columns(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with :data:`THRESHOLD_COLUMNS`: per (beta, data, dt), the threshold times of its eps_v extrapolated
    to eps_v -> 0 (:func:`jko_cvx.blowup.extrapolate_thresholds`, the step's quantum in the bar), the same value
    on every entry of the column; NaN where too few thresholds fired for the fit or the law does not fit."""
    out = df.copy()
    T0 = np.full(len(out), np.nan)
    err = np.full(len(out), np.nan)
    for _, idx in out.groupby(["beta", "data", "dt"], sort=False).groups.items():
        rows = out.loc[idx]
        fired = rows.T_b.notna().to_numpy()
        pos = out.index.get_indexer(idx)
        T0[pos], err[pos] = threshold_limit(rows.eps_v.to_numpy()[fired], rows.T_b.to_numpy()[fired], rows.dt.iloc[0])
    out[THRESHOLD_COLUMNS[0]], out[THRESHOLD_COLUMNS[1]] = T0, err
    return out


def threshold_limit(eps_v: np.ndarray, T_b: np.ndarray, dt: float) -> tuple[float, float]:
    """``(T_0, T_0 err)`` of :func:`jko_cvx.blowup.extrapolate_thresholds` on the thresholds that fired, or two
    NaN where fewer than three fired, too few are distinct, or the law does not fit (a table's cell, not an error)."""
    if len(eps_v) < 3:
        return float("nan"), float("nan")
    try:
        ex = extrapolate_thresholds(eps_v, T_b, dt)
    except (ValueError, RuntimeError):
        return float("nan"), float("nan")
    return ex.T, ex.T_err


def threshold_summary(df: pd.DataFrame) -> str:
    """The cross-check in words: T_0 against the exact time and against the fit of the column's smallest eps_v."""
    cols = df.dropna(subset=[THRESHOLD_COLUMNS[0]]).sort_values("eps_v").groupby(["beta", "data", "dt"], sort=False)
    first = cols.head(1)  # one row per column: its smallest eps_v (the whole run)
    if first.empty:
        return "Threshold extrapolation (eps_v -> 0): no column with three fired thresholds."
    T0, bar = first[THRESHOLD_COLUMNS[0]], first[THRESHOLD_COLUMNS[1]]
    gap = (T0 - first.exact).abs()
    fit = first[first.blowup_kind == "finite_time"] if "blowup_kind" in first else first.iloc[:0]
    both = (fit[THRESHOLD_COLUMNS[0]] - fit.T_b_fit).abs() <= np.hypot(fit[THRESHOLD_COLUMNS[1]], fit.T_b_fit_err)
    return (
        f"Cross-check (jko_cvx.blowup.extrapolate_thresholds: each (data, dt) column's threshold times fitted by "
        f"T_0 - c eps_v^p and extrapolated to eps_v -> 0; columns `{THRESHOLD_COLUMNS[0]}`, `{THRESHOLD_COLUMNS[1]}`): "
        f"{len(first)} columns, |T_0 - exact| median {gap.median():.2g}, max {gap.max():.2g}; the bar covers the "
        f"exact time in {int((gap <= bar).sum())} of {len(first)}; T_0 and the finite_time T_b_fit of the column's "
        f"smallest eps_v agree within their combined bars in {int(both.sum())} of {len(fit)}."
    )


def _write(df: pd.DataFrame, out: Path, name: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    df.drop(columns=["cached"]).to_csv(out / f"{name}.csv", index=False)
    record_csv(out / f"{name}.csv")
    lines = [
        f"# {name}: T_b ours / paper (exact T in the heading)",
        "",
        "Last column: when the paper's mesh rule applied to the exact solution first gives min dv < eps_v "
        "(`mesh_rule_time`): what a solver without error in t and f would report.",
        "",
    ]
    for data, block in df.groupby("data", sort=False):
        dts = sorted(block["dt"].unique(), reverse=True)
        lines.append(f"**{data}** (exact T = {paper.EXACT_T[data]})")
        lines.append("")
        lines.append("| eps_v | " + " | ".join(f"dt = {t:g}" for t in dts) + " | exact + mesh rule |")
        lines.append("|:--|" + "--:|" * (len(dts) + 1))
        for eps, rows in block.groupby("eps_v", sort=False):
            cells = []
            for t in dts:
                r = rows[rows["dt"] == t].iloc[0]
                cells.append(f"{r.T_b:.5g} / {r.paper:g}")
            cells.append(f"{rows['exact + mesh rule'].iloc[0]:.4f}")
            lines.append(f"| 1e-3/{round(1e-3 / eps):d} | " + " | ".join(cells) + " |")
        lines.append("")
    diff = df.ours_minus_paper.abs()
    within = diff <= 0.03 + 1e-12  # NaN (no blow-up flagged by 2 T) counts as a difference
    lines.append(
        f"{int(within.sum())} of {len(df)} entries within 0.03 of the paper's; "
        f"{int(df.T_b.isna().sum())} runs flagged no blow-up by t = 2 T (nan); largest finite "
        f"|ours - paper| = {diff.max():.4g}.  Sweep wall time {df.attrs.get('wall_seconds', float('nan')):.1f} s, "
        f"one run per column ({df.attrs.get('cached_runs', 0)} of {df.attrs.get('runs', 0)} runs from the cache)."
    )
    if "T_b_fit" in df:
        lines += ["", fit_summary(df)]
    if THRESHOLD_COLUMNS[0] in df:
        lines += ["", threshold_summary(df)]
    lines += ["", scores_markdown(scores(name, df))]  # beside the count: what a run-free answer scores
    write_markdown(out / f"{name}.md", "\n".join(lines) + "\n")
    _figure(df, out / f"{name}.png")


def fit_summary(df: pd.DataFrame) -> str:
    """The estimator's record on a table with ``exact``, ``T_b``, ``T_b_fit``, ``T_b_fit_err`` and ``blowup_kind``.

    Errors and coverage are counted over the ``finite_time`` entries only (the estimates the kind vouches
    for); ``undetermined`` entries that still locate a time (:attr:`jko_cvx.blowup.BlowupFit.located`: an
    error bar too wide, a rise too small, a run stopped early) are counted apart; the others carry no T_b_fit.
    """
    kinds = df.blowup_kind.value_counts()
    text = (
        f"T_b_fit (jko_cvx.blowup, the power-law fit of max f) over {len(df)} entries: "
        + ", ".join(f"{int(kinds.get(k, 0))} {k}" for k in KINDS)
        + f" (|T_b - exact| median {(df.T_b - df.exact).abs().median():.2g} over every entry)."
    )
    for kind, label in (("finite_time", "finite_time"), ("undetermined", "undetermined with a located time")):
        part = df[(df.blowup_kind == kind) & df.T_b_fit.notna()]
        if part.empty:
            continue
        err = (part.T_b_fit - part.exact).abs()
        text += (
            f"  {label}: {len(part)} entries, |T_b_fit - exact| median {err.median():.2g}, max {err.max():.2g}; "
            f"error bars {part.T_b_fit_err.min():.2g} to {part.T_b_fit_err.max():.2g}, covering the exact time in "
            f"{int((err <= part.T_b_fit_err).sum())} of {len(part)}."
        )
    return text


def _figure(df: pd.DataFrame, path: Path) -> None:
    # a Figure of its own, not pyplot's: the caller's backend (a notebook's inline one) is left as it was
    from matplotlib.figure import Figure

    datas = list(dict.fromkeys(df.data))
    fig = Figure(figsize=(4.2 * len(datas), 3.6))
    axes = fig.subplots(1, len(datas), squeeze=False)
    for ax, data in zip(axes[0], datas, strict=True):
        block = df[df.data == data]
        for i, (eps, rows) in enumerate(block.groupby("eps_v", sort=False)):
            rows = rows.sort_values("dt")
            colour = f"C{i}"
            ax.semilogx(rows["dt"], rows.T_b, "o-", color=colour, label=f"eps_v = 1e-3/{round(1e-3 / eps)}")
            ax.semilogx(rows["dt"], rows.paper, "x--", color=colour, alpha=0.6)
        ax.axhline(paper.EXACT_T[data], color="k", lw=0.8)
        ax.set_title(f"{data}: ours (o) and paper (x); exact T (line)", fontsize=9)
        ax.set_xlabel("dt")
        ax.set_ylabel("T_b")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def reproduce_tab_bu(out: Path, quick: bool = False, **sweep_opts) -> pd.DataFrame:
    """Table ``tab:bu``: g1-g3, eps_v in 1e-3 x {1, ..., 1/16}, dt in {0.02, ..., 0.00125}.

    ``quick``: g1 and g3 at eps_v in {1e-3, 1e-3/4} and dt in {0.02, 0.01}.
    """
    if quick:
        points = table_points(("g1", "g3"), (1e-3, 1e-3 / 4), (0.02, 0.01))
    else:
        points = table_points(("g1", "g2", "g3"), paper.EPS_V, paper.TAB_BU_DT)
    df = _sweep(points, Path(out), "tab_bu", **sweep_opts)
    _write(df, Path(out), "tab_bu")
    return df


def reproduce_tab_bu_tb2(out: Path, quick: bool = False, **sweep_opts) -> pd.DataFrame:
    """Table ``tab:bu_tb2``: g4, eps_v in 1e-3 x {1, ..., 1/8}, dt in {0.01, ..., 0.00125}.

    ``quick``: eps_v in {1e-3, 1e-3/8} and dt in {0.01, 0.005}.
    """
    eps = (1e-3, 1e-3 / 8) if quick else paper.EPS_V[:4]
    dts = (0.01, 0.005) if quick else paper.TAB_BU_TB2_DT
    df = _sweep(table_points(("g4",), eps, dts, TAB_BU_TB2_BETA), Path(out), "tab_bu_tb2", **sweep_opts)
    _write(df, Path(out), "tab_bu_tb2")
    return df
