"""Panels of the paper's figures the main entries do not draw.

* ``ibu_panels`` -- ``fig:gk3``: the initial datum, the whole f(20, v) and its zoom at
  v = 0, from the ``sec:ibu`` scene (:func:`~jko_cvx.studies.reproduce.ibu.ibu_scene`).
* ``g2bu_loglog`` -- ``fig:loglog`` against lambda: log(rho/rho0)/log(m/m0) at T_b and the
  infinite-mass value 2/(lambda rho0 T), read from the shipped ``tab_g2bu.csv`` (no rerun).
* ``g2bu_records`` -- the records panel of ``fig:gk2_evo_example2``: min dx, min dv and max f
  per step of the lambda = 310 run (:func:`~jko_cvx.studies.reproduce.g2bu.g2bu_scene`, 121 x 201).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.g2bu import RECORDS, g2bu_run
from jko_cvx.studies.reproduce.ibu import ibu_point
from jko_cvx.studies.solvers.figures import pyplot
from jko_cvx.studies.sweep import run_sweep

__all__ = ["reproduce_g2bu_loglog", "reproduce_g2bu_records", "reproduce_ibu_panels"]


def reproduce_ibu_panels(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """``fig:gk3``: f(0, v), f(20, v) and its zoom (``quick``: t = 5); ``ibu_panels.{csv,md,png}``.

    The run is ``ibu``'s sweep point (:func:`~jko_cvx.studies.reproduce.ibu.ibu_run`).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    run = ibu_point(out, 5.0 if quick else 20.0, "ibu_panels", **sweep_opts)
    first, last = run["snapshots"][0], run["snapshots"][-1]
    df = pd.concat(
        [pd.DataFrame({"t": s["t"], "v": s["v"], "f": s["f"]}) for s in (first, last)], ignore_index=True
    )
    df.to_csv(out / "ibu_panels.csv", index=False)
    record_csv(out / "ibu_panels.csv")
    v, f = np.asarray(last["v"]), np.asarray(last["f"])
    pos = v > 0
    record = {
        "t": float(last["t"]),
        "max f": float(f.max()),
        "peak position (v > 0)": float(v[pos][np.argmax(f[pos])]),
        "f at v = 0 / max f": float(np.interp(0.0, v, f) / f.max()),
        "seconds": run["seconds"],
    }
    write_markdown(out / "ibu_panels.md",
        "# fig:gk3: the initial datum and f(t_end, v) of sec:ibu\n\n"
        + pd.DataFrame([record]).to_markdown(index=False, floatfmt=".4g")
        + "\n"
    )
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    axes[0].plot(first["v"], first["f"], ".-", ms=2)
    axes[0].set_title("fig:gk3 (left): f(0, v)", fontsize=9)
    axes[1].plot(v, f, ".-", ms=2)
    axes[1].set_title(f"fig:gk3 (middle): f({last['t']:.0f}, v)", fontsize=9)
    zoom = np.abs(v) <= 3 * record["peak position (v > 0)"]
    axes[2].plot(v[zoom], f[zoom], ".-", ms=3)
    axes[2].set_title("fig:gk3 (right): zoom at v = 0 (grid points marked)", fontsize=9)
    for ax in axes:
        ax.set_xlabel("v")
    fig.tight_layout()
    fig.savefig(out / "ibu_panels.png", dpi=120)
    plt.close(fig)
    return pd.DataFrame([record])


def reproduce_g2bu_loglog(out: Path, quick: bool = False, **_sweep_opts: Any) -> pd.DataFrame:
    """``fig:loglog`` against lambda from ``tab_g2bu.csv`` in ``out``; writes ``g2bu_loglog.png``."""
    out = Path(out)
    df = pd.read_csv(out / "tab_g2bu.csv")
    df = df[df.n_v == df.n_v.min()].sort_values("lambda")
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    ax.plot(df["lambda"], df["log ratio at T_b"], "o-", label="ours: log(rho/rho0)/log(m/m0) at T_b")
    ax.plot(df["lambda"], df["infinite-mass ratio 2/(lambda rho0 T)"], "k--", label="infinite mass: 2/(lambda rho0 T)")
    ax.axhline(1.0, color="grey", lw=0.6)
    ax.set_xlabel("lambda")
    ax.set_title("fig:loglog against lambda (tab_g2bu.csv)", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "g2bu_loglog.png", dpi=120)
    plt.close(fig)
    return df


def reproduce_g2bu_records(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """``fig:gk2_evo_example2`` records (lambda = 310; ``quick``: to t = 0.05); ``g2bu_records.{csv,png}``.

    The run is ``tab_g2bu``'s lambda = 310 sweep point (:func:`~jko_cvx.studies.reproduce.g2bu.g2bu_run`),
    which in ``jko-cvx reproduce section`` runs once for both entries.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    point = {"lam": 310.0, "n_x": 121, "n_v": 201, **({"t_end": 0.05} if quick else {})}
    run = run_sweep(g2bu_run, [point], out / "cache" / "g2bu_records", desc="g2bu_records", **sweep_opts).iloc[0]
    d = pd.DataFrame(run.records)[list(RECORDS)]
    d.to_csv(out / "g2bu_records.csv", index=False)
    record_csv(out / "g2bu_records.csv")
    write_markdown(out / "g2bu_records.md",
        "# fig:gk2_evo_example2 records: lambda = 310, 121 x 201\n\n"
        f"{len(d) - 1} steps; verdict: {run.reason} at t = {d.t.iloc[-1]:.5g}; "
        f"min dx {d.min_dx.min():.3g}, min dv {d.min_dv.min():.3g}, max f {d.max_f.max():.4g}; "
        f"{time.perf_counter() - t0:.0f} s.\n"
    )
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    ax.semilogy(d.t, d.min_dx, label="min dx")
    ax.semilogy(d.t, d.min_dv, label="min dv")
    ax.semilogy(d.t, d.max_f, label="max f")
    ax.set_xlabel("t")
    ax.set_title("fig:gk2_evo_example2 (bottom right): records, lambda = 310", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "g2bu_records.png", dpi=120)
    plt.close(fig)
    return d
