"""The collision step: problem, solvers, the certificate every solver's answer gets, results."""

from .certify import Certificate, certify
from .conic import conic_solvers, solve_conic
from .explicit import explicit_step, sqp_step
from .newton import solve_newton
from .nlp import solve_nlp
from .problem import CollisionProblem, KKTResidual
from .result import CollisionResult, Status
from .solve import METHODS, solve_collision
from .sqp import solve_sqp

__all__ = [
    "METHODS",
    "Certificate",
    "CollisionProblem",
    "CollisionResult",
    "KKTResidual",
    "Status",
    "certify",
    "conic_solvers",
    "explicit_step",
    "solve_collision",
    "solve_conic",
    "solve_newton",
    "solve_nlp",
    "solve_sqp",
    "sqp_step",
]
