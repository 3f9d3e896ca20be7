"""Figures of a run (returned by ``simulate`` or read back with :func:`jko_cvx.load_run`).

* :func:`plot_solution`: the final density beside the initial datum f0 (homogeneous: f(v) with f0(v),
  and a zoom at its maximum; inhomogeneous: f(x, v) on the run's last grids, a labelled colorbar,
  the contours of f0);
* :func:`plot_records`: the blow-up records against t (min dv, min dx, max f; min spread_v
  where the scene stops on it) with the scene's thresholds (eps_v, eps_x, spread_v) as
  horizontal lines, the refinement switches (steps at which the mesh map changed the grid)
  marked on the mesh records, T_b where a rule fired, and the exact law where one is known:
  for gamma = 1 in the homogeneous equation ``eqn: gke_hom`` (``W = |v|``, strength s) f obeys
  df/dt = 2 s f^2 along characteristics, so max f(t) = M0 / (1 - 2 s M0 t) with M0 = max f0,
  and the blow-up time is T = 1 / (2 s M0) (Table ``tab:bu``);
* :func:`save_figures`: both, as ``solution.png`` and ``records.png`` (the CLI's figures).

Matplotlib is imported when a function is called; pass ``ax`` to draw into your own axes.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jko_cvx.engine._state import atomic_write
from jko_cvx.engine.verdict import StopReason, fit_rows

if TYPE_CHECKING:
    from jko_cvx.engine.run import Run

__all__ = ["exact_max_f", "initial_datum", "plot_records", "plot_solution", "refinement_switches", "save_figures"]


def exact_max_f(run: Run) -> tuple[np.ndarray, np.ndarray, float] | None:
    """``(t, max f(t), T)`` of the exact gamma = 1 homogeneous solution (None for other scenes).

    M0 is max f0 on the run's initial grid (the diagnostics' step-0 row).
    """
    sc = run.scene
    if not (sc.homogeneous and sc.gamma == 1.0):
        return None
    m0 = float(run.column("max_f")[0])
    T = 1.0 / (2.0 * sc.strength * m0)
    t = np.linspace(0.0, min(float(run.column("t")[-1]), T), 400)
    with np.errstate(divide="ignore"):
        law = m0 / (1.0 - 2.0 * sc.strength * m0 * t)
    return t[np.isfinite(law)], law[np.isfinite(law)], T


def refinement_switches(run: Run, axis: str = "v") -> np.ndarray:
    """Steps (rows of the diagnostics) at which refinement changed the ``axis`` grid.

    Read from the records: the smallest spacing of a grid that was not rebuilt is the same
    number, bit for bit, as at the previous step.  Empty for an axis the scene does not refine.
    """
    spec = run.scene.refine.v if axis == "v" else run.scene.refine.x
    if spec is None:
        return np.array([], dtype=int)
    col = run.column(f"min_d{axis}")
    changed = np.flatnonzero(col[1:] != col[:-1]) + 1
    return run.column("step")[changed]


def _new_axes(ax, ncols: int = 1, figsize=(6, 4)):
    if ax is not None:  # the caller's axes: no pyplot (importing it chooses a backend)
        return ax.figure if ncols == 1 else np.ravel(ax)[0].figure, ax
    import matplotlib.pyplot as plt

    return plt.subplots(1, ncols, figsize=figsize)


def initial_datum(run: Run):
    """``(x grid or None, v grid, f0)``: the scene's initial datum on its uniform grids (before any refinement)."""
    xg, vg = run.scene.xgrid(), run.scene.vgrid()
    return xg, vg, run.scene.initial_density(xg, vg)


def plot_solution(run: Run, ax=None):
    """The final density beside the initial datum f0; returns the figure.

    Homogeneous runs use two axes (give a pair as ``ax``): f(t, v) and f0(v), and a zoom at the
    maximum.  Inhomogeneous runs: f(t, x, v) in colour (the colorbar names it) under the contours
    of f0(x, v).  A figure created here is laid out (``tight_layout``); one whose axes are passed
    in keeps the caller's layout.
    """
    xg0, vg0, f0 = initial_datum(run)
    start = "initial datum f0 (t = 0)"
    if run.xgrid is None:
        fig, (a, b) = _new_axes(ax, 2, (10, 4))
        v = run.vgrid.points
        a.plot(vg0.points, f0, "--", color="0.5", lw=1, label=start)
        a.plot(v, run.f, ".-", ms=2, label=f"f at t = {run.t:.4g}")
        a.set_xlabel("velocity v"), a.set_ylabel("density f(t, v)"), a.set_title(f"f at t = {run.t:.4g}")
        a.legend(fontsize=7)
        k = int(np.argmax(run.f))
        sel = np.abs(v - v[k]) <= max(20 * run.vgrid.dv.min(), 1e-3)
        b.plot(v[sel], run.f[sel], ".-", ms=3, label=f"f at t = {run.t:.4g} (grid points)")
        b.set_xlabel("velocity v"), b.set_ylabel("density f(t, v)"), b.set_title("zoom at the maximum")
        b.legend(fontsize=7)
    else:
        from matplotlib.lines import Line2D

        fig, a = _new_axes(ax)
        X, V = np.meshgrid(run.xgrid.points, run.vgrid.points, indexing="ij")
        pc = a.pcolormesh(X, V, run.f, shading="auto")
        fig.colorbar(pc, ax=a, label=f"density f(t = {run.t:.4g}, x, v)")
        a.contour(xg0.points, vg0.points, f0.T, levels=4, colors="w", linewidths=0.7, linestyles="--")
        a.legend(handles=[Line2D([], [], color="w", ls="--", lw=0.7, label=f"{start}: contours")], fontsize=7,
                 facecolor="0.3", labelcolor="w")  # fmt: skip
        a.set_xlabel("x"), a.set_ylabel("v"), a.set_title(f"f(t = {run.t:.4g}, x, v)")
    if ax is None:  # axes passed in belong to a figure whose layout is the caller's
        fig.tight_layout()
    return fig


def plot_records(run: Run, ax=None):
    """The blow-up records against t with thresholds, refinement switches, T_b and the exact law; returns the figure.

    A figure created here is laid out (``tight_layout``); one whose axes are passed in keeps the
    caller's layout.  The log axis is labelled 10⁻⁴, 2×10⁻¹, ... in Unicode: matplotlib's labels
    without its mathtext, whose parser's first use costs about a fifth of drawing the run's figures.
    """
    fig, a = _new_axes(ax)
    sc = run.scene
    t = run.column("t")
    series = [("min dv", "min_dv", sc.stop.eps_v, "eps_v", "v"), ("max f", "max_f", 0.0, "", "")]
    if run.xgrid is not None:
        series.insert(1, ("min dx", "min_dx", sc.stop.eps_x, "eps_x", "x"))
    if sc.stop.spread_v > 0:
        series.append(("min spread_v", "min_spread_v", sc.stop.spread_v, "spread_v", ""))
    for label, col, eps, eps_label, axis in series:
        values = run.column(col)
        (line,) = a.semilogy(t, values, label=label)
        if eps > 0:
            a.axhline(eps, ls=":", color=line.get_color(), label=f"{eps_label} = {eps:.3g}")
        if axis:
            steps = refinement_switches(run, axis)
            rows = np.isin(run.column("step"), steps)
            if rows.any():
                a.plot(t[rows], values[rows], "|", ms=8, color=line.get_color(), label=f"{axis}-grid remeshed")
    exact = exact_max_f(run)
    if exact is not None:
        te, law, T = exact
        a.semilogy(te, law, "k--", lw=1, label="exact max f = m0 / (1 - 2 s m0 t), m0 = max f0, s = strength")
        a.axvline(T, color="k", ls="--", lw=0.8, label=f"exact T = {T:.4g}")
    if run.blowup:
        a.axvline(run.verdict.T_b, color="r", lw=0.8, label=f"T_b = {run.verdict.T_b:.4g}")
    _draw_fit(run, a)
    v = run.verdict
    if v.uncertified_steps:  # drawn from uncertified states: say so, claim no verdict
        title = f"NOT CERTIFIED: {v.uncertified_steps} uncertified step(s) from t = {v.first_uncertified_t:.4g}"
        a.axvline(v.first_uncertified_t, color="m", lw=0.8, ls=":", label="first uncertified step")
    elif v.stop is StopReason.NO_STEP:
        title = "NOT CERTIFIED: no step was accepted"
    elif not v.certified:  # the paper's exit-flag rule: a failed solve, not a measured concentration
        title = f"NOT CERTIFIED: e_f (failed collision solve) at T_b = {v.T_b:.4g}"
    elif v.blowup:
        title = f"blow-up at T_b = {v.T_b:.4g}"
    else:  # no rule fired up to the end of the run: no statement about later times
        title = f"no blow-up rule fired by t = {run.t:.4g}"
    spacing = "min dv, min dx" if run.xgrid is not None else "min dv"
    spread = "\nmin spread_v: smallest velocity spread" if sc.stop.spread_v > 0 else ""
    quantities = f"{spacing}: smallest grid spacing\nmax f: largest density{spread} (log scale)"
    a.set_xlabel("time t"), a.set_ylabel(quantities, fontsize=8), a.legend(fontsize=7)
    a.set_title(f"{sc.name}: {title}\n{_fit_line(v)}", fontsize=9)
    _use_plain_log_labels(a.yaxis)  # after the last semilogy, which resets the formatters
    if ax is None:
        fig.tight_layout()
    return fig


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")
_MATHTEXT_LABEL = re.compile(
    r"\$\\mathdefault\{(?P<head>[-+0-9.e]*(?:\\times)?[-+0-9.e]*)(?:\^\{(?P<exp>-?[0-9]+)\})?\}\$"
)
"""The labels matplotlib's log formatters write: ``$\\mathdefault{10^{-4}}$``, ``$\\mathdefault{2\\times10^{-1}}$``,
``$\\mathdefault{0.5}$``."""


def _plain_label(label: str) -> str:
    """A log-axis tick label of :class:`matplotlib.ticker.LogFormatterSciNotation` in Unicode (10⁻⁴, 2×10⁻¹);
    any other label unchanged."""
    m = _MATHTEXT_LABEL.fullmatch(label)
    if m is None:
        return label
    return m["head"].replace("\\times", "×") + (m["exp"] or "").translate(_SUPERSCRIPT)


@functools.cache
def _plain_log_formatter():
    from matplotlib.ticker import LogFormatterSciNotation

    class PlainLogFormatter(LogFormatterSciNotation):
        """matplotlib's scientific-notation log labels as plain text: the same labels, no mathtext to lay out."""

        def __call__(self, x, pos=None):
            return _plain_label(super().__call__(x, pos))

    return PlainLogFormatter


def _use_plain_log_labels(axis):
    """Give a log ``axis`` the Unicode form of its default tick labels (major, minor); returns the two formatters.

    The labels read as matplotlib's (10⁻⁴ for its mathtext 10^{-4}); drawing them needs no mathtext parser,
    whose first use costs about a fifth of drawing the run's figures.
    """
    cls = _plain_log_formatter()
    made = []
    for old, setter in ((axis.get_major_formatter(), axis.set_major_formatter),
                        (axis.get_minor_formatter(), axis.set_minor_formatter)):  # fmt: skip
        new = cls(old._base, labelOnlyBase=old.labelOnlyBase, minor_thresholds=old.minor_thresholds,
                  linthresh=old._linthresh)  # fmt: skip
        setter(new)
        made.append(new)
    return tuple(made)


def _fit_line(v) -> str:
    """The verdict's blow-up kind for the title: the fitted time with its bar where the fit locates one."""
    kind = v.blowup_kind or "not fitted"
    if v.T_b_fit is not None and v.T_b_fit_err is not None:
        return f"max f(t) fit: {kind}, T_b_fit = {v.T_b_fit:.4g} +- {v.T_b_fit_err:.2g}"
    return f"max f(t) fit: {kind}"


def _records(run: Run) -> list[dict[str, float]]:
    """The diagnostics rows ``fit_rows`` reads (t, max f, failed), from the run's columns."""
    cols = zip(run.column("t"), run.column("max_f"), run.column("failed"), strict=True)
    return [{"t": t, "max_f": m, "failed": f} for t, m, f in cols]


def _draw_fit(run: Run, a) -> None:
    """The power law fitted to max f on its window, and T_b_fit with its error bar (finite_time runs)."""
    v = run.verdict
    if v.blowup_kind != "finite_time":
        return
    fit = fit_rows(_records(run), v)  # the fit the verdict holds, with its window
    t = run.column("t")
    start, stop = fit.window
    tw = np.linspace(t[start], t[stop - 1] + 0.9 * (fit.T_b_fit - t[stop - 1]), 200)
    a.semilogy(tw, fit.curve(tw), color="tab:green", ls="-.", lw=1,
               label=f"fit C (T - t)^-a, a = {fit.blowup_rate:.3g}")  # fmt: skip
    y = float(np.nanmax(run.column("max_f")))
    # the verdict's bar: it may hold more than the fit's own (a first-order step's lag)
    a.errorbar([v.T_b_fit], [y], xerr=[v.T_b_fit_err], fmt="o", ms=3, color="tab:green", capsize=3,
               label=f"T_b_fit = {v.T_b_fit:.4g} +- {v.T_b_fit_err:.2g}")  # fmt: skip


# Figure fractions for the sizes save_figures uses (10 x 4, 6 x 4 and 9 x 4 inches); room for the
# tick labels of a log axis, the axis labels and the records' two-line title.
_MARGINS = {"left": 0.11, "right": 0.97, "bottom": 0.12, "top": 0.91}
_MARGINS_PAIR = {"left": 0.07, "right": 0.985, "bottom": 0.12, "top": 0.91, "wspace": 0.22}
_MARGINS_RECORDS = {"left": 0.105, "right": 0.595, "bottom": 0.12, "top": 0.87}  # the legend right of the axes


def save_figures(run: Run, out: str | Path, dpi: int = 110) -> list[Path]:
    """Write ``solution.png`` and ``records.png`` into ``out``; returns their paths.

    The figures are drawn without pyplot (no backend is chosen or changed), with fixed margins
    that fit their labels: measuring the text to lay them out (``tight_layout``) would draw each
    figure twice, half of their cost.  The records' log-axis labels are plain Unicode (10⁻⁴), as
    in :func:`plot_records`.
    """
    paths = [Path(out) / "solution.png", Path(out) / "records.png"]
    for fig, path in zip(_run_figures(run), paths, strict=True):
        # a figure interrupted mid-write must not be left as a truncated PNG
        atomic_write(path, lambda tmp, fig=fig: fig.savefig(tmp, dpi=dpi, format="png"))
    return paths


def _run_figures(run: Run):
    """The solution and records figures of ``save_figures``, laid out with the fixed margins."""
    from matplotlib.figure import Figure

    two = run.xgrid is None  # the homogeneous solution figure has two panels
    sol = Figure(figsize=(10, 4) if two else (6, 4))
    rec = Figure(figsize=(9, 4))
    plot_solution(run, ax=sol.subplots(1, 2) if two else sol.subplots())
    a = rec.subplots()
    plot_records(run, ax=a)
    # beside the axes, not over the records (up to ten entries: inside, it hid a curve wherever it went)
    a.legend(*a.get_legend_handles_labels(), fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0),
             borderaxespad=0.0)  # fmt: skip
    sol.subplots_adjust(**(_MARGINS_PAIR if two else _MARGINS))
    rec.subplots_adjust(**_MARGINS_RECORDS)
    return sol, rec
