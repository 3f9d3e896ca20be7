"""jko_cvx: Fisher-regularised JKO collision steps for the granular kinetic equation.

Following Carrillo, Shu, Wang and Xu, "To blow-up or not to blow-up for a granular
kinetic equation".  The public contract::

    from jko_cvx import Grid, PowerKernel, CollisionProblem, solve_collision
    grid = Grid(points)                      # also Grid.uniform(a, b, n)
    prob = CollisionProblem(grid, PowerKernel(gamma), f_star, dt, strength=1.0, beta=..., fisher="perspective")
    res = solve_collision(prob, method="conic")   # or "sqp"
    res.f, res.m, res.status, res.success, res.iterations, res.kkt_residual, res.objective

    run = jko_cvx.load_run("runs/NAME")      # a run directory as the Run that simulate returned
    run.to_xarray()                          # as an xarray.Dataset (extra jko_cvx[netcdf])
"""

from importlib.metadata import PackageNotFoundError, version

from jko_cvx.collision import CollisionProblem, CollisionResult, KKTResidual, Status, conic_solvers, solve_collision
from jko_cvx.grid import Grid
from jko_cvx.kernels import PowerKernel

try:
    __version__ = version("jko_cvx")
except PackageNotFoundError:  # running from a source tree
    __version__ = "0.0.0+unknown"



def __getattr__(name: str):
    # runs as data: imported on first use (they need pandas and the scene module)
    if name in ("Run", "load_run"):
        from jko_cvx.engine import run

        return getattr(run, name)
    raise AttributeError(f"module 'jko_cvx' has no attribute {name!r}")


__all__ = [
    "CollisionProblem",
    "CollisionResult",
    "Grid",
    "KKTResidual",
    "PowerKernel",
    "Run",
    "Status",
    "__version__",
    "conic_solvers",
    "load_run",
    "solve_collision",
]
