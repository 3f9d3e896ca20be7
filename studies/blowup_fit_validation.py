"""Validation of the blow-up-time estimator (:func:`jko_cvx.blowup.fit_blowup`) on homogeneous runs.

* gamma = 1 (exact T = 1/(2 max f0), Burgers in the cumulative distribution) on several data of
  our own, across dt, eps_v and N_v: the error T_b_fit - T, the error bar, whether the bar
  covers the error, and the paper's threshold time T_b beside it;
* the kind against the Osgood criterion for W = |v|^gamma / gamma (finite-time collapse
  exactly when gamma < 2; gamma = 2 the exact linear contraction).

Writes ``studies/results/blowup_fit_validation.csv`` and ``.md`` (date, commit, BLAS threads)::

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python studies/blowup_fit_validation.py [--quick]
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import time
from pathlib import Path

import pandas as pd

from jko_cvx.blowup import fit_blowup
from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.exact import GaussianMixture, blowup_time_gamma1
from jko_cvx.scene import shipped_scene

DATA = {  # amplitudes, rates, centres
    "g1": ([1.0], [2.0], [0.0]),
    "A2r4": ([2.0], [4.0], [0.0]),
    "A0.8r1": ([0.8], [1.0], [0.0]),
    "A1.5r3": ([1.5], [3.0], [0.0]),
    "g1_at_0.3": ([1.0], [2.0], [0.3]),  # off-centre: the map follows the concentration
    "two_asym": ([1.0, 0.6], [4.0, 4.0], [0.3, -0.5]),  # asymmetric two bumps, a one-bump following map
}
OSGOOD = (1.1, 1.25, 1.5, 1.75, 1.9, 2.0, 2.25, 2.5, 3.0)
RESULTS = Path(__file__).resolve().parent / "results"


def _fit(overrides: dict) -> tuple[object, object]:
    run = simulate(shipped_scene("tab_bu_g1", overrides))
    d = run.diagnostics
    return run, fit_blowup(d.t.to_numpy(), d.max_f.to_numpy(), certified=(d.failed == 0).to_numpy())


def gamma1_rows(quick: bool) -> list[dict]:
    rows = []
    grid = [(121, 0.01), (121, 0.005), (121, 0.0025), (241, 0.005), (481, 0.005), (481, 0.0025)]
    for name, (A, r, c) in DATA.items():
        for n, dt in grid[:2] if quick else grid:
            for eps in (2.5e-4, 1e-4):
                T = blowup_time_gamma1(GaussianMixture(A, r, c, -2.0, 2.0))  # v.L = 2
                t0 = time.perf_counter()
                run, fit = _fit({"initial.amplitudes": A, "initial.rates": r, "initial.centres": c, "v.n": n,
                                 "time.dt": dt, "stop.eps_v": eps, "t_end": 2 * T})  # fmt: skip
                err = None if fit.T_b_fit is None else fit.T_b_fit - T
                rows.append({
                    "datum": name, "N_v": n, "dt": dt, "eps_v": eps, "T_exact": T, "T_b": run.verdict.T_b,
                    "T_b_fit": fit.T_b_fit, "T_b_fit_err": fit.T_b_fit_err, "error": err,
                    "covered": None if err is None else abs(err) <= fit.T_b_fit_err,
                    "rate": fit.blowup_rate, "kind": fit.blowup_kind, "seconds": time.perf_counter() - t0,
                })  # fmt: skip
    return rows


def osgood_rows(quick: bool) -> list[dict]:
    rows = []
    for gamma in OSGOOD[::2] if quick else OSGOOD:
        for dt in (0.02,) if quick else (0.02, 0.01):
            run, fit = _fit({"gamma": gamma, "time.dt": dt, "t_end": 2.0})
            expected = "finite_time" if gamma < 2 else "no_finite_time"
            rows.append({"gamma": gamma, "dt": dt, "expected": expected, "kind": fit.blowup_kind,
                         "right": fit.blowup_kind == expected, "T_b": run.verdict.T_b, "T_b_fit": fit.T_b_fit,
                         "T_b_fit_err": fit.T_b_fit_err, "rate": fit.blowup_rate, "reason": fit.reason})  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a few runs (the test)")
    ap.add_argument("--out", type=Path, default=RESULTS)
    a = ap.parse_args(argv)
    g1, osg = pd.DataFrame(gamma1_rows(a.quick)), pd.DataFrame(osgood_rows(a.quick))
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                                cwd=Path(__file__).parent, check=False).stdout.strip() or "unknown"  # fmt: skip
    except OSError:
        commit = "unknown"
    head = (f"date {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC, commit {commit}, "
            f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}, "
            f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}")  # fmt: skip
    a.out.mkdir(parents=True, exist_ok=True)
    stem = "blowup_fit_validation" + ("_quick" if a.quick else "")
    g1.assign(provenance=head).to_csv(a.out / f"{stem}.csv", index=False)
    record_csv(a.out / f"{stem}.csv")
    osg.assign(provenance=head).to_csv(a.out / f"{stem}_osgood.csv", index=False)
    record_csv(a.out / f"{stem}_osgood.csv")
    fitted = g1.dropna(subset=["error"])
    abs_err = fitted.error.abs()
    lines = [
        "# Blow-up-time estimator against exact times (homogeneous gamma = 1) and the Osgood criterion", "", head, "",
        f"gamma = 1: {len(g1)} runs, {int((g1.kind == 'finite_time').sum())} classified finite_time; "
        f"|T_b_fit - T|: median {abs_err.median():.2g}, max {abs_err.max():.2g}, "
        f"{int((abs_err < 1e-3).sum())} within 1e-3; error bar covers the error in "
        f"{int(fitted.covered.sum())} / {len(fitted)}; paper's threshold |T_b - T| median "
        f"{(g1.T_b - g1.T_exact).abs().median():.2g}.", "",
        "Per datum (coverage: the error bar covers the true error):", "",
        fitted.assign(abs_err=abs_err).groupby("datum", sort=False).agg(
            runs=("error", "size"), median_abs_err=("abs_err", "median"), max_abs_err=("abs_err", "max"),
            coverage=("covered", "mean"), median_err_bar=("T_b_fit_err", "median"),
        ).to_markdown(floatfmt=".3g"), "",
        g1.drop(columns=["seconds"]).to_markdown(index=False, floatfmt=".5g"), "",
        f"Osgood: {int(osg.right.sum())} / {len(osg)} kinds right.", "",
        osg.drop(columns=["reason"]).to_markdown(index=False, floatfmt=".5g"), "",
    ]  # fmt: skip
    write_markdown(a.out / f"{stem}.md", "\n".join(lines))
    print("\n".join(lines[:6]) + "\n" + lines[-3])


if __name__ == "__main__":
    main()
