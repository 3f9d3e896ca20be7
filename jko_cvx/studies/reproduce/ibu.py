"""``sec:ibu`` (``fig:gk3``, ``fig:gk3_2``): gamma = 3, two bumps approaching 0 at rate 1/t.

Homogeneous, ``in_two`` = exp(-10 (v - 1.5)^2) + exp(-10 (v + 1.5)^2), the paper's
N_v = 101, dt = 0.01, two-bump map with delta0 = 0.8, delta = 0.5, to t = 20.  Two
point masses M/2 at +-p obey p' = -2 M p^2 (W = |v|^3/3), p = p0 / (1 + 2 M p0 t): the
analytic law the peaks are compared with.  The scene is the shipped ``ibu_gamma3``
(``jko_cvx/scene/shipped/ibu_gamma3.toml``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.scene.model import Scene, shipped_scene
from jko_cvx.studies.solvers.figures import pyplot
from jko_cvx.studies.sweep import run_sweep

__all__ = ["bump_positions", "ibu_point", "ibu_run", "ibu_scene", "reproduce_ibu"]


def ibu_scene(t_end: float = 20.0) -> Scene:
    """The shipped ``ibu_gamma3`` scene (``jko_cvx/scene/shipped/ibu_gamma3.toml`` for the choices), to ``t_end``."""
    return shipped_scene("ibu_gamma3", {"t_end": t_end, "output.every": 25, "output.checkpoint_every": 10**6})


def ibu_run(t_end: float) -> dict[str, Any]:
    """One sweep point: the ``sec:ibu`` run to ``t_end``.

    Its snapshots (t, v, f), the records t and min dv, the initial mass, the verdict's
    reason and where the run ended; ``ibu`` and ``ibu_panels`` draw from the same point,
    which ``jko-cvx reproduce section`` runs once for both.
    """
    t0 = time.perf_counter()
    run = simulate(ibu_scene(t_end))
    d = run.diagnostics
    return {
        "snapshots": [
            {"t": float(sn["t"]), "v": np.asarray(sn["v"]).tolist(), "f": np.asarray(sn["f"]).tolist()}
            for sn in run.snapshots
        ],
        "t_steps": d.t.tolist(),
        "min_dv": d.min_dv.tolist(),
        "mass0": float(d.mass.iloc[0]),
        "reason": run.verdict["reason"],
        "t_run": float(run.t),
        "seconds": time.perf_counter() - t0,
    }


def ibu_point(out: Path, t_end: float, name: str, **sweep_opts: Any) -> dict[str, Any]:
    """:func:`ibu_run` through the sweep cache ``out/cache/name``, its snapshots' v and f as arrays."""
    row = run_sweep(ibu_run, [{"t_end": float(t_end)}], Path(out) / "cache" / name, desc=name, **sweep_opts).iloc[0]
    snaps = [{"t": sn["t"], "v": np.asarray(sn["v"]), "f": np.asarray(sn["f"])} for sn in row.snapshots]
    return {**row.to_dict(), "snapshots": snaps}


def bump_positions(snapshots) -> pd.DataFrame:
    """Per snapshot: t, the peak position (argmax of f over v > 0) and the v > 0 bump's centre of mass."""
    rows = []
    for sn in snapshots:
        v, f = sn["v"], sn["f"]
        pos = v > 0
        rows.append(
            {
                "t": sn["t"],
                "peak": float(v[pos][np.argmax(f[pos])]),
                "centre_of_mass": float((v[pos] * f[pos]).sum() / f[pos].sum()),
            }
        )
    return pd.DataFrame(rows)


def reproduce_ibu(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """Run ``sec:ibu`` (to t = 20; ``quick``: t = 5) and compare the peaks with the point-mass law.

    One run (the sweep point :func:`ibu_run`, which ``ibu_panels`` shares).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_end = 5.0 if quick else 20.0
    run = ibu_point(out, t_end, "ibu", **sweep_opts)
    wall = run["seconds"]
    M = run["mass0"]
    df = bump_positions(run["snapshots"])
    df["law"] = 1.5 / (1 + 2 * M * 1.5 * df.t)
    late = df.t >= t_end / 2
    slope_peak = float(np.polyfit(np.log(df.t[late]), np.log(df.peak[late]), 1)[0])
    slope_com = float(np.polyfit(np.log(df.t[late]), np.log(df.centre_of_mass[late]), 1)[0])
    dev = float((df.centre_of_mass[late] / df.law[late] - 1).abs().max())
    df.to_csv(out / "ibu.csv", index=False)
    record_csv(out / "ibu.csv")
    write_markdown(out / "ibu.md",
        f"# sec:ibu: gamma = 3, two bumps, N_v = 101, dt = 0.01, to t = {t_end:g}\n\n"
        f"Fitted exponent of the peak position (argmax f, v > 0) over t in [{t_end / 2:g}, {t_end:g}]: "
        f"{slope_peak:.3f}; of the bump's centre of mass: {slope_com:.3f} (the law p0/(1 + 2 M p0 t) has "
        f"local exponent {-(2 * M * 1.5 * t_end) / (1 + 2 * M * 1.5 * t_end):.3f} at t = {t_end:g}).  Largest "
        f"deviation of the centre of mass from the law over that range: {100 * dev:.2f} %.  "
        f"Verdict: {run['reason']} at t = {run['t_run']:g} (no finite-time blow-up, as the paper reports).  "
        f"Wall time {wall:.1f} s.\n"
    )
    _figure(df, run, out / "ibu.png")
    df.attrs.update(slope_peak=slope_peak, slope_com=slope_com, max_deviation=dev, wall_seconds=wall)
    return df


def _figure(df: pd.DataFrame, run: dict[str, Any], path: Path) -> None:
    plt = pyplot()

    fig, ax = plt.subplots(1, 3, figsize=(13, 3.6))
    last = run["snapshots"][-1]
    ax[0].plot(last["v"], last["f"], ".-", ms=3)
    ax[0].set_title(f"f(t = {last['t']:g}, v)")
    ax[0].set_xlim(-0.2, 0.2)
    d = df[df.t > 0]
    ax[1].loglog(d.t, d.peak, "o", ms=3, label="peak (argmax f)")
    ax[1].loglog(d.t, d.centre_of_mass, "-", label="bump centre of mass")
    ax[1].loglog(d.t, d.law, "k--", lw=0.8, label="p0/(1 + 2 M p0 t)")
    ax[1].set_xlabel("t")
    ax[1].set_title("peak position (fig:gk3_2, left)")
    ax[1].legend(fontsize=7)
    ax[2].semilogy(run["t_steps"], run["min_dv"])
    ax[2].set_xlabel("t")
    ax[2].set_title("min dv (fig:gk3_2, right)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
