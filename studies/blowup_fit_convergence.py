"""Convergence of the blow-up-time estimator in the grid and the time step (homogeneous gamma = 1).

For homogeneous gamma = 1 every datum's max f follows the exact law max f(t) = 1 / (2 (T - t)),
T = 1 / (2 max f0), up to T (the density along each characteristic is f0 / (1 - 2 f0 t), largest
where f0 is), so each record k of a run carries its own *solution time*

.. math:: \\tau_k = t_k + \\frac{1}{2 \\max f_k},

the blow-up time of the exact law through that record (``T`` itself for the exact solution).  Its
error at the fit window's last record before T, ``tau_error``, is how late the numerical solution
itself is: no estimator drawn from the records can be more accurate than the records, so
``tau_error`` beside the estimator's error ``error = T_b_fit - T`` separates the two.

The runs: ``tab_bu_g1`` with four data (centred, narrow, off-centre and a held-out wide one), the
C^1 junction of the one-bump map (``refine.v.junction = "c1"``), second-order steps
(``time.order = 2``), eps_v = 1e-4, on N_v = 121 to 961 and dt = 0.01 to 0.00125, with the paper's remap
and the cumulative one (``refine.v.remap``): 128 runs, about 12 minutes on one core.  Writes
``studies/results/blowup_fit_convergence.{csv,md,png}`` (environment recorded)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python studies/blowup_fit_convergence.py [--quick] [--out DIR]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx.blowup import fit_blowup
from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.exact import GaussianMixture, blowup_time_gamma1
from jko_cvx.scene import shipped_scene
from jko_cvx.threads import thread_environment

DATA = {  # amplitudes, rates, centres
    "g1": ([1.0], [2.0], [0.0]),
    "A1.5r3": ([1.5], [3.0], [0.0]),
    "g1_at_0.3": ([1.0], [2.0], [0.3]),
    "A0.6r0.8c-0.2": ([0.6], [0.8], [-0.2]),
}
N_V = (121, 241, 481, 961)
DT = (0.01, 0.005, 0.0025, 0.00125)
REMAPS = ("paper", "cumulative")  # refine.v.remap
TARGET = 1e-3  # the accuracy asked of T_b_fit
RESULTS = Path(__file__).resolve().parent / "results"


def run_row(name: str, n: int, dt: float, remap: str) -> dict:
    """One run of ``tab_bu_g1`` with datum ``name`` on ``n`` points with step ``dt`` and the given remap, fitted."""
    A, r, c = DATA[name]
    T = blowup_time_gamma1(GaussianMixture(A, r, c, -2.0, 2.0))  # v.L = 2
    t0 = time.perf_counter()
    run = simulate(shipped_scene("tab_bu_g1", {
        "initial.amplitudes": A, "initial.rates": r, "initial.centres": c, "v.n": n, "time.dt": dt,
        "stop.eps_v": 1e-4, "t_end": 2 * T, "time.order": 2, "refine.v.junction": "c1",
        "refine.v.remap": remap}))  # fmt: skip
    d = run.diagnostics
    t, m = d.t.to_numpy(), d.max_f.to_numpy()
    fit = fit_blowup(t, m, certified=(d.failed == 0).to_numpy())
    T_fit, T_err, rate = fit.estimate()  # as the verdict reports them
    tau_error = None
    if fit.window is not None:
        before = np.flatnonzero(t[: fit.window[1]] < T)
        if before.size:
            k = before[-1]
            tau_error = float(t[k] + 0.5 / m[k] - T)
    err = None if T_fit is None else T_fit - T
    return {
        "remap": remap, "datum": name, "N_v": n, "dt": dt, "T_exact": T, "T_b": run.verdict.T_b,
        "kind": fit.blowup_kind,
        "T_b_fit": T_fit, "T_b_fit_err": T_err, "rate": rate, "error": err,
        "covered": None if err is None else bool(abs(err) <= T_err), "tau_error": tau_error,
        "seconds": time.perf_counter() - t0,
    }  # fmt: skip


def _orders(table: pd.DataFrame, axis: str) -> str:
    """Observed orders of the median |error| between successive refinements along ``axis`` (N_v or dt)."""
    out = []
    if axis == "N_v":
        col = table.columns.min()  # the smallest dt
        s = table[col]
        for a, b in zip(s.index[:-1], s.index[1:], strict=True):
            out.append(f"{a} -> {b}: {np.log(s[a] / s[b]) / np.log(b / a):.2f}")
        return f"in N_v at dt = {col:g}: " + ", ".join(out)
    row = table.index.max()  # the finest grid
    s = table.loc[row].sort_index(ascending=False)
    for a, b in zip(s.index[:-1], s.index[1:], strict=True):
        out.append(f"{a:g} -> {b:g}: {np.log(s[a] / s[b]) / np.log(a / b):.2f}")
    return f"in dt at N_v = {row}: " + ", ".join(out)


def _remap_section(df: pd.DataFrame, remap: str) -> list[str]:
    """The tables of one remap: |error| median and largest, runs within the target, coverage, |tau_error|."""
    d = df[df.remap == remap]
    fitted = d.dropna(subset=["error"])

    def pivot(frame: pd.DataFrame, values: str, agg) -> pd.DataFrame:
        return frame.pivot_table(index="N_v", columns="dt", values=values, aggfunc=agg)

    def md(t: pd.DataFrame, fmt: str = ".2g") -> str:
        return t.rename(columns=lambda c: f"dt = {c:g}").to_markdown(floatfmt=fmt)

    piv, mx = pivot(fitted, "abs_err", "median"), pivot(fitted, "abs_err", "max")
    within = pivot(fitted, "abs_err", lambda e: f"{int((e < TARGET).sum())}/{len(e)}")
    cover = pivot(fitted, "covered", lambda e: f"{int(e.sum())}/{len(e)}")
    signed = pivot(fitted, "error", "median")
    tau = pivot(d.dropna(subset=["tau_error"]), "abs_tau", "max")
    ok = mx < TARGET
    cells = [f"N_v = {n}, dt = {dt:g}" for n in ok.index for dt in ok.columns if ok.loc[n, dt]]
    kinds = ", ".join(f"{k} {v}" for k, v in d.kind.value_counts().items())
    return [
        f"## `refine.v.remap = \"{remap}\"`", "",
        f"{len(fitted)} of {len(d)} runs located a finite-time blow-up (kinds: {kinds}); the error bar covers the "
        f"exact time in {int(fitted.covered.sum())} of {len(fitted)}; {int((fitted.abs_err < TARGET).sum())} of "
        f"{len(fitted)} are within {TARGET:g}.", "",
        "Median |T_b_fit - T| over the data:", "", md(piv), "",
        f"Observed orders {_orders(piv, 'N_v')}; {_orders(piv, 'dt')}.", "",
        "Median signed T_b_fit - T (negative: early):", "", md(signed, ".2e"), "",
        "Largest |T_b_fit - T| over the data:", "", md(mx), "",
        f"Cells where every datum is within {TARGET:g}: " + ("; ".join(cells) if cells else "none") + ".", "",
        f"Runs within {TARGET:g}:", "", within.rename(columns=lambda c: f"dt = {c:g}").to_markdown(), "",
        "Runs whose error bar covers the exact time:", "",
        cover.rename(columns=lambda c: f"dt = {c:g}").to_markdown(), "",
        "Largest |tau_error| (how far the records themselves are from the exact law at the window's end):", "",
        md(tau), "",
    ]  # fmt: skip


def report(df: pd.DataFrame) -> str:
    df = df.assign(abs_err=df.error.abs(), abs_tau=df.tau_error.abs())
    per = df.dropna(subset=["error"]).groupby(["datum", "remap"]).error.agg(["median", "min", "max"]).unstack("remap")
    lines = [
        "# The blow-up-time estimator in the grid and the time step (homogeneous gamma = 1)", "",
        f"Threads: {thread_environment()}.", "",
        f"`tab_bu_g1` with {df.datum.nunique()} data ({', '.join(df.datum.unique())}; amplitudes, rates and "
        "centres in the script), the C^1 junction of the one-bump map, second-order steps, eps_v = 1e-4, remeshing "
        "every step (the paper's tol = 0) with each remap; per cell of N_v and dt one run per datum.  `error` = "
        "T_b_fit - T against the exact T = 1 / (2 max f0); `tau_error` = the records' own blow-up time "
        "t + 1 / (2 max f) at the fit window's last record before T, minus T: how far the numerical solution itself "
        "is from the exact law there (the law holds for every datum until T, so an exact record gives 0).  The "
        "estimator extrapolates the records, so it cannot be more accurate than they are.", "",
        "Signed T_b_fit - T per datum over all grids and steps (median, min, max) for each remap.  The paper's "
        "remap rescales each line to its mass after interpolating, so each remap's interpolation error is spread "
        "over the line, the peak included; where the datum is cut by the walls (here A0.6r0.8c-0.2, 0.045 at "
        "v = -2, where a data set includes it) the vacuum that opens there is a steep front, its error lifts the "
        "peak at every remap, the records run ahead of the exact law and the blow-up comes early by an amount that "
        "refining the grid and the step does not remove.", "",
        per.to_markdown(floatfmt=".2e"), "",
    ]  # fmt: skip
    for remap in df.remap.unique():
        lines += _remap_section(df, remap)
    return "\n".join(lines)


def figure(df: pd.DataFrame, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fitted = df.dropna(subset=["error"]).assign(abs_err=lambda d: d.error.abs(), abs_tau=lambda d: d.tau_error.abs())
    remaps = list(fitted.remap.unique())
    fig, axes = plt.subplots(len(remaps), 2, figsize=(10, 3.6 * len(remaps)), constrained_layout=True,
                             squeeze=False, sharey=True)  # fmt: skip
    for row, remap in zip(axes, remaps, strict=True):
        d = fitted[fitted.remap == remap]
        for dt, g in d.groupby("dt"):
            med = g.groupby("N_v")[["abs_err", "abs_tau"]].median()
            (line,) = row[0].loglog(med.index, med.abs_err, "o-", label=f"dt = {dt:g}")
            row[0].loglog(med.index, med.abs_tau, "x--", color=line.get_color())
        for n, g in d.groupby("N_v"):
            med = g.groupby("dt")[["abs_err"]].median()
            row[1].loglog(med.index, med.abs_err, "o-", label=f"N_v = {n}")
        row[0].set_xlabel("N_v (points in v)")
        row[0].set_title(f"remap = {remap}: against the grid (x, dashed: |tau_error|)")
        row[1].set_xlabel("dt")
        row[1].set_title(f"remap = {remap}: against the time step")
        for ax in row:
            ax.axhline(TARGET, color="k", lw=0.8, ls=":")
            ax.set_ylabel("median |T_b_fit - T| over the data")
            ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two grids, two steps, two data (the test)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    a = ap.parse_args(argv)
    data, grids, steps = (list(DATA)[:2], N_V[:2], DT[:2]) if a.quick else (list(DATA), N_V, DT)
    rows = []
    for remap in REMAPS:
        for name in data:
            for n in grids:
                for dt in steps:
                    rows.append(run_row(name, n, dt, remap))
                    r = rows[-1]
                    print(f"{remap} {name} N_v {n} dt {dt:g}: error {r['error']}, tau_error {r['tau_error']} "
                          f"({r['seconds']:.1f} s)", flush=True)  # fmt: skip
    df = pd.DataFrame(rows)
    a.out.mkdir(parents=True, exist_ok=True)
    stem = "blowup_fit_convergence" + ("_quick" if a.quick else "")
    df.to_csv(a.out / f"{stem}.csv", index=False)
    figure(df, a.out / f"{stem}.png")
    record_csv(a.out / f"{stem}.csv", a.out / f"{stem}.png")
    write_markdown(a.out / f"{stem}.md", report(df))


if __name__ == "__main__":
    main()
