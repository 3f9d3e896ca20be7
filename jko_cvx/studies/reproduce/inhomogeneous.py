"""``sec:sp_inhom_gamma_3`` and ``sec:sup_g3``: gamma = 3, two phase-space bumps, lambda in {2, 4, 6, 8, 10}.

The set-up of the shipped ``jko_cvx/scene/shipped/inhom_gamma3_lambdaK.toml`` (``eqn:f0`` with a = b = 6,
c = 1.5, d = 2, L_x = L_v = 4, N_x = N_v = 121, delta0 = 0.02, delta = 0.5, dt = 0.05, to
t = 4).  Each lambda is one sweep point; the figures are the record plots (min dx, min dv,
max f against t), the final snapshots, the snapshots at the paper's times for lambda = 4
and 10 (``fig:gk3_ih_2_C2_2``, ``fig:gk3_ih_2_C5_2``), and ``fig:gk3_properties`` (mass, momentum,
moments of order 2-4 and the entropy integral of f log f against t).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.engine.loop import simulate, snapshot_record
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.scene.model import Scene, shipped_scene, shipped_scene_names
from jko_cvx.studies.reproduce.blowup_tables import FIT_COLUMNS, fit_columns
from jko_cvx.studies.solvers.figures import pyplot
from jko_cvx.studies.sweep import run_sweep

__all__ = ["inhomogeneous_gamma3", "inhomogeneous_scene", "reproduce_inhom_gamma3"]

PAPER_TIMES = {4.0: (0.4, 0.6, 0.8, 1.0, 1.6, 2.0), 10.0: (0.2, 0.6, 0.8, 1.0, 1.2, 2.0)}
"""Snapshot times of ``fig:gk3_ih_2_C2_2`` (lambda = 4) and ``fig:gk3_ih_2_C5_2`` (lambda = 10)."""
_SERIES = ("t", "mass", "momentum", "moment2", "moment3", "moment4", "entropy", "max_f", "min_dx", "min_dv")


def inhomogeneous_scene(lam: float, n: int = 121, t_end: float = 4.0) -> Scene:
    """The ``sec:sp_inhom_gamma_3`` scene for lambda (strength lambda / 2) on an n x n grid, to ``t_end``.

    The shipped ``inhom_gamma3_lambda{lam}`` scene where there is one (lambda = 2, 4, ..., 10),
    else ``inhom_gamma3_lambda4`` with the strength and name set.
    """
    name = f"inhom_gamma3_lambda{lam:g}"
    own = name in shipped_scene_names()
    overrides = {} if own else {"name": name, "strength": lam / 2, "description": f"{_DESCRIPTION}, lambda = {lam:g}"}
    return shipped_scene(
        name if own else "inhom_gamma3_lambda4",
        {
            **overrides,
            "t_end": t_end,
            "v.n": n,
            "x.n": n,
            "output.every": 10**6,
            "output.times": [tk for tk in PAPER_TIMES.get(lam, ()) if tk <= t_end],
            "output.checkpoint_every": 10**6,
        },
    )


_DESCRIPTION = "inhomogeneous gamma = 3, two phase-space bumps"


def inhomogeneous_gamma3(lam: float, n: int, t_end: float) -> dict[str, Any]:
    """One sweep point: the diagnostics series, the verdict and the final density with its grids."""
    t0 = time.perf_counter()
    run = simulate(inhomogeneous_scene(lam, n, t_end))
    d = run.diagnostics
    return {
        **{k: d[k].tolist() for k in _SERIES},
        "blowup": run.blowup,
        "verdict": run.verdict["reason"],
        **fit_columns(run.verdict),
        "x": run.xgrid.points.tolist(),
        "v": run.vgrid.points.tolist(),
        "f": run.f.tolist(),
        "snapshots": [snapshot_record(snap) for snap in run.snapshots_at(PAPER_TIMES.get(lam, ()))],
        "seconds": time.perf_counter() - t0,
    }


def reproduce_inhom_gamma3(out: Path, quick: bool = False, **sweep_opts) -> pd.DataFrame:
    """All five lambdas at 121 x 121 to t = 4 (``quick``: lambda = 4 and 10 at 61 x 61 to t = 2)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    lams, n, t_end = ((4.0, 10.0), 61, 2.0) if quick else ((2.0, 4.0, 6.0, 8.0, 10.0), 121, 4.0)
    points = [{"lam": lam, "n": n, "t_end": t_end} for lam in lams]
    t0 = time.perf_counter()
    df = run_sweep(inhomogeneous_gamma3, points, out / "cache" / "inhom_gamma3", desc="inhom_gamma3", **sweep_opts)
    wall = time.perf_counter() - t0
    rows = []
    for _, r in df.iterrows():
        m2 = np.asarray(r.moment2)
        rows.append(
            {
                "lambda": r.lam,
                "N": r.n,
                "blow-up flagged": r.blowup,
                "verdict": r.verdict,
                **{k: r.get(k, float("nan")) for k in FIT_COLUMNS},
                "max f (peak)": max(r.max_f),
                "min dx (min)": min(r.min_dx),
                "min dx at end": r.min_dx[-1],
                "mass drift": float(np.max(np.abs(np.asarray(r.mass) - r.mass[0])) / r.mass[0]),
                "momentum drift": float(np.max(np.abs(np.asarray(r.momentum) - r.momentum[0]))),
                "moment2 increases": int(np.sum(np.diff(m2) > 1e-14 * m2[0])),
                "seconds": r.seconds,
            }
        )
    summary = pd.DataFrame(rows)
    summary.to_csv(out / "inhom_gamma3.csv", index=False)
    record_csv(out / "inhom_gamma3.csv")
    write_markdown(out / "inhom_gamma3.md",
        f"# sec:sp_inhom_gamma_3 / sec:sup_g3: gamma = 3, N = {n}, to t = {t_end:g}\n\n"
        "Paper: no blow-up for any lambda; the bumps concentrate, meet and separate.  T_b_fit, T_b_fit_err, "
        "blowup_kind: the power-law fit of max f (jko_cvx.blowup) on the run's certified records.\n\n"
        + summary.to_markdown(index=False, floatfmt=".4g")
        + f"\n\nSweep wall time {wall:.1f} s.\n"
    )
    _figures(df, out)
    return summary


def _figures(df: pd.DataFrame, out: Path) -> None:
    plt = pyplot()

    k = len(df)
    fig, ax = plt.subplots(2, k, figsize=(3.6 * k, 6.4), squeeze=False)
    for j, (_, r) in enumerate(df.iterrows()):
        X, V = np.meshgrid(r.x, r.v, indexing="ij")
        ax[0][j].contourf(X, V, np.asarray(r.f), levels=20)
        ax[0][j].set_title(f"lambda = {r.lam:g}: f(t = {r.t[-1]:g})", fontsize=9)
        ax[1][j].semilogy(r.t, r.min_dx, label="min dx")
        ax[1][j].semilogy(r.t, r.min_dv, label="min dv")
        ax[1][j].semilogy(r.t, r.max_f, label="max f")
        ax[1][j].set_xlabel("t")
    ax[1][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "inhom_gamma3.png", dpi=110)
    plt.close(fig)
    names = ("mass", "momentum", "moment2", "moment3", "moment4", "entropy")
    fig, ax = plt.subplots(1, len(names), figsize=(3.2 * len(names), 3.2))
    for _, r in df.iterrows():
        for a, name in zip(ax, names, strict=True):
            a.plot(r.t, r[name], label=f"lambda = {r.lam:g}")
            a.set_title(name if name != "entropy" else "entropy (int f log f)", fontsize=9)
            a.set_xlabel("t")
    ax[0].legend(fontsize=7)
    fig.suptitle("fig:gk3_properties", fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "inhom_gamma3_properties.png", dpi=110)
    plt.close(fig)
    with_snaps = [r for _, r in df.iterrows() if len(r.snapshots)]
    if with_snaps:
        k = max(len(r.snapshots) for r in with_snaps)
        fig, ax = plt.subplots(len(with_snaps), k, figsize=(3.0 * k, 2.8 * len(with_snaps)), squeeze=False)
        for row, r in zip(ax, with_snaps, strict=True):
            for a, snap in zip(row, r.snapshots, strict=False):
                X, V = np.meshgrid(snap["x"], snap["v"], indexing="ij")
                a.contourf(X, V, np.asarray(snap["f"]), levels=20)
                a.set_title(f"lambda = {r.lam:g}: t = {snap['t']:.3g}", fontsize=9)
            for a in row[len(r.snapshots) :]:
                a.axis("off")
        fig.suptitle("fig:gk3_ih_2_C2_2 (lambda = 4), fig:gk3_ih_2_C5_2 (lambda = 10)", fontsize=9)
        fig.tight_layout()
        fig.savefig(out / "inhom_gamma3_snapshots.png", dpi=110)
        plt.close(fig)
