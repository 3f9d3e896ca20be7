"""The collision step: problem, solvers, results."""

from .conic import conic_solvers, solve_conic
from .newton import solve_newton
from .nlp import solve_nlp
from .problem import CollisionProblem, KKTResidual
from .result import CollisionResult, Status
from .solve import METHODS, solve_collision
from .sqp import solve_sqp

__all__ = [
    "METHODS",
    "CollisionProblem",
    "CollisionResult",
    "KKTResidual",
    "Status",
    "conic_solvers",
    "solve_collision",
    "solve_conic",
    "solve_newton",
    "solve_nlp",
    "solve_sqp",
]
