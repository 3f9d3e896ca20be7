"""Shared figure helpers of the studies: pyplot-free figures, Pareto fronts, the common axes finish."""

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


class _Headless:
    """The slice of pyplot the studies draw with (``subplots``, ``figure``, ``close``, ``cm``), on
    pyplot-free :class:`matplotlib.figure.Figure` objects: no backend is chosen or changed (a
    notebook's inline backend survives a study) and no figure stays in pyplot's registry."""

    @staticmethod
    def figure(**fig_kw):
        from matplotlib.figure import Figure

        return Figure(**fig_kw)

    @classmethod
    def subplots(cls, nrows: int = 1, ncols: int = 1, **kw):
        fig_kw = {k: kw.pop(k) for k in ("figsize", "dpi", "layout", "constrained_layout") if k in kw}
        fig = cls.figure(**fig_kw)
        return fig, fig.subplots(nrows, ncols, **kw)

    @staticmethod
    def close(fig=None) -> None:
        """Nothing to release: the figure was never registered with pyplot."""

    @property
    def cm(self):
        import matplotlib.cm

        return matplotlib.cm


def pyplot() -> _Headless:
    """What the studies use of matplotlib.pyplot, without pyplot: figures are written to files only."""
    return _Headless()


def finish_figure(fig, axes, path: Path, **legend) -> None:
    """Grid on every axis and a legend on every axis with labelled artists (``legend``: keyword arguments of
    ``Axes.legend``, default ``fontsize=7``), tight layout, save at 120 dpi, close."""
    for ax in axes:
        ax.grid(True, which="both", alpha=0.2)
        if ax.get_legend_handles_labels()[0]:  # an axis with nothing labelled gets no (empty) legend
            ax.legend(**{"fontsize": 7, **legend})
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    pyplot().close(fig)
