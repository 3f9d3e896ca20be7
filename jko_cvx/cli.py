"""The ``jko-cvx`` command.

``jko-cvx run`` runs the built-in default scene: the homogeneous equation with
W = |v| and f0 = g1 = exp(-2 v^2) (the paper's first test, ``sec31``) on a fixed
velocity grid up to t = 0.45, just before the exact blow-up time T = 0.5, and compares
every step with the exact Burgers solution.  ``jko-cvx solve`` solves one collision
step with every method and prints the comparison.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from . import __version__
from .collision import CollisionProblem, conic_solvers, solve_collision
from .evolve import evolve_fixed_grid
from .exact import GaussianMixture, blowup_time_gamma1, exact_gamma1
from .grid import Grid
from .kernels import PowerKernel

DEFAULT_SCENE = {
    "description": "homogeneous gamma = 1, f0 = g1 = exp(-2 v^2), fixed grid (paper sec31)",
    "gamma": 1.0,
    "strength": 1.0,
    "v_min": -2.0,
    "v_max": 2.0,
    "n_v": 121,
    "dt": 0.01,
    "t_end": 0.45,
    "beta": 30.0,
    "fisher": "perspective",
    "method": "conic",
}


def _run_default(out: Path, method: str, quiet: bool) -> int:
    import pandas as pd

    sc = dict(DEFAULT_SCENE, method=method)
    grid = Grid.uniform(sc["v_min"], sc["v_max"], sc["n_v"])
    f0 = GaussianMixture([1.0], [2.0], [0.0], sc["v_min"], sc["v_max"])
    t0 = time.perf_counter()
    run = evolve_fixed_grid(
        grid,
        PowerKernel(sc["gamma"]),
        f0.pdf(grid.points),
        sc["dt"],
        sc["t_end"],
        strength=sc["strength"],
        beta=sc["beta"],
        fisher=sc["fisher"],
        method=method,
        progress=not quiet,
    )
    wall = time.perf_counter() - t0
    rows = []
    for k, res in enumerate(run.results):
        t = run.times[k + 1]
        ex = exact_gamma1(f0, t, grid.points)
        f = run.f[k + 1]
        rows.append(
            {
                "t": t,
                "status": res.status.name,
                "iterations": res.iterations,
                "kkt_residual": res.kkt_residual,
                "mass_error": res.mass_error,
                "max_f": f.max(),
                "exact_max_f": ex.max(),
                "l1_error": float(grid.h @ np.abs(f - ex) / (grid.h @ ex)),
                "seconds": res.seconds,
            }
        )
    table = pd.DataFrame(rows)
    out.mkdir(parents=True, exist_ok=True)
    table.to_csv(out / "diagnostics.csv", index=False)
    (out / "scene.json").write_text(json.dumps(sc, indent=2))
    _plot_default(out, grid, run, f0, table)
    last = table.iloc[-1]
    print(f"jko-cvx {__version__}: {sc['description']}")
    print(f"  method={method}, N={sc['n_v']}, dt={sc['dt']}, beta={sc['beta']}, {len(table)} steps in {wall:.2f} s")
    print(f"  exact blow-up time T = 1/(2 max f0) = {blowup_time_gamma1(f0):.4f}")
    print(
        f"  at t = {last.t:.2f}: max f = {last.max_f:.4f} (exact {last.exact_max_f:.4f}), "
        f"relative L1 error {last.l1_error:.2e}"
    )
    print(
        f"  steps certified: {int((table.status == 'CONVERGED').sum())}/{len(table)}, "
        f"max KKT residual {table.kkt_residual.max():.1e}, max mass error {table.mass_error.max():.1e}"
    )
    print(f"  wrote {out / 'diagnostics.csv'}, {out / 'solution.png'}")
    return 0 if run.completed else 1


def _plot_default(out: Path, grid: Grid, run, f0: GaussianMixture, table) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for k in np.linspace(0, len(run.times) - 1, 4).astype(int):
        t = run.times[k]
        (line,) = a.plot(grid.points, run.f[k], label=f"t = {t:.2f}")
        a.plot(grid.points, exact_gamma1(f0, t, grid.points), "--", color=line.get_color(), lw=1)
    a.set_xlabel("v"), a.set_ylabel("f"), a.set_title("JKO (solid) vs exact Burgers solution (dashed)")
    a.legend()
    b.semilogy(table.t, table.l1_error, "o-", label="relative L1 error")
    b.semilogy(table.t, table.kkt_residual, "s-", label="KKT residual")
    b.set_xlabel("t"), b.legend(), b.set_title("error and solver certification")
    fig.tight_layout()
    fig.savefig(out / "solution.png", dpi=120)
    plt.close(fig)


def _solve_one(args) -> int:
    grid = Grid.uniform(-args.L, args.L, args.n)
    prob = CollisionProblem(grid, PowerKernel(args.gamma), np.exp(-2 * grid.points**2), args.dt, beta=args.beta)
    print(prob)
    for method, opts in [("conic", {}), ("sqp", {})]:
        res = solve_collision(prob, method=method, **opts)
        print(f"  {res!r}\n    {res.message}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="jko-cvx", description=__doc__.split("\n")[0])
    parser.add_argument("--version", action="version", version=f"jko-cvx {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run the built-in default scene (homogeneous gamma = 1, g1)")
    p_run.add_argument("--out", type=Path, default=Path("runs/default"), help="output directory")
    p_run.add_argument("--method", default="conic", choices=["conic", "sqp"], help="collision solver")
    p_run.add_argument("--quiet", action="store_true", help="no progress bar")
    p_solve = sub.add_parser("solve", help="one collision step with every method, side by side")
    p_solve.add_argument("--gamma", type=float, default=1.0)
    p_solve.add_argument("--n", type=int, default=121)
    p_solve.add_argument("--L", type=float, default=2.0)
    p_solve.add_argument("--dt", type=float, default=0.01)
    p_solve.add_argument("--beta", type=float, default=10.0)
    sub.add_parser("solvers", help="list the installed conic solvers")
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            return _run_default(args.out, args.method, args.quiet)
        if args.command == "solve":
            return _solve_one(args)
        print("\n".join(conic_solvers()))
        return 0
    except (ValueError, TypeError) as exc:
        print(f"jko-cvx: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
