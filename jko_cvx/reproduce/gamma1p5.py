"""``sec:sp_inhom_gamma_1p5``: gamma = 3/2 inhomogeneous, both parameter sets.

``eqn:f0`` with a = 6, c = d = 2.5, L_x = L_v = 5: two phase-space bumps at x = -+c moving
with velocities +-d, so their centres meet at x = 0 at t = c/d = 1 (free transport).  The
paper reports blow-up in v *before* the bumps meet for lambda = 10 (b = 6, snapshots to
t = 0.4) and *after* they have passed for lambda = 5 (b = 3, snapshots to t = 1.3).

Settings not stated in the paper are those of ``studies/scenes/inhom_gamma1p5_*.toml``
(CFL steps with dt0 = 0.01, eps = 1e-3/16, delta0 = delta = 0.5, two-bump map in v; a test
checks the scenes agree).  The table compares T_b with the meeting time c/d.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..scene import Scene, scene_from_dict
from ..simulate import simulate
from ..sweep import run_sweep

__all__ = ["gamma1p5_scene", "reproduce_inhom_gamma1p5"]

_CASES = {"before": (10.0, 6.0, 1.0), "after": (5.0, 3.0, 2.0)}  # lambda, b, t_end
_C = _D = 2.5
_PAPER = {"before": "blow-up in v before the bumps meet", "after": "blow-up in v after the bumps pass x = 0"}


def gamma1p5_scene(case: str, n: int = 121) -> Scene:
    """The ``inhom_gamma1p5_{before,after}`` scene on an n x n grid."""
    if case not in _CASES:
        raise ValueError(f"case must be one of {sorted(_CASES)}, got {case!r}")
    lam, b, t_end = _CASES[case]
    return scene_from_dict(
        {
            "name": f"inhom_gamma1p5_{case}",
            "gamma": 1.5,
            "strength": lam / 2,
            "t_end": t_end,
            "v": {"L": 5.0, "n": n},
            "x": {"L": 5.0, "n": n},
            "initial": {"kind": "two_bump_phase", "a": 6.0, "b": b, "c": _C, "d": _D},
            "time": {"policy": "cfl", "dt": 0.01},
            "refine": {
                "v": {"bumps": 2, "delta0": 0.5, "delta": 0.5},
                "x": {"bumps": 1, "delta0": 0.5, "delta": 0.5},
            },
            "collision": {"method": "newton", "beta": 1000.0, "fisher": "log"},
            "stop": {"eps_v": 6.25e-5, "eps_x": 6.25e-5, "on_solver_failure": True},
            "output": {"every": 100, "checkpoint_every": 100},
        }
    )


def gamma1p5_run(case: str, n: int) -> dict[str, Any]:
    """One sweep point: verdict, T_b and the records of the run."""
    t0 = time.perf_counter()
    run = simulate(gamma1p5_scene(case, n))
    d = run.diagnostics
    return {
        "blowup": bool(run.blowup),
        "T_b": float(run.verdict["T_b"]) if run.blowup else float("nan"),
        "B_v": bool(run.verdict["B_v"]),
        "B_x": bool(run.verdict["B_x"]),
        "e_f": bool(run.verdict["e_f"]),
        "reason": run.verdict["reason"],
        "steps": len(d) - 1,
        "min_dv": float(d.min_dv.min()),
        "min_dx": float(d.min_dx.min()),
        "max_f": float(d.max_f.max()),
        "mass_drift": float(np.abs(d.mass - d.mass.iloc[0]).max() / d.mass.iloc[0]),
        "t": d.t.tolist(),
        "min_dv_series": d.min_dv.tolist(),
        "max_f_series": d.max_f.tolist(),
        "seconds": time.perf_counter() - t0,
    }


def reproduce_inhom_gamma1p5(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """Both cases at 121 x 121 (``quick``: 41 x 41); writes ``inhom_gamma1p5.{csv,md,png}``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    n = 41 if quick else 121
    points = [{"case": c, "n": n} for c in _CASES]
    df = run_sweep(gamma1p5_run, points, out / "cache" / "inhom_gamma1p5", desc="inhom_gamma1p5", **sweep_opts)
    meet = _C / _D
    df["lambda"] = [_CASES[c][0] for c in df.case]
    df["meeting time c/d"] = meet
    df["ours"] = [
        ("no blow-up by t_end" if not bu else f"blow-up in {'v' if bv else 'x'} {'before' if tb < meet else 'after'}")
        for bu, bv, tb in zip(df.blowup, df.B_v, df.T_b, strict=True)
    ]
    df["paper"] = df.case.map(_PAPER)
    df["supports"] = [
        bool(bu and bv and ((tb < meet) == (c == "before")))
        for bu, bv, tb, c in zip(df.blowup, df.B_v, df.T_b, df.case, strict=True)
    ]
    cols = ["case", "lambda", "n", "T_b", "meeting time c/d", "ours", "paper", "supports", "reason"]
    cols += ["steps", "min_dv", "min_dx", "max_f", "mass_drift", "seconds"]
    df[cols].to_csv(out / "inhom_gamma1p5.csv", index=False)
    (out / "inhom_gamma1p5.md").write_text(
        "# sec:sp_inhom_gamma_1p5: gamma = 3/2 inhomogeneous\n\n"
        "T_b against the time c/d = 1 at which the bumps' centres meet at x = 0 (free transport).\n\n"
        + df[cols].to_markdown(index=False, floatfmt=".4g")
        + "\n"
    )
    _figure(df, out / "inhom_gamma1p5.png", meet)
    return df


def _figure(df: pd.DataFrame, path: Path, meet: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for i, row in df.iterrows():
        label = f"{row.case}, lambda = {row['lambda']:g}"
        axes[0].semilogy(row.t, row.min_dv_series, color=f"C{i}", label=label)
        axes[1].semilogy(row.t, row.max_f_series, color=f"C{i}", label=label)
    for ax, what in zip(axes, ("min dv", "max f"), strict=True):
        ax.axvline(meet, color="k", ls=":", lw=1, label="bumps meet (c/d)")
        ax.set_xlabel("t")
        ax.set_title(what, fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
