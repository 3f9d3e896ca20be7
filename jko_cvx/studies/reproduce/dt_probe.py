"""The gamma = 3 inhomogeneous runs in the grid and in dt: ``jko-cvx reproduce g3_dt_probe``.

``sec:sp_inhom_gamma_3`` concludes "no blow-up" for gamma = 3 from one run per lambda at the shipped step
dt = 0.05 on 121 x 121.  This entry runs the shipped ``inhom_gamma3_lambda{4,10}`` scenes (eps_x = eps_v =
1e-5, beta = 1000, log Fisher form, Newton, the paper's maps in x and v) on n x n grids, n = 61 to 481, with dt
halved from 0.05 down to 0.003125, with first-order steps as shipped (``time.order = 1``) or the second-order
scheme (``time.order = 2``: Richardson-extrapolated collision steps, Strang splitting), and with controls
(``variant``: a weaker Fisher term, ``collision.beta``; remeshing a tenth as often, ``refine.*.tol``), to the
scenes' ``t_end = 4``.  A row (:func:`probe_run`) records the peak of max f and its time, max f at the end, the
smallest x and v spacings, the paper's verdict (``T_b``) and the run's own estimate from its max f records
(``blowup_kind``, ``T_b_fit``, :mod:`jko_cvx.blowup`).  The report (:func:`probe_report`) gives each grid and
order against dt, each dt against the grid, the two orders at one dt (which dt is right), and the controls;
the conclusions table reads the rows through :func:`probe_rows`, :func:`order_pairs` and
:func:`control_ratios`.

The full form (:data:`FULL_CASES`) takes many hours on one core (the ``seconds`` column; the lambda = 10
runs at small dt on 481 x 481 most of it); the shipped table was assembled case by case over several sessions
by the project's probe script with the same :func:`probe_run` and :func:`probe_report` (each row names the
commit that ran it), and the report lists the cases of the full form it lacks.  Rows written before the order
or the variant were recorded are first-order runs as shipped.  Written: ``g3_dt_probe.{csv,md,png}``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.engine.errors import RunDirError
from jko_cvx.engine.loop import simulate
from jko_cvx.engine.run import load_run
from jko_cvx.environment import code_fingerprint, environment, record_csv, write_markdown
from jko_cvx.scene.model import shipped_scene
from jko_cvx.studies.solvers.figures import finish_figure, pyplot
from jko_cvx.studies.sweep import run_sweep

__all__ = [
    "CONTROL_COLUMNS",
    "FULL_CASES",
    "QUICK_CASES",
    "VARIANT_KEYS",
    "control_ratios",
    "grid_table",
    "missing_cases",
    "order_pairs",
    "parse_variant",
    "probe_figure",
    "probe_report",
    "probe_rows",
    "probe_run",
    "reproduce_g3_dt_probe",
    "variant_key",
]

VARIANT_KEYS = ("collision.beta", "refine.x.tol", "refine.v.tol")
"""What a case may change besides lambda, n, dt and the order (the controls): the Fisher weight (its term scales as
(dt / beta)^2, so a smaller dt also weakens the regularisation) and how often the grids are remapped (every step
by default, so a smaller dt also remaps more often)."""

_HALVINGS = (0.05, 0.025, 0.0125, 0.00625)
FULL_CASES: tuple[tuple[float, int, float, int, str], ...] = (
    *((lam, n, dt, 1, "") for lam in (4.0, 10.0) for n in (61, 121, 241, 481) for dt in _HALVINGS),
    (4.0, 61, 0.003125, 1, ""), (4.0, 121, 0.003125, 1, ""), (4.0, 241, 0.003125, 1, ""),
    (10.0, 61, 0.003125, 1, ""),
    *((lam, n, dt, 2, "") for lam in (4.0, 10.0) for n in (61, 121) for dt in (0.05, 0.025)),
    (4.0, 61, 0.0125, 2, ""), (10.0, 61, 0.0125, 2, ""),
    (4.0, 61, 0.05, 1, "collision.beta=1e5"), (4.0, 61, 0.0125, 1, "collision.beta=1e5"),
    (10.0, 61, 0.05, 1, "collision.beta=1e5"),
    *((4.0, 61, dt, 1, "refine.x.tol=0.1,refine.v.tol=0.1") for dt in (0.025, 0.0125, 0.00625)),
)  # fmt: skip
"""(lambda, n, dt, time order, variant) of the full form: each lambda on 61^2 to 481^2 with dt halved three times
from the shipped 0.05 (and a fourth time on the coarser grids), second-order steps on 61^2 and 121^2, and the
controls on 61^2."""

QUICK_CASES: tuple[tuple[float, int, float, int, str], ...] = (
    (4.0, 21, 0.1, 1, ""), (4.0, 21, 0.05, 1, ""), (4.0, 31, 0.1, 1, ""), (10.0, 21, 0.1, 1, ""),
    (10.0, 21, 0.1, 2, ""), (10.0, 21, 0.1, 1, "collision.beta=100000"),
)  # fmt: skip
"""The quick form's cases (with t_end = :data:`QUICK_T_END`): every section of the report, in seconds."""

QUICK_T_END = 0.4

CONTROL_COLUMNS = ("lambda", "n", "dt", "time_order", "variant", "peak", "peak as shipped", "ratio")


def parse_variant(variant: str) -> dict[str, float]:
    """The scene overrides of a variant ``key=value,...`` (empty: none); keys of :data:`VARIANT_KEYS`."""
    out = {}
    for item in filter(None, variant.split(",")):
        key, _, value = item.partition("=")
        if key not in VARIANT_KEYS:
            raise ValueError(f"a variant key must be one of {list(VARIANT_KEYS)}, got {key!r}")
        if key in out:
            raise ValueError(f"a variant sets each key once, got {key!r} twice in {variant!r}")
        out[key] = float(value)
    return out


def variant_key(variant: str) -> tuple[tuple[str, float], ...]:
    """What a variant changes, as a sorted tuple: ``collision.beta=1e5`` and ``collision.beta=100000`` are one
    variant, whatever the spelling or the order of the keys."""
    return tuple(sorted(parse_variant(variant).items()))


def probe_run(
    lam: float,
    n: int,
    dt: float,
    time_order: int = 1,
    variant: str = "",
    t_end: float | None = None,
    out: str | Path | None = None,
) -> dict[str, Any]:
    """One run of the shipped ``inhom_gamma3_lambda{lam}`` scene on n x n with step dt, the time order and variant.

    ``t_end``: the scene's (4) unless given (the quick form).  ``out``: a run directory, checkpointed every step
    and continued from its checkpoint when it holds one of this scene and code (a run longer than a session
    continues where it stopped; an ended run is read back, not run again).  Returns the row of the report's
    table; ``seconds`` is the run's wall time summed over its legs when ``out`` is given.
    """
    t0 = time.perf_counter()
    over: dict[str, Any] = {"v.n": n, "x.n": n, "time.dt": dt, "time.order": time_order, **parse_variant(variant)}
    if t_end is not None:
        over["t_end"] = t_end
    if out is None:
        run = simulate(shipped_scene(f"inhom_gamma3_lambda{lam:g}", over))
        seconds = time.perf_counter() - t0
    else:
        out = Path(out)
        scene = shipped_scene(f"inhom_gamma3_lambda{lam:g}", {**over, "output.checkpoint_every": 1})
        if (out / "verdict.json").exists():
            run = load_run(out)  # its files checked against their recorded digests
            if run.scene.to_dict() != scene.to_dict():
                raise RunDirError(f"the run in {out} is not of the case asked for ({lam:g}:{n}:{dt:g}:{time_order})")
            made_by = json.loads((out / "metadata.json").read_text()).get("code_sha256")
            if made_by != code_fingerprint():  # the row is labelled with this code's commit: it must be its run
                raise RunDirError(
                    f"the run in {out} was made by other jko_cvx code (code SHA-256 {str(made_by)[:12]}...); read it "
                    "back under that code, or move it away to run the case again"
                )
        else:
            run = simulate(scene, out=out, resume=(out / "checkpoint.npz").exists(), progress=True)
        seconds = run.seconds["wall"]
    scene = run.scene
    d = run.diagnostics
    peak = int(d.max_f.to_numpy().argmax())
    v = run.verdict
    return {
        "lambda": lam, "n": n, "dt": dt, "time_order": time_order, "variant": variant, "t_end": scene.t_end,
        "steps": int(len(d) - 1),
        "max_f_peak": float(d.max_f.iloc[peak]), "t_peak": float(d.t.iloc[peak]),
        "max_f_final": float(d.max_f.iloc[-1]), "min_dx": float(d.min_dx.min()), "min_dv": float(d.min_dv.min()),
        "blowup": v.blowup, "reason": v.reason, "T_b": v.T_b,
        "blowup_kind": v.blowup_kind, "T_b_fit": v.T_b_fit, "T_b_fit_err": v.T_b_fit_err, "blowup_rate": v.blowup_rate,
        "failed_steps": int(run.failed_steps), "seconds": seconds,
    }  # fmt: skip


def probe_rows(df: pd.DataFrame) -> pd.DataFrame:
    """The probe's rows with ``time_order`` (1 where not recorded), ``variant`` ("" where not recorded) and ``t_end``
    (the shipped scenes' where not recorded)."""
    df = df.copy()
    if "time_order" not in df:
        df["time_order"] = 1
    if "t_end" not in df:  # rows written before it was recorded ran to the shipped scenes' t_end
        df["t_end"] = shipped_scene("inhom_gamma3_lambda4").t_end
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


def grid_table(df: pd.DataFrame) -> pd.DataFrame:
    """Peak of max f per lambda, order and dt (rows) against the grid (columns), runs as shipped."""
    df = probe_rows(df)
    df = df[df.variant == ""]
    return df.pivot_table(index=["lambda", "time_order", "dt"], columns="n", values="max_f_peak").sort_index(
        ascending=[True, True, False]
    )


def missing_cases(df: pd.DataFrame, cases=FULL_CASES) -> list[tuple[float, int, float, int, str]]:
    """The ``cases`` without a row in ``df``."""
    have = {(float(r["lambda"]), int(r["n"]), float(r["dt"]), int(r["time_order"]), variant_key(r["variant"]))
            for _, r in probe_rows(df).iterrows()}  # fmt: skip
    return [c for c in cases if (*c[:4], variant_key(c[4])) not in have]


def probe_report(df: pd.DataFrame, title_note: str = "", cases=FULL_CASES) -> str:
    """The Markdown report of the rows ``df``: the table, each grid and order against dt, each dt against the grid,
    the two orders at one dt, and the controls; the ``cases`` of the form that have no row are listed."""
    df = probe_rows(df)
    shipped = df[df.variant == ""]
    missing = missing_cases(df, cases)
    lines = [
        "# gamma = 3 inhomogeneous runs in the grid and in dt" + title_note,
        "",
        "The shipped scenes `inhom_gamma3_lambda4` and `_lambda10` (eps_x = eps_v = 1e-5, beta = 1000, log Fisher "
        f"form, Newton), on N x N grids (N = {_listed(df.n)}), to t_end = {_listed(df.t_end)} with the step dt = "
        f"{_listed(df['dt'], reverse=True)} (the scenes' own is 0.05); first-order "
        "steps as shipped (`time_order` 1) or the second-order scheme (`time_order` 2: Richardson-extrapolated "
        "collision steps and Strang splitting); everything else as shipped.  `T_b` is the paper's threshold time, "
        "`blowup_kind` / `T_b_fit` the run's own estimate from its max f records (jko_cvx.blowup; empty in rows "
        "written before it was recorded).  `jko-cvx reproduce g3_dt_probe` (one BLAS thread); the shipped table "
        "was assembled case by case by `python studies/g3_dt_probe.py`: each row's `commit` names the code that "
        "ran it, and rows of earlier sessions may come from another machine or BLAS kernel (the environment "
        "lines are those of the last write).",
        "",
        f"Cases of the form not run (lambda, n, dt, order, variant): {missing}."
        if missing
        else "Every case of the form has a row.",
        "",
        df.sort_values(
            ["lambda", "n", "time_order", "variant", "dt"], ascending=[True, True, True, True, False]
        ).to_markdown(index=False, floatfmt=".4g"),
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
                f"{int(g.blowup.astype(str).str.lower().eq('true').sum())} of {len(g)}."
            )
    table = grid_table(df)
    if table.shape[1] > 1:
        lines += [
            "",
            "## Each dt against the grid",
            "",
            "Peak of max f over the run, runs as shipped (rows: lambda, time order, dt; columns: N per axis).  Where "
            "a row settles across the columns the grid is not what the peak depends on; where a column moves down "
            "its rows, the step is.",
            "",
            table.reset_index().to_markdown(index=False, floatfmt=".4g"),
            "",
        ]
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


def _listed(values: pd.Series, reverse: bool = False) -> str:
    """The distinct values, sorted, as the report prints them."""
    return ", ".join(f"{v:g}" for v in sorted(set(values), reverse=reverse))


def probe_figure(df: pd.DataFrame, path: Path) -> None:
    """Peak of max f against dt, one line per lambda, grid and order (runs as shipped), log-log."""
    df = probe_rows(df)
    df = df[df.variant == ""]
    plt = pyplot()
    lams = sorted(df["lambda"].unique())
    fig, axes = plt.subplots(1, len(lams), figsize=(5.2 * len(lams), 4.2), squeeze=False)
    grids = sorted(df.n.unique())
    for ax, lam in zip(axes[0], lams, strict=True):
        for (n, order), g in df[df["lambda"] == lam].groupby(["n", "time_order"]):
            g = g.sort_values("dt")
            ax.loglog(g.dt, g.max_f_peak, "-o" if order == 1 else "--s", ms=3, color=f"C{grids.index(n)}",
                      label=f"{n}^2, order {order}")  # fmt: skip
        ax.set_xlabel("dt")
        ax.set_ylabel("peak of max f over the run")
        ax.set_title(f"gamma = 3, lambda = {lam:g}", fontsize=9)
        ax.legend(fontsize=7)
    finish_figure(fig, list(axes[0]), path, fontsize=8)


def reproduce_g3_dt_probe(out: Path, quick: bool = False, **sweep_opts: Any) -> pd.DataFrame:
    """The runs of :data:`FULL_CASES` (``quick``: :data:`QUICK_CASES` to t = :data:`QUICK_T_END`); writes
    ``g3_dt_probe.{csv,md,png}``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    cases, t_end = (QUICK_CASES, QUICK_T_END) if quick else (FULL_CASES, None)
    points = [
        {"lam": lam, "n": n, "dt": dt, "time_order": order, "variant": variant, "t_end": t_end}
        for lam, n, dt, order, variant in cases
    ]
    df = run_sweep(probe_run, points, out / "cache" / "g3_dt_probe", desc="g3_dt_probe", **sweep_opts)
    # probe_run's own row: the sweep adds the point's ``lam`` and its ``cached`` flag
    table = df.drop(columns=["lam", "cached"]).assign(commit=environment().get("git_commit"))
    table = table[["lambda", *(c for c in table.columns if c != "lambda")]]
    csv = out / "g3_dt_probe.csv"
    table.to_csv(csv, index=False)
    record_csv(csv)
    write_markdown(out / "g3_dt_probe.md", probe_report(table, " (quick form)" if quick else "", cases))
    probe_figure(table, out / "g3_dt_probe.png")
    return table
