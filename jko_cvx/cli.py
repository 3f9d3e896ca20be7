"""The ``jko-cvx`` command.

``jko-cvx run [SCENE.toml] [--out DIR] [--resume]`` runs a scene (default: the built-in
homogeneous gamma = 1, g1 = exp(-2 v^2) scene of Table ``tab:bu``, with mesh refinement,
run until the blow-up criterion min dv < eps_v fires; exact T = 0.5), writes the run
directory and prints the verdict.  ``jko-cvx solve`` solves one collision step with
every method; ``jko-cvx solvers`` lists the installed conic solvers; ``jko-cvx reproduce NAME [--quick]``
regenerates one of the paper's tables or figures (:mod:`jko_cvx.reproduce`).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from . import __version__
from .collision import CollisionProblem, conic_solvers, solve_collision
from .grid import Grid
from .kernels import PowerKernel


def _run_scene(scene_path: Path | None, out: Path | None, resume: bool, quiet: bool) -> int:
    from .scene import default_scene, load_scene
    from .simulate import simulate

    scene = default_scene() if scene_path is None else load_scene(scene_path)
    out = out if out is not None else Path("runs") / scene.name
    t0 = time.perf_counter()
    run = simulate(scene, out=out, resume=resume, progress=not quiet)
    wall = time.perf_counter() - t0
    _plot_run(run, out)
    d = run.diagnostics
    print(f"jko-cvx {__version__}: {scene.name} -- {scene.description}")
    print(f"  {run.summary()}")
    print(
        f"  wall {wall:.2f} s (collision {run.seconds['collision']:.2f} s, transport {run.seconds['transport']:.2f} s, "
        f"refinement {run.seconds['refine']:.2f} s); steps with a failed collision solve: {int((d.failed > 0).sum())}"
    )
    print(
        f"  mass drift {abs(d.mass.iloc[-1] - d.mass.iloc[0]) / d.mass.iloc[0]:.1e} (relative), "
        f"momentum drift {abs(d.momentum.iloc[-1] - d.momentum.iloc[0]):.1e}, max f {d.max_f.max():.4g}, "
        f"min dv {d.min_dv.min():.3g}" + ("" if scene.homogeneous else f", min dx {d.min_dx.min():.3g}")
    )
    if scene.gamma == 1.0 and scene.homogeneous and run.blowup:
        print(
            f"  exact blow-up time 1/(2 max f0) = {1 / (2 * d.max_f.iloc[0] * scene.strength):.4f} (max f0 on the grid)"
        )
    print(f"  wrote {out}/ (diagnostics.csv, snapshots/, checkpoint.npz, verdict.json, solution.png, records.png)")
    return 0


def _plot_run(run, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = run.diagnostics
    fig, ax = plt.subplots(1, 2 if run.xgrid is None else 1, figsize=(10 if run.xgrid is None else 6, 4))
    if run.xgrid is None:
        a, b = ax
        a.plot(run.vgrid.points, run.f, ".-", ms=2)
        a.set_xlabel("v"), a.set_ylabel("f"), a.set_title(f"f at t = {run.t:.4g}")
        k = int(np.argmax(run.f))
        w = max(20 * run.vgrid.dv.min(), 1e-3)
        sel = np.abs(run.vgrid.points - run.vgrid.points[k]) <= w
        b.plot(run.vgrid.points[sel], run.f[sel], ".-", ms=3)
        b.set_xlabel("v"), b.set_title("zoom at the maximum")
    else:
        X, V = np.meshgrid(run.xgrid.points, run.vgrid.points, indexing="ij")
        pc = ax.pcolormesh(X, V, run.f, shading="auto")
        fig.colorbar(pc, ax=ax)
        ax.set_xlabel("x"), ax.set_ylabel("v"), ax.set_title(f"f(t = {run.t:.4g}, x, v)")
    fig.tight_layout()
    fig.savefig(out / "solution.png", dpi=110)
    plt.close(fig)
    fig, a = plt.subplots(figsize=(6, 4))
    a.semilogy(d.t, d.min_dv, label="min dv")
    if run.xgrid is not None:
        a.semilogy(d.t, d.min_dx, label="min dx")
    a.semilogy(d.t, d.max_f, label="max f")
    a.set_xlabel("t"), a.legend()
    a.set_title(f"{run.scene.name}: " + (f"blow-up at T_b = {run.verdict['T_b']:.4g}" if run.blowup else "no blow-up"))
    fig.tight_layout()
    fig.savefig(out / "records.png", dpi=110)
    plt.close(fig)


def _solve_one(args) -> int:
    grid = Grid.uniform(-args.L, args.L, args.n)
    prob = CollisionProblem(grid, PowerKernel(args.gamma), np.exp(-2 * grid.points**2), args.dt, beta=args.beta)
    print(prob)
    for method, opts in [("conic", {}), ("sqp", {}), ("newton", {})]:
        res = solve_collision(prob, method=method, **opts)
        print(f"  {res!r}\n    {res.message}")
    return 0


def _compare(args) -> int:
    from .compare import compare_solvers, problem_from_scene
    from .scene import load_scene

    if args.scene is not None:
        prob = problem_from_scene(load_scene(args.scene), args.t)
        name = f"{args.scene.stem}_t{args.t:g}"
    else:
        grid = Grid.uniform(-args.L, args.L, args.n)
        f0 = np.exp(-2 * grid.points**2)
        prob = CollisionProblem(grid, PowerKernel(args.gamma), f0, args.dt, beta=args.beta)
        name = f"builtin_gamma{args.gamma:g}_n{args.n}_dt{args.dt:g}_beta{args.beta:g}"
    print(prob)
    df = compare_solvers(prob, repeats=args.repeats)
    args.out.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out / f"{name}.csv", index=False)
    text = (
        f"# Solver comparison: {prob!r}\n\nReference: {df.attrs['reference']}.\n\n"
        + df.to_markdown(index=False, floatfmt=".3g")
        + "\n"
    )
    (args.out / f"{name}.md").write_text(text)
    print(text)
    print(f"wrote {args.out}/{name}.csv and .md")
    return 0


def _study(args) -> int:
    from .benchmarks import STUDIES

    return _run_named("study", STUDIES[args.name], args, progress_kw={})


def _reproduce(args) -> int:
    from .reproduce import REPRODUCTIONS

    return _run_named("reproduce", REPRODUCTIONS[args.name], args, progress_kw={"progress": True})


def _run_named(command: str, func, args, progress_kw: dict) -> int:
    """Run one named reproduction or study with the sweep options, print its Markdown table and wall time."""
    t0 = time.perf_counter()
    func(
        args.out,
        quick=args.quick,
        executor=args.executor,
        scheduler=args.scheduler,
        workers=args.workers,
        **progress_kw,
    )
    wall = time.perf_counter() - t0
    md = args.out / f"{args.name}.md"
    if md.exists():
        print(md.read_text())
    quick = " --quick" if args.quick else ""
    print(f"jko-cvx {command} {args.name}{quick}: {wall:.1f} s; wrote {args.out}/{args.name}*")
    return 0


def _sweep_arguments(parser: argparse.ArgumentParser, out: str, executor: str, quick_help: str) -> None:
    """The options shared by ``reproduce`` and ``study``: quick form, output, where sweep points run."""
    parser.add_argument("--quick", action="store_true", help=quick_help)
    parser.add_argument("--out", type=Path, default=Path(out), help="output directory")
    parser.add_argument(
        "--executor", choices=("process", "serial", "dask"), default=executor, help="where sweep points run"
    )
    parser.add_argument("--scheduler", default=None, help="Dask scheduler address (tcp://host:port)")
    parser.add_argument("--workers", type=int, default=None, help="local workers (default: CPU count)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="jko-cvx", description=__doc__.split("\n")[0])
    parser.add_argument("--version", action="version", version=f"jko-cvx {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run a scene (default: the built-in homogeneous gamma = 1, g1 scene)")
    p_run.add_argument("scene", nargs="?", type=Path, help="scene TOML file (studies/scenes/*.toml)")
    p_run.add_argument("--out", type=Path, default=None, help="run directory (default runs/<scene name>)")
    p_run.add_argument("--resume", action="store_true", help="continue a killed run from its checkpoint")
    p_run.add_argument("--quiet", action="store_true", help="no progress bar")
    p_solve = sub.add_parser("solve", help="one collision step with every method, side by side")
    p_solve.add_argument("--gamma", type=float, default=1.0)
    p_solve.add_argument("--n", type=int, default=121)
    p_solve.add_argument("--L", type=float, default=2.0)
    p_solve.add_argument("--dt", type=float, default=0.01)
    p_solve.add_argument("--beta", type=float, default=10.0)
    sub.add_parser("solvers", help="list the installed conic solvers")
    from .reproduce import REPRODUCTIONS

    p_rep = sub.add_parser("reproduce", help="regenerate one of the paper's tables or figures beside its numbers")
    p_rep.add_argument("name", choices=sorted(REPRODUCTIONS), help="which table or figure")
    _sweep_arguments(p_rep, "results/reproduce", "process", "a reduced version (under 2 minutes)")
    from .benchmarks import STUDIES

    p_std = sub.add_parser("study", help="a solver study: work-precision (also vs the FV peer), cost growth, extremes")
    p_std.add_argument("name", choices=sorted(STUDIES), help="which study")
    # serial by default: the studies time their runs, which must not share the cores
    _sweep_arguments(p_std, "results/study", "serial", "a reduced version (about a minute)")
    p_cmp = sub.add_parser("compare", help="every solver and tolerance on one collision step: one table")
    p_cmp.add_argument("scene", nargs="?", type=Path, help="scene TOML (default: a built-in problem, see --gamma ...)")
    p_cmp.add_argument("--t", type=float, default=0.0, help="take the step from the scene's state at this time")
    p_cmp.add_argument("--gamma", type=float, default=1.0)
    p_cmp.add_argument("--n", type=int, default=121)
    p_cmp.add_argument("--L", type=float, default=2.0)
    p_cmp.add_argument("--dt", type=float, default=0.01)
    p_cmp.add_argument("--beta", type=float, default=10.0)
    p_cmp.add_argument("--repeats", type=int, default=5)
    p_cmp.add_argument("--out", type=Path, default=Path("results/compare"), help="output directory")
    args = parser.parse_args(argv)
    try:
        if args.command == "run":
            return _run_scene(args.scene, args.out, args.resume, args.quiet)
        if args.command == "solve":
            return _solve_one(args)
        if args.command == "reproduce":
            return _reproduce(args)
        if args.command == "compare":
            return _compare(args)
        if args.command == "study":
            return _study(args)
        print("\n".join(conic_solvers()))
        return 0
    except (ValueError, TypeError, FileNotFoundError) as exc:
        print(f"jko-cvx: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
