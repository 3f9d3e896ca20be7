"""The tables of the gamma = 3 time-step probe (``studies/g3_dt_probe.py``): its rows read, the two orders at one
dt, and the controls.

A probe row is one run of a shipped ``inhom_gamma3_lambda*`` scene on n x n with step dt and time order 1 or 2,
as shipped or with a ``variant`` (overrides such as a weaker Fisher term); rows written before the order or the
variant were recorded are first-order runs as shipped.  The conclusions table and the probe's own report both
read the rows through these functions.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["CONTROL_COLUMNS", "control_ratios", "order_pairs", "probe_rows"]

CONTROL_COLUMNS = ("lambda", "n", "dt", "time_order", "variant", "peak", "peak as shipped", "ratio")


def probe_rows(df: pd.DataFrame) -> pd.DataFrame:
    """The probe's rows with ``time_order`` (1 where not recorded) and ``variant`` ("" where not recorded)."""
    df = df.copy()
    if "time_order" not in df:
        df["time_order"] = 1
    df["variant"] = df["variant"].fillna("").astype(str) if "variant" in df else ""
    return df


def order_pairs(df: pd.DataFrame) -> pd.DataFrame:
    """Per lambda, grid and dt with runs of both orders as shipped: the two peaks of max f, their ratio, and the
    first-order dt whose peak is closest (in log) to the second-order one's."""
    df = probe_rows(df)
    df = df[df.variant == ""]
    out = []
    for (lam, n), g in df.groupby(["lambda", "n"]):
        first, second = g[g.time_order == 1], g[g.time_order == 2]
        for _, r2 in second.sort_values("dt", ascending=False).iterrows():
            r1 = first[first["dt"] == r2["dt"]]
            if r1.empty:
                continue
            closest = first.iloc[int(np.abs(np.log(first.max_f_peak.to_numpy() / r2["max_f_peak"])).argmin())]
            out.append({
                "lambda": lam, "n": n, "dt": float(r2["dt"]), "peak_order1": float(r1.max_f_peak.iloc[0]),
                "peak_order2": float(r2["max_f_peak"]),
                "order2_over_order1": float(r2["max_f_peak"] / r1.max_f_peak.iloc[0]),
                "t_peak_order1": float(r1.t_peak.iloc[0]), "t_peak_order2": float(r2["t_peak"]),
                "order1_dt_matching": float(closest["dt"]), "peak_there": float(closest["max_f_peak"]),
            })  # fmt: skip
    return pd.DataFrame(out)


def control_ratios(df: pd.DataFrame) -> pd.DataFrame:
    """Each variant row beside the run as shipped at its lambda, grid, dt and order: both peaks of max f and
    their ratio (NaN where the probe has no such run)."""
    df = probe_rows(df)
    shipped = df[df.variant == ""]
    rows = []
    for _, r in df[df.variant != ""].iterrows():
        same = shipped[(shipped["lambda"] == r["lambda"]) & (shipped["n"] == r["n"]) & (shipped["dt"] == r["dt"])
                       & (shipped["time_order"] == r["time_order"])]  # fmt: skip
        base = float(same.max_f_peak.iloc[0]) if len(same) else float("nan")
        rows.append({"lambda": r["lambda"], "n": r["n"], "dt": r["dt"], "time_order": r["time_order"],
                     "variant": r["variant"], "peak": float(r["max_f_peak"]), "peak as shipped": base,
                     "ratio": float(r["max_f_peak"]) / base})  # fmt: skip
    return pd.DataFrame(rows, columns=list(CONTROL_COLUMNS))
