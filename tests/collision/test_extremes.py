"""Numerical stability at the extremes: every solve is certified or flagged, never silently wrong.

For each hard case both solvers run.  A returned success must (a) carry a KKT residual
within tolerance, mass to 1e-12 and f >= 0, and (b) agree with the other solver when
that one succeeds too -- the independent cross-check that catches a wrong answer the
residual might miss.  A failure must carry a non-success status with a message.
"""

import numpy as np
import pytest

from jko_cvx import CollisionProblem, Grid, PowerKernel, Status, solve_collision

G = Grid.uniform(-2.0, 2.0, 121)
F_GAUSS = np.exp(-2 * G.points**2)
G_TAILS = Grid.uniform(-4.0, 4.0, 121)
F_TAILS = np.exp(-4.3 * G_TAILS.points**2)  # down to 1.3e-30 at the ends
_s = np.linspace(-1, 1, 121)
G_RATIO = Grid(2 * np.sinh(7.6 * _s) / np.sinh(7.6))  # spacing ratio ~ 1e3
F_RATIO = np.exp(-50 * G_RATIO.points**2) + 1e-3
_w = Grid.uniform(-2.0, 2.0, 61)
F_PEAK = np.exp(-(_w.points**2) / (2 * 0.1**2)) + 1e-3

CASES = {
    "tails 1e-30, beta=10": (G_TAILS, 1.0, F_TAILS, 0.01, 10.0),
    "tails 1e-30, beta=inf": (G_TAILS, 1.0, F_TAILS, 0.01, np.inf),
    "dt=1e-6, gamma=1": (G, 1.0, F_GAUSS, 1e-6, 10.0),
    "dt=1e-6, gamma=3": (G, 3.0, F_GAUSS, 1e-6, 10.0),
    "dt=1, gamma=1.5": (G, 1.5, F_GAUSS, 1.0, 10.0),
    "dt=3, gamma=2": (G, 2.0, F_GAUSS, 3.0, 10.0),
    "dt=10, gamma=3": (G, 3.0, F_GAUSS, 10.0, 10.0),
    "beta=1": (G, 1.0, F_GAUSS, 0.01, 1.0),
    "beta=inf": (G, 1.0, F_GAUSS, 0.01, np.inf),
    "spacing ratio 1e3, gamma=1": (G_RATIO, 1.0, F_RATIO, 1e-3, 10.0),
    "spacing ratio 1e3, gamma=3": (G_RATIO, 3.0, F_RATIO, 1e-3, 10.0),
    "non-convex step (peak, dt=0.3)": (_w, 1.0, F_PEAK, 0.3, np.inf),
    "non-convex step (peak, dt=10)": (_w, 1.0, F_PEAK, 10.0, np.inf),
}


# The outcome class of each case (measured 2026-12-01, Clarabel, SQP with I_max = 5000):
# "certified" (CONVERGED), "flagged" (any status that is not a success: how a solve fails, e.g.
# SOLVER_ERROR against MAX_ITERATIONS, depends on the BLAS kernel's rounding and is not pinned),
# "NONCONVEX" (the step's reduced Hessian is indefinite: a property of the problem), or "either"
# where the measured residual sits within a few times the certification threshold (its side of the
# line moves with the kernel): then a certified answer must agree with Newton's.
# A change here is a change of behaviour: update it with a reason.
EXPECTED = {
    "tails 1e-30, beta=10": ("certified", "flagged"),  # SQP: the zeta test stops on vacuum tails, KKT ~ 5
    "tails 1e-30, beta=inf": ("certified", "flagged"),
    "dt=1e-6, gamma=1": ("certified", "certified"),
    "dt=1e-6, gamma=3": ("certified", "certified"),
    "dt=1, gamma=1.5": ("either", "flagged"),  # conic KKT 1.9e-7 to 5.0e-7 across kernels, against 1e-6
    # conic: the DC loop does not settle in 50 passes; one Newton correction of its answer (a move of 5e-7 in f)
    # certifies it (KKT 2.7e-9, within 1.2e-9 of Newton); flagged before the refinement
    "dt=3, gamma=2": ("either", "flagged"),
    # conic: the DC loop does not settle, but its 9th pass is certified (KKT 5.8e-7, within 1.7e-6 of Newton)
    "dt=10, gamma=3": ("either", "flagged"),
    "beta=1": ("certified", "flagged"),
    "beta=inf": ("certified", "certified"),
    "spacing ratio 1e3, gamma=1": ("certified", "certified"),
    "spacing ratio 1e3, gamma=3": ("flagged", "either"),  # SQP: KKT 1.4e-6 against 1e-6
    "non-convex step (peak, dt=0.3)": ("NONCONVEX", "flagged"),  # SQP: safeguard-cut steps to I_max
    "non-convex step (peak, dt=10)": ("NONCONVEX", "flagged"),
}


def _matches(res, want: str) -> bool:
    if want == "certified":
        return res.success
    if want == "flagged":
        return not res.success
    if want == "either":
        return True
    return res.status.name == want


def _check_outcome(prob, res):
    assert isinstance(res.status, Status) and res.message
    assert res.f.shape == prob.f_star.shape and np.all(np.isfinite(res.f))
    assert res.mass_error <= 1e-12
    assert res.f.min() >= 0
    if res.success:
        assert res.kkt_residual <= 1e-6
        assert prob.is_local_minimiser(res.f, res.m)


@pytest.mark.parametrize("name", list(CASES))
def test_extreme_case_is_certified_or_flagged(name):
    grid, gamma, f_star, dt, beta = CASES[name]
    prob = CollisionProblem(grid, PowerKernel(gamma), f_star, dt, beta=beta)
    conic = solve_collision(prob, method="conic")
    sqp = solve_collision(prob, method="sqp", max_iter=5000)
    for res in (conic, sqp):
        _check_outcome(prob, res)
    want_conic, want_sqp = EXPECTED[name]
    assert _matches(conic, want_conic) and _matches(sqp, want_sqp), (want_conic, want_sqp, conic.message, sqp.message)
    # Algorithm 1's exit flag: e_f = 1 exactly when I_max iterations ran
    assert sqp.info["exit_flag"] == int(sqp.iterations == 5000) == int(sqp.status.name == "MAX_ITERATIONS")
    certified = [r for r in (conic, sqp) if r.success]
    if certified and "either" in (want_conic, want_sqp):  # a certified answer at the line agrees with Newton's
        newton = solve_collision(prob, method="newton")
        assert newton.success, newton.message
        for r in certified:
            assert np.abs(r.f - newton.f).max() <= 1e-4 * newton.f.max()
    if conic.success and sqp.success:
        assert np.abs(conic.f - sqp.f).max() <= 1e-4 * sqp.f.max()
        assert abs(conic.objective - sqp.objective) <= 1e-7 * abs(sqp.objective)


def test_every_convex_extreme_up_to_dt_1_is_certified():
    """Not vacuous: each convex hard case with dt <= 1 is certified by at least one solver.

    Measured limitations (flagged, never certified wrongly): Clarabel fails on gamma = 3
    over the 1e3-ratio grid (the SQP certifies it), and for dt >= 3 both solvers flag
    the step (SOLVER_ERROR / INFEASIBLE from Clarabel, MAX_ITERATIONS from the SQP).
    """
    for name, (grid, gamma, f_star, dt, beta) in CASES.items():
        if name.startswith("non-convex") or dt > 1:
            continue
        prob = CollisionProblem(grid, PowerKernel(gamma), f_star, dt, beta=beta)
        res = solve_collision(prob, method="conic")
        if not res.success:
            res = solve_collision(prob, method="sqp", tol=1e-13, max_iter=20000)
        assert res.success, f"{name}: {res.message} (kkt={res.kkt_residual:.1e})"


@pytest.mark.parametrize("dt", [0.3, 1.0, 10.0])
def test_loss_of_convexity_is_reported(dt):
    prob = CollisionProblem(_w, PowerKernel(1.0), F_PEAK, dt)
    res = solve_collision(prob, method="conic")
    assert res.status is Status.NONCONVEX and not res.success
    assert prob.convexity_margin(res.f, res.m) < 0
    # ... while a small step from the same datum is convex and certified
    small = solve_collision(prob.with_dt(0.01), method="conic")
    assert small.status is Status.CONVERGED


def test_sqp_reports_the_iteration_limit_as_the_paper_exit_flag():
    prob = CollisionProblem(G, PowerKernel(1.0), F_GAUSS, 0.01, beta=1.0)
    res = solve_collision(prob, method="sqp", max_iter=50)
    assert res.status is Status.MAX_ITERATIONS and res.info["exit_flag"] == 1 and not res.success


def test_inaccurate_solver_status_is_never_hidden():
    """A loose SCS solve is reported as what it is: success only when certified."""
    prob = CollisionProblem(G, PowerKernel(1.0), F_GAUSS, 0.01, beta=10.0)
    res = solve_collision(prob, method="conic", solver="SCS", tol=1e-3)
    assert res.info["solver"] == "SCS"
    # pinned (SCS 3, 2026-12-01): SCS says "optimal", the KKT residual says 6e-5, and so does the status
    assert res.info["solver_status"] == "optimal"
    assert res.status is Status.NOT_CERTIFIED and not res.success and 1e-6 < res.kkt_residual < 1e-3
