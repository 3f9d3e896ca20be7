"""How the gamma = 3 inhomogeneous runs depend on the time step: the watched quantities against dt.

``python studies/g3_dt_probe.py [--cases lam:n:dt[:order] ...]`` runs the shipped
``inhom_gamma3_lambda{4,10}`` scenes (121 x 121 in the paper; here N x N, N = 61 to 481) to their ``t_end``
with the step dt halved from the shipped 0.05, first-order steps as shipped (``time.order = 1``) or the
second-order scheme (``time.order = 2``: Richardson-extrapolated collision steps, Strang splitting), everything
else as shipped, and writes ``studies/results/reproduce/g3_dt_probe.{csv,md}``: per run the peak of max f and
its time, max f at the end, the smallest x and v spacings of the mapped grids, the verdict (the paper's
threshold time ``T_b`` and the run's own estimate from its max f records: ``blowup_kind``, ``T_b_fit`` with
its error bar, :mod:`jko_cvx.blowup`) and the seconds.  A point already in the CSV (same lambda, N, dt, order
and the same package commit) is not run again, so the probe can be extended case by case; rows written
before the order and the estimate were recorded are first-order runs and leave the estimate empty.

The two orders at one dt separate the time-discretisation error from the rest: where the second-order run
at dt agrees with first-order runs at a smaller dt and not with the first-order run at dt, the first-order
run at dt is not converged in time.

This is a probe, not the grid-convergence study: it asks whether the paper's "no blow-up" verdict
for gamma = 3 and the quantities it rests on (max f, min dx against eps_x = 1e-5) settle as dt
shrinks on a fixed grid.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import pandas as pd

from jko_cvx.engine.loop import simulate
from jko_cvx.environment import environment, environment_line, record_csv, write_markdown
from jko_cvx.scene.model import shipped_scene
from jko_cvx.studies.reproduce.dt_probe import control_ratios, order_pairs, probe_rows

OUT = Path(__file__).parent / "results" / "reproduce"  # evidence of the conclusions table
CSV = OUT / "g3_dt_probe.csv"
DEFAULT_CASES = tuple(
    [(4.0, 61, dt, 1, "") for dt in (0.05, 0.025, 0.0125, 0.00625)]
    + [(4.0, 121, dt, 1, "") for dt in (0.05, 0.025, 0.0125)]
    + [(10.0, 61, dt, 1, "") for dt in (0.05, 0.025, 0.0125, 0.00625)]
    + [(10.0, 121, dt, 1, "") for dt in (0.05, 0.025)]
    + [(lam, 61, dt, 2, "") for lam in (4.0, 10.0) for dt in (0.05, 0.025)]
)
KEY = ("lambda", "n", "dt", "time_order", "variant")
VARIANT_KEYS = ("collision.beta", "refine.x.tol", "refine.v.tol")
"""What a case may change besides lambda, n, dt and the order (the controls of the "why" section): the Fisher
weight (its term scales as (dt / beta)^2, so a smaller dt also weakens the regularisation) and how often the grids
are remapped (every step by default, so a smaller dt also remaps more often)."""


def parse_case(text: str) -> tuple[float, int, float, int, str]:
    """``lam:n:dt[:order[:key=value,...]]`` (order 1 or 2, default 1; keys of :data:`VARIANT_KEYS`), checked."""
    parts = text.split(":")
    if len(parts) not in (3, 4, 5):
        raise ValueError(f"a case is lam:n:dt[:order[:key=value,...]], got {text!r}")
    lam, n, dt = float(parts[0]), int(parts[1]), float(parts[2])
    order = int(parts[3]) if len(parts) >= 4 else 1
    if lam not in (4.0, 10.0):
        raise ValueError(f"lambda must be 4 or 10 (the shipped scenes), got {parts[0]!r}")
    if not (n >= 3 and dt > 0 and order in (1, 2)):
        raise ValueError(f"need n >= 3, dt > 0 and order 1 or 2, got {text!r}")
    variant = parts[4] if len(parts) == 5 else ""
    _overrides(variant)  # checked here, before any run
    return lam, n, dt, order, variant


def _overrides(variant: str) -> dict[str, float]:
    """The scene overrides of a variant ``key=value,...`` (empty: none)."""
    out = {}
    for item in filter(None, variant.split(",")):
        key, _, value = item.partition("=")
        if key not in VARIANT_KEYS:
            raise ValueError(f"a variant key must be one of {list(VARIANT_KEYS)}, got {key!r}")
        out[key] = float(value)
    return out


def run_case(lam: float, n: int, dt: float, order: int = 1, variant: str = "") -> dict:
    """One run of the shipped scene at lambda ``lam`` on n x n with step dt, the given time order and variant."""
    t0 = time.perf_counter()
    over = {"v.n": n, "x.n": n, "time.dt": dt, "time.order": order, **_overrides(variant)}
    scene = shipped_scene(f"inhom_gamma3_lambda{lam:g}", over)
    run = simulate(scene)
    d = run.diagnostics
    peak = int(d.max_f.to_numpy().argmax())
    v = run.verdict
    return {
        "lambda": lam, "n": n, "dt": dt, "time_order": order, "variant": variant, "steps": int(len(d) - 1),
        "max_f_peak": float(d.max_f.iloc[peak]), "t_peak": float(d.t.iloc[peak]),
        "max_f_final": float(d.max_f.iloc[-1]), "min_dx": float(d.min_dx.min()), "min_dv": float(d.min_dv.min()),
        "blowup": bool(v.blowup), "reason": v.reason, "T_b": v.T_b,
        "blowup_kind": v.blowup_kind, "T_b_fit": v.T_b_fit, "T_b_fit_err": v.T_b_fit_err, "blowup_rate": v.blowup_rate,
        "failed_steps": int(run.failed_steps), "seconds": time.perf_counter() - t0,
    }  # fmt: skip


def _report(df: pd.DataFrame) -> str:
    df = probe_rows(df)
    shipped = df[df.variant == ""]
    lines = [
        "# gamma = 3 inhomogeneous runs against the time step",
        "",
        "The shipped scenes `inhom_gamma3_lambda4` and `_lambda10` (eps_x = eps_v = 1e-5, beta = 1000, log Fisher "
        "form, Newton), on N x N grids, to t_end = 4 with the step dt halved from the shipped 0.05; first-order "
        "steps as shipped (`time_order` 1) or the second-order scheme (`time_order` 2: Richardson-extrapolated "
        "collision steps and Strang splitting); everything else as shipped.  `T_b` is the paper's threshold time, "
        "`blowup_kind` / `T_b_fit` the run's own estimate from its max f records (jko_cvx.blowup; empty in rows "
        "written before it was recorded).  `python studies/g3_dt_probe.py` (one BLAS thread).  Rows were added "
        "over several sessions: each row's `commit` names the code that ran it, and rows of earlier sessions may "
        "come from another machine or BLAS kernel (the environment lines are those of the last write).",
        "",
        df.sort_values(["lambda", "n", "time_order", "variant", "dt"], ascending=[True, True, True, True, False])
        .to_markdown(index=False, floatfmt=".4g"),
        "",
        "## Each grid and order against dt",
        "",
    ]
    for (lam, n, order), g in shipped.groupby(["lambda", "n", "time_order"]):
        g = g.sort_values("dt", ascending=False)
        if len(g) > 1:
            ratios = ", ".join(f"{r:.2f}" for r in (g.max_f_peak.to_numpy()[1:] / g.max_f_peak.to_numpy()[:-1]))
            lines.append(
                f"- lambda = {lam:g}, {n} x {n}, order {order}: peak max f {g.max_f_peak.iloc[0]:.4g} at dt = "
                f"{g.dt.iloc[0]:g} to {g.max_f_peak.iloc[-1]:.4g} at dt = {g.dt.iloc[-1]:g} (ratio per halving: "
                f"{ratios}); min dx {g.min_dx.iloc[0]:.3g} to {g.min_dx.iloc[-1]:.3g}; blow-up flagged in "
                f"{int(g.blowup.astype(bool).sum())} of {len(g)}."
            )
    pairs = order_pairs(df)
    if not pairs.empty:
        lines += [
            "",
            "## The two orders at one dt: which is right",
            "",
            "The time-discretisation error of a first-order run at dt is of the size of the difference between "
            "it and the second-order run at the same dt.  `order1_dt_matching` is the first-order run (same lambda "
            "and grid) whose peak of max f is closest to the second-order run's, in log: where it is a smaller dt, "
            "the first-order run at dt under-resolves the concentration in time and the smaller steps are the "
            "better answer.",
            "",
            pairs.to_markdown(index=False, floatfmt=".4g"),
            "",
        ]
    controls = control_ratios(df)
    if len(controls):
        lines += [
            "## Controls: what else changes with dt",
            "",
            "A smaller dt also weakens the Fisher regularisation (its term scales as (dt / beta)^2) and remaps the "
            "grids more often (every step as shipped).  The same runs with a weaker Fisher term (larger "
            "`collision.beta`) or with remeshing only when the set moved by a tenth of its width (`refine.*.tol`), "
            "beside the run as shipped: where the ratio stays near 1, that mechanism is not what makes the peak "
            "depend on dt.",
            "",
            controls.to_markdown(index=False, floatfmt=".4g"),
            "",
        ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cases", nargs="*", default=None, help="lam:n:dt triples (default: the probe's set)")
    args = parser.parse_args(argv)
    cases = DEFAULT_CASES if args.cases is None else [parse_case(c) for c in args.cases]
    commit = environment().get("git_commit")
    done = probe_rows(pd.read_csv(CSV)) if CSV.exists() else pd.DataFrame()
    rows = done.to_dict("records")

    def key(r: dict) -> tuple:
        return tuple(r[k] for k in KEY)

    for lam, n, dt, order, variant in cases:
        case = (lam, n, dt, order, variant)
        if any(key(r) == case and r.get("commit") == commit for r in rows):
            continue
        rows = [r for r in rows if key(r) != case]
        row = {**run_case(lam, n, dt, order, variant), "commit": commit}
        rows.append(row)
        print(f"lambda {lam:g} n {n} dt {dt:g} order {order} {variant}: peak max f {row['max_f_peak']:.4g}, min dx "
              f"{row['min_dx']:.3g}, {row['reason']}, {row['blowup_kind']} ({row['seconds']:.0f} s)", flush=True)
        df = pd.DataFrame(rows)
        df.to_csv(CSV, index=False)  # after every run: a killed probe keeps what it ran
        record_csv(CSV)
    df = pd.DataFrame(rows)
    write_markdown(OUT / "g3_dt_probe.md", _report(df))
    print(environment_line())


if __name__ == "__main__":
    main()
