"""jko_cvx: Fisher-regularised JKO collision steps for the granular kinetic equation.

Following Carrillo, Shu, Wang and Xu, "To blow-up or not to blow-up for a granular kinetic
equation".  What a researcher imports is here; the subpackages hold the rest
(``docs/architecture.md``):

* the discrete problem: :class:`Grid`, :class:`PeriodicGrid`, :class:`PowerKernel`,
  :class:`CollisionProblem` (``eqn:non-uniform JKO`` with ``eqn:linear_constraint``);
* its solvers and their judge: :func:`solve_collision` (methods ``"conic"``, ``"newton"``,
  ``"nlp"``, ``"sqp"``), :func:`certify`, :func:`f_error_estimate` (an answer's distance in f
  to the minimiser), :func:`explicit_step`, :func:`conic_solvers`, and the
  results :class:`CollisionResult`, :class:`Status`, :class:`KKTResidual`, :class:`Certificate`;
* the homogeneous equation on a fixed grid: :func:`evolve_fixed_grid`;
* scenes and runs: :class:`Scene`, :func:`load_scene`, :func:`shipped_scene`,
  :func:`default_scene`, :func:`simulate`, :class:`Run`, :func:`load_run`;
* a solver verified along a run against an independent reference: :func:`verify`,
  :func:`load_verification` (:mod:`jko_cvx.engine.verify`).

::

    from jko_cvx import Grid, PowerKernel, CollisionProblem, solve_collision
    grid = Grid.uniform(-2.0, 2.0, 121)
    prob = CollisionProblem(grid, PowerKernel(1.0), f_star, dt=0.01, beta=10.0, fisher="perspective")
    res = solve_collision(prob, method="conic")   # or "newton", "nlp", "sqp"
    res.f, res.m, res.status, res.success, res.iterations, res.kkt_residual, res.objective

    run = jko_cvx.simulate(jko_cvx.shipped_scene("tab_bu_g1"), out="runs/tab_bu_g1")
    run = jko_cvx.load_run("runs/tab_bu_g1")      # the same Run, read back and verified

The scene and engine names are imported on first use: ``import jko_cvx`` loads neither pandas
nor CVXPY.
"""

from importlib import import_module

import jko_cvx.environment  # noqa: F401  (first: it reads the package's files as imported, their code fingerprint)
from jko_cvx._version import __version__
from jko_cvx.collision import (
    Certificate,
    CollisionProblem,
    CollisionResult,
    KKTResidual,
    Status,
    certify,
    conic_solvers,
    explicit_step,
    f_error_estimate,
    solve_collision,
)
from jko_cvx.evolve import evolve_fixed_grid
from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.kernels import PowerKernel

# name -> module: scenes and runs need pandas and the scene schema, so they load on first use
_LAZY = {
    "Scene": "jko_cvx.scene",
    "SceneError": "jko_cvx.scene",
    "default_scene": "jko_cvx.scene",
    "load_scene": "jko_cvx.scene",
    "shipped_scene": "jko_cvx.scene",
    "simulate": "jko_cvx.engine.loop",
    "Run": "jko_cvx.engine.run",
    "load_run": "jko_cvx.engine.run",
    "verify": "jko_cvx.engine.verify",
    "load_verification": "jko_cvx.engine.verify",
}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'jko_cvx' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)


__all__ = [
    "Certificate",
    "CollisionProblem",
    "CollisionResult",
    "Grid",
    "KKTResidual",
    "PeriodicGrid",
    "PowerKernel",
    "Run",
    "Scene",
    "SceneError",
    "Status",
    "__version__",
    "certify",
    "conic_solvers",
    "default_scene",
    "evolve_fixed_grid",
    "explicit_step",
    "f_error_estimate",
    "load_run",
    "load_scene",
    "load_verification",
    "shipped_scene",
    "simulate",
    "solve_collision",
    "verify",
]
