"""Probe the Python API misuse classes: does each give a clear error naming the argument?

Each class is one call of the public API with one mistake.  The probe imports a source
tree (default: this checkout) once, then runs every class in a forked child with a
working directory of its own and a time limit of ``TIMEOUT`` s.  A class counts as
*clear* when

* ``expect = "raise"``: the call raised ``ValueError`` / ``TypeError`` (or a subclass, e.g.
  ``SceneError``, ``RunDirError``), from a frame in the package's own code (a deliberate
  check, not a traceback from inside NumPy, SciPy or CVXPY), whose message names the
  argument (one of the class's names appears in it as a whole word), and it wrote no file;
* ``expect = "accept"``: the call returned (valid input that must not be refused);
* ``expect = "honest"``: either a clear error as above, or a returned
  ``CollisionResult`` that is honest: a failure status, or a success with a finite
  objective, finite f and a mass error below 1e-8 (solver outcomes are results).

Hanging (time-out), any other exception, or accepting bad input silently is a miss.  A
class whose API does not exist in the tree is ``n/a``.

    python studies/misuse_api_probe.py                       # this checkout
    python studies/misuse_api_probe.py --before OLD_TREE     # and an older tree, side by side

writes ``studies/results/misuse_api.{csv,md}`` (the API table of docs/guides/bad_input.md).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import re
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TIMEOUT = 60.0

SETUP = """
import inspect
import numpy as np
import tomllib
from jko_cvx import Grid, PowerKernel, CollisionProblem, solve_collision
grid = Grid.uniform(-2.0, 2.0, 21)
K = PowerKernel(1.0)
f = np.exp(-2 * grid.points**2)
prob = CollisionProblem(grid, K, f, 0.01, beta=10.0)
"""

SCENE = """
from jko_cvx.scene.model import scene_from_dict
SCENE_TOML = '''name = "probe"
gamma = 1.0
t_end = 0.02
[v]
L = 2.0
n = 21
[initial]
kind = "gaussians"
amplitudes = [1.0]
rates = [2.0]
centres = [0.0]
[time]
dt = 0.01
[collision]
method = "newton"
beta = 1000.0
fisher = "log"
[stop]
eps_v = 1e-4
[output]
every = 1
'''
scene_dict = tomllib.loads(SCENE_TOML)
scene = scene_from_dict(scene_dict)
"""

FV = "from jko_cvx.finite_volume import Cells, evolve_finite_volume\ncells = Cells(-2.0, 2.0, 20)\n"
PG = "from jko_cvx.grid import PeriodicGrid\nxg = PeriodicGrid.uniform(1.0, 8)\nv = grid.points\nF = np.ones((8, 21))\n"
SWEEP = "import os\nfrom jko_cvx.studies.sweep import run_sweep\n"


def _case(cls, call, names, expect="raise", setup="", requires=None):
    return {"class": cls, "call": call, "names": names, "expect": expect, "setup": setup, "requires": requires}


C = _case
CASES = [
    # ---------------------------------------------------------------- grids and kernel
    C("Grid: too few points", "Grid([0.0, 1.0])", ["points"]),
    C("Grid: not increasing", "Grid([0.0, 2.0, 1.0])", ["points"]),
    C("Grid: NaN point", "Grid([0.0, np.nan, 1.0])", ["points"]),
    C("Grid: not numbers", "Grid('abc')", ["points"]),
    C("Grid: 2-D points", "Grid(np.zeros((3, 3)))", ["points"]),
    C("Grid.uniform: a >= b", "Grid.uniform(1.0, 0.0, 5)", ["a=", "a must"]),
    C("Grid.uniform: infinite end", "Grid.uniform(0.0, np.inf, 5)", ["a=", "b=", "a and b"]),
    C("Grid.uniform: n < 3", "Grid.uniform(0.0, 1.0, 2)", ["n"]),
    C("Grid.uniform: n not an integer", "Grid.uniform(0.0, 1.0, 5.5)", ["n"]),
    C("Grid.uniform: n = None", "Grid.uniform(0.0, 1.0, None)", ["n"]),
    C("Grid.uniform: a as a string", "Grid.uniform('0', 1.0, 5)", ["a=", "a must", "a and b"]),
    C("PeriodicGrid: period too short", "PeriodicGrid([0.0, 1.0, 2.0], period=1.5)", ["period"],
      setup="from jko_cvx.grid import PeriodicGrid"),
    C("PeriodicGrid.uniform: half_width < 0", "PeriodicGrid.uniform(-1.0, 10)", ["half_width"],
      setup="from jko_cvx.grid import PeriodicGrid"),
    C("PeriodicGrid.uniform: n < 3", "PeriodicGrid.uniform(1.0, 2)", ["n"],
      setup="from jko_cvx.grid import PeriodicGrid"),
    C("PowerKernel: gamma = 0", "PowerKernel(0.0)", ["gamma"]),
    C("PowerKernel: gamma = NaN", "PowerKernel(np.nan)", ["gamma"]),
    C("PowerKernel: gamma not a number", "PowerKernel('x')", ["gamma"]),
    # ---------------------------------------------------------------- CollisionProblem
    C("problem: grid not a Grid", "CollisionProblem(grid.points, K, f, 0.01)", ["grid"]),
    C("problem: kernel not a PowerKernel", "CollisionProblem(grid, 1.0, f, 0.01)", ["kernel"]),
    C("problem: f_star wrong length", "CollisionProblem(grid, K, f[:-1], 0.01)", ["f_star"]),
    C("problem: f_star 3-D", "CollisionProblem(grid, K, f[None, None], 0.01)", ["f_star"]),
    C("problem: empty batch (0, N)", "solve_collision(CollisionProblem(grid, K, np.zeros((0, 21)), 0.01), 'newton')",
      ["f_star"]),
    C("problem: f_star with NaN", "CollisionProblem(grid, K, np.where(grid.points > 1, np.nan, f), 0.01)", ["f_star"]),
    C("problem: f_star with inf", "CollisionProblem(grid, K, np.where(grid.points > 1, np.inf, f), 0.01)", ["f_star"]),
    C("problem: f_star negative entry", "CollisionProblem(grid, K, f - 0.1, 0.01)", ["f_star"]),
    C("problem: f_star zero mass", "CollisionProblem(grid, K, 0 * f, 0.01)", ["f_star"]),
    C("problem: f_star not numbers", "CollisionProblem(grid, K, ['a'] * 21, 0.01)", ["f_star"]),
    C("problem: mass overflow (conic)",
      "solve_collision(CollisionProblem(grid, K, np.full(21, 1.5e308), 0.01), 'conic')", ["f_star"], expect="honest"),
    C("problem: f_star of order 1e-320 (conic)",
      "solve_collision(CollisionProblem(grid, K, 1e-320 * (1 + f), 0.01, beta=10.0), 'conic')",
      ["f_star"], expect="honest"),
    C("problem: tails at 1e-300 (conic)",
      "solve_collision(CollisionProblem(g2, K, np.maximum(np.exp(-30 * g2.points**2), 1e-300), 0.01, beta=10.0), "
      "'conic')", ["f_star"], expect="honest", setup="g2 = Grid.uniform(-6.0, 6.0, 61)"),
    C("problem: fisher='log' with a zero", "CollisionProblem(grid, K, f * (grid.points < 1), 0.01, beta=10.0, "
      "fisher='log')", ["f_star"]),
    C("problem: dt = 0", "CollisionProblem(grid, K, f, 0.0)", ["dt"]),
    C("problem: dt = NaN", "CollisionProblem(grid, K, f, np.nan)", ["dt"]),
    C("problem: dt = 1e300", "CollisionProblem(grid, K, f, 1e300, beta=10.0)", ["dt"]),
    C("problem: beta = 0", "CollisionProblem(grid, K, f, 0.01, beta=0.0)", ["beta"]),
    C("problem: beta = 1e-300", "CollisionProblem(grid, K, f, 0.01, beta=1e-300)", ["beta"]),
    C("problem: strength = inf", "CollisionProblem(grid, K, f, 0.01, strength=np.inf)", ["strength"]),
    C("problem: fisher name", "CollisionProblem(grid, K, f, 0.01, beta=10.0, fisher='fisher')", ["fisher"]),
    C("problem: fisher name in capitals", "CollisionProblem(grid, K, f, 0.01, beta=10.0, fisher='Log')", ["fisher"]),
    C("problem: conserve_momentum = 'yes'", "CollisionProblem(grid, K, f, 0.01, conserve_momentum='yes')",
      ["conserve_momentum"]),
    C("problem: beta as a string", "CollisionProblem(grid, K, f, 0.01, beta='10')", ["beta"]),
    C("problem: dt = True", "CollisionProblem(grid, K, f, True)", ["dt"]),
    C("kernel: gamma = True", "PowerKernel(True)", ["gamma"]),
    C("problem: complex f_star", "CollisionProblem(grid, K, f + 0j, 0.01)", ["f_star"]),
    C("problem: masked f_star", "CollisionProblem(grid, K, np.ma.masked_array(f, f < 0.1), 0.01)", ["f_star"]),
    C("problem: object f_star", "CollisionProblem(grid, K, f.astype(object), 0.01)", ["f_star"]),
    C("problem: bool f_star", "CollisionProblem(grid, K, f > 0.5, 0.01)", ["f_star"]),
    C("grid: complex points", "Grid(np.linspace(0.0, 1.0, 5) + 0j)", ["points"]),
    C("solve: callback of the wrong signature (sqp)", "solve_collision(prob, 'sqp', callback=lambda it: None)",
      ["callback"]),
    # ---------------------------------------------------------------- solve_collision
    C("solve: problem not a CollisionProblem", "solve_collision({'f': f}, 'newton')", ["problem"]),
    C("solve: unknown method", "solve_collision(prob, 'cvx')", ["method"]),
    C("solve: method = None", "solve_collision(prob, None)", ["method"]),
    C("solve: unknown option (conic)", "solve_collision(prob, 'conic', tolerance=1e-9)", ["tolerance"]),
    C("solve: unknown option (newton)", "solve_collision(prob, 'newton', solver='SCS')", ["solver"]),
    C("solve: unknown option (sqp)", "solve_collision(prob, 'sqp', m0=np.zeros(20))", ["m0"]),
    C("solve: tol = 0 (newton)", "solve_collision(prob, 'newton', tol=0.0)", ["tol"]),
    C("solve: tol = 1.5 (sqp)", "solve_collision(prob, 'sqp', tol=1.5)", ["tol"]),
    C("solve: tol as a string (conic)", "solve_collision(prob, 'conic', tol='1e-8')", ["tol"]),
    C("solve: tol = np.float32 (newton)", "solve_collision(prob, 'newton', tol=np.float32(1e-8))", ["tol"],
      expect="accept"),
    C("solve: tol = np.float32 (sqp)", "solve_collision(prob, 'sqp', tol=np.float32(1e-8))", ["tol"], expect="accept"),
    C("solve: tol = np.float32 (conic)", "solve_collision(prob, 'conic', tol=np.float32(1e-8))", ["tol"],
      expect="accept"),
    C("solve: max_iter = np.int64 (newton)", "solve_collision(prob, 'newton', max_iter=np.int64(50))", ["max_iter"],
      expect="accept"),
    C("solve: kkt_tol = -1 (conic)", "solve_collision(prob, 'conic', kkt_tol=-1.0)", ["kkt_tol"]),
    C("solve: kkt_tol = 2 (newton)", "solve_collision(prob, 'newton', kkt_tol=2.0)", ["kkt_tol"]),
    C("solve: max_iter = 0 (newton)", "solve_collision(prob, 'newton', max_iter=0)", ["max_iter"]),
    C("solve: max_iter = 2.5 (sqp)", "solve_collision(prob, 'sqp', max_iter=2.5)", ["max_iter"]),
    C("solve: check_convexity = 'no' (newton)", "solve_collision(prob, 'newton', check_convexity='no')",
      ["check_convexity"]),
    C("solve: check_convexity = 'no' (sqp)", "solve_collision(prob, 'sqp', check_convexity='no')", ["check_convexity"]),
    C("solve: check_convexity = 'no' (conic)", "solve_collision(prob, 'conic', check_convexity='no')",
      ["check_convexity"]),
    C("solve: m0 of the wrong shape (newton)", "solve_collision(prob, 'newton', m0=np.zeros(7))", ["m0"]),
    C("solve: callback = 5 (sqp)", "solve_collision(prob, 'sqp', callback=5)", ["callback"]),
    C("solve: solver_options = 5 (conic)", "solve_collision(prob, 'conic', solver_options=5)", ["solver_options"]),
    C("solve: unknown solver_options key (SCS)",
      "solve_collision(prob, 'conic', solver='SCS', solver_options={'eps_absolute': 1e-9})", ["eps_absolute"]),
    C("solve: file-writing solver option (SCS)",
      "solve_collision(prob, 'conic', solver='SCS', solver_options={'write_data_filename': 'leak.txt'})",
      ["write_data_filename"]),
    C("solve: solver name in lower case", "solve_collision(prob, 'conic', solver='clarabel')", ["solver"]),
    C("solve: solver not installed", "solve_collision(prob, 'conic', solver='GUROBI')", ["solver"]),
    C("solve: energy mode", "solve_collision(prob, 'conic', energy='exact')", ["energy"]),
    C("solve: time_limit = 0 (conic)", "solve_collision(prob, 'conic', time_limit=0.0)", ["time_limit"]),
    C("solve: fisher='log' with conic", "solve_collision(CollisionProblem(grid, K, f, 0.01, beta=10.0, fisher='log'), "
      "'conic')", ["fisher"]),
    C("solve: sqp with conserve_momentum", "solve_collision(CollisionProblem(grid, K, f, 0.01, beta=10.0, "
      "conserve_momentum=True), 'sqp')", ["conserve_momentum"]),
    C("solve: step = 0 (sqp)", "solve_collision(prob, 'sqp', step=0.0)", ["step"]),
    C("solve: qp name (sqp)", "solve_collision(prob, 'sqp', qp='dense')", ["qp"]),
    C("solve: start name (newton)", "solve_collision(prob, 'newton', start='random')", ["start"]),
    # ---------------------------------------------------------------- evolve_fixed_grid
    C("evolve: time_order = 3", "evolve_fixed_grid(grid, K, f, 0.01, 0.05, time_order=3)", ["time_order"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: dt = 0", "evolve_fixed_grid(grid, K, f, 0.0, 0.05)", ["dt"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: dt < 0", "evolve_fixed_grid(grid, K, f, -0.01, 0.05)", ["dt"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: dt = 1e-300 (step count)", "evolve_fixed_grid(grid, K, f, 1e-300, 0.05)", ["dt"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: t_end < 0", "evolve_fixed_grid(grid, K, f, 0.01, -1.0)", ["t_end"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: t_end as a string", "evolve_fixed_grid(grid, K, f, 0.01, '1')", ["t_end"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: f0 with NaN", "evolve_fixed_grid(grid, K, np.where(grid.points > 1, np.nan, f), 0.01, 0.05)", ["f0"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: f0 2-D", "evolve_fixed_grid(grid, K, np.stack([f, f]), 0.01, 0.02)", ["f0"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: unknown method", "evolve_fixed_grid(grid, K, f, 0.01, 0.05, method='cvx')", ["method"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: unknown solver option", "evolve_fixed_grid(grid, K, f, 0.01, 0.05, tolerance=1e-9)", ["tolerance"],
      setup="from jko_cvx.evolve import evolve_fixed_grid"),
    C("evolve: stop_on_failure = 'no'", "evolve_fixed_grid(grid, K, f, 0.01, 0.02, stop_on_failure='no')",
      ["stop_on_failure"], setup="from jko_cvx.evolve import evolve_fixed_grid"),
    # ---------------------------------------------------------------- evolve_finite_volume
    C("finite volume: cells not Cells", "evolve_finite_volume(grid, K, f, 0.1)", ["cells"], setup=FV),
    C("finite volume: Cells n < 3", "Cells(-2.0, 2.0, 2)", ["n"], setup=FV),
    C("finite volume: f0 wrong shape", "evolve_finite_volume(cells, K, np.ones(7), 0.1)", ["f0"], setup=FV),
    C("finite volume: f0 negative", "evolve_finite_volume(cells, K, -np.ones(20), 0.1)", ["f0"], setup=FV),
    C("finite volume: cfl = 0.9", "evolve_finite_volume(cells, K, np.ones(20), 0.1, cfl=0.9)", ["cfl"], setup=FV),
    C("finite volume: theta = 3", "evolve_finite_volume(cells, K, np.ones(20), 0.1, theta=3.0)", ["theta"], setup=FV),
    C("finite volume: t_end = inf", "evolve_finite_volume(cells, K, np.ones(20), np.inf)", ["t_end"], setup=FV),
    C("finite volume: strength as a string", "evolve_finite_volume(cells, K, np.ones(20), 0.1, strength='a')",
      ["strength"], setup=FV),
    C("finite volume: max_steps as a string", "evolve_finite_volume(cells, K, np.ones(20), 0.1, max_steps='x')",
      ["max_steps"], setup=FV),
    # ---------------------------------------------------------------- simulate and runs
    C("simulate: resume without out", "simulate(scene, resume=True)", ["out"],
      setup=SCENE + "from jko_cvx.engine.loop import simulate"),
    C("simulate: overwrite without out", "simulate(scene, overwrite=True)", ["out"],
      setup=SCENE + "from jko_cvx.engine.loop import simulate",
      requires="'overwrite' in inspect.signature(simulate).parameters"),
    C("simulate: a path instead of a Scene", "simulate('scene.toml')", ["scene"],
      setup=SCENE + "from jko_cvx.engine.loop import simulate"),
    C("simulate: out is a file", "simulate(scene, out='afile')", ["afile"],
      setup=SCENE + "from jko_cvx.engine.loop import simulate\nopen('afile', 'w').write('x')"),
    C("simulate: rerun into a run directory", "simulate(scene, out='run')", ["run", "overwrite"],
      setup=SCENE + "from jko_cvx.engine.loop import simulate\nsimulate(scene, out='run')"),
    C("simulate: resume with nothing to resume", "simulate(scene, out='run', resume=True)", ["resume"],
      setup=SCENE + "from jko_cvx.engine.loop import simulate"),
    C("simulate: resume = 'yes'", "simulate(scene, out='run', resume='yes')", ["resume"],
      setup=SCENE + "from jko_cvx.engine.loop import simulate"),
    C("load_run: not a run directory", "load_run('empty')", ["empty"],
      setup="import os\nos.mkdir('empty')\nfrom jko_cvx.engine.run import load_run"),
    C("load_run: missing path", "load_run('missing')", ["missing"], setup="from jko_cvx.engine.run import load_run"),
    # ---------------------------------------------------------------- scenes
    C("load_scene: a directory", "load_scene('adir')", ["adir"],
      setup="import os\nos.mkdir('adir')\nfrom jko_cvx.scene.model import load_scene"),
    C("load_scene: missing file", "load_scene('missing.toml')", ["missing.toml"],
      setup="from jko_cvx.scene.model import load_scene"),
    C("scene_from_dict: not a mapping", "scene_from_dict('gamma = 1')", ["scene"], setup=SCENE),
    C("scene_from_dict: section as a scalar", "scene_from_dict({**scene_dict, 'v': 5})", ["v"], setup=SCENE),
    C("scene_from_dict: string for a number", "scene_from_dict({**scene_dict, 'gamma': '1'})", ["gamma"], setup=SCENE),
    C("scene_from_dict: unknown key", "scene_from_dict({**scene_dict, 'gama': 1.0})", ["gama"], setup=SCENE),
    C("scene_from_dict: int list for amplitudes", "scene_from_dict({**scene_dict, 'initial': {**scene_dict['initial'],"
      " 'amplitudes': 1.0}})", ["amplitudes"], setup=SCENE),
    # ---------------------------------------------------------------- sweeps
    C("run_sweep: func not callable", "run_sweep(5, [{'a': 1}], 'cache', executor='serial', progress=False)",
      ["func"], setup=SWEEP),
    C("run_sweep: executor name", "run_sweep(os.path.join, [{'a': 1}], 'cache', executor='threads', progress=False)",
      ["executor"], setup=SWEEP),
    C("run_sweep: workers = 0", "run_sweep(os.path.join, [{'a': 1}], 'cache', workers=0, progress=False)", ["workers"],
      setup=SWEEP),
    C("run_sweep: points not mappings", "run_sweep(os.path.join, [1, 2], 'cache', executor='serial', progress=False)",
      ["points", "point"], setup=SWEEP),
    C("run_sweep: point not JSON",
      "run_sweep(os.path.join, [{'a': object()}], 'cache', executor='serial', progress=False)", ["points", "point"],
      setup=SWEEP),
    C("run_sweep: fresh = 'yes'", "run_sweep(os.path.join, [{'a': 1}], 'cache', executor='serial', progress=False, "
      "fresh='yes')", ["fresh"], setup=SWEEP, requires="'fresh' in inspect.signature(run_sweep).parameters"),
    # ---------------------------------------------------------------- remap and transport
    C("remap: old not a Grid", "remap(grid.points, f, grid)", ["old"], setup="from jko_cvx.mesh import remap"),
    C("remap: f wrong length", "remap(grid, f[:-1], grid)", ["f"], setup="from jko_cvx.mesh import remap"),
    C("remap: new grid outside", "remap(grid, f, Grid.uniform(-3.0, 3.0, 21))", ["new"],
      setup="from jko_cvx.mesh import remap"),
    C("remap: f with NaN", "remap(grid, np.where(grid.points > 1, np.nan, f), Grid.uniform(-1.0, 1.0, 11))", ["f"],
      setup="from jko_cvx.mesh import remap"),
    C("remap: floor < 0", "remap(grid, f, Grid.uniform(-1.0, 1.0, 11), floor=-1.0)", ["floor"],
      setup="from jko_cvx.mesh import remap"),
    C("transport_step: xgrid not a PeriodicGrid", "transport_step(xg.points, v, F, 0.01)", ["xgrid"],
      setup=PG + "from jko_cvx.transport import transport_step"),
    C("transport_step: f wrong shape", "transport_step(xg, v, F[:, :-1], 0.01)", ["f"],
      setup=PG + "from jko_cvx.transport import transport_step"),
    C("transport_step: dt = NaN", "transport_step(xg, v, F, np.nan)", ["dt"],
      setup=PG + "from jko_cvx.transport import transport_step"),
    C("transport_step: f with NaN", "transport_step(xg, v, np.where(F > 0, np.nan, F), 0.01)", ["f"],
      setup=PG + "from jko_cvx.transport import transport_step"),
    C("transport_step: floor < 0", "transport_step(xg, v, F, 0.01, floor=-1.0)", ["floor"],
      setup=PG + "from jko_cvx.transport import transport_step"),
]


def _names(message: str, names: list[str]) -> bool:
    for name in names:
        if re.search(r"(?<![A-Za-z0-9_])" + re.escape(name) + (r"(?![A-Za-z0-9_])" if name[-1].isalnum() else ""),
                     message):
            return True
    return False


def _files(cwd: Path) -> set[str]:
    return {str(p.relative_to(cwd)) for p in cwd.rglob("*")}


def _child(case: dict, tree: str, conn) -> None:
    """Run one case in a fresh directory; send a dict describing what happened."""
    os.chdir(tempfile.mkdtemp(prefix="apiprobe-"))
    cwd = Path.cwd()
    env: dict = {}
    out = {"kind": "setup failed", "exc": "", "message": "", "in_package": False, "wrote": False, "result": ""}
    try:
        exec(SETUP + case["setup"], env)
        if case["requires"] and not eval(case["requires"], env):
            raise ImportError("requires")
    except (ImportError, AttributeError) as exc:
        out.update(kind="n/a", message=f"{type(exc).__name__}: {exc}")
        conn.send(out)
        return
    except Exception as exc:
        out.update(message=f"{type(exc).__name__}: {exc}")
        conn.send(out)
        return
    before = _files(cwd)
    t0 = time.perf_counter()
    try:
        res = eval(case["call"], env)
    except Exception as exc:
        tb = traceback.extract_tb(exc.__traceback__)
        last = tb[-1].filename if tb else ""
        out.update(
            kind="raised",
            exc=type(exc).__name__,
            message=re.sub(r"0x[0-9a-f]+", "0x...", " ".join(str(exc).split())),  # no object addresses
            clear_type=isinstance(exc, (ValueError, TypeError)),
            in_package=str(Path(last).resolve()).startswith(str(Path(tree, "jko_cvx").resolve())),
            where=f"{Path(last).name}:{tb[-1].lineno}" if tb else "",
        )
    else:
        out.update(kind="returned", result=_describe(res))
    out["seconds"] = time.perf_counter() - t0
    out["wrote"] = _files(cwd) != before
    conn.send(out)


def _describe(res) -> str:
    import numpy as np

    if type(res).__name__ != "CollisionResult":
        return type(res).__name__
    st = np.atleast_1d(res.status)
    ok = bool(np.all(np.atleast_1d(res.success)))
    honest = (not ok) or (
        np.all(np.isfinite(res.objective))
        and np.all(np.isfinite(res.f))
        and np.all(np.atleast_1d(res.mass_error) < 1e-8)
    )
    return f"{'honest' if honest else 'DISHONEST'}: status {[s.name for s in st]}, objective {res.objective}"


def run_tree(tree: str) -> list[dict]:
    """All cases against the tree already on sys.path (this process imported it)."""
    # imported once, inherited by the forked children
    import jko_cvx
    import jko_cvx.collision.conic  # noqa: F401

    ctx = mp.get_context("fork")
    rows = []
    for case in CASES:
        a, b = ctx.Pipe(duplex=False)
        p = ctx.Process(target=_child, args=(case, tree, b))
        p.start()
        b.close()
        if a.poll(TIMEOUT):
            try:
                out = a.recv()
            except EOFError:
                out = {"kind": "crashed", "message": f"child died (exit {p.exitcode})"}
        else:
            out = {"kind": "timed out", "message": f"still running after {TIMEOUT:g} s"}
            p.kill()
        p.join()
        rows.append({**case, **out})
    return rows


def verdict(row: dict) -> tuple[str, str]:
    """(clear: "yes" / "no" / "n/a", outcome in words)."""
    kind = row["kind"]
    if kind == "n/a":
        return "n/a", "API absent"
    if kind == "returned":
        res = row.get("result", "")
        if row["expect"] == "accept":
            return "yes", f"accepted ({res})"
        if row["expect"] == "honest" and res.startswith("honest"):
            return "yes", f"returned {res}"
        return "no", f"accepted silently ({res})" + (", wrote files" if row.get("wrote") else "")
    if kind != "raised":
        return "no", kind + (f": {row['message']}" if kind == "setup failed" else "")
    where = row.get("where", "")
    named = _names(row["message"], row["names"])
    if row["expect"] == "accept":
        return "no", f"refused: {row['exc']}"
    ok = row.get("clear_type") and row.get("in_package") and named and not row.get("wrote")
    what = f"{row['exc']}" + ("" if row.get("in_package") else f" from {where}")
    if not named:
        what += ", names no argument"
    if row.get("wrote"):
        what += ", wrote files"
    return ("yes" if ok else "no"), what


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", type=Path, default=None, help="an older source tree to probe as well")
    parser.add_argument("--out", type=Path, default=ROOT / "studies" / "results")
    parser.add_argument("--worker", type=str, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker is not None:  # child mode: this process imports the tree named by PYTHONPATH
        print(json.dumps(run_tree(args.worker)))
        return
    import pandas as pd

    def probe(tree: Path) -> list[dict]:
        env = {**os.environ, "PYTHONPATH": str(tree), "OPENBLAS_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
        cmd = [sys.executable, __file__, "--worker", str(tree)]
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(proc.stderr)
        return json.loads(proc.stdout.strip().splitlines()[-1])

    after = probe(ROOT)
    before = probe(args.before.resolve()) if args.before is not None else None
    rows = []
    for i, row in enumerate(after):
        clear, outcome = verdict(row)
        rec = {"class": row["class"], "call": row["call"], "expect": row["expect"], "names": " / ".join(row["names"])}
        if before is not None:
            rec["clear (before)"], rec["outcome (before)"] = verdict(before[i])
        rec["clear (now)"], rec["outcome (now)"] = clear, outcome
        rec["message (now)"] = (row.get("message") or row.get("result") or "")[:240]
        if before is not None:
            rec["message (before)"] = (before[i].get("message") or before[i].get("result") or "")[:240]
        rows.append(rec)
        print(f"{clear:3} {row['class']}: {outcome}: {rec['message (now)'][:100]}", flush=True)
    table = pd.DataFrame(rows)
    args.out.mkdir(parents=True, exist_ok=True)
    table.to_csv(args.out / "misuse_api.csv", index=False)
    n = len(table)
    counts = f"clear: {int((table['clear (now)'] == 'yes').sum())} of {n} now"
    if before is not None:
        na = int((table["clear (before)"] == "n/a").sum())
        counts += (
            f", {int((table['clear (before)'] == 'yes').sum())} of {n - na} before "
            f"({na} classes n/a before: their API did not exist)"
        )
    md = table.drop(columns=[c for c in table.columns if c in ("message (before)", "names")])
    (args.out / "misuse_api.md").write_text(
        "# Python API misuse classes (`python studies/misuse_api_probe.py`)\n\n"
        + counts
        + ".\n\n"
        + md.to_markdown(index=False)
        + "\n"
    )
    print(counts)


if __name__ == "__main__":
    main()
