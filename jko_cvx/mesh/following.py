"""Maps that follow the concentration: sets placed where they form, on a bounded or a periodic axis.

The paper's maps (:mod:`jko_cvx.mesh.maps`) refine sets centred at 0 (``mu1``) or symmetric
about it (``mu2``).  A concentration that forms elsewhere -- the delta of an asymmetric datum,
bumps moving in x -- is refined where it forms by the maps here:

* :func:`periodic_following_grid`: the paper's one-bump x-grid rotated onto the periodic
  axis so that its refined set is centred at c (a rotation: the same spacings, shifted);
* :class:`ClusterMap`: one or more sets :math:`[c_k - r_k, c_k + r_k]`, each where its bump
  is, by equidistribution of a monitor function (the moving-mesh construction of Huang and
  Russell):

  .. math::

      m(y) = 1 + (K - 1) \\max_k \\big(1 + (d_k(y) - r_k)_+ / w_k\\big)^{-2}, \\qquad
      \\int_{-L}^{\\mu(s)} m = \\frac{1 + s}{2} \\int_{-L}^{L} m,

  :math:`d_k(y) = |y - c_k|` (periodic: the distance on the circle), tail widths
  :math:`w_k = r_k (1 - \\delta)/(2\\delta)`, and K chosen so that the sets hold the share
  :math:`\\delta` of :math:`\\int m`, i.e. about :math:`\\delta N` of the N points, spaced
  uniformly inside each set (the paper's linear piece).  Outside, the spacing grows like
  :math:`(1 + z/w)^2` with the distance z from the set, so neighbouring cells differ by a
  factor :math:`1 + O(1/((1 - \\delta) N))` (the map is C^1; the paper's are too).  Sets
  wider than their share (K would be below 1) give the uniform grid, as the paper's maps do
  past :math:`r = L\\delta`.

:func:`concentration_clusters` finds the sets: the connected runs of grid points with
:math:`f > \\delta_0 \\max f` (wrapping round a periodic axis), the ``bumps`` of them with the
largest f, each centred at its point of max f with the half-width reaching its farthest point.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jko_cvx._numbers import real_scalar
from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.mesh.maps import OneBumpMap, periodic_map_grid

__all__ = ["ClusterMap", "concentration_clusters", "periodic_following_grid"]

_SAMPLES_PER_POINT = 64
"""Fine samples of the monitor per grid point: the inverse of its integral is read off them (linear)."""


def _check_fraction(name: str, x: object) -> float:
    x = real_scalar(name, x)
    if not 0 < x < 1:
        raise ValueError(f"{name} must lie in (0, 1), got {x!r}")
    return x


def _distance(y: NDArray, c: float, period: float | None) -> NDArray:
    d = np.abs(y - c)
    return d if period is None else np.minimum(d, period - d)


def _runs(sel: NDArray[np.bool_], periodic: bool) -> list[NDArray[np.intp]]:
    """The index runs of consecutive True entries (a run through the end joins the start's when periodic)."""
    idx = np.flatnonzero(sel)
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1) + 1
    runs = np.split(idx, breaks)
    if periodic and len(runs) > 1 and runs[0][0] == 0 and runs[-1][-1] == sel.size - 1:
        runs = [np.concatenate([runs[-1], runs[0]]), *runs[1:-1]]
    return runs


def concentration_clusters(
    points: ArrayLike, f: ArrayLike, delta0: float, bumps: int, period: float | None = None
) -> list[tuple[float, float]]:
    """The concentration sets of ``f`` on ``points``: ``[(c, r), ...]``, at most ``bumps``, ordered by c.

    A set is a run of consecutive points with :math:`f > \\delta_0 \\max f` (on a periodic axis,
    ``period`` given, a run may wrap round); the ``bumps`` runs with the largest f are kept.
    c is the run's point of max f; r its farthest point's distance from c, at least the larger
    grid spacing next to c (a set of one point is its cell).
    """
    _check_fraction("delta0", delta0)
    if bumps < 1:
        raise ValueError(f"bumps must be >= 1, got {bumps!r}")
    x, f = np.asarray(points, dtype=float), np.asarray(f, dtype=float)
    if x.shape != f.shape or x.ndim != 1 or x.size < 3:
        raise ValueError(f"points and f must be one-dimensional of one length >= 3, got {x.shape} and {f.shape}")
    runs = _runs(f > delta0 * f.max(), period is not None)
    runs = sorted(runs, key=lambda run: -f[run].max())[:bumps]
    if period is None:
        gaps = np.diff(x)
    else:
        gaps = np.diff(np.concatenate([x, [x[0] + period]]))
    sets = []
    for run in runs:
        k = int(run[np.argmax(f[run])])
        near = max(float(gaps[k - 1]), float(gaps[k % gaps.size])) if period is not None else max(
            float(gaps[max(k - 1, 0)]), float(gaps[min(k, gaps.size - 1)])
        )
        r = max(float(_distance(x[run], x[k], period).max()), near)
        sets.append((float(x[k]), r))
    return sorted(sets)


def periodic_following_grid(
    L: float, c: float, r: float, delta: float, n: int, junction: str = "paper"
) -> PeriodicGrid:
    """The paper's one-bump periodic x-grid (:func:`~jko_cvx.mesh.maps.periodic_map_grid` of ``mu1``) rotated to c.

    The grid on :math:`[-L, L)` whose refined set is :math:`[c - r, c + r]` (mod 2L):
    :math:`x_i = c + \\mu_1(s_i)` wrapped into :math:`[-L, L)` and sorted.  ``mu1`` is odd with
    equal spacings at :math:`s = \\pm 1`, so the wrap point is a point of the grid like any
    other; ``c = 0`` gives the paper's grid.  r is capped at the uniform share :math:`L\\delta`.
    ``junction``: the map's outer piece (:class:`~jko_cvx.mesh.maps.OneBumpMap`).
    """
    period = 2.0 * L
    mu = OneBumpMap(L=L, r=min(float(r), L * delta), delta=delta, junction=junction)
    base = periodic_map_grid(mu, n, period).points
    if c == 0:
        return PeriodicGrid(base, period)
    x = np.sort((base + c + L) % period - L)
    return PeriodicGrid(x, period)


def _tail(z: NDArray) -> NDArray:
    """The monitor's profile: 1 for z <= 0, (1 + z)^-2 beyond."""
    return 1.0 / (1.0 + np.maximum(z, 0.0)) ** 2


@dataclass(frozen=True)
class ClusterMap:
    """Sets ``[c_k - r_k, c_k + r_k]`` refined where they are: equidistribution of a monitor (module docstring).

    Parameters
    ----------
    L : float
        Half-width of the axis ``[-L, L]``.
    sets : sequence of (c, r)
        Centre and half-width of each set, ``|c| < L``, ``r > 0``.
    delta : float
        Share of the points the sets hold together, ``0 < delta < 1``.
    periodic : bool
        The axis is periodic with period 2L (distances on the circle, cell-centred points).
    """

    L: float
    sets: tuple[tuple[float, float], ...]
    delta: float
    periodic: bool = False
    _K: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        _check_fraction("delta", self.delta)
        if not (np.isfinite(self.L) and self.L > 0):
            raise ValueError(f"L must be a finite number > 0, got {self.L!r}")
        sets = tuple((float(c), float(r)) for c, r in self.sets)
        if not sets:
            raise ValueError("sets must hold at least one (c, r)")
        for c, r in sets:
            if not (abs(c) < self.L and 0 < r < self.L):
                raise ValueError(f"each set needs |c| < L = {self.L} and 0 < r < L, got (c, r) = ({c!r}, {r!r})")
        object.__setattr__(self, "sets", sets)
        y = self._samples(1024)
        inside = self._inside(y)
        weight = self._transition(y) * ~inside
        S, T = (float(np.trapezoid(w.astype(float), y)) for w in (inside, weight))
        # the sets' share of the monitor's integral is K S / (2L + (K - 1)(S + T)) = delta
        denominator = S - self.delta * (S + T)
        K = self.delta * (2 * self.L - S - T) / denominator if denominator > 0 else np.inf
        object.__setattr__(self, "_K", float(max(K, 1.0)))

    @property
    def K(self) -> float:
        """The monitor's value inside the sets (1: the uniform grid): the refinement factor of the spacing."""
        return self._K

    def _samples(self, n: int) -> NDArray[np.float64]:
        return np.linspace(-self.L, self.L, _SAMPLES_PER_POINT * max(int(n), 16) + 1)

    def _inside(self, y: NDArray) -> NDArray[np.bool_]:
        period = 2 * self.L if self.periodic else None
        return np.any([_distance(y, c, period) <= r for c, r in self.sets], axis=0)

    def _transition(self, y: NDArray) -> NDArray[np.float64]:
        period = 2 * self.L if self.periodic else None
        w = (1 - self.delta) / (2 * self.delta)
        return np.max([_tail((_distance(y, c, period) - r) / (w * r)) for c, r in self.sets], axis=0)

    def monitor(self, y: ArrayLike) -> NDArray[np.float64]:
        """:math:`m(y)`: K inside the sets, 1 away from them."""
        return 1.0 + (self._K - 1.0) * self._transition(np.asarray(y, dtype=float))

    def __call__(self, s: ArrayLike, n: int = 64) -> NDArray[np.float64]:
        """:math:`\\mu(s)` for s in [-1, 1], read off ``64 max(n, 16) + 1`` samples of the monitor."""
        s = np.asarray(s, dtype=float)
        y = self._samples(n)
        m = self.monitor(y)
        cumulative = np.concatenate([[0.0], np.cumsum((m[1:] + m[:-1]) / 2 * np.diff(y))])
        return np.interp((s + 1) / 2 * cumulative[-1], cumulative, y)

    def grid(self, n: int) -> Grid:
        """The refined bounded grid ``mu(s_j)``, s_j uniform on [-1, 1], n points (the ends exactly +-L)."""
        if self.periodic:
            raise ValueError("a periodic ClusterMap builds a PeriodicGrid: use periodic_grid(n)")
        v = self(np.linspace(-1.0, 1.0, int(n)), int(n))
        v[0], v[-1] = -self.L, self.L
        return Grid(v)

    def periodic_grid(self, n: int) -> PeriodicGrid:
        """The refined periodic grid on ``[-L, L)``: cell-centred s, :math:`x_i = \\mu(-1 + (i + 1/2) 2/n)`."""
        if not self.periodic:
            raise ValueError("a bounded ClusterMap builds a Grid: use grid(n)")
        s = -1 + (np.arange(int(n)) + 0.5) * 2 / n
        return PeriodicGrid(self(s, int(n)), 2 * self.L)

    def extent(self) -> NDArray[np.float64]:
        """``(c_1 - r_1, c_1 + r_1, c_2 - r_2, ...)``: what the remeshing policy compares between steps."""
        return np.array([b for c, r in self.sets for b in (c - r, c + r)])
