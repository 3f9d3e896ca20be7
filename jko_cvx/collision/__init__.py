"""The collision step: problem, solvers, the certificate every solver's answer gets, results."""

from jko_cvx.collision.certify import Certificate, certify
from jko_cvx.collision.conic import conic_solvers, solve_conic
from jko_cvx.collision.estimate import f_error_estimate
from jko_cvx.collision.newton import solve_newton
from jko_cvx.collision.nlp import solve_nlp
from jko_cvx.collision.problem import CollisionProblem, KKTResidual
from jko_cvx.collision.result import CollisionResult, Status
from jko_cvx.collision.solve import METHODS, solve_collision
from jko_cvx.collision.sqp import explicit_step, solve_sqp, sqp_step

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
    "f_error_estimate",
    "solve_collision",
    "solve_conic",
    "solve_newton",
    "solve_nlp",
    "solve_sqp",
    "sqp_step",
]
