"""The ``jko-cvx`` command.

``jko-cvx run [SCENE.toml] [--out DIR] [--resume | --overwrite]`` runs a scene (default: the
built-in homogeneous gamma = 1, g1 = exp(-2 v^2) scene of Table ``tab:bu``, with mesh refinement,
run until the blow-up criterion min dv < eps_v fires; exact T = 0.5), writes the run
directory (refusing one that holds a run, unless ``--overwrite``) and prints the verdict;
Ctrl-C (SIGINT) or SIGTERM writes a checkpoint, prints the command that resumes it and exits
with status 130.  ``jko-cvx export RUN_DIR --netcdf FILE`` writes a run as netCDF.
``jko-cvx verify SCENE [--reference conic|nlp] [--every K] [--slices all|N] [--workers W] [--trajectory]``
runs a scene and re-solves every K-th step's collision problems, and the last step's, with a reference
(:mod:`jko_cvx.engine.verify`).
``jko-cvx solve [--method M ...] [--fisher perspective|log]`` solves one collision step with every
method (or the given ones); ``jko-cvx solvers`` lists the installed conic solvers;
``jko-cvx scene template [--kind homogeneous|inhomogeneous]`` prints a commented scene template and
``jko-cvx scene keys`` the scene key reference (:mod:`jko_cvx.scene.reference`);
``jko-cvx reproduce NAME [--quick]`` regenerates one of the paper's tables or figures
(:mod:`jko_cvx.studies.reproduce`).
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import signal
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from jko_cvx._version import __version__
from jko_cvx.collision import CollisionProblem, conic_solvers, f_error_estimate, solve_collision
from jko_cvx.grid import Grid
from jko_cvx.kernels import PowerKernel
from jko_cvx.scene.limits import check_step_size

# Bad input the user can fix: one line on stderr, exit code 2, no traceback.  SceneError is
# a ValueError; OSError covers unreadable or unwritable paths; ImportError a missing extra; MemoryError a
# problem larger than the machine (the size checks estimate, they cannot promise).
EXPECTED_ERRORS = (ValueError, TypeError, OSError, ImportError, MemoryError)


_DOTTED_KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
_BARE_WORD = re.compile(r"[A-Za-z_][A-Za-z0-9_.+-]*")


def _setting(text: str) -> tuple[str, Any, str]:
    """``--set KEY=VALUE``: a dotted scene key and its value, parsed as a TOML value (data, never
    evaluated); a bare word that is not TOML (``conic``) is a string.  Returns (key, value, text)."""
    key, eq, raw = text.partition("=")
    key, raw = key.strip(), raw.strip()
    if not eq or not _DOTTED_KEY.fullmatch(key) or not raw:
        raise argparse.ArgumentTypeError(f"must be KEY=VALUE with a dotted scene key (v.n=61), got {text!r}")
    try:
        doc = tomllib.loads(f"value = {raw}")
        if set(doc) != {"value"}:  # more TOML after the value (a newline, then other keys or tables)
            raise argparse.ArgumentTypeError(f"{key}: one TOML value, nothing after it, got {raw!r}")
        value = doc["value"]
    except tomllib.TOMLDecodeError:
        if not _BARE_WORD.fullmatch(raw):
            raise argparse.ArgumentTypeError(
                f"{key}: the value must be a TOML value (a number, true/false, inf, a quoted string, a [list]), "
                f"got {raw!r}"
            ) from None
        value = raw
    return key, value, text


def _printable(text: str) -> str:
    """``text`` with its control characters escaped (a scene's description must not drive the terminal)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _overrides(settings: list[tuple[str, Any, str]] | None) -> dict[str, Any]:
    """The ``--set`` options as the dotted-key overrides of a scene (a key given twice is refused)."""
    out: dict[str, Any] = {}
    for key, value, _ in settings or ():
        if key in out:
            raise ValueError(f"--set {key} is given twice")
        out[key] = value
    return out


def _load(scene_path: Path | None, settings) -> Any:
    """The scene a command runs: a file or a shipped scene by name (the default scene without one),
    with the ``--set`` overrides applied before validation."""
    from jko_cvx.scene.model import default_scene, load_scene

    overrides = _overrides(settings)
    if scene_path is not None:
        return load_scene(scene_path, overrides)
    return default_scene(overrides)  # the limits are checked on the scene with its overrides


def _set_args(settings) -> list[str]:
    """The ``--set`` options as they were given, for a printed resume command."""
    return [arg for _, _, text in settings or () for arg in ("--set", text)]


def _set_option(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", dest="settings", action="append", type=_setting, metavar="KEY=VALUE",
                   help="override a scene key, e.g. --set v.n=61 --set collision.method=sqp (a TOML value; repeat "
                        "for more keys; default: none)")  # fmt: skip


def _run_scene(
    scene_path: Path | None, out: Path | None, resume: bool, overwrite: bool, quiet: bool, settings=None
) -> int:
    from jko_cvx.engine._interrupts import RunInterrupted
    from jko_cvx.engine.loop import simulate
    from jko_cvx.engine.plot import save_figures

    scene = _load(scene_path, settings)
    out = out if out is not None else Path("runs") / scene.name
    # what continues this run (after an interrupt) or redraws its figures (after a finished run)
    cmd = ["jko-cvx", "run", *([] if scene_path is None else [str(scene_path)]), *_set_args(settings)]
    cmd += ["--out", str(out), "--resume"]
    finished: list = []

    def figures(run) -> None:  # drawn while the run directory is still locked (simulate's on_finish)
        finished.append(run)
        save_figures(run, out)

    try:
        run = simulate(scene, out=out, resume=resume, overwrite=overwrite, progress=not quiet, on_finish=figures)
    except RunInterrupted as exc:
        print(
            f"\njko-cvx: interrupted ({signal.Signals(exc.signum).name}) at step {exc.step}, t = {exc.t:.6g}; "
            f"checkpoint written to {out / 'checkpoint.npz'}.\nResume with:\n  {shlex.join(cmd)}",
            file=sys.stderr,
        )
        return 130
    except KeyboardInterrupt:
        if finished:  # the run itself is complete and on disk; only figures are missing
            print(
                f"\njko-cvx: interrupted while drawing the figures; the run in {out} is complete "
                f"(verdict.json written: {finished[0].summary()}).\nRedraw the figures with:\n  {shlex.join(cmd)}",
                file=sys.stderr,
            )
            return 130
        # before the run had a state to checkpoint
        print(
            f"\njko-cvx: interrupted before the run started (nothing was checkpointed); start it again with "
            f"--overwrite (--out {out})",
            file=sys.stderr,
        )
        return 130
    # the description is the scene file's own words: --set may have changed what it describes
    changed = ", ".join(f"{key} = {raw.partition('=')[2].strip()}" for key, _, raw in settings or ())
    print(f"jko-cvx {__version__}: {scene.name} -- {_printable(scene.description)}"
          + (f" [--set: {_printable(changed)}]" if changed else ""))  # fmt: skip
    print(f"  {run.summary()}")
    print(f"  {_seconds_line(run)}; steps with a failed collision solve: {run.failed_steps}")
    print(f"  {run.records_line()}")
    if scene.gamma == 1.0 and scene.homogeneous:  # Burgers in the cumulative distribution: whether a rule fired or not
        print(
            f"  exact blow-up time 1/(2 s max f0) = {1 / (2 * run.column('max_f')[0] * scene.strength):.4f} "
            f"(s = strength = {scene.strength:g}, max f0 on the grid)"
        )
    print(f"  wrote {out}/ (diagnostics.csv, snapshots/, checkpoint.npz, verdict.json, solution.png, records.png)")
    return 0


def _seconds_line(run) -> str:
    """The run's wall and solver seconds, over every leg of an interrupted and resumed run (as recorded in
    verdict.json); a run directory written before the wall time was recorded has none."""
    s = run.seconds
    wall = f"wall {s['wall']:.2f} s" if "wall" in s else "wall not recorded"
    return (f"{wall} (collision {s['collision']:.2f} s, transport {s['transport']:.2f} s, refinement "
            f"{s['refine']:.2f} s; summed over the run's legs)")  # fmt: skip


def _export(args) -> int:
    from jko_cvx.engine.run import export_netcdf, load_run

    try:
        path = export_netcdf(load_run(args.run_dir), args.netcdf)
    except ImportError as exc:  # the optional extra is missing
        print(f"jko-cvx: error: {exc}", file=sys.stderr)
        return 2
    print(f"jko-cvx export: wrote {path} (xarray Dataset of {args.run_dir}: diagnostics over t, snapshots over t_snap)")
    return 0


def _builtin_problem(args) -> CollisionProblem:
    """The built-in problem of ``solve`` / ``compare``: f* = exp(-2 v^2) on [-L, L] with the options' values."""
    grid = Grid.uniform(-args.L, args.L, args.n)
    f0 = np.exp(-2 * grid.points**2)
    return CollisionProblem(grid, PowerKernel(args.gamma), f0, args.dt, beta=args.beta, fisher=args.fisher)


def _solve_one(args) -> int:
    from jko_cvx.collision.conic import ConicOptions
    from jko_cvx.collision.nlp import INSTALL_HINT, nlp_available

    asked = args.method is not None
    # asked for, conic on the log form is refused below, naming the methods that pose it
    methods = list(dict.fromkeys(args.method)) if asked else _methods_that_run(args.fisher)
    if "nlp" in methods and not nlp_available():
        raise ImportError(f"--method nlp needs IPOPT: {INSTALL_HINT}")
    check_step_size(args.n, args.gamma, methods)  # the methods that run, before anything is allocated
    prob = _builtin_problem(args)
    if "conic" in methods and prob.fisher == "log":
        ConicOptions.checked(prob)
    print(prob)
    for method in methods:
        res = solve_collision(prob, method=method)
        print(f"  {res!r}\n    {res.message}\n    {_error_line(prob, res)}")
    if not asked and prob.fisher == "log":
        print("  conic: not run (the log Fisher form is not conic-representable)")
    if not asked and "nlp" not in methods:
        print('  nlp: not installed (pip install "jko_cvx[nlp]")')
    return 0


def _methods_that_run(fisher: str) -> list[str]:
    """The methods ``solve`` and ``compare`` run unasked on the built-in problem: the installed ones, conic not on
    the log form (it does not pose it)."""
    from jko_cvx.collision.nlp import nlp_available

    return [m for m in _SOLVE_METHODS if (m != "nlp" or nlp_available()) and (m != "conic" or fisher != "log")]


def _error_line(prob: CollisionProblem, res) -> str:
    """The answer's a posteriori distance in f to the minimiser (one Newton step on the constraint's null space)."""
    err = f_error_estimate(prob, res.f, res.m)
    label = "error in f (a posteriori estimate, relative to max f)"
    if not np.isfinite(err):
        return f"{label}: not available (a non-finite point, or a reduced Hessian not positive definite there)"
    return f"{label}: {err:.1e}"


def _compare(args) -> int:
    from jko_cvx.studies.compare import compare_solvers, problem_from_scene

    if args.settings and args.scene is None:
        raise ValueError("--set overrides a scene's keys: give a scene (the built-in problem takes --gamma, --n, ...)")
    if args.scene is not None:
        prob = problem_from_scene(_load(args.scene, args.settings), args.t)
        name = f"{args.scene.stem}_t{args.t:g}"
    else:
        check_step_size(args.n, args.gamma, _methods_that_run(args.fisher))  # before anything is allocated
        prob = _builtin_problem(args)
        name = f"builtin_gamma{args.gamma:g}_n{args.n}_dt{args.dt:g}_beta{args.beta:g}"
        name += "_log" if args.fisher == "log" else ""
    print(prob)
    df = compare_solvers(prob, repeats=args.repeats)
    args.out.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out / f"{name}.csv", index=False)
    text = (
        f"# Solver comparison: {prob!r}\n\nReference: {df.attrs['reference']}.  f_error: distance to it "
        "in f (max-norm, relative to max f); f_error_est: each row's own a posteriori estimate of that "
        "distance, cells weighted by f / max f (near-vacuum tails count less).\n\n"
        + df.to_markdown(index=False, floatfmt=".3g")
        + "\n"
    )
    (args.out / f"{name}.md").write_text(text)
    print(text)
    print(f"wrote {args.out}/{name}.csv and .md")
    return 0


def _study(args) -> int:
    from jko_cvx.studies.solvers import STUDIES

    return _run_named("study", STUDIES[args.name], args, progress_kw={})


def _reproduce(args) -> int:
    from jko_cvx.studies.reproduce import REPRODUCTIONS

    entry: str = args.name
    if entry == "section":
        from jko_cvx.studies.reproduce.section import reproduce_section

        func = reproduce_section
    else:
        func = REPRODUCTIONS[entry]
    opts = {"progress": True, "fresh": args.fresh}
    if args.audit:
        if args.fresh:
            raise ValueError("--audit K checks cached points against recomputed ones; --fresh ignores the cache")
        opts["audit"] = args.audit
    return _run_named("reproduce", func, args, progress_kw=opts)


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


def _at_least(low: int):
    """An argparse type: an integer >= low (argparse names the option in its error)."""

    def parse(text: str) -> int:
        try:
            val = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}") from None
        if val < low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}")
        return val

    return parse


def _directory(text: str) -> Path:
    """An argparse type: a non-empty path (``Path("")`` would silently mean the current directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("must name a directory, got an empty path")
    return Path(text)


def _positive(text: str, allow_inf: bool = False) -> float:
    """An argparse type: a finite number > 0 (or inf with ``allow_inf``)."""
    what = "a number > 0 (inf allowed)" if allow_inf else "a finite number > 0"
    try:
        val = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
    if not (val > 0 and (np.isfinite(val) or (allow_inf and val == np.inf))):
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
    return val


def _weight(text: str) -> float:
    """An argparse type for the Fisher weight beta: > 0, inf for no Fisher term."""
    return _positive(text, allow_inf=True)


def _sweep_arguments(parser: argparse.ArgumentParser, out: str, executor: str, quick_help: str) -> None:
    """The options shared by ``reproduce`` and ``study``: quick form, output, where sweep points run."""
    parser.add_argument("--quick", action="store_true", help=quick_help)
    parser.add_argument("--out", type=_directory, default=Path(out), help="output directory (default %(default)s)")
    parser.add_argument(
        "--executor",
        choices=("process", "serial", "dask"),
        default=executor,
        help="where sweep points run: %(choices)s (default %(default)s)",
    )
    parser.add_argument(
        "--scheduler", default=None, help="Dask scheduler address tcp://host:port (default: a local Dask cluster)"
    )
    parser.add_argument("--workers", type=_at_least(1), default=None, help="local workers (default: CPU count)")


class _Names:
    """Choices loaded on first use, so that only ``reproduce`` and ``study`` import the studies (0.7 s)."""

    def __init__(self, load) -> None:
        self._load = load

    def __iter__(self):
        return iter(self._load())

    def __contains__(self, name: object) -> bool:
        return name in self._load()


def _reproductions() -> dict:
    from jko_cvx.studies.reproduce import REPRODUCTIONS

    return REPRODUCTIONS


def _studies() -> dict:
    from jko_cvx.studies.solvers import STUDIES

    return STUDIES


# ---- jko-cvx verify: a solver against a reference along a whole run (jko_cvx.engine.verify) ----
def _slices(text: str) -> str | int:
    """An argparse type for --slices: ``all`` or an integer >= 1."""
    if text == "all":
        return text
    try:
        return _at_least(1)(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"must be 'all' or an integer >= 1, got {text!r}") from None


def _verify_parser(sub) -> None:
    p = sub.add_parser("verify", help="run a scene and re-solve every K-th step's collision problems with a reference")
    p.add_argument("scene", type=Path, help="scene TOML file, or the name of a shipped scene")
    p.add_argument("--reference", choices=("conic", "nlp"), default=None,
                   help="the reference solver (default: conic; nlp for collision.fisher = 'log')")  # fmt: skip
    p.add_argument("--every", type=_at_least(1), default=1,
                   help="compare every K-th step and the last (default %(default)s)")  # fmt: skip
    p.add_argument("--slices", type=_slices, default="all",
                   help="x-slices compared: all, or N evenly spread (default %(default)s)")  # fmt: skip
    p.add_argument("--out", type=_directory, default=None, help="directory (default runs/<scene name>_verify)")
    p.add_argument("--workers", type=_at_least(1), default=None,
                   help="processes for a step's reference solves (default: the usable cores; 1: here)")  # fmt: skip
    p.add_argument("--trajectory", action="store_true",
                   help="also run the whole scene with the reference (into DIR/reference/) and compare T_b, the stop "
                        "reason and max f(t)")  # fmt: skip
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue an interrupted verification")
    again.add_argument("--overwrite", action="store_true", help="replace what the directory holds")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _set_option(p)


def _verify(args) -> int:
    """Exit status 0 when verified, 1 when not (the verdict says where and why), 130 when interrupted."""
    from jko_cvx.engine._interrupts import RunInterrupted
    from jko_cvx.engine.verify import verify

    scene = _load(args.scene, args.settings)
    out = args.out if args.out is not None else Path("runs") / f"{scene.name}_verify"
    t0 = time.perf_counter()
    try:
        ver = verify(scene, args.reference, every=args.every, slices=args.slices, out=out, resume=args.resume,
                     overwrite=args.overwrite, progress=not args.quiet, trajectory=args.trajectory,
                     workers=args.workers)  # fmt: skip
    except RunInterrupted as exc:
        cmd = ["jko-cvx", "verify", str(args.scene), *_set_args(args.settings), "--out", str(out), "--resume",
               "--every", str(args.every), "--slices", str(args.slices)]  # fmt: skip
        cmd += [] if args.reference is None else ["--reference", args.reference]
        cmd += ["--trajectory"] if args.trajectory else []
        cmd += [] if args.workers is None else ["--workers", str(args.workers)]
        print(f"\njko-cvx: interrupted ({signal.Signals(exc.signum).name}) at step {exc.step}, t = {exc.t:.6g}; "
              f"checkpoint written.\nResume with:\n  {shlex.join(cmd)}", file=sys.stderr)  # fmt: skip
        return 130
    wall = time.perf_counter() - t0
    print(f"jko-cvx {__version__} verify: {scene.name}, {scene.collision.method} against {ver.settings.reference}")
    print(f"  {ver.run.summary()}")
    print(f"  {ver.verdict}")
    print(f"  {_seconds_line(ver.run)}; reference solves {ver.table['seconds_ref'].sum():.2f} s (inside the run's "
          f"wall); this command {wall:.2f} s")  # fmt: skip
    if ver.reference_run is not None:
        print(f"  reference run: {ver.reference_run.summary()}")
    print(f"  wrote {out}/ (verify.csv, verify.md, verify.png beside the run's files"
          f"{'; trajectory.csv, reference/' if ver.trajectory is not None else ''})")  # fmt: skip
    return 0 if ver.verified else 1


def main(argv: list[str] | None = None) -> int:
    """The ``jko-cvx`` command: 0 on success, 2 on bad input, 130 when interrupted (SIGINT)."""
    try:
        return _main(argv)
    except BrokenPipeError:  # the reader went away (jko-cvx scene keys | head): nothing left to tell it
        try:  # so that the interpreter's final flush of stdout does not fail again
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError, AttributeError):  # stdout without a file descriptor
            pass
        return 141  # 128 + SIGPIPE, as a shell reports a command killed by a closed pipe
    except KeyboardInterrupt:  # SIGINT outside a run's own handling: while loading, in a study, a table
        print(
            "\njko-cvx: interrupted; run the same command again (reproductions and studies reuse the points "
            "already cached in their output directory)",
            file=sys.stderr,
        )
        return 130


def build_parser() -> argparse.ArgumentParser:
    """The ``jko-cvx`` argument parser (its subcommands and options; the CLI reference is generated from it)."""
    parser = argparse.ArgumentParser(
        prog="jko-cvx",
        description="Blow-up in the granular kinetic equation: run scenes, verify them against a reference, "
        "solve and compare collision steps, reproduce the paper's tables and figures.",
    )
    parser.add_argument("--version", action="version", version=f"jko-cvx {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run a scene (default: the built-in homogeneous gamma = 1, g1 scene)")
    p_run.add_argument(
        "scene",
        nargs="?",
        type=Path,
        help="scene TOML file, or the name of a shipped scene (jko-cvx scene list); default: "
        "the built-in homogeneous gamma = 1 scene; jko-cvx scene template prints one to start from",
    )
    p_run.add_argument("--out", type=_directory, default=None, help="run directory (default: runs/<scene name>)")
    again = p_run.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue an interrupted run from its checkpoint")
    again.add_argument("--overwrite", action="store_true", help="replace the run already in the run directory")
    p_run.add_argument("--quiet", action="store_true", help="no progress bar")
    _set_option(p_run)
    p_exp = sub.add_parser("export", help="write a run directory as a netCDF file (extra jko_cvx[netcdf])")
    p_exp.add_argument("run_dir", type=Path, help="run directory (jko-cvx run --out)")
    p_exp.add_argument("--netcdf", type=Path, required=True, help="the netCDF file to write")
    p_solve = sub.add_parser(
        "solve", help="one collision step (f* = exp(-2 v^2) on [-L, L]) with every method, side by side"
    )
    _problem_arguments(p_solve)
    p_solve.add_argument(
        "--method",
        nargs="+",
        choices=_SOLVE_METHODS,
        default=None,
        help="the methods to run, one or several of %(choices)s (default: every installed one; conic is left out "
        "for --fisher log, which it cannot pose)",
    )
    sub.add_parser("solvers", help="list the installed conic solvers")
    p_rep = sub.add_parser("reproduce", help="regenerate one of the paper's tables or figures beside its numbers")
    p_rep.add_argument(
        "name",
        choices=_Names(lambda: [*sorted(_reproductions()), "section"]),
        metavar="NAME",  # a metavar: argparse would list the choices (import them) when the parser is built
        help="which table or figure: %(choices)s; 'section': every entry of the paper's numerical section, "
        "on one shared pool",
    )
    _sweep_arguments(p_rep, "results/reproduce", "process", "a reduced version (under 2 minutes)")
    p_rep.add_argument("--fresh", action="store_true", help="ignore the sweep cache: recompute every point")
    p_rep.add_argument(
        "--audit",
        type=_at_least(0),
        default=0,
        metavar="K",
        help="recompute K randomly chosen cached points and compare them with the cache bit for bit "
        "(default %(default)s: none)",
    )
    p_std = sub.add_parser("study", help="a solver study: work-precision (also vs the FV peer), cost growth, extremes")
    p_std.add_argument(
        "name", choices=_Names(lambda: sorted(_studies())), metavar="NAME", help="which study: %(choices)s"
    )
    # serial by default: the studies time their runs, which must not share the cores
    _sweep_arguments(p_std, "results/study", "serial", "a reduced version (about a minute)")
    p_cmp = sub.add_parser("compare", help="every solver and tolerance on one collision step: one table")
    p_cmp.add_argument("scene", nargs="?", type=Path, help="scene TOML (default: a built-in problem, see --gamma ...)")
    p_cmp.add_argument("--t", type=float, default=0.0,
                       help="with a scene: the step from its state at this time (default %(default)s)")  # fmt: skip
    _problem_arguments(p_cmp, " (without a scene)")
    _set_option(p_cmp)
    p_cmp.add_argument("--repeats", type=_at_least(1), default=5,
                       help="timed solves per setting, the median kept (default %(default)s)")  # fmt: skip
    p_cmp.add_argument("--out", type=_directory, default=Path("results/compare"),
                       help="output directory (default %(default)s)")  # fmt: skip
    _verify_parser(sub)
    _scene_parser(sub)
    return parser


_SOLVE_METHODS = ("conic", "sqp", "newton", "nlp")


def _problem_arguments(p: argparse.ArgumentParser, where: str = "") -> None:
    """The built-in collision problem of ``solve`` and ``compare``: f* = exp(-2 v^2) on [-L, L]."""
    p.add_argument("--gamma", type=_positive, default=1.0,
                   help=f"kernel exponent, W(v) = |v|^gamma / gamma{where} (default %(default)s)")  # fmt: skip
    p.add_argument("--n", type=_at_least(3), default=121,
                   help=f"velocity grid points, an integer >= 3{where} (default %(default)s)")  # fmt: skip
    p.add_argument("--L", type=_positive, default=2.0,
                   help=f"half-width of the velocity domain [-L, L]{where} (default %(default)s)")  # fmt: skip
    p.add_argument("--dt", type=_positive, default=0.01, help=f"time step{where} (default %(default)s)")
    p.add_argument("--beta", type=_weight, default=10.0,
                   help=f"Fisher weight beta, > 0, inf for no Fisher term{where} (default %(default)s)")  # fmt: skip
    p.add_argument("--fisher", choices=("perspective", "log"), default="perspective",
                   help=f"form of the Fisher term: %(choices)s{where} (default %(default)s)")  # fmt: skip


# ---- jko-cvx scene: the shipped scenes, the scene template and the key reference (jko_cvx.scene.reference) ----
def _scene_parser(sub) -> None:
    p = sub.add_parser("scene", help="list the shipped scenes, print a commented scene template or the key reference")
    what = p.add_subparsers(dest="scene_command", required=True, metavar="{list,template,keys}",
                            help="list: the shipped scenes; template: a scene to start from; keys: the key "
                                 "reference")  # fmt: skip
    what.add_parser("list", help="the shipped scenes jko-cvx run takes by name, each with its description")
    t = what.add_parser("template", help="a commented TOML scene (every key, type, range, default) jko-cvx run accepts")
    t.add_argument("--kind", choices=("homogeneous", "inhomogeneous"), default="homogeneous",
                   help="a homogeneous scene (no x-grid) or an inhomogeneous one: %(choices)s "
                        "(default %(default)s)")  # fmt: skip
    what.add_parser("keys", help="every scene key: type, allowed values, default and meaning")


def _scene(args) -> int:
    from jko_cvx.scene import shipped_scene, shipped_scene_names
    from jko_cvx.scene.reference import keys_text, scene_template

    if args.scene_command == "list":
        names = shipped_scene_names()
        width = max(map(len, names))
        for name in names:
            print(f"{name:<{width}}  {_printable(shipped_scene(name).description)}")
        return 0
    sys.stdout.write(scene_template(args.kind) if args.scene_command == "template" else keys_text())
    return 0


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "verify":
            return _verify(args)
        if args.command == "run":
            return _run_scene(args.scene, args.out, args.resume, args.overwrite, args.quiet, args.settings)
        if args.command == "export":
            return _export(args)
        if args.command == "solve":
            return _solve_one(args)
        if args.command == "reproduce":
            return _reproduce(args)
        if args.command == "compare":
            return _compare(args)
        if args.command == "study":
            return _study(args)
        if args.command == "scene":
            return _scene(args)
        print("\n".join(conic_solvers()))
        return 0
    except BrokenPipeError:  # an OSError, but not bad input: main() ends quietly
        raise
    except EXPECTED_ERRORS as exc:
        print(f"jko-cvx: error: {_one_line(exc)}", file=sys.stderr)
        return 2


def _one_line(exc: BaseException) -> str:
    """The exception's message on one line (OSError: the strerror and the path it names)."""
    if isinstance(exc, OSError) and exc.strerror and exc.filename is not None:
        return f"{exc.strerror}: {exc.filename}"
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
