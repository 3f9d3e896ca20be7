"""Exact solutions of the homogeneous equation used to verify the scheme.

The homogeneous collision equation with strength :math:`\\sigma` (``eqn: gke_hom`` has
:math:`\\sigma = 1`) is :math:`f_t = \\sigma\\,\\partial_v((W' * f) f)`.  Two kernels have
closed-form solutions (``sec: concentration``):

* :math:`\\gamma = 2`: :math:`W' * f = M (v - \\bar v)`, so the equation is linear and the
  solution contracts about the mean velocity :math:`\\bar v`:
  :math:`f(t, v) = e^{\\sigma M t} f_0(\\bar v + (v - \\bar v) e^{\\sigma M t})`.
* :math:`\\gamma = 1`: :math:`W' * f = 2F - M` with :math:`F(v) = \\int_{-L}^v f`; the
  cumulative mass satisfies a Burgers equation (the paper's :math:`u = -F`), whose
  characteristics are :math:`v = v_0 + \\sigma (M - 2 F_0(v_0)) t`, along which
  :math:`f = f_0(v_0) / (1 - 2 \\sigma f_0(v_0) t)`.  The solution blows up at
  :math:`T = 1 / (2 \\sigma \\max f_0)`.

Both formulas hold verbatim on a bounded interval :math:`[-L, L]` with no-flux ends
(the velocity field points inwards at both ends), with :math:`M`, :math:`\\bar v` and
:math:`F_0` the truncated quantities -- which is what the discrete problem solves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import erf

__all__ = ["GaussianMixture", "blowup_time_gamma1", "exact_gamma1", "exact_gamma2"]


@dataclass(frozen=True)
class GaussianMixture:
    """:math:`f_0(v) = \\sum_i A_i \\exp(-a_i (v - c_i)^2)` restricted to ``[lo, hi]``.

    Covers the paper's one- and two-bump data :math:`g_1, \\dots, g_4`.
    """

    amplitudes: Sequence[float]
    rates: Sequence[float]
    centres: Sequence[float]
    lo: float = -np.inf
    hi: float = np.inf

    def __post_init__(self) -> None:
        n = len(self.amplitudes)
        if not (len(self.rates) == len(self.centres) == n and n >= 1):
            raise ValueError("amplitudes, rates and centres must have the same non-zero length")
        if any(a <= 0 for a in self.rates):
            raise ValueError(f"rates must be > 0, got {list(self.rates)}")
        if any(a < 0 for a in self.amplitudes):
            raise ValueError(f"amplitudes must be >= 0, got {list(self.amplitudes)}")
        if not self.lo < self.hi:
            raise ValueError(f"lo must be smaller than hi, got lo={self.lo}, hi={self.hi}")

    def pdf(self, v: ArrayLike) -> NDArray[np.float64]:
        v = np.asarray(v, dtype=float)
        out = sum(
            A * np.exp(-a * (v - c) ** 2) for A, a, c in zip(self.amplitudes, self.rates, self.centres, strict=True)
        )
        return np.where((v >= self.lo) & (v <= self.hi), out, 0.0)

    def _antiderivative(self, v: NDArray[np.float64]) -> NDArray[np.float64]:
        return sum(
            A * 0.5 * np.sqrt(np.pi / a) * erf(np.sqrt(a) * (v - c))
            for A, a, c in zip(self.amplitudes, self.rates, self.centres, strict=True)
        )

    def cdf(self, v: ArrayLike) -> NDArray[np.float64]:
        """:math:`\\int_{lo}^{v} f_0`."""
        v = np.clip(np.asarray(v, dtype=float), self.lo, self.hi)
        return self._antiderivative(v) - self._antiderivative(np.asarray(self.lo))

    @property
    def mass(self) -> float:
        return float(self.cdf(self.hi))

    def moment1(self) -> float:
        """:math:`\\int v f_0` over ``[lo, hi]`` (closed form)."""
        tot = 0.0
        for A, a, c in zip(self.amplitudes, self.rates, self.centres, strict=True):
            g = lambda x, A=A, a=a, c=c: -A / (2 * a) * np.exp(-a * (x - c) ** 2)  # noqa: E731
            tot += (g(self.hi) - g(self.lo)) + c * float(
                A * 0.5 * np.sqrt(np.pi / a) * (erf(np.sqrt(a) * (self.hi - c)) - erf(np.sqrt(a) * (self.lo - c)))
            )
        return float(tot)

    @property
    def max(self) -> float:
        """Maximum of the density (on a fine sample when several bumps overlap)."""
        lo = max(self.lo, min(self.centres) - 10 / np.sqrt(min(self.rates)))
        hi = min(self.hi, max(self.centres) + 10 / np.sqrt(min(self.rates)))
        return float(self.pdf(np.linspace(lo, hi, 200001)).max())


def exact_gamma2(f0: GaussianMixture, t: float, v: ArrayLike, strength: float = 1.0) -> NDArray[np.float64]:
    """Exact solution for :math:`W = |v|^2/2`: contraction about the mean velocity."""
    mass = f0.mass
    vbar = f0.moment1() / mass
    k = np.exp(strength * mass * t)
    return k * f0.pdf(vbar + (np.asarray(v, dtype=float) - vbar) * k)


def blowup_time_gamma1(f0: GaussianMixture, strength: float = 1.0) -> float:
    """:math:`T = 1/(2\\sigma \\max f_0)` for :math:`W = |v|`."""
    return 1.0 / (2 * strength * f0.max)


def exact_gamma1(f0: GaussianMixture, t: float, v: ArrayLike, strength: float = 1.0) -> NDArray[np.float64]:
    """Exact solution for :math:`W = |v|` before blow-up, by Burgers characteristics.

    Solves :math:`v = v_0 + \\sigma (M - 2F_0(v_0)) t` for :math:`v_0` by bisection (the map is
    increasing for :math:`t < T`) and returns :math:`f_0(v_0)/(1 - 2\\sigma f_0(v_0) t)`.
    """
    if not 0 <= t < blowup_time_gamma1(f0, strength):
        raise ValueError(f"t must lie in [0, T_blowup) = [0, {blowup_time_gamma1(f0, strength):.6g}), got {t!r}")
    v = np.asarray(v, dtype=float)
    mass = f0.mass
    lo, hi = (f0.lo, f0.hi) if np.isfinite(f0.lo) and np.isfinite(f0.hi) else (v.min() - 10, v.max() + 10)

    def char(v0: NDArray[np.float64]) -> NDArray[np.float64]:
        return v0 + strength * (mass - 2 * f0.cdf(v0)) * t

    a = np.full_like(v, lo)
    b = np.full_like(v, hi)
    for _ in range(200):
        mid = 0.5 * (a + b)
        below = char(mid) < v
        a = np.where(below, mid, a)
        b = np.where(below, b, mid)
    v0 = 0.5 * (a + b)
    g = f0.pdf(v0)
    return g / (1 - 2 * strength * g * t)
