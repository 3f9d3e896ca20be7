"""The mesh-map demonstrations of the paper (``fig:mr_demon``, ``fig:mr_demon_mu2``).

Left: mu(s) for delta = 0.5 and delta0 in {0.2, 0.5, 0.8}; right: the density on a
uniform grid and after refinement (delta0 = 0.5).  Writes
``studies/results/fig_mr_demon.png`` and ``fig_mr_demon_mu2.png``.
Run: ``python studies/fig_mesh_maps.py``.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from jko_cvx import Grid
from jko_cvx.refine import OneBumpMap, TwoBumpMap, remap

OUT = Path(__file__).parent / "results"


def demo(name: str, grid: Grid, f: np.ndarray, cls, title: str) -> None:
    s = np.linspace(-1, 1, 1001)
    fig, (a, b, c) = plt.subplots(1, 3, figsize=(13, 3.8))
    for d0 in (0.2, 0.5, 0.8):
        mu = cls.from_density(grid, f, delta0=d0, delta=0.5)
        a.plot(s, mu(s), label=f"delta0 = {d0}")
    a.set_xlabel("s"), a.set_ylabel("v = mu(s)"), a.legend(), a.set_title("mesh map, delta = 0.5")
    b.plot(grid.points, f, ".-", ms=3)
    b.set_title(f"uniform grid, N = {grid.n}, min dv = {grid.dv.min():.3g}")
    new = cls.from_density(grid, f, delta0=0.5, delta=0.5).grid(grid.n)
    c.plot(new.points, remap(grid, f, new), ".-", ms=3)
    c.set_title(f"after refinement (delta0 = 0.5), min dv = {new.dv.min():.3g}")
    for ax in (b, c):
        ax.set_xlabel("v")
    fig.suptitle(title)
    fig.tight_layout()
    OUT.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT / name, dpi=110)
    plt.close(fig)
    print(f"wrote {OUT / name}")


if __name__ == "__main__":
    g = Grid.uniform(-2, 2, 121)
    demo("fig_mr_demon.png", g, np.exp(-30 * g.points**2), OneBumpMap, "one bump: f = exp(-30 v^2)")
    g4 = Grid.uniform(-4, 4, 121)
    f4 = np.exp(-50 * (g4.points - 2) ** 2) + np.exp(-50 * (g4.points + 2) ** 2)
    demo("fig_mr_demon_mu2.png", g4, f4, TwoBumpMap, "two bumps: f = exp(-50 (v-2)^2) + exp(-50 (v+2)^2)")
