"""The trust-region subproblem, solved exactly on an eigendecomposition.

.. math::

    \\min_q \\; g^\\top q + \\tfrac12 q^\\top H q \\quad \\text{subject to} \\quad \\|q\\| \\le \\Delta,

for a symmetric ``H`` that need not be positive definite (Nocedal and Wright, *Numerical Optimization*,
2nd ed., section 4.3; Moré and Sorensen 1983).  A global minimiser is :math:`q = -(H + \\sigma I)^{-1} g` with
:math:`\\sigma \\ge \\max(0, -\\lambda_1)` and :math:`\\sigma (\\Delta - \\|q\\|) = 0`; in the eigenbasis
:math:`H = Q \\Lambda Q^\\top`, :math:`\\|q(\\sigma)\\|^2 = \\sum_i c_i^2 / (\\lambda_i + \\sigma)^2` with
:math:`c = Q^\\top g`, and :math:`\\sigma` solves the secular equation :math:`1/\\|q(\\sigma)\\| = 1/\\Delta`
(safeguarded Newton in a bracket).  In the *hard case* (:math:`g` orthogonal to the eigenspace of
:math:`\\lambda_1 < 0`, and the step at :math:`\\sigma = -\\lambda_1` inside the region) a multiple of that
eigenvector takes the step to the boundary.

SciPy solves this subproblem only inside :func:`scipy.optimize.minimize` (``method="trust-exact"``), whose loop
cannot carry the Newton solver's domain (f > 0), barrier weight and per-iteration Jacobi scaling; the
eigendecomposition is LAPACK's (``numpy.linalg.eigh``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Eigensystem", "TrustRegionStep", "trust_region_step"]


@dataclass(frozen=True)
class TrustRegionStep:
    """A solution of the trust-region subproblem.

    ``q``: the step; ``interior``: the Newton step :math:`-H^{-1} g` of a positive definite ``H``, inside the
    region (:math:`\\sigma = 0`); ``lowest``: the smallest eigenvalue of ``H``; ``slope`` and ``curvature``:
    :math:`-g^\\top q` and :math:`q^\\top H q`, the model along the step (:meth:`predicted`).
    """

    q: NDArray[np.float64]
    interior: bool
    lowest: float
    slope: float
    curvature: float

    def predicted(self, alpha: float = 1.0) -> float:
        """The model's decrease along ``alpha q``: :math:`-(\\alpha g^\\top q + \\tfrac12 \\alpha^2 q^\\top H q)`
        (non-negative for ``0 <= alpha <= 1``: the model is minimised at ``alpha = 1`` over the region)."""
        return alpha * self.slope - 0.5 * alpha * alpha * self.curvature


class Eigensystem:
    """``H = Q diag(lam) Q'`` and ``c = Q' g``, factorised once for the radii tried at one point."""

    def __init__(self, H: NDArray[np.float64], g: NDArray[np.float64]) -> None:
        self.lam, self.Q = np.linalg.eigh(H)  # ascending; LinAlgError where it does not converge
        self.c = self.Q.T @ g

    def step(self, radius: float) -> TrustRegionStep:
        """The subproblem's global minimiser for ``radius`` > 0 (finite)."""
        if not 0.0 < radius < np.inf:
            raise ValueError(f"radius must be positive and finite, got {radius!r}")
        lam, c = self.lam, self.c
        lowest = float(lam[0])
        if lowest > 0.0:
            w = -c / lam
            if np.linalg.norm(w) <= radius:
                return self._result(w, interior=True)
        floor = max(0.0, -lowest)
        # the hard case: c has no component along lam_1's eigenspace, and the step at sigma = -lam_1 is short
        tie = lam <= lowest + 1e-12 * max(1.0, float(np.abs(lam).max()))
        if lowest <= 0.0 and np.abs(c[tie]).max() <= 1e-14 * max(float(np.linalg.norm(c)), np.finfo(float).tiny):
            w = np.zeros_like(c)
            w[~tie] = -c[~tie] / (lam[~tie] - lowest)
            if np.linalg.norm(w) <= radius:
                return self._result(self._to_boundary(w, radius), interior=False)
        w = -c / (lam + self._sigma(floor, radius))
        if lowest <= 0.0 and np.linalg.norm(w) < (1.0 - 1e-8) * radius:
            # near the hard case sigma + lam_1 falls below sigma's rounding (c_1 tiny, or lam_1 clustered with
            # eigenvalues whose c is not): the root is not representable, and the step at the nearest sigma
            # that is stops short of the boundary; the lowest eigenvector takes it there
            w = self._to_boundary(w, radius)
        return self._result(w, interior=False)

    def _to_boundary(self, w: NDArray[np.float64], radius: float) -> NDArray[np.float64]:
        """``w + tau e_1`` (the lowest eigenvector) with norm ``radius``, of the two such tau the one with the lower
        model value."""
        rest = float(np.linalg.norm(w[1:]))
        reach = np.sqrt(max(radius - rest, 0.0)) * np.sqrt(radius + rest)  # no radius^2 to overflow
        best = None
        for tau in (-w[0] + reach, -w[0] - reach):
            trial = w.copy()
            trial[0] += tau
            t = trial / radius  # the model over radius^2, compared in units that cannot overflow
            value = float((self.c / radius) @ t + 0.5 * (self.lam * t) @ t)
            if best is None or value < best[0]:
                best = (value, trial)
        return best[1]

    def _sigma(self, floor: float, radius: float) -> float:
        """The root sigma > floor of 1/||q(sigma)|| = 1/radius (safeguarded Newton in a bracket).

        Newton's step on 1/||q|| is :math:`(1 - \\|q\\| / \\Delta) / \\sum_i u_i^2 / (\\lambda_i + \\sigma)` with
        :math:`u = q / \\|q\\|`: no power of ``||q||`` that could underflow at a tiny radius or gradient.
        """
        lam, c = self.lam, self.c
        lo = floor
        hi = floor + float(np.linalg.norm(c)) / radius + 1.0
        while np.linalg.norm(c / (lam + hi)) > radius:
            hi *= 2.0
        sigma = hi
        for _ in range(100):
            w = c / (lam + sigma)
            size = float(np.linalg.norm(w))
            if abs(size - radius) <= 1e-10 * radius or hi - lo <= 1e-15 * hi:
                break
            if size > radius:
                lo = sigma
            else:
                hi = sigma
            u = w / size if size > 0.0 else w
            curve = float(np.sum(u * u / (lam + sigma)))
            trial = sigma - (1.0 - size / radius) / curve if curve > 0.0 else np.nan
            sigma = trial if lo < trial < hi else 0.5 * (lo + hi)
        else:
            return hi
        # converged, or the bracket is one rounding wide: its upper end, where the step is finite and inside
        return sigma if abs(size - radius) <= 1e-10 * radius else hi

    def _result(self, w: NDArray[np.float64], interior: bool) -> TrustRegionStep:
        slope, curvature = -float(self.c @ w), float((self.lam * w) @ w)
        return TrustRegionStep(self.Q @ w, interior, float(self.lam[0]), slope, curvature)


def trust_region_step(H: NDArray[np.float64], g: NDArray[np.float64], radius: float) -> TrustRegionStep:
    """The global minimiser of :math:`g^\\top q + \\tfrac12 q^\\top H q` on :math:`\\|q\\| \\le` ``radius``.

    Parameters
    ----------
    H : (n, n) array
        Symmetric, finite; indefinite allowed.
    g : (n,) array
    radius : float
        Positive.

    Raises ``numpy.linalg.LinAlgError`` where the eigendecomposition fails.  For several radii at one point,
    factorise once with :class:`Eigensystem` and call its :meth:`~Eigensystem.step`.
    """
    return Eigensystem(H, g).step(radius)
