"""Shared figure helpers of the studies: headless pyplot, Pareto fronts, the common axes finish."""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["finish_figure", "pareto_front", "pyplot"]


def pareto_front(t: np.ndarray, e: np.ndarray) -> tuple[list[float], list[float]]:
    """The points of (time, error) that no faster point beats in error, in order of time."""
    order = np.argsort(t)
    front_t, front_e, best = [], [], np.inf
    for i in order:
        if e[i] < best:
            best = e[i]
            front_t.append(float(t[i]))
            front_e.append(float(e[i]))
    return front_t, front_e


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (studies run headless)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def finish_figure(fig, axes, path: Path) -> None:
    """Grid and legend on every axis, tight layout, save at 120 dpi, close."""
    for ax in axes:
        ax.grid(True, which="both", alpha=0.2)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    pyplot().close(fig)
