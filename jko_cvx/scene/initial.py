"""Initial conditions: one frozen dataclass per ``initial.kind``, each the owner of its density.

The keys of each kind are declared as for every other table (:func:`jko_cvx.scene.schema.key`)
and parsed by :func:`jko_cvx.scene.schema.parse_table`; :data:`INITIAL_KINDS` maps the
``kind`` string to its class.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray

from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.scene.schema import POSITIVE, REAL, Rule, SceneError, Table, key

__all__ = ["INITIAL_KINDS", "Gamma2Initial", "GaussiansInitial", "Initial", "TwoBumpInitial"]


class Initial(Table):
    """Shared behaviour of the kinds: ``kind`` (the TOML value) and whether it needs an x-grid."""

    kind: ClassVar[str]
    phase_space: ClassVar[bool] = True

    def density(self, xgrid: PeriodicGrid | None, vgrid: Grid) -> NDArray[np.float64]:
        """f0 on the grids, shape (Nv,) or (Nx, Nv)."""
        raise NotImplementedError


@dataclass(frozen=True)
class GaussiansInitial(Initial):
    """``initial.kind = "gaussians"``: f0(v) = sum_j A_j exp(-a_j (v - c_j)^2), the same on every x."""

    kind: ClassVar[str] = "gaussians"
    phase_space: ClassVar[bool] = False

    amplitudes: tuple[float, ...] = key(Rule("floats", lo=0.0, nonempty=True), doc="the amplitudes A_j")
    rates: tuple[float, ...] = key(Rule("floats", lo=0.0, lo_open=True, nonempty=True), doc="the rates a_j")
    centres: tuple[float, ...] = key(Rule("floats", nonempty=True), doc="the centres c_j")

    def check(self, where: str) -> None:
        if not len(self.amplitudes) == len(self.rates) == len(self.centres):
            raise SceneError(
                f"{where}.amplitudes, rates and centres must be lists of the same length, got "
                f"{len(self.amplitudes)}, {len(self.rates)} and {len(self.centres)}"
            )
        if not any(a > 0 for a in self.amplitudes):
            raise SceneError(f"{where}.amplitudes must have at least one entry > 0 (f0 = 0 has no mass)")

    def density(self, xgrid: PeriodicGrid | None, vgrid: Grid) -> NDArray[np.float64]:
        """:math:`f_0(v) = \\sum_j A_j e^{-a_j (v - c_j)^2}`, shape (Nv,), or tiled to (Nx, Nv) on an x-grid.

        >>> GaussiansInitial((1.0,), (2.0,), (0.0,)).density(None, Grid.uniform(-1.0, 1.0, 3)).round(4)
        array([0.1353, 1.    , 0.1353])
        """
        v = vgrid.points
        fv = sum(
            A * np.exp(-a * (v - c) ** 2) for A, a, c in zip(self.amplitudes, self.rates, self.centres, strict=True)
        )
        return fv if xgrid is None else np.tile(fv, (xgrid.n, 1))


@dataclass(frozen=True)
class TwoBumpInitial(Initial):
    """``initial.kind = "two_bump_phase"`` (``eqn:f0``): two Gaussian bumps in phase space."""

    kind: ClassVar[str] = "two_bump_phase"

    a: float = key(POSITIVE, doc="eqn:f0: the rate a of the bumps in x")
    b: float = key(POSITIVE, doc="eqn:f0: the rate b of the bumps in v")
    c: float = key(REAL, doc="eqn:f0: the bumps sit at x = -c and x = c")
    d: float = key(REAL, doc="eqn:f0: the bumps move with v = d and v = -d")

    def density(self, xgrid: PeriodicGrid | None, vgrid: Grid) -> NDArray[np.float64]:
        """``eqn:f0``: :math:`f_0 = e^{-a (x + c)^2} e^{-b (v - d)^2} + e^{-a (x - c)^2} e^{-b (v + d)^2}`, (Nx, Nv)."""
        x, v = xgrid.points[:, None], vgrid.points
        a, b, c, d = self.a, self.b, self.c, self.d
        return np.exp(-a * (x + c) ** 2) * np.exp(-b * (v - d) ** 2) + np.exp(-a * (x - c) ** 2) * np.exp(
            -b * (v + d) ** 2
        )


@dataclass(frozen=True)
class Gamma2Initial(Initial):
    """``initial.kind = "gamma2"`` (``eqn:ic_g2``): a sheared Gaussian cut off at |x| = x1."""

    kind: ClassVar[str] = "gamma2"

    a: float = key(POSITIVE, doc="eqn:ic_g2: the rate a of the Gaussian")
    b: float = key(REAL, doc="eqn:ic_g2: the shear b (the Gaussian is in b x + v)")
    x1: float = key(POSITIVE, doc="eqn:ic_g2: the cut-off |x| = x1")

    def density(self, xgrid: PeriodicGrid | None, vgrid: Grid) -> NDArray[np.float64]:
        """``eqn:ic_g2``: :math:`f_0 = e^{-a (b x + v)^2} / \\sqrt{2\\pi}` for :math:`|x| \\le x_1`, times
        :math:`e^{-1000 (|x| - x_1)^2}` beyond; shape (Nx, Nv)."""
        x, v = xgrid.points[:, None], vgrid.points
        a, b, x1 = self.a, self.b, self.x1
        base = np.exp(-a * (b * x + v) ** 2) / np.sqrt(2 * np.pi)
        cut = np.where(np.abs(x) <= x1, 1.0, np.exp(-1000 * (np.abs(x) - x1) ** 2))
        return base * cut


INITIAL_KINDS: dict[str, type[Initial]] = {cls.kind: cls for cls in (GaussiansInitial, TwoBumpInitial, Gamma2Initial)}
"""``initial.kind`` -> its class."""
