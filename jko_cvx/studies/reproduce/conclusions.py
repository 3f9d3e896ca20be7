"""``jko-cvx reproduce conclusions``: the paper's conclusions, one row each, against the result files.

One row per conclusion of the paper's numerical (``sec:numerical_examples``) and heuristic
(``sec: explicit``, ``sec:sp_inhom_gamma_2``) sections: what the paper claims, what our
result files say (numbers read from them here, never typed), the file(s) that say it and a
verdict: ``supported`` (our evidence agrees and could have disagreed: an exact solution, an
analytic law, or a count a wrong answer would fail), ``contradicted`` (our evidence
disagrees, under the settings stated in the reproductions' choices table), ``not settled``
(our evidence does not discriminate: no control, no convergence study in the axis that
decides, a count the run-free answer matches, or an event whose nature is in doubt), each
with its reason.

The entry reads the other entries' files in the output directory (``tab_bu.csv``,
``discrimination.csv``, ``inhom_gamma3.csv``, ...: :data:`EVIDENCE`; also ``paper_variants.csv``
of the paper-variants study script and the ``grid_convergence`` files, so it is not part of
``jko-cvx reproduce section``); a missing file, read or named as evidence, is a
``FileNotFoundError`` naming it.  Writes ``conclusions.{csv,md}``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.environment import record_csv, write_markdown
from jko_cvx.studies.reproduce.dt_probe import control_ratios, order_pairs, probe_rows

__all__ = ["CONCLUSIONS", "EVIDENCE", "VERDICTS", "conclusions", "reproduce_conclusions"]

VERDICTS = ("supported", "contradicted", "not settled")


def _read(root: Path, name: str) -> pd.DataFrame:
    return pd.read_csv(root / name)


def _disc(root: Path, table: str) -> pd.Series:
    """The table's overall row of ``discrimination.csv`` (its last: "all", or its one data set)."""
    d = _read(root, "discrimination.csv")
    return d[d.table == table].iloc[-1]


def _tab_bu(root: Path) -> dict[str, Any]:
    a = _disc(root, "tab_bu")
    n_fit = int(a["fit finite_time entries"])
    # the fit vouches for its finite_time entries only: it settles the claim where they are most of the table
    fit_ok = 2 * n_fit >= a.entries and a["median |fit - analytic T|"] < 0.01
    why_not = (
        f"the fit classifies only {n_fit} of {a.entries} entries finite_time" if 2 * n_fit < a.entries
        else "the fit's median error against the exact time is 0.01 or more"
    )  # fmt: skip
    return {
        "claim": "tab:bu: the scheme reproduces the blow-up and captures the analytic time (gamma = 1, one bump)",
        "paper": "T_b within about 0.03 of T = 0.5, 0.25, 0.125; closer as eps_v and dt decrease",
        "ours": (
            f"|T_b - T| median {a['median |ours - analytic T|']:.3g}, max {a['max |ours - analytic T|']:.3g} "
            f"(the paper's: median {a['median |paper - analytic T|']:.3g}); the blow-up fit T_b_fit median "
            f"{a['median |fit - analytic T|']:.2g} over its {a['fit finite_time entries']} finite_time entries; "
            f"{a['ours within tol of paper']} of {a.entries} within 0.03 of "
            f"the paper, where the run-free answer (T for every entry) scores "
            f"{a['trivial (analytic T) within tol of paper']}"
        ),
        "evidence": "discrimination.csv; tab_bu.csv",
        "verdict": "supported" if fit_ok else "not settled",
        "why": (
            "errors against the exact time discriminate (the agreement count does not: the run-free answer "
            "scores higher)" if fit_ok else why_not
        ),
    }


def _eps_v(root: Path) -> dict[str, Any]:
    b = _read(root, "tab_bu_beta_scan_summary.csv")
    target = next(c for c in b.columns if c.startswith("g1 at"))
    t = _read(root, "tab_bu.csv")
    entry = t[(t.data == "g1") & (t.eps_v == t.eps_v.min()) & (t["dt"] == t["dt"].min())].iloc[0]
    return {
        "claim": "sec:ibu: eps_v = 1e-3/16 is the threshold to detect one-bump blow-up with fixed dt",
        "paper": f"at eps_v = 1e-3/16, dt = 0.00125: {entry.paper:g} against T = 0.5",
        "ours": (
            f"{entry.T_b:.5g} at beta = {entry.beta:g}; the same entry over the beta scan: "
            f"{b[target].min():.5g}-{b[target].max():.5g}"
        ),
        "evidence": "tab_bu.csv; tab_bu_beta_scan_summary.csv",
        "verdict": "not settled",
        "why": "beta (not stated by the paper) was chosen so that this entry lies within 0.01 of 0.5: not independent",
    }


def _criterion(root: Path) -> dict[str, Any]:
    d = _read(root, "criterion_control.csv")
    none = d[d.osgood == "none"]
    false_fire = none[none["fires where theory forbids"]]
    finite = d[d.osgood == "finite-time"]
    drift = "drift dT_b/dln(1/eps)"
    return {
        "claim": "sec:ibu, alg:MR_JKO: the first t with min dv < eps_v is the blow-up time",
        "paper": "the criterion decides blow-up and gives T_b in every table",
        "ours": (
            f"homogeneous g1 to t = {none['t end'].max():g}: it fires in {len(false_fire)} of {len(none)} runs with "
            f"gamma >= 2 (no finite-time blow-up: Osgood), T_b drifting {none[drift].min():.2g}-"
            f"{none[drift].max():.2g} per e-fold of 1/eps_v against {finite[drift].min():.2g}-"
            f"{finite[drift].max():.2g} for gamma < 2; the fit of max f gives the Osgood kind in "
            f"{int(d['kind right'].sum())} of {len(d)}"
        ),
        "evidence": "criterion_control.csv",
        "verdict": "contradicted" if len(false_fire) else "supported",
        "why": (
            "a criterion that fires without a singularity cannot decide blow-up alone: T_b's drift in eps_v and "
            "the fit of max f tell the two apart"
        ),
    }


def _tab_bu_tb2(root: Path) -> dict[str, Any]:
    a = _disc(root, "tab_bu_tb2")
    return {
        "claim": "tab:bu_tb2: the analytic time is captured for two bumps (g4, T = 0.5)",
        "paper": f"entries 0.4775-0.56; |T_b - T| median {a['median |paper - analytic T|']:.3g}",
        "ours": (
            f"|T_b - T| median {a['median |ours - analytic T|']:.3g}, max {a['max |ours - analytic T|']:.3g}; "
            f"fit median {a['median |fit - analytic T|']:.3g} over its {a['fit finite_time entries']} finite_time "
            f"entries; {a['ours within tol of paper']} of {a.entries} "
            f"within 0.03 of the paper (run-free answer: {a['trivial (analytic T) within tol of paper']})"
        ),
        "evidence": "discrimination.csv; tab_bu_tb2.csv",
        "verdict": "not settled" if a["median |ours - analytic T|"] > 0.03 else "supported",
        "why": (
            "our runs of the method are further from the exact time than the paper's entries, and the cause is not "
            "found: they neither confirm nor refute the paper's numbers"
        ),
    }


def _adaptive(root: Path) -> dict[str, Any]:
    p = _read(root, "paper_variants.csv")
    by = p[(p.delta0 == 0.5) & (p.safeguard == "floor") & (p.halve_on == "any_failure")]
    default = p[(p.delta0 == 0.5) & (p.max_iter == p.max_iter.max())].iloc[0]
    small = p[(p.delta0 == 0.5) & (p.max_iter < p.max_iter.max())].sort_values("max_iter", ascending=False)
    s = small.iloc[0] if len(small) else by.iloc[0]
    g = _read(root, "gk1_records.csv")
    rerun = g[(g.policy == "halving") & (g.halve_on == "max_iterations")]
    figure = "".join(
        f"; gk1_records reruns I_max = {r.max_iter:g} beside ours (gk1_adpt_tau.png): first halving at "
        f"t = {r.first_halving_t:.3g}, T_b = {r.T_end:.4g}"
        for _, r in rerun.iterrows()
    )
    return {
        "claim": "fig:gk1_adpt_tau: the adaptive step decays significantly as t approaches the blow-up time",
        "paper": "dt halved repeatedly before T = 0.5 (g1, dt0 = 0.01)",
        "ours": (
            f"I_max = {default.max_iter:g} (shipped): first halving at t = {default['first halving t']:.3g}, after T; "
            f"I_max = {s.max_iter:g}: first halving at t = {s['first halving t']:.3g}, T_b = {s.T_b:.4g}"
            + figure
        ),
        "evidence": "paper_variants.csv; gk1_records.csv; gk1_adpt_tau.png",
        "verdict": "not settled",
        "why": "whether the step decays before T depends on the SQP's I_max, which the paper does not state",
    }


def _gk1_final(root: Path) -> dict[str, Any]:
    g = pd.read_csv(root / "gk1_final.csv")
    dv = g.v.diff().fillna(0).to_numpy()
    w = (dv + pd.Series(dv).shift(-1).fillna(0).to_numpy()) / 2  # trapezoidal weights
    mass = float((g.f * w).sum())
    near = float((g.f * w)[g.v.abs() <= 0.05].sum()) / mass
    return {
        "claim": "fig:gk1_final: f(0.5, v) nearly a Dirac delta at v = 0 (g1, dt = 0.01)",
        "paper": "the solution at t = T = 0.5 nearly converges to a Dirac delta centred at 0",
        "ours": f"max f {g.f.max():.4g}; mass share at |v| <= 0.05: {near:.3f} (initially 0.056 for g1)",
        "evidence": "gk1_final.csv; gk1_final.md",
        "verdict": "supported" if near > 0.5 else "not settled",
        "why": "against the exact Burgers solution, which concentrates the mass at v = 0 at T",
    }


def _ibu(root: Path) -> dict[str, Any]:
    d = _read(root, "ibu.csv")
    late = d[d.t >= d.t.max() / 2]
    slope = float(np.polyfit(np.log(late.t), np.log(late.centre_of_mass), 1)[0])
    law = float(np.polyfit(np.log(late.t), np.log(late.law), 1)[0])
    rel = float(((late.centre_of_mass - late.law) / late.law).abs().max())
    return {
        "claim": "sec:ibu: gamma = 3 homogeneous two bumps shrink to Diracs approaching 0 at rate O(1/t)",
        "paper": "peaks converge to the origin at O(1/t); min dv decreases slowly (no finite-time blow-up)",
        "ours": (
            f"centre of mass of v > 0 over t in [{late.t.min():.3g}, {d.t.max():.3g}]: fitted exponent {slope:.3f} "
            f"(the point-mass law p0/(1 + 2 M p0 t): {law:.3f}); largest relative distance to the law {rel:.2g}"
        ),
        "evidence": "ibu.csv; ibu_panels.csv",
        "verdict": "supported" if abs(slope + 1) <= 0.1 else "contradicted",
        "why": "against the analytic point-mass law: a rate t^-1/2 or t^-2 would fail the 0.1 margin on the exponent",
    }


def _gamma3(root: Path) -> dict[str, Any]:
    d = _read(root, "inhom_gamma3.csv")
    flagged = int(d["blow-up flagged"].astype(str).str.lower().eq("true").sum())
    rows = probe_rows(_read(root, "g3_dt_probe.csv"))
    controls = control_ratios(rows).dropna(subset=["ratio"])
    probe_all = rows[rows.variant == ""]  # the controls (a weaker Fisher term, fewer remaps) are not as shipped
    probe = probe_all[probe_all.time_order == 1]
    rise = []
    for (lam, n), g in probe.groupby(["lambda", "n"]):
        g = g.sort_values("dt", ascending=False)
        if len(g) > 1:
            rise.append(
                f"lambda = {lam:g}, {n}^2: peak max f {g.max_f_peak.iloc[0]:.3g} at dt = {g.dt.iloc[0]:g} -> "
                f"{g.max_f_peak.iloc[-1]:.3g} at dt = {g.dt.iloc[-1]:g}, min dx {g.min_dx.iloc[-1]:.2g}"
            )
    fired = probe[probe.blowup.astype(str).str.lower().eq("true")]
    coarse = probe[probe["dt"] == probe["dt"].max()]
    grids = []
    for lam, g in coarse.groupby("lambda"):
        g = g.sort_values("n")
        if len(g) > 1:
            grids.append(f"lambda = {lam:g}: " + ", ".join(f"{p:.3g}" for p in g.max_f_peak) + " on "
                         + ", ".join(f"{n}^2" for n in g.n))  # fmt: skip
    grid_text = f" (at dt = {coarse['dt'].iloc[0]:g}, peak max f: " + "; ".join(grids) + ")" if grids else ""
    fine = []  # the same at the smallest dt each lambda ran on three grids or more
    for lam, g in probe.groupby("lambda"):
        on = g.groupby("dt").n.nunique()
        if (on >= 3).any():
            dt_small = float(on[on >= 3].index.min())
            h = g[g["dt"] == dt_small].sort_values("n")
            spread = h.max_f_peak.max() / h.max_f_peak.min()
            fine.append(f"lambda = {lam:g} at dt = {dt_small:g}: " + ", ".join(f"{p:.3g}" for p in h.max_f_peak)
                        + " on " + ", ".join(f"{n}^2" for n in h.n) + f", max / min {spread:.2g}")  # fmt: skip
    if fine:
        grid_text += "; the peak against the grid at the smallest dt run on three grids or more: " + "; ".join(fine)
    swept = max(n for (_lam, n), g in probe.groupby(["lambda", "n"]) if g["dt"].nunique() > 1)
    fired_text = ", ".join(f"lambda = {r['lambda']:g} on {r['n']}^2 at dt = {r['dt']:g}" for _, r in fired.iterrows())
    order2, time_text = _gamma3_orders(probe_all)
    if len(controls):
        time_text += "; controls of what else changes with dt (peak of max f against the run as shipped): " + "; ".join(
            f"{r.variant}: {r.ratio:.2g}x at lambda = {r['lambda']:g}, {r.n}^2, dt = {r['dt']:g}"
            for _, r in controls.iterrows()
        )
    return {
        "claim": "sec:sp_inhom_gamma_3: no blow-up for gamma = 3 inhomogeneous (lambda = 2 to 10)",
        "paper": "the experiments firmly support no blow-up for gamma = 3",
        "ours": (
            f"{flagged} of {len(d)} runs flagged at the shipped dt = 0.05 (lambda {d['lambda'].min():g}-"
            f"{d['lambda'].max():g}, N = {d.N.iloc[0]}); max f {d['max f (peak)'].min():.3g}-"
            f"{d['max f (peak)'].max():.3g}; min dx >= {d['min dx (min)'].min():.2g}.  With dt halved: "
            + "; ".join(rise)
            + f"; eps_x = 1e-5 reached in {len(fired)} of {len(probe)} first-order probe runs"
            + order2
        ),
        "evidence": "inhom_gamma3.csv; g3_dt_probe.csv",
        "verdict": "not settled",
        "why": (
            "the watched quantities do not converge in dt: the peak of max f keeps growing as dt is halved, on every "
            f"grid where dt was halved (up to {swept}^2, g3_dt_probe.md), while at the shipped dt it moves little "
            "with the grid"
            f"{grid_text}, so the shipped dt = 0.05 does not resolve the concentration the verdict rests on; "
            f"eps_x = 1e-5 is reached only at smaller dt ({fired_text or 'none'}), and whether that is a "
            "blow-up or a concentration resolved below the threshold is open"
            + time_text
        ),
    }


def _gamma3_orders(probe: pd.DataFrame) -> tuple[str, str]:
    """What the probe's second-order runs add to the gamma = 3 row: the two orders at one dt (``ours``) and which
    is right (``why``); empty where the probe has no second-order run beside a first-order one."""
    pairs = order_pairs(probe)
    if pairs.empty:
        return "", ""
    text = "; ".join(
        f"lambda = {r['lambda']:g}, {int(r.n)}^2, dt = {r['dt']:g}: peak max f {r.peak_order1:.3g} (order 1) against "
        f"{r.peak_order2:.3g} (order 2)"
        for _, r in pairs.iterrows()
    )
    settled = []
    for (lam, n), g in probe[probe.time_order == 2].groupby(["lambda", "n"]):
        g = g.sort_values("dt", ascending=False)
        if len(g) > 1:
            change = g.max_f_peak.iloc[-1] / g.max_f_peak.iloc[-2] - 1
            settled.append(
                f"lambda = {lam:g}, {n}^2: {change:+.0%} from dt = {g.dt.iloc[-2]:g} to {g.dt.iloc[-1]:g} "
                f"(final max f {g.max_f_final.iloc[-1]:.3g}, {g.blowup_kind.iloc[-1]})"
            )
    worst = pairs.iloc[int(np.abs(np.log(pairs.order2_over_order1.to_numpy())).argmax())]
    ratio = float(worst.order2_over_order1)
    verdict = (
        "so the first-order runs at the shipped dt are not converged in time and the smaller steps are the better "
        "answer" if abs(np.log(ratio)) > np.log(1.5) else "within a factor 1.5 of each other"
    )
    why = (
        f"; the second-order scheme (time.order = 2) at the same dt gives {ratio:.3g} times the first-order peak at "
        f"most (lambda = {worst['lambda']:g}, {int(worst.n)}^2, dt = {worst['dt']:g}), {verdict} (the probe's section "
        "'The two orders at one dt')"
        + (f"; the second-order peak against dt: {'; '.join(settled)}" if settled else "")
    )
    return f".  Second order in time: {text}", why


def _span(values: pd.Series, fmt: str) -> str:
    """ "lo-hi" of the values as printed, one value where they print alike."""
    lo, hi = f"{values.min():{fmt}}", f"{values.max():{fmt}}"
    return lo if lo == hi else f"{lo}-{hi}"


def _spread_events(root: Path, case: str) -> dict[str, Any]:
    """What sigma_v does after the collapse in ``case``, on every grid (``inhom_gamma1p5_events.csv``)."""
    e = _read(root, "inhom_gamma1p5_events.csv")
    e = e[(e.case == case) & e.followed.astype(bool) & e["t below"].notna()]
    mapped, uniform = (e[e.grid.str.endswith(kind)] for kind in ("mapped", "uniform"))
    back = mapped["t back above"]
    return {
        "mapped": len(mapped),
        "reversed": int(back.notna().sum()),
        "below": _span(mapped["t below"], ".3g"),
        "min": _span(mapped["min sigma_v"], ".2g"),
        "back": _span(back, ".3g"),
        "uniform": "; ".join(f"{r.grid}: {r.event}" for _, r in uniform.iterrows()) or "none",
    }


def _gamma1p5(case: str) -> Callable[[Path], dict[str, Any]]:
    def row(root: Path) -> dict[str, Any]:
        d = _read(root, "inhom_gamma1p5.csv").set_index("case").loc[case]
        ev = _spread_events(root, case)
        every = ev["mapped"] > 0 and ev["reversed"] == ev["mapped"]
        ours = (
            f"lambda = {d['lambda']:g}: T_b {d.T_b:.4g} at 121^2 ({d['T_b over grids']} over 41^2-121^2) against "
            f"the meeting time {d['meeting time c/d']:g}; the event is a collapse that reverses: sigma_v < 0.05 at "
            f"t = {ev['below']} on the mapped grids, recorded minimum {ev['min']}, back above 0.05 by t = "
            f"{ev['back']} on {ev['reversed']} of {ev['mapped']} mapped grids followed past it (by T_b at the "
            f"latest); uniform reference: {ev['uniform']}"
        )
        timing_agrees = str(d.supports).lower() == "true"
        return {
            "claim": f"sec:sp_inhom_gamma_1p5: gamma = 3/2 blows up in v {d.paper.split(' in v ', 1)[-1]}",
            "paper": d.paper,
            "ours": ours + f"; the paper's criterion: {d.ours}",
            "evidence": "inhom_gamma1p5_events.csv; inhom_gamma1p5.csv; inhom_gamma1p5_resolution.csv; "
            "grid_convergence.csv",
            "verdict": "not settled",
            "why": (
                ("the timing of the paper's criterion agrees, but " if timing_agrees else
                 f"the paper's criterion fires before the bumps meet (T_b {d['T_b over grids']} over the grids, "
                 f"c/d = {d['meeting time c/d']:g}), not after they pass, but ")
                + ("on every mapped grid followed past the collapse" if every else "on some mapped grids")
                + " the spread grows back above the threshold by T_b: the criterion fires on a collapse that "
                "reversed, not on a demonstrated blow-up"
                + ("" if timing_agrees else "; no run follows the bumps past x = 0 (t >= 1), where the paper places it")
            ),
        }

    return row


def _properties(root: Path) -> dict[str, Any]:
    s = _read(root, "property_budget_summary.csv")
    cols = [f"{q}: wrong-way steps" for q in ("moment2", "moment3", "moment4", "entropy")]
    by = {c: s[s.case.str.startswith(c)] for c in ("gamma3", "gamma1.5")}
    worst = {c: {q.split(":")[0]: int(d[q].max()) for q in cols} for c, d in by.items()}
    g3 = _read(root, "inhom_gamma3.csv")
    return {
        "claim": "prop:properties: mass and momentum conserved, moments and entropy dissipated up to blow-up",
        "paper": "all well captured (fig:gk3_properties, gamma = 3 and gamma = 3/2 rows)",
        "ours": (
            f"gamma = 3: mass drift <= {g3['mass drift'].max():.1g}, momentum drift <= "
            f"{g3['momentum drift'].max():.1g}; steps where a quantity moves the wrong way, gamma = 3: "
            f"{worst['gamma3']}; gamma = 3/2: {worst['gamma1.5']}"
        ),
        "evidence": "property_budget_summary.csv; property_budget.csv; inhom_gamma3.csv",
        "verdict": "contradicted" if max(worst["gamma1.5"].values()) > 0 else "supported",
        "why": (
            "conservation holds to rounding, but the moments rise and the entropy falls the wrong way on some "
            "steps (the remaps, property_budget.md), most for gamma = 3/2, which the paper reports as well captured"
        ),
    }


def _g2bu_control(root: Path) -> dict[str, Any]:
    """What the control sweep shows below the threshold lambda = 309.8."""
    d = _read(root, "tab_g2bu_control.csv")
    below = d[~d["above threshold"].astype(bool)]
    fired = below[below.verdict == "blow-up"]
    return {
        "below": len(below),
        "fired": len(fired),
        "first": "; ".join(
            f"from lambda = {g['lambda'].min():g} on {nx} x {nv}" for (nx, nv), g in fired.groupby(["n_x", "n_v"])
        )
        or "nowhere",
        "tb_lo": float(fired.T_b.min()) if len(fired) else float("nan"),
        "tb_hi": float(fired.T_b.max()) if len(fired) else float("nan"),
    }


def _g2bu(root: Path) -> dict[str, Any]:
    a = _disc(root, "tab_g2bu")
    c = _g2bu_control(root)
    return {
        "claim": "tab:g2bu: gamma = 2 finite mass blows up near T = 0.1 as lambda approaches the threshold 310",
        "paper": "T_b 0.10349 (lambda = 220) to 0.10009 (310)",
        "ours": (
            f"{a['ours within tol of paper']} of {a.entries} within 0.005 of the paper, where the run-free answer "
            f"0.1 scores {a['trivial (analytic T) within tol of paper']}; |T_b - 0.1| max "
            f"{a['max |ours - analytic T|']:.3g}"
        ),
        "evidence": "discrimination.csv; tab_g2bu.csv; tab_g2bu_control.csv; grid_convergence_g2bu.csv",
        "verdict": "not settled",
        "why": (
            f"the count does not discriminate (the paper's row spans 0.0034), and the control shows the criterion "
            f"does not either: below the threshold it fires in {c['fired']} of {c['below']} runs "
            f"({c['first']}: tab_g2bu_control.csv, refined in x and v), with T_b "
            f"{c['tb_lo']:.3g} to {c['tb_hi']:.3g} there; the grid study refines v only though the blow-up is "
            "detected in x"
        ),
    }


def _loglog(root: Path) -> dict[str, Any]:
    d = _read(root, "tab_g2bu.csv").sort_values(["lambda", "n_v"])
    top = d[d["lambda"] == d["lambda"].max()]
    coarse = d[d.n_v == d.n_v.min()]
    return {
        "claim": "fig:loglog: log rho / log m approaches 1 as lambda approaches 310",
        "paper": "verified in fig:loglog",
        "ours": (
            f"log(rho/rho0)/log(m/m0) at T_b: {coarse['log ratio at T_b'].iloc[0]:.3g} (lambda = "
            f"{coarse['lambda'].iloc[0]:g}) to {coarse['log ratio at T_b'].iloc[-1]:.3g} (lambda = "
            f"{coarse['lambda'].iloc[-1]:g}); at lambda = {top['lambda'].iloc[0]:g}: "
            + ", ".join(f"{r['log ratio at T_b']:.3g} (n_v = {r.n_v})" for _, r in top.iterrows())
        ),
        "evidence": "tab_g2bu.csv",
        "verdict": "not settled",
        "why": (
            "a normalised ratio, not the paper's log rho / log m (they agree only as t -> T); at 310 it moves with "
            "n_v and x is not refined"
        ),
    }


def _level_sets(root: Path) -> dict[str, Any]:
    d = _read(root, "tab_g2bu.csv")
    comp = d["max components of {f > 0.1}"]
    return {
        "claim": (
            "thm_condbu (sec:sp_inhom_gamma_2, sec:sup_g2): each level set meets every vertical line in one component"
        ),
        "paper": "verified numerically (fig:gk2_bu, fig:gk2_bu_2)",
        "ours": (
            f"at level 0.1, the most components on one x-slice: {comp.min()}-{comp.max()} over the runs (split "
            f"slice-steps {', '.join(d['split slice-steps'].astype(str))}); secondary peaks "
            f"{d['secondary peak'].min():.2g}-{d['secondary peak'].max():.2g}"
        ),
        "evidence": "tab_g2bu.csv; gk2_bu.csv",
        "verdict": "contradicted" if comp.max() > 1 else "supported",
        "why": (
            "more than one component on a minority of slice-steps, also at n_v = 401; only the level 0.1 is checked"
        ),
    }


def _explicit(root: Path) -> dict[str, Any]:
    d = _read(root, "explicit.csv")
    worst = d[["rho rel. diff", "m rel. diff", "b rel. diff"]].abs().max(axis=1)
    # the ODE is integrated at rtol 1e-12 (explicit.md); near T its conditioning multiplies that by T/(T - t)
    allowed = 10 * ODE_RTOL / d["(T-t)/T"]
    return {
        "claim": (
            "sec: explicit1: the infinite-mass self-similar solution (eqn:brhom) and its threshold lambda rho0 T > 2"
        ),
        "paper": "rho = rho0 T/(T - t), m = (T/(T - t))^(lambda rho0 T/2): blow-up at T above the threshold",
        "ours": (
            f"ODE integration against the closed forms to (T - t)/T = {d['(T-t)/T'].min():.0e}: largest relative "
            f"difference {worst.max():.2g}, at most {float((worst / (ODE_RTOL / d['(T-t)/T'])).max()):.2g} x "
            "rtol T/(T - t)"
        ),
        "evidence": "explicit.csv; explicit.md",
        "verdict": "supported" if bool((worst <= allowed).all()) else "contradicted",
        "why": "the closed forms against an independent ODE integration, within its conditioning",
    }


ODE_RTOL = 1e-12
"""The relative tolerance ``explicit`` integrates the ODE at (its Markdown states it)."""


CONCLUSIONS: tuple[Callable[[Path], dict[str, Any]], ...] = (
    _tab_bu,
    _eps_v,
    _criterion,
    _tab_bu_tb2,
    _adaptive,
    _gk1_final,
    _ibu,
    _gamma3,
    _gamma1p5("before"),
    _gamma1p5("after"),
    _properties,
    _g2bu,
    _loglog,
    _level_sets,
    _explicit,
)
"""One function per conclusion: the directory of result files -> the row."""

EVIDENCE = (
    "discrimination.csv", "tab_bu.csv", "tab_bu_beta_scan_summary.csv", "tab_bu_tb2.csv", "paper_variants.csv",
    "gk1_records.csv",
    "gk1_final.csv", "ibu.csv", "inhom_gamma3.csv", "g3_dt_probe.csv", "inhom_gamma1p5.csv",
    "inhom_gamma1p5_events.csv",
    "property_budget_summary.csv",
    "tab_g2bu.csv", "tab_g2bu_control.csv", "explicit.csv", "criterion_control.csv",
)  # fmt: skip
"""The files the rows read (each row's ``evidence`` names these and the files beside them)."""


def conclusions(root: Path) -> pd.DataFrame:
    """The table of conclusions from the result files in ``root`` (columns claim, paper, ours, evidence,
    verdict, why); ``FileNotFoundError`` naming any file of :data:`EVIDENCE` that is missing."""
    root = Path(root)
    missing = [name for name in EVIDENCE if not (root / name).is_file()]
    if missing:
        raise FileNotFoundError(f"out: reproduce conclusions reads {missing} in {root}; run those entries first")
    df = pd.DataFrame([row(root) for row in CONCLUSIONS])
    named = sorted({name for ev in df.evidence for name in ev.split("; ")})
    absent = [name for name in named if not (root / name).is_file()]
    if absent:
        raise FileNotFoundError(f"out: the conclusions name {absent} as evidence, not in {root}")
    bad = df[~df.verdict.isin(VERDICTS)]
    if len(bad):
        raise AssertionError(f"verdicts must be one of {VERDICTS}: {bad[['claim', 'verdict']].to_dict('records')}")
    return df


def reproduce_conclusions(out: Path, quick: bool = False, **_sweep_opts: Any) -> pd.DataFrame:
    """Write ``conclusions.{csv,md}`` in ``out`` from the result files there (:func:`conclusions`).

    ``quick`` changes nothing: no run is made, the rows are read off the other entries' files.
    """
    out = Path(out)
    df = conclusions(out)
    df.to_csv(out / "conclusions.csv", index=False)
    record_csv(out / "conclusions.csv")
    counts = df.verdict.value_counts()
    lines = [
        "# The paper's conclusions against our result files",
        "",
        "One row per conclusion of the paper's numerical and heuristic sections; every number is read from the "
        "evidence files (in this directory) by `jko-cvx reproduce conclusions`.  supported: our evidence agrees "
        "and could have disagreed; contradicted: it disagrees under our stated settings (the choices table of "
        "the reproductions' README); not settled: it does not discriminate (why).  "
        + ", ".join(f"{counts.get(v, 0)} {v}" for v in VERDICTS)
        + ".",
        "",
        df.to_markdown(index=False),
        "",
    ]
    write_markdown(out / "conclusions.md", "\n".join(lines))
    return df
