"""The mesh maps of ``sec:mr``: ``mu1`` and ``mu2``, their concentration sets and the grids they build.

A map :math:`v = \\mu(s)` from uniform :math:`s \\in [-1, 1]` onto :math:`[-L, L]` packs about
:math:`\\delta N` of the N grid points into the concentration set
:math:`S = \\{v > 0 : f(v) > \\delta_0 \\max f\\}` (odd extension to negative s).

One bump (``mu1``): linear :math:`\\mu = (r/\\delta) s` on :math:`[0, \\delta]`, then to
:math:`(1, L)` by :math:`a s^5 + b s` if :math:`r/\\delta < L` (concave up) or by the logistic
:math:`a/(1 + e^{-bs})` otherwise (concave down), constants from continuity at
:math:`s = \\delta` and :math:`\\mu(1) = L`.  The map has a kink at :math:`s = \\delta`: the
spacing jumps there (7- to 11-fold on ``tab_bu_g1`` near its blow-up), and the collision step
(``eqn:non-uniform JKO``) piles mass on the kink's node, a spike next to the concentration that holds
back the peak's growth.  ``junction = "c1"`` (this package's option, not the paper's) replaces the
outer piece by one whose slope rises from the linear part's :math:`r/\\delta` at :math:`s = \\delta`
to the value that reaches :math:`(1, L)`, along the cubic :math:`3u^2 - 2u^3`,
:math:`u = (s - \\delta)/(1 - \\delta)`:

.. math:: \\mu(s) = r + (1 - \\delta)\\bigl(k_0 u + (m - k_0)(u^3 - u^4/2)\\bigr), \\qquad
          k_0 = r/\\delta, \\quad m = k_0 + 2\\Bigl(\\frac{L - r}{1 - \\delta} - k_0\\Bigr),

a C^1 map, increasing wherever :math:`m > 0` (always for :math:`r \\le L\\delta`, which
``from_density`` ensures), the same grid as the paper's inside the set.  (On ``tab_bu_g1`` with
second-order steps it halves the fitted blow-up time's grid error or better: the repository's
blow-up estimator validation, section "The map's junction".)

Two bumps (``mu2``): linear between :math:`(\\tfrac12 - \\tfrac\\delta2, r_1)` and
:math:`(\\tfrac12 + \\tfrac\\delta2, r_2)`; outer piece to :math:`(1, L)` as for one bump; inner
piece from the origin.

Decisions where the paper is ambiguous (DESIGN.md):

* ``eqn:Sr`` writes :math:`r = \\min S`, which would put r at the first positive grid point;
  the map needs the half-width of the concentrated set, so **r = max S** (the largest
  positive v at which f exceeds :math:`\\delta_0 \\max f`).  With S empty (the peak sits
  at v <= 0) r is the smallest positive grid point.
* ``mu2``'s logistic cannot pass through the origin (it is :math:`a/2` at s = 0), which would
  break the odd extension, so the **inner piece is** :math:`a s^5 + b s` **matched to the
  linear piece in value and slope** (C^1); it needs :math:`k s_1 < 5 r_1` (k the slope of the
  linear piece) to be increasing, else the map cannot be built.
* The outer piece follows the paper's rule (quintic if :math:`r/\\delta \\le L`, else
  logistic; for ``mu2`` quintic iff :math:`(r_2 - r_1)/\\delta < L`); where the logistic
  cannot join the points, a concave-down quintic is used while it is increasing; between
  the two ranges no map of the family exists (the constructor raises).  ``from_density``
  caps r at the uniform share :math:`L\\delta` (a wider set gains nothing from refinement:
  the map is the identity there) and keeps :math:`r_2` clear of L.  A two-bump set
  resolved by a single grid point is widened to that point's cell, and one reaching so
  close to 0 that the inner piece would be flat at 0 (spacings of 1e-8 there) is trimmed
  at :math:`r_1 = r_2 s_1/(4\\delta + s_1)`, where the slope at 0 is a quarter of the inner
  piece's mean slope.

A map that cannot be built (not increasing, or no logistic through the two end values)
raises ``ValueError`` saying why and which parameter to change.  The paper's logistic
piece has a limited range: through :math:`(s_0, v_0)` and :math:`(1, L)` it exists only for
:math:`L/v_0 \\le \\max_b (1 + e^{-b s_0})/(1 + e^{-b})` (about 1.2 for :math:`s_0 = 1/2`), so
e.g. ``OneBumpMap(L=2, r=1.5, delta=0.5)`` cannot be built.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jko_cvx.grid import Grid, PeriodicGrid

__all__ = [
    "JUNCTIONS",
    "VALLEY",
    "FollowingMap",
    "OneBumpMap",
    "TwoBumpMap",
    "bump_about_maximum",
    "concentration_set",
    "periodic_map_grid",
    "quadrant_set",
]

_OUTER_RULES = ("paper", "slopes")
JUNCTIONS = ("paper", "c1")
"""How a one-bump map's linear part meets its outer piece (the module docstring): the paper's continuous
piece, or the C^1 one."""


def _check_fraction(name: str, x: float) -> float:
    x = float(x)
    if not 0 < x < 1:
        raise ValueError(f"{name} must lie in (0, 1), got {x!r}")
    return x


class _Piece:
    """One monotone piece of a map on [s0, s1] (absolute s)."""

    def __init__(self, kind: str, a: float, b: float, s0: float = 0.0, v0: float = 0.0) -> None:
        self.kind, self.a, self.b, self.s0, self.v0 = kind, a, b, s0, v0

    def __call__(self, s: NDArray) -> NDArray:
        if self.kind == "linear":  # v0 + a (s - s0)
            return self.v0 + self.a * (s - self.s0)
        if self.kind == "quintic":
            return self.a * s**5 + self.b * s
        if self.kind == "c1":  # slope from a (at s0, value v0) to b (at 1) along 3u^2 - 2u^3
            w = 1 - self.s0
            u = np.clip((s - self.s0) / w, 0.0, 1.0)
            return self.v0 + w * (self.a * u + (self.b - self.a) * (u**3 - u**4 / 2))
        return self.a / (1 + np.exp(-self.b * s))


def _logistic_ratio_max(s0: float) -> tuple[float, float]:
    """(max over b of (1 + e^{-b s0})/(1 + e^{-b}), argmax): the largest L/v a logistic piece can join."""
    from scipy.optimize import minimize_scalar  # on first use: importing jko_cvx need not load scipy.optimize

    def q(b):
        return (1 + np.exp(-b * s0)) / (1 + np.exp(-b))

    # q rises from 1 at b = 0 to a maximum and falls back to 1: locate the maximum on a
    # log grid, then refine (a bounded search over a wide range stalls on the flat tail).
    bs = np.geomspace(1e-6, 1e4, 801)
    k = int(np.argmax(q(bs)))
    lo, hi = bs[max(k - 1, 0)], bs[min(k + 1, bs.size - 1)]
    best = minimize_scalar(lambda b: -q(b), bounds=(lo, hi), method="bounded")
    return float(q(best.x)), float(best.x)


def _outer_piece(s0: float, v0: float, L: float, concave_up: bool) -> _Piece:
    """A piece through (s0, v0) and (1, L): a s^5 + b s (concave up) or a/(1+e^{-bs})."""
    if concave_up:
        a = (L * s0 - v0) / (s0 - s0**5)
        b = L - a
        # mu' = 5 a s^4 + b is monotone in s: its minimum on [s0, 1] is at s0 (a >= 0) or 1 (a < 0)
        if min(5 * a * s0**4 + b, 5 * a + b) <= 0:
            raise ValueError(
                f"the a*s^5 + b*s piece through (s={s0:.4g}, v={v0:.4g}) and (1, L={L:.4g}) is not increasing; "
                "increase delta or decrease delta0"
            )
        return _Piece("quintic", a, b)
    target = L / v0

    def q(b: float) -> float:  # mu(s0)/mu(1) ratio of the logistic, inverted
        return (1 + np.exp(-b * s0)) / (1 + np.exp(-b))

    qmax, bmax = _logistic_ratio_max(s0)
    if target > qmax or target <= 1:
        raise ValueError(
            f"no logistic a/(1+exp(-b s)) joins (s={s0:.4g}, v={v0:.4g}) to (1, L={L:.4g}) "
            f"(needs L/v in (1, {qmax:.4g}], got {target:.4g}); decrease delta or increase delta0"
        )
    from scipy.optimize import brentq

    b = brentq(lambda x: q(x) - target, 1e-12, bmax)
    return _Piece("logistic", L * (1 + np.exp(-b)), b)


class _OddMap:
    """What both maps share: checks on L and delta, and the grid they generate."""

    L: float
    delta: float

    def _check_domain(self) -> None:
        _check_fraction("delta", self.delta)
        if not (np.isfinite(self.L) and self.L > 0):
            raise ValueError(f"L must be a finite number > 0, got {self.L!r}")

    def grid(self, n: int) -> Grid:
        """The refined grid ``mu(s_j)``, s_j uniform on [-1, 1], n points."""
        return Grid(self(np.linspace(-1.0, 1.0, int(n))))  # type: ignore[operator]


@dataclass(frozen=True)
class OneBumpMap(_OddMap):
    """The one-bump map ``mu1`` (concentration centred at 0).

    Parameters
    ----------
    L : float
        Half-width of the domain, ``mu(+-1) = +-L``.
    r : float
        Half-width of the concentration set, ``0 < r < L``.
    delta : float
        Fraction of s in the linear (concentrated) part, ``0 < delta < 1``.
    junction : {"paper", "c1"}
        The outer piece: the paper's (continuous at :math:`s = \\delta`) or the C^1 one (module docstring).
    """

    L: float
    r: float
    delta: float
    junction: str = "paper"

    def __post_init__(self) -> None:
        self._check_domain()
        if not 0 < self.r < self.L:
            raise ValueError(f"r must lie in (0, L) = (0, {self.L}), got {self.r!r}")
        if self.junction not in JUNCTIONS:
            raise ValueError(f"junction must be one of {list(JUNCTIONS)}, got {self.junction!r}")
        if self.junction == "c1":
            k0 = self.r / self.delta
            m = k0 + 2 * ((self.L - self.r) / (1 - self.delta) - k0)
            if not m > 0:
                raise ValueError(
                    f"the C^1 outer piece from (s={self.delta:.4g}, v={self.r:.4g}) with slope {k0:.4g} to "
                    f"(1, L={self.L:.4g}) is not increasing; r must be at most about L delta (r = {self.r:.4g})"
                )
            object.__setattr__(self, "_outer", _Piece("c1", k0, m, self.delta, self.r))
            return
        paper_quintic = self.r / self.delta <= self.L
        try:
            outer = _outer_piece(self.delta, self.r, self.L, concave_up=paper_quintic)
        except ValueError:
            if paper_quintic:
                raise
            # The paper's logistic cannot join these points; a concave-down quintic can
            # while it stays increasing (r <= L delta + (L/4)(delta - delta^5)).
            outer = _outer_piece(self.delta, self.r, self.L, concave_up=True)
        object.__setattr__(self, "_outer", outer)

    def __call__(self, s: ArrayLike) -> NDArray[np.float64]:
        s = np.asarray(s, dtype=float)
        a = np.abs(s)
        out = np.where(a <= self.delta, self.r / self.delta * a, self._outer(a))  # type: ignore[attr-defined]
        return np.sign(s) * out

    @property
    def outer_kind(self) -> str:
        """``"quintic"`` (concave up), ``"logistic"`` (concave down) or ``"c1"`` (``junction = "c1"``)."""
        return self._outer.kind  # type: ignore[attr-defined]

    @classmethod
    def from_density(
        cls, grid: Grid, f: ArrayLike, delta0: float, delta: float, junction: str = "paper"
    ) -> OneBumpMap:
        """The map for density ``f`` on ``grid`` (symmetric domain ``[-L, L]``)."""
        _check_fraction("delta0", delta0)
        _check_fraction("delta", delta)
        r, _ = concentration_set(grid, f, delta0)
        return cls.from_extent(grid, r, delta, junction)

    @classmethod
    def from_extent(cls, grid: Grid, r: float, delta: float, junction: str = "paper") -> OneBumpMap:
        """The map for a set reaching out to ``r`` (its largest positive point) on ``grid``.

        A set wider than its uniform share (r > L delta) gains nothing from refinement: the
        map is then the identity (uniform grid) at r = L delta.
        """
        _check_fraction("delta", delta)
        L = float(grid.points[-1])
        return cls(L=L, r=min(float(r), L * delta), delta=delta, junction=junction)


@dataclass(frozen=True)
class TwoBumpMap(_OddMap):
    """The two-bump map ``mu2`` (concentrations at +-c, symmetric about 0).

    ``mu(1/2 - delta/2) = r1``, ``mu(1/2 + delta/2) = r2``, ``mu(1) = L``, odd extension.

    ``outer_rule`` chooses the piece on ``[1/2 + delta/2, 1]``: ``"paper"`` (default,
    ``eqn mu2``) takes :math:`a_3 s^5 + b_3 s` if :math:`(r_2 - r_1)/\\delta < L` and the
    logistic otherwise; ``"slopes"`` (the rule before 2026-12-01) takes the quintic iff the
    outer chord slope :math:`(L - r_2)/(1 - s_2)` is at least the linear piece's.  Where the
    chosen logistic cannot join :math:`(s_2, r_2)` to :math:`(1, L)` the quintic is used
    while it is increasing (as for ``mu1``).  At L = 4, r1 = 2, r2 = 3.5, delta = 0.5 the
    paper's quintic exists while the slope rule asked for a logistic that does not.
    """

    L: float
    r1: float
    r2: float
    delta: float
    outer_rule: str = "paper"

    def __post_init__(self) -> None:
        self._check_domain()
        if not 0 < self.r1 < self.r2 < self.L:
            raise ValueError(f"need 0 < r1 < r2 < L, got r1={self.r1!r}, r2={self.r2!r}, L={self.L!r}")
        s1, s2 = 0.5 - self.delta / 2, 0.5 + self.delta / 2
        k = (self.r2 - self.r1) / self.delta
        if not k * s1 < 5 * self.r1:
            raise ValueError(
                f"the inner piece cannot be increasing (slope {k:.4g} of the linear part times {s1:.4g} "
                f">= 5 r1 = {5 * self.r1:.4g}); decrease delta"
            )
        a_in = (k * s1 - self.r1) / (4 * s1**5)
        inner = _Piece("quintic", a_in, k - 5 * a_in * s1**4)
        if self.outer_rule not in _OUTER_RULES:
            raise ValueError(f"outer_rule must be one of {_OUTER_RULES}, got {self.outer_rule!r}")
        if self.outer_rule == "paper":
            quintic = k < self.L  # eqn mu2: a3 s^5 + b3 s iff (r2 - r1)/delta < L
        else:  # "slopes": the outer piece's chord slope against the linear piece's
            quintic = (self.L - self.r2) / (1 - s2) >= k
        try:
            outer = _outer_piece(s2, self.r2, self.L, concave_up=quintic)
        except ValueError:
            if quintic:
                raise
            # the logistic cannot join (s2, r2) to (1, L): the quintic while it is increasing
            outer = _outer_piece(s2, self.r2, self.L, concave_up=True)
        object.__setattr__(self, "_pieces", (s1, s2, inner, _Piece("linear", k, 0.0, s1, self.r1), outer))

    def __call__(self, s: ArrayLike) -> NDArray[np.float64]:
        s = np.asarray(s, dtype=float)
        a = np.abs(s)
        s1, s2, inner, mid, outer = self._pieces  # type: ignore[attr-defined]
        out = np.where(a < s1, inner(a), np.where(a <= s2, mid(a), outer(a)))
        return np.sign(s) * out

    @property
    def outer_kind(self) -> str:
        """The piece on ``[1/2 + delta/2, 1]``: ``"quintic"`` or ``"logistic"``."""
        return self._pieces[4].kind  # type: ignore[attr-defined]

    @classmethod
    def from_density(cls, grid: Grid, f: ArrayLike, delta0: float, delta: float) -> TwoBumpMap:
        _check_fraction("delta0", delta0)
        r1, r2 = concentration_set(grid, f, delta0, both_ends=True)
        return cls.from_extent(grid, r1, r2, delta)

    @classmethod
    def from_extent(cls, grid: Grid, r1: float, r2: float, delta: float) -> TwoBumpMap:
        """The map for a set spanning ``[r1, r2]`` (grid points, ``0 < r1 <= r2``) on ``grid``,
        widened or trimmed as described below (and in the module docstring)."""
        r1, r2 = float(r1), float(r2)
        if r1 == r2:
            # A set resolved by one grid point: take that point's cell (midpoints to its
            # neighbours), which is what the grid can say about the bump's width.
            v = grid.points
            k = int(np.searchsorted(v, r1))
            r1 = 0.5 * (v[k - 1] + v[k]) if v[k - 1] > 0 else 0.5 * v[k]
            r2 = 0.5 * (v[k] + v[k + 1]) if k + 1 < v.size else v[k]
        # The inner piece's slope at 0 is b = (5 r1/s1 - k)/4 (k the linear slope): it is
        # increasing only for r1 > r2 s1 / (5 delta + s1), and near that limit b -> 0 packs
        # points at 0 with spacings down to 1e-8 (measured on ibu_gamma3 at t = 15, where the
        # overlapping bumps make S reach 0, and the step then fails).  A set reaching closer
        # to 0 is trimmed so that b >= r1 / (4 s1), a quarter of the piece's mean slope:
        # r1 >= r2 s1 / (4 delta + s1).
        _check_fraction("delta", delta)
        s1, s2 = 0.5 - delta / 2, 0.5 + delta / 2
        L = float(grid.points[-1])
        r2 = min(r2, 0.5 * (L * s2 + L))  # keep room for the outer piece
        r1 = min(max(r1, r2 * s1 / (4 * delta + s1)), r2 * (1 - 1e-6))
        return cls(L=float(grid.points[-1]), r1=r1, r2=r2, delta=delta)


@dataclass(frozen=True)
class FollowingMap:
    """``mu1`` centred on the concentration at ``c`` instead of 0: the map that follows the peak.

    On :math:`[-L, L]`, :math:`\\mu(s) = c + \\mu_+(s)` for :math:`s \\ge 0` and
    :math:`c - \\mu_-(-s)` for :math:`s < 0`, with :math:`\\mu_\\pm` the one-bump maps of half-width
    :math:`L \\mp c` and the same set half-width r and delta: both linear pieces have slope
    :math:`r/\\delta`, so the map is C^1 at c and packs :math:`\\delta N` points into
    :math:`[c - r, c + r]`; :math:`\\mu(\\pm 1) = \\pm L`.  ``c = 0`` is :class:`OneBumpMap`
    (the same points).

    Parameters
    ----------
    L : float
        Half-width of the domain.
    c : float
        Centre of the concentration, ``|c| < L``.
    r : float
        Half-width of the set about c, ``0 < r < L - |c|``.
    delta : float
        Fraction of s in the linear part.
    junction : {"paper", "c1"}
        The outer pieces of both sides (:class:`OneBumpMap`).
    """

    L: float
    c: float
    r: float
    delta: float
    junction: str = "paper"

    def __post_init__(self) -> None:
        if not abs(self.c) < self.L:
            raise ValueError(f"the centre c must lie in (-L, L) = (-{self.L}, {self.L}), got {self.c!r}")
        if not 0 < self.r < self.L - abs(self.c):
            raise ValueError(f"r must lie in (0, L - |c|) = (0, {self.L - abs(self.c):.6g}), got {self.r!r}")
        side = {"r": self.r, "delta": self.delta, "junction": self.junction}
        object.__setattr__(self, "_right", OneBumpMap(L=self.L - self.c, **side))
        object.__setattr__(self, "_left", OneBumpMap(L=self.L + self.c, **side))

    def __call__(self, s: ArrayLike) -> NDArray[np.float64]:
        s = np.asarray(s, dtype=float)
        return np.where(s >= 0, self.c + self._right(np.abs(s)), self.c - self._left(np.abs(s)))  # type: ignore[attr-defined]

    def grid(self, n: int) -> Grid:
        """The refined grid ``mu(s_j)``, s_j uniform on [-1, 1], n points (the ends exactly +-L)."""
        v = self(np.linspace(-1.0, 1.0, int(n)))
        v[0], v[-1] = -self.L, self.L
        return Grid(v)

    @classmethod
    def from_density(
        cls, grid: Grid, f: ArrayLike, delta0: float, delta: float, junction: str = "paper"
    ) -> FollowingMap:
        """The map for density ``f`` on ``grid``: c the grid point of max f, r the largest distance from c
        of a point of c's own bump where :math:`f > \\delta_0 \\max f` (at least the larger spacing next to c),
        capped at the uniform share :math:`(L - |c|)\\,\\delta` (a wider set gains nothing from refinement).
        c's bump is the run of points about c above :data:`VALLEY` :math:`\\delta_0 \\max f`
        (:func:`bump_about_maximum`): another bump, beyond a valley that deep, is not c's concentration (counted
        in, it would widen the set to the cap and leave the grid all but uniform), while points of c's flank that
        dip below the threshold (the paper's map leaves a spike at its kink, s = delta) do not cut the set."""
        _check_fraction("delta0", delta0)
        _check_fraction("delta", delta)
        f = np.asarray(f, dtype=float)
        v = grid.points
        L = float(v[-1])
        k = int(np.argmax(f))
        c = float(v[k])
        # keep c off the ends: a set at the wall is refined as if centred one cell inside it
        c = float(np.clip(c, v[1], v[-2]))
        lo, hi = bump_about_maximum(f, VALLEY * delta0)
        sel = np.zeros(f.size, dtype=bool)
        sel[lo : hi + 1] = f[lo : hi + 1] > delta0 * f[k]
        gaps = np.diff(v)
        r = max(float(np.abs(v[sel] - c).max()), float(gaps[max(k - 1, 0)]), float(gaps[min(k, gaps.size - 1)]))
        return cls(L=L, c=c, r=min(r, (L - abs(c)) * delta), delta=delta, junction=junction)


VALLEY = 0.1
"""Another bump lies beyond a valley below ``VALLEY`` times the set's threshold :math:`\\delta_0 \\max f`
(:meth:`FollowingMap.from_density`; two Gaussians of rate 8 at -0.8 and 0.8 dip to 0.012 of their height
between them, where the paper's one-bump map at 0.5 max f leaves its kink nodes' neighbours near 0.2)."""


def bump_about_maximum(f: ArrayLike, level: float) -> tuple[int, int]:
    """``(lo, hi)``: the indices of the run of consecutive points about the first maximum of ``f`` where
    :math:`f > \\text{level} \\max f` (both ends included; the maximum alone where no neighbour is above)."""
    f = np.asarray(f, dtype=float)
    k = int(np.argmax(f))
    below = np.flatnonzero(~(f > level * f[k]))
    left, right = below[below < k], below[below > k]
    return (int(left[-1]) + 1 if left.size else 0), (int(right[0]) - 1 if right.size else f.size - 1)


def concentration_set(grid: Grid, f: ArrayLike, delta0: float, both_ends: bool = False):
    """Extent of :math:`S = \\{v_j > 0 : f_j > \\delta_0 \\max f\\}`.

    Returns ``(r, None)`` with r = max S (the half-width; smallest positive grid point if S
    is empty) or, with ``both_ends``, ``(min S, max S)``.
    """
    f = np.asarray(f, dtype=float)
    v = grid.points
    pos = v > 0
    if not pos.any():
        raise ValueError("the grid has no positive points: the maps assume a domain [-L, L]")
    sel = pos & (f > delta0 * f.max())
    if not sel.any():
        r = float(v[pos].min())
        return (r, r) if both_ends else (r, None)
    if both_ends:
        return float(v[sel].min()), float(v[sel].max())
    return float(v[sel].max()), None


def quadrant_set(x: ArrayLike, v: ArrayLike, f_star: ArrayLike, delta0: float):
    """The concentration set of ``alg:SPMCSL-JKO`` step 4, as written: one set on the quadrant.

    :math:`S = \\{(x_i, v_j) : f^*(x_i, v_j) > \\delta_0 \\max_{i,j} f^*, x_i > 0, v_j > 0\\}`
    from the post-transport, pre-collision density :math:`f^*` (shape (Nx, Nv)).  Returns
    ``((min x, max x), (min v, max v))`` over S, or ``None`` when S is empty -- which it is
    for ``eqn:f0`` at t = 0 (its bumps sit in the quadrants x < 0 < v and v < 0 < x), where
    the paper does not say what to do.  The time loop (``simulate``) uses it with
    ``refine.concentration_set = "quadrant"`` (an empty set: the uniform grid); by default it
    builds its maps from the post-collision f and separate projections (max over x for the
    v-set, max over v for the x-set, each on its positive half-axis).
    """
    _check_fraction("delta0", delta0)
    x, v, f = np.asarray(x, dtype=float), np.asarray(v, dtype=float), np.asarray(f_star, dtype=float)
    if f.shape != (x.size, v.size):
        raise ValueError(f"f_star must have shape (Nx, Nv) = ({x.size}, {v.size}), got {f.shape}")
    sel = (f > delta0 * f.max()) & (x[:, None] > 0) & (v[None, :] > 0)
    if not sel.any():
        return None
    xi, vj = np.nonzero(sel)
    return (float(x[xi].min()), float(x[xi].max())), (float(v[vj].min()), float(v[vj].max()))


def periodic_map_grid(mu, n: int, period: float):
    """A periodic x-grid from a map: cell-centred uniform s, :math:`x_i = \\mu(-1 + (i + 1/2) 2/n)`."""
    s = -1 + (np.arange(int(n)) + 0.5) * 2 / n
    return PeriodicGrid(mu(s), period)
