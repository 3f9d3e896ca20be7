"""The first-order step's lag in the fitted blow-up time, gamma != 1 (the calibration of ``FIRST_ORDER_LAG``).

Homogeneous gamma = 1 moves mass along straight characteristics, so an implicit (first-order) step adds no lag
at a concentration that stays put, and the error bar of :func:`jko_cvx.blowup.fit_blowup` was calibrated there
(``DT_SCALE``).  For other gamma the characteristics curve and the first-order fitted time ``T_b_fit`` lags by
O(dt).  Each gamma runs ``tab_bu_g1``'s datum (121 points, eps_v as shipped) at first order with dt = 0.01 and
0.005 and at second order with dt = 0.005 (the reference: its own lag is O(dt^2)); the table gives each
first-order lag, in units of dt and of |gamma - 1| dt, the verdict's error bar (widened by
``FIRST_ORDER_LAG |gamma - 1| dt``) and whether it covers the lag.  A held-out datum (off-centre, 161 points)
checks the constant on data it was not read from.  About two minutes on one core::

    OPENBLAS_NUM_THREADS=1 python studies/first_order_lag.py

writes ``studies/results/first_order_lag.{csv,md}`` (environment recorded).
"""

from __future__ import annotations

import time
from pathlib import Path

import pandas as pd

from jko_cvx.blowup import FIRST_ORDER_LAG
from jko_cvx.engine.loop import simulate
from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.scene import shipped_scene
from jko_cvx.threads import thread_environment

RESULTS = Path(__file__).resolve().parent / "results"
GAMMAS = (0.75, 1.25, 1.5, 1.75)
DATA = {"tab_bu_g1": {}, "held-out: centre 0.5, 161 points": {"initial.centres": [0.5], "v.n": 161}}


def _fit(gamma: float, order: int, dt: float, data: dict) -> tuple[float | None, float | None]:
    run = simulate(shipped_scene("tab_bu_g1", {"gamma": gamma, "time.order": order, "time.dt": dt, "t_end": 6.0,
                                               **data}))  # fmt: skip
    return run.verdict.T_b_fit, run.verdict.T_b_fit_err


def main() -> int:
    rows = []
    for label, data in DATA.items():
        for gamma in GAMMAS if not data else (0.75, 1.5):
            t0 = time.perf_counter()
            ref, ref_err = _fit(gamma, 2, 0.005, data)
            for dt in (0.01, 0.005):
                T, err = _fit(gamma, 1, dt, data)
                lag = None if T is None or ref is None else T - ref
                rows.append({
                    "data": label, "gamma": gamma, "dt": dt, "T_b_fit order 1": T, "bar order 1": err,
                    "T_b_fit order 2 (dt 0.005)": ref, "bar order 2": ref_err, "lag": lag,
                    "lag / dt": None if lag is None else lag / dt,
                    "lag / (|gamma - 1| dt)": None if lag is None else lag / (abs(gamma - 1) * dt),
                    "bar covers lag": None if lag is None or err is None else abs(lag) <= err,
                })  # fmt: skip
            print(f"{label} gamma {gamma}: {time.perf_counter() - t0:.0f} s", flush=True)
    df = pd.DataFrame(rows)
    print(df.to_string(index=False))
    out = RESULTS / "first_order_lag.csv"
    df.to_csv(out, index=False)
    record_csv(out)
    calib = df[df.data == "tab_bu_g1"]["lag / (|gamma - 1| dt)"].abs().max()
    covered = df["bar covers lag"].dropna()
    write_markdown(
        RESULTS / "first_order_lag.md",
        "# The first-order step's lag in T_b_fit (gamma != 1)\n\n"
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; threads: {thread_environment()}.  First-order "
        "T_b_fit against second order at dt = 0.005 (the reference).  Largest |lag| / (|gamma - 1| dt) on "
        f"tab_bu_g1's datum: {calib:.3g}; FIRST_ORDER_LAG = {FIRST_ORDER_LAG:g}, so the bar's lag term is "
        f"ERR_SCALE x {FIRST_ORDER_LAG:g} |gamma - 1| dt.  Bars covering the lag: {int(covered.sum())} of "
        f"{len(covered)} (the held-out rows included).\n\n" + df.to_markdown(index=False, floatfmt=".4g") + "\n",
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
