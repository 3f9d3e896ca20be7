"""``sec:sp_inhom_gamma_1p5``: gamma = 3/2 inhomogeneous, both parameter sets.

``eqn:f0`` with a = 6, c = d = 2.5, L_x = L_v = 5: two phase-space bumps at x = -+c moving
with velocities +-d, so their centres meet at x = 0 at t = c/d = 1 (free transport).  The
paper reports blow-up in v *before* the bumps meet for lambda = 10 (b = 6, snapshots to
t = 0.4, ``fig:gk1p5_C5``) and *after* they have passed for lambda = 5 (b = 3, snapshots to
t = 1.3, ``fig:gk1p5_C2p5``); rows 3-4 of ``fig:gk3_properties`` are the two runs'
conservation and dissipation records.

Settings not stated in the paper are those of the shipped scenes
``jko_cvx/scene/shipped/inhom_gamma1p5_*.toml`` (CFL steps with dt0 = 0.01, eps = 1e-3/16,
delta0 = delta = 0.5, two-bump map in v), which the runs load and override.  The table
compares T_b with the meeting time c/d.

The paper's criterion (min dv < eps_v) watches the grid the map builds.  Beside it the
sweep records two indicators of the density itself (:func:`jko_cvx.diagnostics.diagnostics`):
the smallest local velocity spread sigma_v over populated slices and max_x rho; it runs each
case at several resolutions (a criterion that fires at the same time on every grid is
measuring the solution) and on fixed uniform grids, where no map is involved, as a
map-free reference for sigma_v.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.engine.loop import simulate, snapshot_record
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.scene.model import Scene, shipped_scene
from jko_cvx.studies.reproduce.blowup_tables import FIT_COLUMNS, fit_columns
from jko_cvx.studies.solvers.figures import pyplot
from jko_cvx.studies.sweep import run_sweep

__all__ = [
    "COLLAPSE_SPREAD",
    "MEETING_TIME",
    "SPREAD_TIMES",
    "gamma1p5_run",
    "gamma1p5_scene",
    "gamma1p5_uniform",
    "reproduce_inhom_gamma1p5",
    "spread_event",
]

_SHIPPED = {case: shipped_scene(f"inhom_gamma1p5_{case}") for case in ("before", "after")}
_CASES = {case: (2 * s.strength, s.initial.b, s.t_end) for case, s in _SHIPPED.items()}  # lambda, b, t_end
_C, _D = _SHIPPED["before"].initial.c, _SHIPPED["before"].initial.d  # 2.5, 2.5 in both cases
_L = _SHIPPED["before"].x.L  # both half-widths (5)
MEETING_TIME = _C / _D
"""c/d: the bumps' centres meet at x = 0 at t = 1 under free transport."""
_PAPER = {"before": "blow-up in v before the bumps meet", "after": "blow-up in v after the bumps pass x = 0"}
PAPER_TIMES = {"before": (0.04, 0.1, 0.2, 0.3, 0.4), "after": (0.1, 0.4, 0.8, 1.2, 1.3)}
"""Snapshot times of ``fig:gk1p5_C5`` and ``fig:gk1p5_C2p5``."""
RESOLUTIONS = (41, 61, 81, 121)
"""N_x = N_v of the full sweep (the paper's runs are 121 x 121)."""
UNIFORM = (121, 201, 0.7)
"""The map-free reference: N_x, N_v and the end time of the fixed uniform-grid runs."""
_SERIES = (
    "t",
    "dt",
    "mass",
    "momentum",
    "moment2",
    "moment3",
    "moment4",
    "entropy",
    "max_f",
    "min_dx",
    "min_dv",
    "max_rho",
    "min_spread_v",
)
SPREAD_TIMES = (0.2, 0.4, 0.6)
"""The times the resolution table samples sigma_v at (besides the threshold crossing and the end)."""
COLLAPSE_SPREAD = 0.05
"""The density criterion: the first time sigma_v (``min_spread_v``) falls below this, a sixth
of lambda = 10's initial 0.29 and an eighth of lambda = 5's 0.41 (``stop.spread_v`` of a scene)."""
QUICK_T_END = 0.6
"""End of the quick form's mapped runs (the collapse comes at t ~ 0.33-0.45 on its grids)."""
_SEPARATE = 0.7  # until then the bumps (x-width 0.29) stay 1.5 apart: each keeps x-bar' = u-bar


def gamma1p5_scene(case: str, n: int = 121, overrides: dict[str, Any] | None = None) -> Scene:
    """The shipped ``inhom_gamma1p5_{before,after}`` scene on an n x n grid, with further ``overrides``."""
    if case not in _CASES:
        raise ValueError(f"case must be one of {sorted(_CASES)}, got {case!r}")
    return shipped_scene(f"inhom_gamma1p5_{case}", {"v.n": n, "x.n": n, **(overrides or {})})


def _series(run) -> dict[str, list[float]]:
    return {k: run.diagnostics[k].tolist() for k in _SERIES}


def _ours(flagged: str, in_v: bool, before: bool) -> str:
    """A run's verdict in the table's words; ``flagged`` is its ``blowup`` as lower-case text."""
    if flagged == "true":
        return f"blow-up in {'v' if in_v else 'x'} {'before' if before else 'after'}"
    return "no blow-up by t_end" if flagged == "false" else "undetermined (not certified)"


def _verdict(run) -> dict[str, Any]:
    return {
        "blowup": run.blowup,  # None: undetermined (an uncertified run no rule stopped)
        "T_b": float(run.verdict["T_b"]) if run.blowup else float("nan"),
        "B_v": bool(run.verdict["B_v"]),
        "B_x": bool(run.verdict["B_x"]),
        "e_f": bool(run.verdict["e_f"]),
        "reason": run.verdict["reason"],
        "t_end": float(run.t),
        "steps": len(run.diagnostics) - 1,
        **fit_columns(run.verdict),
    }


def gamma1p5_run(case: str, n: int, collapse_stop: bool = False) -> dict[str, Any]:
    """One sweep point: the scene on an n x n grid; verdict, records and the paper's snapshots.

    ``collapse_stop`` (the quick form) also stops on the density criterion sigma_v <
    COLLAPSE_SPREAD and at t = QUICK_T_END: on coarse grids the paper's criterion fires only
    after thousands of CFL steps on a collapsed grid (41 x 41, lambda = 10: 3250 steps,
    T_b = 0.82, against 111 steps to the collapse at t = 0.33).
    """
    t0 = time.perf_counter()
    overrides = {}
    if collapse_stop:
        t_end = min(_CASES[case][2], QUICK_T_END)
        # the paper's times past the shortened end are never reached: dropped from the scene
        times = [tk for tk in PAPER_TIMES[case] if tk <= t_end]
        overrides = {"stop.spread_v": COLLAPSE_SPREAD, "t_end": t_end, "output.times": times}
    scene = gamma1p5_scene(case, n, overrides)
    run = simulate(scene)
    # the paper's times and the last state (T_b where the run stopped on blow-up)
    snaps = [snapshot_record(s) for s in run.snapshots_at((*PAPER_TIMES[case], run.t))]
    return {**_verdict(run), **_series(run), "snapshots": snaps, "seconds": time.perf_counter() - t0}


def gamma1p5_uniform(case: str, n_x: int, n_v: int, t_end: float) -> dict[str, Any]:
    """One sweep point: the case on fixed uniform n_x x n_v grids (no maps, no eps stop) to t_end.

    With ``v.floor_every_step``: the 1e-10 floor of ``eqn:mass_conserv_v`` after every step, as
    the mapped runs' every-step remap applies it (without it the edge lines in v drain).
    """
    t0 = time.perf_counter()
    scene = gamma1p5_scene(
        case,
        overrides={
            "x.n": n_x,
            "v.n": n_v,
            "refine": None,
            "v.floor_every_step": True,  # the floor of the mapped runs' every-step v-remap
            "stop.eps_v": 0.0,
            "stop.eps_x": 0.0,
            "t_end": t_end,
            "output.times": None,
            "output.every": 10**9,
        },
    )
    run = simulate(scene)
    return {**_verdict(run), **_series(run), "seconds": time.perf_counter() - t0}


def _at(t: list[float], y: list[float], tk: float) -> float:
    """y at time tk (linear in t), nan past the end of the record."""
    return float(np.interp(tk, t, y)) if tk <= t[-1] else float("nan")


def _first_below(t: list[float], y: list[float], level: float) -> float:
    """The first recorded time with y < level (nan if none)."""
    below = np.flatnonzero(np.asarray(y) < level)
    return float(t[below[0]]) if below.size else float("nan")


def spread_event(
    t: list[float],
    sigma: list[float],
    level: float = COLLAPSE_SPREAD,
    t_below: float = float("nan"),
    t_back: float | None = None,
    followed: bool = True,
) -> dict[str, Any]:
    """Blow-up or collapse: the event of one run, named from its record of sigma_v against t.

    Parameters
    ----------
    t, sigma
        The recorded times (increasing) and sigma_v there: a run's whole record, or samples of it.
    level
        The threshold (:data:`COLLAPSE_SPREAD`).
    t_below
        The first time sigma_v < level, where the caller knows it better than the samples
        (nan: read off the samples).
    t_back
        The first time after ``t_below`` with sigma_v >= level, from the whole record where the
        caller has it (nan: the record never comes back); None: read off the samples.
    followed
        False for a run stopped at the threshold: nothing is known after ``t_below``.

    Returns
    -------
    dict
        ``t below``, ``min sigma_v`` and ``t(min sigma_v)`` (over the record), ``t back above``,
        ``t (end)``, ``sigma_v (end)``, ``end / min`` (the growth after the minimum),
        ``followed``, ``event`` and the record (``sample t``, ``sample sigma_v``).  The event is
        ``"no collapse by t = T"``, ``"collapse at t = t_c, reversed by t = t_r"`` (sigma_v came back
        above the threshold: not a blow-up), ``"collapse at t = t_c, not reversed by t = T"`` or
        ``"collapse at t = t_c, not followed past it"``.
    """
    tt, ss = np.asarray(t, dtype=float), np.asarray(sigma, dtype=float)
    if tt.size == 0 or tt.shape != ss.shape or np.any(np.diff(tt) < 0):
        raise ValueError(f"t and sigma must be records of one length, t increasing; got {tt.size} and {ss.size}")
    if np.isnan(t_below):
        t_below = _first_below(tt.tolist(), ss.tolist(), level)
    k = int(np.nanargmin(ss))
    if t_back is None:
        t_back = float("nan")
        if not np.isnan(t_below) and followed:
            back = np.flatnonzero((tt > t_below) & (ss >= level))
            t_back = float(tt[back[0]]) if back.size else float("nan")
    if np.isnan(t_below):
        event = f"no collapse by t = {tt[-1]:.3g}"
    elif not followed:
        event = f"collapse at t = {t_below:.3g}, not followed past it"
    elif not np.isnan(t_back):
        event = f"collapse at t = {t_below:.3g}, reversed by t = {t_back:.3g}"
    else:
        event = f"collapse at t = {t_below:.3g}, not reversed by t = {tt[-1]:.3g}"
        if tt[-1] > tt[k]:
            event += f" (rising: {ss[-1] / ss[k]:.2g} x its minimum at t = {tt[k]:.3g})"
    return {
        "t below": t_below,
        "min sigma_v": float(ss[k]),
        "t(min sigma_v)": float(tt[k]),
        "t back above": t_back,
        "t (end)": float(tt[-1]),
        "sigma_v (end)": float(ss[-1]),
        "end / min": float(ss[-1] / ss[k]) if ss[k] > 0 else float("nan"),
        "followed": bool(followed),
        "event": event,
        "sample t": tt.tolist(),
        "sample sigma_v": ss.tolist(),
    }


def _centre_error(snapshots: list[dict[str, Any]]) -> float:
    """Largest |x-bar - (-c + d t)| of the right-moving (v > 0) half over the snapshots with t <= _SEPARATE.

    Until the bumps overlap, collisions act within one bump and keep its momentum, so the
    centre of mass of the v > 0 half moves at exactly d (eqn:f0 has mean velocity d).
    """
    errors = []
    for snap in snapshots:
        if snap["t"] > _SEPARATE or "x" not in snap:
            continue
        x, v, f = (np.asarray(snap[k]) for k in ("x", "v", "f"))
        w = np.outer(PeriodicGrid(x, 2 * _L).h, Grid(v).h) * f
        right = w[:, v > 0].sum(axis=1)
        errors.append(abs(x @ right / right.sum() - (-_C + _D * snap["t"])))
    return max(errors) if errors else float("nan")


def _summary(r: pd.Series, uniform: bool = False) -> dict[str, Any]:
    """One table row for one run (a mapped or a uniform sweep point); 'end' is its last record, T_b on blow-up."""
    # a run stopped on the density criterion (the quick form) is not followed past the threshold
    event = spread_event(r.t, r.min_spread_v, followed=not r.reason.startswith("min spread_v"))
    return {
        "case": r.case,
        "lambda": _CASES[r.case][0],
        "grid": f"{r.n_x:g} x {r.n_v:g} uniform" if uniform else f"{r.n:g} x {r.n:g}",
        "T_b": r.T_b,
        **{k: r[k] for k in FIT_COLUMNS},
        "reason": r.reason,
        "steps": r.steps,
        "max f (end)": r.max_f[-1],
        "max rho (end)": r.max_rho[-1],
        "sigma_v (end)": r.min_spread_v[-1],
        **{f"sigma_v(t={tk:g})": _at(r.t, r.min_spread_v, tk) for tk in SPREAD_TIMES},
        f"t(sigma_v < {COLLAPSE_SPREAD:g})": _first_below(r.t, r.min_spread_v, COLLAPSE_SPREAD),
        # the whole record's minimum, return above the threshold and end (gamma1p5_events reads them)
        "min sigma_v": event["min sigma_v"],
        "t(min sigma_v)": event["t(min sigma_v)"],
        f"t(sigma_v back >= {COLLAPSE_SPREAD:g})": event["t back above"],
        "t (end)": event["t (end)"],
        "event": event["event"],
        f"x-bar error (t <= {_SEPARATE:g})": float("nan") if uniform else _centre_error(r.snapshots),
        "min dv (end)": r.min_dv[-1],
        "mass drift": float(np.abs(np.asarray(r.mass) - r.mass[0]).max() / r.mass[0]),
        "seconds": r.seconds,
    }


def reproduce_inhom_gamma1p5(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """Both cases on the resolutions of ``RESOLUTIONS`` and the uniform reference ``UNIFORM``.

    Writes ``inhom_gamma1p5.{csv,md,png}`` (the 121 x 121 runs against the paper, with the
    snapshots and records of ``fig:gk1p5_C5`` / ``fig:gk1p5_C2p5``),
    ``inhom_gamma1p5_resolution.{csv,png}`` (every grid, min dv and sigma_v against t) and
    ``inhom_gamma1p5_properties.{png,csv}`` (rows 3-4 of ``fig:gk3_properties``, and their start,
    extremes, end and wrong-way steps per quantity).  ``quick``:
    41 x 41 and 61 x 61, stopped also at the density collapse (``gamma1p5_run``), uniform
    reference 41 x 81 to t = 0.4.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    resolutions, uniform = ((41, 61), (41, 81, 0.4)) if quick else (RESOLUTIONS, UNIFORM)
    # the longest points first, so that a pool is not left waiting on them at the end
    points = [{"case": c, "n": n} for n in sorted(resolutions, reverse=True) for c in _CASES]
    if quick:
        points = [{**p, "collapse_stop": True} for p in points]
    runs = run_sweep(gamma1p5_run, points, out / "cache" / "inhom_gamma1p5", desc="inhom_gamma1p5", **sweep_opts)
    # rows by case, then grid
    runs = runs.set_index(["case", "n"]).loc[[(c, n) for c in _CASES for n in resolutions]].reset_index()
    upoints = [{"case": c, "n_x": uniform[0], "n_v": uniform[1], "t_end": uniform[2]} for c in _CASES]
    refs = run_sweep(gamma1p5_uniform, upoints, out / "cache" / "inhom_gamma1p5_uniform", desc="uniform", **sweep_opts)
    wall = time.perf_counter() - t0
    meet = MEETING_TIME

    rows = [_summary(r) for _, r in runs.iterrows()] + [_summary(r, uniform=True) for _, r in refs.iterrows()]
    resolution = pd.DataFrame(rows)
    resolution.to_csv(out / "inhom_gamma1p5_resolution.csv", index=False)
    record_csv(out / "inhom_gamma1p5_resolution.csv")

    main = runs[runs.n == max(resolutions)].reset_index(drop=True)
    main["lambda"] = [_CASES[c][0] for c in main.case]
    main["meeting time c/d"] = meet
    flagged = main.blowup.astype(str).str.lower()  # True, False, or missing: undetermined
    main["ours"] = [_ours(bu, bv, tb < meet) for bu, bv, tb in zip(flagged, main.B_v, main.T_b, strict=True)]
    main["paper"] = main.case.map(_PAPER)
    main["supports"] = [
        bool(bu == "true" and bv and ((tb < meet) == (c == "before")))
        for bu, bv, tb, c in zip(flagged, main.B_v, main.T_b, main.case, strict=True)
    ]
    tb = runs.groupby("case").T_b
    main["T_b over grids"] = [f"{tb.min()[c]:.3f}-{tb.max()[c]:.3f}" for c in main.case]
    ends = pd.DataFrame([_summary(r) for _, r in main.iterrows()])
    collapse, centre = f"t(sigma_v < {COLLAPSE_SPREAD:g})", f"x-bar error (t <= {_SEPARATE:g})"
    main[["max f (end)", "sigma_v (end)", "mass drift", collapse, centre]] = ends[
        ["max f (end)", "sigma_v (end)", "mass drift", collapse, centre]
    ]
    # the density criterion on every grid, the uniform reference included
    tc = resolution.groupby("case")[collapse]
    main[f"{collapse} over grids"] = [f"{tc.min()[c]:.3f}-{tc.max()[c]:.3f}" for c in main.case]
    main["density criterion"] = [
        "no collapse by t_end" if np.isnan(t) else f"collapse in v {'before' if t < meet else 'after'}"
        for t in main[collapse]
    ]
    cols = ["case", "lambda", "n", "T_b", *FIT_COLUMNS, "meeting time c/d", "ours", "paper", "supports",
            "T_b over grids"]  # fmt: skip
    cols += [collapse, f"{collapse} over grids", "density criterion", centre]
    cols += ["reason", "steps", "max f (end)", "sigma_v (end)", "mass drift", "seconds"]
    main[cols].to_csv(out / "inhom_gamma1p5.csv", index=False)
    record_csv(out / "inhom_gamma1p5.csv")
    write_markdown(
        out / "inhom_gamma1p5.md",
        "# sec:sp_inhom_gamma_1p5: gamma = 3/2 inhomogeneous\n\n"
        "T_b (the paper's criterion, min dv < eps_v) against the time c/d = 1 at which the bumps' "
        "centres meet at x = 0 (free transport), on the paper's 121 x 121 grids.  Beside it the "
        f"density criterion: the first time sigma_v < {COLLAPSE_SPREAD:g}, on every grid.  x-bar error: "
        "the largest distance of the right-moving half's centre of mass from -c + d t "
        f"(exact until the bumps overlap) over the snapshots up to t = {_SEPARATE:g}.\n\n"
        + main[cols].to_markdown(index=False, floatfmt=".4g")
        + "\n\n## Every grid, and the map-free reference\n\n"
        "sigma_v: the smallest local velocity spread over slices with rho >= 0.1 max rho "
        "(a blow-up in v sends it to 0); 'end' is T_b where the run stopped on blow-up.\n\n"
        + resolution.to_markdown(index=False, floatfmt=".4g")
        + f"\n\nSweep wall time {wall:.0f} s (cached points count 0).\n",
    )
    _figure(main, out / "inhom_gamma1p5.png", meet)
    _resolution_figure(runs, refs, out / "inhom_gamma1p5_resolution.png", meet)
    _properties_figure(main, out / "inhom_gamma1p5_properties.png")
    properties = _properties_table(main)
    properties.to_csv(out / "inhom_gamma1p5_properties.csv", index=False)
    record_csv(out / "inhom_gamma1p5_properties.csv")
    return main


def _figure(main: pd.DataFrame, path: Path, meet: float) -> None:
    """``fig:gk1p5_C5`` / ``fig:gk1p5_C2p5``: snapshots at the paper's times and the records."""
    plt = pyplot()
    k = max(len(r.snapshots) for _, r in main.iterrows())
    fig, axes = plt.subplots(len(main), k + 1, figsize=(2.9 * (k + 1), 2.7 * len(main)), squeeze=False)
    for ax_row, (_, r) in zip(axes, main.iterrows(), strict=True):
        for ax, s in zip(ax_row, r.snapshots, strict=False):
            X, V = np.meshgrid(s["x"], s["v"], indexing="ij")
            ax.contourf(X, V, np.asarray(s["f"]), levels=20)
            ax.set_title(f"{r.case}, lambda = {r['lambda']:g}: t = {s['t']:.3g}", fontsize=8)
            ax.set_xlabel("x", fontsize=8)
            ax.set_ylabel("v", fontsize=8)
        for ax in ax_row[len(r.snapshots) : k]:
            ax.axis("off")
        rec = ax_row[k]
        for name, label in (("min_dx", "min dx"), ("min_dv", "min dv"), ("max_f", "max f")):
            rec.semilogy(r.t, r[name], label=label)
        rec.axvline(meet, color="k", ls=":", lw=1, label="bumps meet (c/d)")
        rec.set_xlabel("t", fontsize=8)
        rec.set_title("records", fontsize=8)
        rec.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _resolution_figure(runs: pd.DataFrame, refs: pd.DataFrame, path: Path, meet: float) -> None:
    """min dv (the paper's criterion) and sigma_v (the density's own spread) against t, every grid."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), squeeze=False)
    for row, case in zip(axes, _CASES, strict=True):
        for i, (_, r) in enumerate(runs[runs.case == case].iterrows()):
            row[0].semilogy(r.t, r.min_dv, color=f"C{i}", label=f"{r.n} x {r.n}")
            row[1].semilogy(r.t, r.min_spread_v, color=f"C{i}", label=f"{r.n} x {r.n}")
        for _, r in refs[refs.case == case].iterrows():
            row[1].semilogy(r.t, r.min_spread_v, "k--", label=f"{r.n_x} x {r.n_v} uniform")
        row[1].axhline(COLLAPSE_SPREAD, color="0.4", lw=1, label=f"threshold {COLLAPSE_SPREAD:g}")
        for ax, what in zip(row, ("min dv", "sigma_v (min over populated x)"), strict=True):
            ax.axvline(meet, color="k", ls=":", lw=1)
            ax.set_title(f"{case}, lambda = {_CASES[case][0]:g}: {what}", fontsize=9)
            ax.set_xlabel("t")
            ax.legend(fontsize=7)
            ax.grid(True, which="both", alpha=0.2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


_RIGHT_WAY = {"moment2": -1, "moment3": -1, "moment4": -1, "entropy": 1}
"""The direction prop:properties gives each quantity: the moments dissipate, the integral of f log f rises."""


def _properties_table(main: pd.DataFrame) -> pd.DataFrame:
    """The panels of ``fig:gk3_properties`` (gamma = 3/2 rows) in numbers: per run and quantity, its start,
    extremes and their times, end, and the steps on which it moves against :data:`_RIGHT_WAY`."""
    rows = []
    for _, r in main.iterrows():
        t = np.asarray(r.t)
        for name, sign in _RIGHT_WAY.items():
            y = np.asarray(r[name])
            lo, hi = int(np.argmin(y)), int(np.argmax(y))
            rows.append(
                {
                    "case": r.case,
                    "lambda": _CASES[r.case][0],
                    "n": r.n,
                    "quantity": name,
                    "start": y[0],
                    "min": y[lo],
                    "t(min)": t[lo],
                    "max": y[hi],
                    "t(max)": t[hi],
                    "end": y[-1],
                    "t (end)": t[-1],
                    "wrong-way steps": int((sign * np.diff(y) < 0).sum()),
                    "steps": len(y) - 1,
                }
            )
    return pd.DataFrame(rows)


def _properties_figure(main: pd.DataFrame, path: Path) -> None:
    """Rows 3-4 of ``fig:gk3_properties``: mass, momentum, moments 2-4 and entropy against t."""
    plt = pyplot()
    names = ("mass", "momentum", "moment2", "moment3", "moment4", "entropy")
    fig, axes = plt.subplots(len(main), len(names), figsize=(3.1 * len(names), 2.8 * len(main)), squeeze=False)
    for ax_row, (_, r) in zip(axes, main.iterrows(), strict=True):
        for ax, name in zip(ax_row, names, strict=True):
            ax.plot(r.t, r[name])
            ax.set_title(f"{r.case}: {name if name != 'entropy' else 'entropy (int f log f)'}", fontsize=8)
            ax.set_xlabel("t", fontsize=8)
    fig.suptitle("fig:gk3_properties, gamma = 3/2 rows", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
