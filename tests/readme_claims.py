"""The numbers ``docs/guides/*.md`` and ``studies/README.md`` quote, computed from the shipped result files.

Every claim is (key, file, function, quote): the function returns the number(s) formatted as
the page prints them, and ``quote`` is the page's text with ``{}`` where they go.
``studies/readme_claims.py`` writes ``studies/results/reproduce/summary.md`` (key, value, file,
how it is computed); ``tests/docs/test_quoted_numbers.py`` checks that every filled-in quote appears
in its page (``readme``), so a rerun that changes a number fails the test until the prose follows.

Files: a claim declares every file it reads, ``file`` and then ``also``, as relative POSIX
paths resolved against the directory passed to :func:`claim_values` (the shipped one is
``studies/results/reproduce``; ``../NAME`` is a study script's file in ``studies/results``).
``compute`` receives the declared files in that order, each loaded once (a CSV as a
DataFrame, any other file as text), and opens no file itself: the caller's directory is the
only source (``tests/docs/test_quoted_numbers.py`` checks each claim reads exactly what it declares).

Agreement within a tolerance (``tab:bu``, ``tab:bu_tb2``: 0.03) is tested on
``|ours - paper|`` **rounded to 5 decimals** (:func:`jko_cvx.studies.reproduce.beta_scan.within`;
the tables print at most 5 significant digits, and T_b is a multiple of dt >= 0.00125), so
0.0300000000000002 counts as within; a run that never fires (NaN) counts as a difference.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
import pandas as pd

from jko_cvx.studies.reproduce.beta_scan import within

# The documentation pages whose narrative quotes measured numbers (``readme`` of a claim).
BAD_INPUT_PAGE = "docs/guides/bad_input.md"
FISHER_WEIGHT_PAGE = "docs/guides/fisher_weight.md"
PAPER_CHOICES_PAGE = "docs/guides/paper_choices.md"
REPRODUCING_PAGE = "docs/guides/reproducing.md"
SCALE_THREADS_PAGE = "docs/guides/scale_threads.md"
SCENES_RUNS_PAGE = "docs/guides/scenes_runs.md"
SOLVERS_PAGE = "docs/guides/solvers.md"

__all__ = ["CLAIMS", "Claim", "claim_values", "within", "write_summary"]


@dataclass(frozen=True)
class Claim:
    """One quoted passage: ``compute(*loaded files)`` fills the ``{}`` of ``quote`` in ``readme``.

    ``file`` and ``also`` are the files ``compute`` receives, in that order (paths relative to
    the results directory, see the module docstring); ``how`` says how the value is computed.
    """

    key: str
    file: str
    compute: Callable[..., tuple[str, ...]]
    quote: str
    how: str
    readme: str = "studies/README.md"
    also: tuple[str, ...] = ()

    @property
    def files(self) -> tuple[str, ...]:
        """Every file the claim reads, ``file`` first."""
        return (self.file, *self.also)


def _load(results: Path, name: str) -> Any:
    """``name`` under ``results``: a CSV as a DataFrame, any other file as text."""
    if PurePosixPath(name).is_absolute():
        raise ValueError(f"a claim's file is a relative POSIX path under the results directory, got {name!r}")
    path = Path(results) / name
    return pd.read_csv(path) if path.suffix == ".csv" else path.read_text()


def _g(x: float, digits: int = 4) -> str:
    return f"{x:.{digits}g}"


def _col(df, data, dt, digits=4):
    rows = df[(df.data == data) & (df["dt"] == dt)].sort_values("eps_v", ascending=False)
    return ", ".join(_g(x, digits) for x in rows.T_b)


def _entry(df, data, eps, dt, col="T_b"):
    row = df[(df.data == data) & np.isclose(df.eps_v, eps) & np.isclose(df["dt"], dt)]
    return float(row[col].iloc[0])


def _md_number(pattern: str) -> Callable[[str], tuple[str, ...]]:
    def get(text: str) -> tuple[str, ...]:
        m = re.search(pattern, text)
        if m is None:
            raise ValueError(f"pattern {pattern!r} not found")
        return m.groups()

    return get


def _trace(df, case):
    return df[df.case == case]


def _g3_paper(d, column: str) -> float:
    return float(d[(d.case == "gamma3 lambda10 61x61") & (d.v_remap == "paper")][column].iloc[0])


def _fisher_width(d) -> tuple[str, ...]:
    log = d[d.fisher == "log"]
    ratio = log["error / error(beta = inf)"]
    need = tuple(f"{log[(log.width == w) & (ratio <= 1.06)].beta.min():g}" for w in (0.5, 0.25, 0.125))
    return (*need, f"{ratio[(log.width == 0.125) & (log.beta == 30)].iloc[0]:.1f}")


def _level_sets(d) -> tuple[str, ...]:
    d = d[d.n_v == 201]
    split = d["split slice-steps"].str.split(" /").str[0].astype(int)
    peak = d["secondary peak"]
    low, high = d["lambda"] < 280, d["lambda"] >= 280
    return (
        *(str(x) for x in split[low]),
        *(f"{x:.2f}" for x in peak[low]),
        str(split[high].min()),
        str(split[high].max()),
        f"{peak[high].max():.2f}",
    )


def _g2bu_order(d: pd.DataFrame) -> tuple[str, ...]:
    """tab:g2bu at N_v = 201: T_b at lambda = 220 and 310, whether it falls monotonically (else the first lambda pair
    where it rises), and lambda = 310 at 401.  Which it is depends on the run's rounding (one kernel's run had 308
    above 306, another's none): the differences are below the resolution of T_b, so the prose reads the file."""
    r = d[d.n_v == 201].sort_values("lambda")
    lam, tb = r["lambda"].to_numpy(), r.T_b.to_numpy()
    rises = np.flatnonzero(np.diff(tb) > 0)
    if rises.size:
        i = int(rises[0])
        order = (
            f", but not monotonically: lambda = {lam[i]:g} gives {tb[i]:.5f}, below {lam[i + 1]:g} at {tb[i + 1]:.5f}"
        )
    else:
        order = ", monotonically in lambda on this run"
    fine = d[(d.n_v == 401) & (d["lambda"] == 310)].T_b.iloc[0]
    return f"{tb[0]:.5f}", f"{tb[-1]:.5f}", order, f"{fine:.5f}"


def _seconds(df) -> tuple[str, ...]:
    return (f"{df.seconds.sum():.0f}",)


def _wall(entry: str, minutes: bool = False) -> Callable[[pd.DataFrame], tuple[str, ...]]:
    """The measured wall time of ``jko-cvx reproduce ENTRY --fresh`` (``regenerate_timing.csv``)."""

    def get(d: pd.DataFrame) -> tuple[str, ...]:
        wall = float(d.loc[(d.entry == entry) & (d.returncode == 0), "wall_s"].iloc[0])
        return (f"{wall / 60:.0f}" if minutes else f"{wall:.0f}",)

    return get


def _scale_row(d, gamma: float, linalg: str) -> tuple[str, ...]:
    """A row of the guides' batched-Newton table: wall (CPU) at N_v = 121, 481, 1025 and the exponents."""
    rows = d[(d.gamma == gamma) & (d.linalg == linalg)].set_index("N_v")
    cells = []
    for n in (121, 481, 1025):
        if n in rows.index:
            cells += [_g(rows.median_wall_s[n], 3), _g(rows.median_cpu_s[n], 3)]
    for col in ("median_wall_s", "median_cpu_s"):
        cells.append(f"{np.log(rows[col][481] / rows[col][121]) / np.log(481 / 121):.2f}")
    return tuple(cells)


def _scale_step(d) -> tuple[str, ...]:
    row = d.set_index(["N_x = N_v", "linalg"])
    s481, s1025 = row.loc[(481, "structured (default)")], row.loc[(1025, "structured (default)")]
    dense = row.loc[(481, "dense Cholesky")]
    return (
        f"{s481.wall_per_step_s:.2f}",
        f"{s481.cpu_per_step_s:.2f}",
        f"{dense.wall_per_step_s:.2f}",
        f"{s1025.wall_per_step_s:.2f}",
        f"{s1025.cpu_per_step_s:.2f}",
        f"{s1025.collision_s:.2f}",
        f"{s1025.refine_s:.2f}",
        f"{s1025.transport_s:.2f}",
        f"{s1025.newton_iterations_max:d}",
        f"{row.peak_rss_gib.max():.2f}",
    )


def _span(values, fmt: str) -> str:
    """ "lo-hi" of the values as printed, one value where they print alike."""
    lo, hi = f"{values.min():{fmt}}", f"{values.max():{fmt}}"
    return lo if lo == hi else f"{lo}-{hi}"


def _g1p5_events(d) -> tuple[str, ...]:
    """The gamma = 3/2 events (``inhom_gamma1p5_events.csv``): mapped runs followed past the collapse, and the
    uniform references.

    Raises where the prose's qualitative statements fail: every mapped run back above 0.05 at T_b or before it,
    and the uniform lambda = 10 reference not back above by its end.
    """
    run = d[d.followed.astype(bool) & d["t below"].notna()]
    mapped = run[run.grid.str.endswith("mapped")]
    by = {c: mapped[mapped.case == c] for c in ("before", "after")}
    uni = {c: run[run.grid.str.endswith("uniform") & (run.case == c)].iloc[0] for c in ("before", "after")}
    back = mapped["t back above"].notna()
    if not (mapped["t back above"] <= mapped["t (end)"]).all():
        raise AssertionError("a mapped run is not back above 0.05 by T_b")
    if not (uni["before"]["t back above"] != uni["before"]["t back above"]):  # NaN: not back by its end
        raise AssertionError("the uniform lambda = 10 reference is back above 0.05")
    second_dip = mapped["t(min sigma_v)"] > mapped["t back above"]
    return (
        str(int(back.sum())),
        str(len(mapped)),
        *(_span(by[c]["t below"], ".3g") for c in by),
        *(_span(by[c]["t back above"], ".3g") for c in by),
        *(_span(by[c]["min sigma_v"], ".2g") for c in by),
        str(int(second_dip.sum())),
        str(len(mapped)),
        *(_span(by[c]["end / min"], ".2g") for c in by),
        f"{uni['after']['t back above']:.3g}",
        f"{uni['before']['min sigma_v']:.2g}",
        f"{uni['before']['t(min sigma_v)']:.3g}",
        f"{uni['before']['sigma_v (end)']:.2g}",
        f"{uni['before']['t (end)']:.3g}",
    )


CLAIMS: tuple[Claim, ...] = (
    # tab:bu
    Claim(
        "tab_bu.within",
        "tab_bu.csv",
        lambda d: (str(int(within(d, 0.03).sum())), str(len(d)), str(int((~within(d, 0.03)).sum()))),
        "**{} of {} entries within 0.03 of the paper's** ({} differences",
        "count of round(|T_b - paper|, 5) <= 0.03; NaN is a difference",
    ),
    Claim(
        "tab_bu.never",
        "tab_bu.csv",
        lambda d: (str(int(d.T_b.isna().sum())),),
        "runs that never fire: {}",
        "count of NaN T_b",
    ),
    Claim(
        "tab_bu.target",
        "tab_bu.csv",
        lambda d: (_g(_entry(d, "g1", 1e-3 / 16, 0.00125), 5), _g(_entry(d, "g1", 1e-3 / 16, 0.00125, "paper"), 5)),
        "g1 entry at the smallest eps_v and dt is **{} (exact 0.5, paper {})**",
        "g1, eps_v = 1e-3/16, dt = 0.00125",
    ),
    Claim(
        "tab_bu.smallest_dt",
        "tab_bu.csv",
        lambda d: (_col(d, "g1", 0.00125, 3), _col(d, "g2", 0.00125, 4), _col(d, "g3", 0.00125, 4)),
        "g1 {}; g2 {} (exact 0.25); g3 {} (exact 0.125)",
        "T_b at dt = 0.00125, eps_v = 1e-3 ... 1e-3/16",
    ),
    Claim(
        "tab_bu.mesh_rule_g1",
        "tab_bu.csv",
        lambda d: (
            ", ".join(f"{x:.3f}" for x in d[d.data == "g1"].groupby("eps_v", sort=False)["exact + mesh rule"].first()),
        ),
        "(g1: {} for eps_v = 1e-3 ... 1e-3/16)",
        "column exact + mesh rule, g1",
    ),
    Claim(
        "tab_bu.g2_dt0.0025",
        "tab_bu.csv",
        lambda d: (_col(d, "g2", 0.0025, 4),),
        "g2 at dt = 0.0025 ({} for eps_v = 1e-3 ... 1e-3/16)",
        "T_b, g2, dt = 0.0025",
    ),
    Claim(
        "tab_bu.beta_scan",
        "tab_bu_beta_scan_summary.csv",
        lambda d: (
            "; ".join(
                f"{b:g}: {w} / {n} / {g:.5g}"
                for b, w, n, g in zip(
                    d.beta, d["within 0.03"], d["never fire"], d["g1 at eps_v = 1e-3/16, dt = 0.00125"], strict=True
                )
            ),
        ),
        "(entries within 0.03 / runs that never fire / the g1 entry at the smallest eps_v and dt): {}.",
        "tab_bu_beta_scan_summary.csv",
    ),
    # traces
    Claim(
        "traces.g3",
        "tab_bu_traces.csv",
        lambda d: (
            _g(_trace(d, "g3").T_b.iloc[0], 5),
            f"{_trace(d, 'g3')['f(upper junction)/max f'].iloc[:-1].max():.2f}",
            _g(_trace(d, "g3 beta=1000").T_b.iloc[0], 5),
            f"{_trace(d, 'g3 beta=1000')['f(upper junction)/max f'].iloc[:-1].max():.2f}",
            f"{_trace(d, 'g2 dt=0.0025')['f(upper junction)/max f'].iloc[:-1].max():.2f}",
        ),
        "g3 at dt = 0.00125, eps_v = 1e-3/4 fires at {}; f at the junction reaches {} max f before; "
        "with beta = 1000 the same entry fires at {} (f at the junction at most {} max f).  g2 at dt = 0.0025, "
        "eps_v = 1e-3/8: f at the junction reaches {} max f",
        "tab_bu_traces.csv, cases g3 and g3 beta=1000",
    ),
    Claim(
        "traces.g4",
        "tab_bu_traces.csv",
        lambda d: (
            _g(_trace(d, "g4 dt=0.0025").T_b.iloc[0], 4),
            f"{_trace(d, 'g4 dt=0.0025')['r1 = min S'].iloc[1]:.4g}",
        ),
        "(dt = 0.0025, eps_v = 1e-3/8: {}) the lower end r1 of the set stays at {}",
        "tab_bu_traces.csv, case g4 dt=0.0025: T_b, r1 after the first step",
    ),
    # tab:bu_tb2
    Claim(
        "tab_bu_tb2.within",
        "tab_bu_tb2.csv",
        lambda d: (str(int(within(d, 0.03).sum())), str(len(d))),
        "{} of {} entries within 0.03",
        "count of round(|T_b - paper|, 5) <= 0.03",
    ),
    Claim(
        "tab_bu_tb2.mesh_rule",
        "tab_bu_tb2.csv",
        lambda d: (", ".join(f"{x:.3f}" for x in d.groupby("eps_v", sort=False)["exact + mesh rule"].first()),),
        "two-bump rule fires at {}",
        "column exact + mesh rule",
    ),
    Claim(
        "tab_bu_tb2.smallest_dt",
        "tab_bu_tb2.csv",
        lambda d: (f"{d[d['dt'] == 0.00125].T_b.min():.3f}-{d[d['dt'] == 0.00125].T_b.max():.3f}",),
        "ours ({}) before it",
        "range of T_b at dt = 0.00125",
    ),
    # ibu
    Claim(
        "ibu.fit",
        "ibu.md",
        _md_number(
            r"over t in \[10, 20\]: (-?[0-9.]+); of the bump's centre of mass: (-?[0-9.]+)"
            r".*?over that range: ([0-9.]+) %"
        ),
        "fitted exponent of the peak positions over [10, 20] {} (centre of mass {}; the law's local exponent "
        "-0.985), bump centres of mass within {} %",
        "ibu.md",
    ),
    # mesh maps
    Claim(
        "mesh_maps",
        "mesh_maps.csv",
        lambda d: (
            f"{100 * d['points in set (share)'].min():.0f}-{100 * d['points in set (share)'].max():.0f}",
            f"{d['remap mass error'].max():.1g}",
        ),
        "{} % of the points lie in the set; the remap conserves mass to {}",
        "mesh_maps.csv",
    ),
    # gk1 records
    Claim(
        "gk1_records.halving",
        "gk1_records.csv",
        lambda d: (
            *tuple(
                f"{d[(d.policy == 'halving') & (d.data == 'g1') & (d.delta0 == x)].first_halving_t.iloc[0]:.2f}"
                for x in (0.05, 0.5)
            ),
            f"{d[(d.policy == 'halving') & (d.delta0 == 0.05)].smallest_dt.iloc[0]:.2g}",
            str(int(d[(d.policy == "halving") & (d.delta0 == 0.05)].retries.iloc[0])),
            str(int(d[(d.policy == "halving") & (d.data == "g1") & (d.delta0 == 0.5)].retries.iloc[0])),
            str(int(d[d.policy == "halving_reset"].retries.iloc[0])),
        ),
        "first halving at t = {} (delta0 = 0.05) and {} (delta0 = 0.5); the delta0 = 0.05 step falls to {} "
        "by t = 0.6 ({} failed attempts); delta0 = 0.5 needs {} failed attempts as written and {} with "
        "`halving_reset`",
        "gk1_records.csv, halving and halving_reset rows",
    ),
    Claim(
        "gk1_records.adpt_tau",
        "gk1_records.csv",
        lambda d: (
            lambda ours, paper: (
                str(int(ours.max_iter)),
                f"{ours.first_halving_t:.2f}",
                str(int(paper.max_iter)),
                f"{paper.first_halving_t:.2f}",
                str(int(paper.retries)),
                str(int(paper.steps_below_dt0)),
                f"{paper.T_end:.4f}",
            )
        )(
            d[(d.policy == "halving") & (d.data == "g1") & (d.delta0 == 0.5) & (d.halve_on == "any_failure")].iloc[0],
            d[(d.policy == "halving") & (d.halve_on == "max_iterations")].iloc[0],
        ),
        "with ours (I_max = {}) the delta0 = 0.5 step first halves at t = {}, after T; with I_max = {} and the "
        "paper's halving rule it halves from t = {} on ({} failed attempts, {} steps below dt0) and the run ends "
        "on eps_t at T_b = {}",
        "gk1_records.csv, g1 delta0 = 0.5 halving rows (halve_on any_failure / max_iterations)",
    ),
    # gamma = 3
    Claim(
        "inhom_gamma3.drift",
        "inhom_gamma3.csv",
        lambda d: (f"{d['mass drift'].max():.2g}", f"{d['momentum drift'].max():.3g}"),
        "mass drift <= {}, momentum drift <= {}",
        "max over lambda",
    ),
    Claim(
        "inhom_gamma3.lambda10",
        "inhom_gamma3.csv",
        lambda d: (
            f"{d[d['lambda'] == 10]['min dx (min)'].iloc[0]:.2g}",
            f"{d[d['lambda'] == 10]['min dx at end'].iloc[0]:.2g}",
            f"{d[d['lambda'] == 10]['max f (peak)'].iloc[0]:.4g}",
        ),
        "min dx {}, recovering to {} at t = 4, and max f peaking at {}",
        "lambda = 10 row",
    ),
    Claim(
        "inhom_gamma3.moment2",
        "inhom_gamma3.csv",
        lambda d: tuple(str(int(d[d["lambda"] == x]["moment2 increases"].iloc[0])) for x in (8, 10)),
        "the second moment increases in {} and {} of 80 steps",
        "moment2 increases, lambda = 8, 10",
    ),
    # gamma = 3/2
    Claim(
        "inhom_gamma1p5.T_b",
        "inhom_gamma1p5.csv",
        lambda d: (f"{d.T_b.iloc[0]:.3f}", f"{d.T_b.iloc[1]:.3f}", f"{d['mass drift'].max():.0e}"),
        "**T_b = {} (lambda = 10) and {} (lambda = 5), both before the centres meet at c/d = 1**: "
        "lambda = 10 supports the paper, lambda = 5 does not.  Mass drift <= {}",
        "inhom_gamma1p5.csv",
    ),
    Claim(
        "inhom_gamma1p5.collapse",
        "inhom_gamma1p5_resolution.csv",
        lambda d: tuple(
            f"{d[(d['lambda'] == lam) & (d.grid == g)]['t(sigma_v < 0.05)'].iloc[0]:.3f}"
            for lam in (10.0, 5.0)
            for g in ("121 x 121", "81 x 81")
        ),
        "is {} and {} on 121 and 81 (lambda = 10), and {} and {} (lambda = 5)",
        "t(sigma_v < 0.05) per grid",
    ),
    Claim(
        "inhom_gamma1p5.spread",
        "inhom_gamma1p5.csv",
        lambda d: (d["T_b over grids"].iloc[0], d["T_b over grids"].iloc[1]),
        "the paper's T_b spreads over {} (lambda = 10) and {} (lambda = 5)",
        "T_b over grids",
    ),
    Claim(
        "inhom_gamma1p5.xbar",
        "inhom_gamma1p5_resolution.csv",
        lambda d: tuple(
            f"{d[(d['lambda'] == 10.0) & (d.grid == g)]['x-bar error (t <= 0.7)'].iloc[0]:.2g}"
            for g in ("121 x 121", "81 x 81")
        ),
        "the lambda = 10 bumps are {} (121) and {} (81) ahead",
        "x-bar error (t <= 0.7)",
    ),
    Claim(
        "property_budget.dt",
        "property_budget_summary.csv",
        lambda d: tuple(
            f"{d[d.case == c][k].iloc[0]:.2g}" if "sum" in k else str(int(d[d.case == c][k].iloc[0]))
            for c in ("gamma3 lambda10 61x61 dt=0.025", "gamma3 lambda10 61x61 dt=0.0125")
            for k in ("entropy: collision wrong-way sum", "entropy: wrong-way steps")
        ),
        "to t = 0.8 the collision's decrease of f log f is {} at dt = 0.025 (steps with a net decrease: {}) and {} at "
        "dt = 0.0125 (steps with a net decrease: {})",
        "gamma = 3 dt variants",
    ),
    # property budget
    Claim(
        "property_budget",
        "property_budget_summary.csv",
        lambda d: (
            *tuple(
                str(int(d[(d.case == c) & (d.v_remap == r)][f"{q}: wrong-way steps"].iloc[0]))
                for c, q in (("gamma1.5 lambda10 61x61", "moment2"), ("gamma3 lambda10 61x61", "entropy"))
                for r in ("paper", "energy")
            ),
            f"{_g3_paper(d, 'entropy: collision wrong-way sum'):.3g}",
            f"{_g3_paper(d, 'entropy: x-remap sum'):.3g}",
            f"{_g3_paper(d, 'entropy: transport sum'):.3g}",
        ),
        "the second moment increases in {} steps with the paper's remap and {} with the energy-restoring one; "
        "f log f decreases in {} and {} steps of the gamma = 3 run (collision {}, x-remap {}, transport {})",
        "property_budget_summary.csv",
    ),
    Claim(
        "property_budget.gamma1p5",
        "property_budget_summary.csv",
        lambda d, b: (
            str(len(b[(b.case == "gamma1.5 lambda10 61x61") & (b.v_remap == "paper")])),
            f"{d[(d.case == 'gamma1.5 lambda10 61x61') & (d.v_remap == 'paper')].t_end.iloc[0]:g}",
            *(
                str(int(d[(d.case == "gamma1.5 lambda10 61x61") & (d.v_remap == r)][f"{q}: wrong-way steps"].iloc[0]))
                for q in ("moment3", "moment4", "entropy")
                for r in ("paper", "energy")
            ),
            *(
                f"{d[(d.case == 'gamma1.5 lambda10 61x61') & (d.v_remap == 'paper')][k].iloc[0]:.2g}"
                for k in (
                    "moment2: v-remap wrong-way sum",
                    "entropy: v-remap wrong-way sum",
                    "entropy: x-remap sum",
                    "moment2: collision wrong-way sum",
                    "entropy: collision wrong-way sum",
                )
            ),
        ),
        "in its {} steps to t = {} the third moment moves the wrong way in {} steps with the paper's remap and {} "
        "with the energy-restoring one, the fourth in {} and {}, f log f in {} and {}; the v-remap's wrong-way "
        "share is +{} for the second moment and {} for f log f, the x-remap's {}, the collision's {} and {}",
        "gamma = 3/2 rows of property_budget_summary.csv; steps: rows of property_budget.csv",
        also=("property_budget.csv",),
    ),
    # Fisher weight against the data's width (the solver guide's guidance row)
    Claim(
        "fisher_width",
        "fisher_width.csv",
        _fisher_width,
        "smallest scanned beta with a bias under 6 %: {}, {}, {} for w = 0.5, 0.25, 0.125; beta = 30 multiplies "
        "the error by {} at w = 0.125",
        "log form; error / error(beta = inf) <= 1.06",
        SOLVERS_PAGE,
    ),
    Claim(
        "inhom_gamma1p5.events",
        "inhom_gamma1p5_events.csv",
        lambda d: _g1p5_events(d),
        "on every mapped grid that collapses and is followed past it ({} of {} runs) sigma_v falls below 0.05 at "
        "t = {} (lambda = 10) and {} (lambda = 5) and is back above 0.05 by t = {} and {}, at T_b or before it.  "
        "Its minimum over the whole record is {} and {}; on {} of the {} runs that minimum comes after the return, "
        "in a second dip that does not reach 0, and at T_b sigma_v is {} and {} times that minimum.  "
        "The uniform lambda = 5 reference is back above 0.05 by t = {}; the uniform lambda = 10 one falls to {} "
        "at t = {} and is rising at its end ({} at t = {}), still below the threshold",
        "inhom_gamma1p5_events.csv: followed runs below 0.05, per case and grid kind",
    ),
    Claim(
        "inhom_gamma1p5.grids",
        "inhom_gamma1p5_resolution.csv",
        lambda d: tuple(
            f"{d[(d['lambda'] == lam) & (d.grid == g)][c].iloc[0]:.3f}"
            for g, c in (
                ("121 x 201 uniform", "t(sigma_v < 0.05)"),
                ("41 x 41", "t(sigma_v < 0.05)"),
                ("61 x 61", "T_b"),
                ("61 x 61", "sigma_v (end)"),
            )
            for lam in (10.0, 5.0)
        ),
        "(dv = 0.05, coarser in v than the maps make it) {} and {}.  On 41 x 41 it comes later ({}, {}); "
        "the 61 x 61 runs stop on the paper's criterion before it (t = {} and {}, sigma_v {} and {})",
        "per grid: t(sigma_v < 0.05), T_b, sigma_v (end)",
    ),
    Claim(
        "tab_g2bu.level_sets",
        "tab_g2bu.csv",
        _level_sets,
        "(lambda = 220, 260: {} and {} split slice-steps, second peaks {} and {}; lambda >= 280: {}-{} split "
        "slice-steps, second peaks up to {}; of 2-3.5e4 slice-steps, against a main peak of about 11)",
        "split slice-steps, secondary peak (n_v = 201)",
    ),
    Claim(
        "tab_g2bu.level_sets_nv",
        "tab_g2bu.csv",
        lambda d: (
            tuple(
                str(d[(d["lambda"] == 310) & (d.n_v == n)]["split slice-steps"].iloc[0].split(" /")[0])
                for n in (201, 401)
            )
            + tuple(f"{d[(d['lambda'] == 310) & (d.n_v == n)]['secondary peak'].iloc[0]:.2f}" for n in (201, 401))
        ),
        "doubling N_v cuts the split slice-steps for lambda = 310 from {} to {} and the largest second peak "
        "from {} to {}",
        "lambda = 310, n_v = 201 and 401",
    ),
    # docs/guides/reproducing.md
    Claim(
        "readme.tab_bu",
        "tab_bu.csv",
        lambda d: (
            str(int(within(d, 0.03).sum())),
            str(len(d)),
            _g(_entry(d, "g1", 1e-3 / 16, 0.00125), 5),
            str(len(d.drop_duplicates(["data", "dt"]))),
            f"{d.drop_duplicates(['data', 'dt']).seconds.sum():.0f}",
        ),
        "full `tab_bu` {} of {} entries within 0.03 of the paper's, the g1 entry at the smallest eps_v and dt {} "
        "against the exact 0.5 (its {} runs, one per data and dt, take {} s in all)",
        "as tab_bu.within, tab_bu.target; the seconds of each (data, dt) run once (every eps_v of a column is "
        "read off one run)",
        REPRODUCING_PAGE,
    ),
    Claim(
        "readme.inhom_gamma3",
        "inhom_gamma3.csv",
        _seconds,
        "`inhom_gamma3` {} s; full `tab_g2bu`",
        "sum of seconds",
        REPRODUCING_PAGE,
    ),
    Claim(
        "readme.g3_g2bu",
        "tab_g2bu.csv",
        lambda d: (f"{d.seconds.sum():.0f}", str(int(d[d.n_v == 201]["within 0.005"].sum()))),
        "full `tab_g2bu` {} s, {} of 9 blow-up times within 0.005 of the paper's",
        "sum of seconds; within 0.005 at n_v = 201",
        REPRODUCING_PAGE,
    ),
    Claim(
        "gk1_final",
        "gk1_final.md",
        _md_number(r"\|\s+0\.5 \|\s+([0-9.]+) \|\s+[0-9.e-]+ \|\s+([0-9.]+) \|\s+([0-9.]+) \|"),
        "max f {} at t = 0.5, {} of the mass within |v| <= 0.01 and {} within 0.05",
        "gk1_final.md table",
    ),
    Claim(
        "explicit_figures",
        "explicit_figures.csv",
        lambda d: (
            f"{d['max abs(X numerical - closed form)'].iloc[:2].max():.0e}",
            f"{d['crossing time (numerical)'].iloc[2]:.5f}",
            f"{d['crossing time (closed form)'].iloc[2]:.5f}",
        ),
        "the numerical characteristics of `eq` follow the closed form to {}; the `eqgamma` one crosses x = 0 "
        "at t = {} (closed form {})",
        "explicit_figures.csv",
    ),
    # explicit
    Claim(
        "explicit.widths",
        "explicit.csv",
        lambda d: tuple(
            f"{d[(d['lambda'] == lam) & np.isclose(d['(T-t)/T'], 1e-8)]['width 1/sqrt(a)'].iloc[0]:.2g}"
            for lam in (220.0, 280.0, 300.0, 309.8, 320.0, 400.0)
        ),
        "The width at (T - t)/T = 1e-8 is {}, {}, {} for lambda = 220, 280, 300 (growing), {} at 309.8 "
        "(the threshold 20 sqrt(240) = 309.84), {} and {} for 320 and 400 (closing)",
        "width 1/sqrt(a) at (T-t)/T = 1e-8",
    ),
    Claim(
        "explicit.agreement",
        "explicit.csv",
        lambda d: tuple(
            f"{d[np.isclose(d['(T-t)/T'], e)][['rho rel. diff', 'm rel. diff']].to_numpy().max():.0e}"
            for e in (0.1, 1e-8)
        ),
        "agrees with ``rhot`` and ``mt`` to {} at (T - t)/T = 0.1 and to {} at 1e-8",
        "max rel. diff over lambda",
    ),
    # gamma = 2
    Claim(
        "tab_g2bu.T_b",
        "tab_g2bu.csv",
        lambda d: (
            str(int(d[d.n_v == 201]["within 0.005"].sum())),
            f"{d[d.n_v == 201]['T_b - paper'].max():.4f}",
            f"{d[d.n_v == 201]['T_b - paper'].min():.4f}",
            f"{d[(d.n_v == 401)].T_b.iloc[0]:.5f}",
        ),
        "**T_b: {} of 9 entries within 0.005 of the paper's** (differences {} to {})",
        "n_v = 201 rows; and the n_v = 401 entry",
    ),
    Claim(
        "tab_g2bu.order",
        "tab_g2bu.csv",
        _g2bu_order,
        "T_b falls from {} (220) to {} (310){}.  At twice the velocity resolution (N_v = 401) lambda = 310 gives {}",
        "T_b at lambda = 220, 310 (N_v = 201), the first pair out of order if any, and lambda = 310 at N_v = 401",
    ),
    Claim(
        "tab_g2bu.ratio",
        "tab_g2bu.csv",
        lambda d: (", ".join(f"{x:.2f}" for x in d[d.n_v == 201]["log ratio at T_b"]),),
        "and is {} at T_b",
        "log ratio at T_b, n_v = 201",
    ),
    Claim(
        "scale.newton.gamma3",
        "../bench_scale_newton.csv",
        lambda d: _scale_row(d, 3.0, "structured (default)"),
        "| gamma = 3, structured (default) | {} ({}) | {} ({}) | {} ({}) | {} ({}) |",
        "medians, wall (CPU), N_v = 121, 481, 1025; exponents log(t481/t121)/log(481/121)",
        SCALE_THREADS_PAGE,
    ),
    Claim(
        "scale.newton.gamma1p5",
        "../bench_scale_newton.csv",
        lambda d: _scale_row(d, 1.5, "structured (default)"),
        "| gamma = 3/2, structured (default) | {} ({}) | {} ({}) | {} ({}) | {} ({}) |",
        "as scale.newton.gamma3",
        SCALE_THREADS_PAGE,
    ),
    Claim(
        "scale.newton.dense3",
        "../bench_scale_newton.csv",
        lambda d: _scale_row(d, 3.0, "dense Cholesky"),
        "| gamma = 3, dense Cholesky | {} ({}) | {} ({}) | | {} ({}) |",
        "as scale.newton.gamma3, dense rows",
        SCALE_THREADS_PAGE,
    ),
    Claim(
        "scale.newton.dense1p5",
        "../bench_scale_newton.csv",
        lambda d: _scale_row(d, 1.5, "dense Cholesky"),
        "| gamma = 3/2, dense Cholesky | {} ({}) | {} ({}) | | {} ({}) |",
        "as scale.newton.gamma3, dense rows",
        SCALE_THREADS_PAGE,
    ),
    Claim(
        "scale.newton.gamma4",
        "../bench_scale_gamma4_newton.csv",
        lambda d: _scale_row(d, 4.0, "structured (default)"),
        "| gamma = 4, structured (default) | {} ({}) | {} ({}) | {} ({}) | {} ({}) |",
        "as scale.newton.gamma3, gamma = 4 (low-rank path)",
        SCALE_THREADS_PAGE,
    ),
    Claim(
        "scale.newton.dense4",
        "../bench_scale_gamma4_newton.csv",
        lambda d: _scale_row(d, 4.0, "dense Cholesky"),
        "| gamma = 4, dense Cholesky | {} ({}) | {} ({}) | | {} ({}) |",
        "as scale.newton.gamma3, gamma = 4 dense rows",
        SCALE_THREADS_PAGE,
    ),
    Claim(
        "scale.step",
        "../bench_scale_step.csv",
        _scale_step,
        "at 481 x 481 takes {} s wall ({} s CPU; with the dense Cholesky {} s).  At 1025 x 1025 a step takes "
        "{} s wall ({} s CPU; collision {} s, refinement {} s, transport {} s; the slowest slice needs {} "
        "Newton iterations), peak memory {} GiB.",
        "wall and CPU seconds per step, split, max Newton iterations, peak RSS",
        SCALE_THREADS_PAGE,
    ),
    Claim(
        "scale.loaded",
        "../bench_scale_loaded_step.csv",
        lambda d: (f"{d.wall_per_step_s.iloc[0]:.2f}",),
        "longer wall times: {} s for the 481 x 481 step",
        "the 481 x 481 structured row of the loaded run",
        SCALE_THREADS_PAGE,
    ),
)


_TIMED = {  # entry -> the timing file that measured it; not the summary itself (it reads that file)
    e: "../regenerate_timing.csv"
    for e in (
        "tab_bu",
        "tab_bu_tb2",
        "ibu",
        "gk1_records",
        "inhom_gamma3",
        "explicit",
        "mesh_maps",
        "inhom_gamma1p5",
        "tab_g2bu",
        "tab_bu_traces",
        "property_budget",
        "tab_bu_beta_scan",
        "explicit_figures",
        "gk1_final",
        "fisher_width",
        "ibu_panels",
        "g2bu_loglog",
        "g2bu_records",
        "gk3_panels",
        "gk2_bu",
        "explicit2_sketch",
    )
}


def _regenerate_total(d: pd.DataFrame) -> tuple[str, ...]:
    ok = d[d.returncode == 0]
    loads = pd.concat([ok.load_before, ok.load_after])
    return (
        f"{ok.wall_s.sum():.0f}",
        f"{ok.wall_s.sum() / 60:.0f}",
        str(len(ok)),
        f"{ok.cpu_s.sum():.0f}",
        f"{loads.min():.0f}-{loads.max():.0f}",
        f"{ok.cpu_s.sum() / 2 / 60:.0f}",
    )


CLAIMS += (
    Claim(
        "regenerate.total",
        "../regenerate_timing.csv",
        _regenerate_total,
        "**Regenerating the section took {} s ({} min) of wall time over {} entries, {} s of CPU**, on this "
        "2-core machine (1-minute load {}, in the CSV): two idle "
        "cores need at least half the CPU time, {} min,",
        "sum of wall_s and cpu_s over the entries that finished; load averages before and after each",
    ),
    Claim(
        "regenerate.readme",
        "../regenerate_timing.csv",
        lambda d: (f"{d[d.returncode == 0].wall_s.sum() / 60:.0f}", f"{d[d.returncode == 0].cpu_s.sum() / 60:.0f}"),
        "every `jko-cvx reproduce` entry, fresh, on 2 workers, took {} min of wall time and {} min of CPU",
        "sums over the entries",
        REPRODUCING_PAGE,
    ),
    Claim(
        "regenerate.inhom_gamma1p5",
        "../regenerate_timing.csv",
        lambda d: tuple(f"{d.loc[d.entry == 'inhom_gamma1p5', c].iloc[0]:.0f}" for c in ("wall_s", "cpu_s")),
        "`inhom_gamma1p5` alone took {} s ({} s CPU)",
        "its row",
    ),
    Claim(
        "regenerate.crawl",
        "inhom_gamma1p5_resolution.csv",
        lambda d: (str(int(d[(d.case == "before") & (d.grid == "121 x 121")].steps.iloc[0])),),
        "(121 x 121, lambda = 10: {} steps)",
        "steps of that run",
    ),
)


def _rounding_sensitivity(before: pd.DataFrame, now: pd.DataFrame) -> tuple[str, ...]:
    """T_b of the 121 and 81 mapped runs from the previous code against today's; largest change of a collapse time."""
    tb = {
        (g, c): float(before[(before.grid == g) & (before.case == c)].T_b.iloc[0])
        for g in ("121 x 121", "81 x 81")
        for c in ("before", "after")
    }
    tb_now = float(now[(now.grid == "81 x 81") & (now.case == "before")].T_b.iloc[0])
    collapse = "t(sigma_v < 0.05)"
    change = (now.set_index(["case", "grid"])[collapse] - before.set_index(["case", "grid"])[collapse]).abs()
    coarse = change[change.index.get_level_values("grid") == "41 x 41"].max()
    fine = change[change.index.get_level_values("grid").isin(["81 x 81", "121 x 121"])].max()
    return (
        f"{tb[('121 x 121', 'before')]:.3f}",
        f"{tb[('121 x 121', 'after')]:.3f}",
        f"{tb[('81 x 81', 'before')]:.4f}",
        f"{tb_now:.4f}",
        f"{coarse:.2g}",
        f"{fine:.2g}",
    )


CLAIMS += (
    Claim(
        "inhom_gamma1p5.rounding",
        "inhom_gamma1p5_resolution_previous_code.csv",
        _rounding_sensitivity,
        "gave {} and {} (and {} against {} on 81 x 81), while the density-collapse times changed by at most {} on "
        "41 x 41 and {} on 81 x 81 and 121 x 121",
        "the previous code's resolution table (kept beside today's) against today's",
        also=("inhom_gamma1p5_resolution.csv",),
    ),
)
_SECTION_TOTAL = re.compile(
    r"\*\*Total wall time (\d+) s \(([\d.]+) min\) for (\d+) of (\d+) entries; CPU (\d+) s; "
    r"exit status (-?\d+)\.\*\*  Goal: 20 min: (met|not met)\."
)


def _section_total(text: str) -> tuple[str, ...]:
    """``jko-cvx reproduce section --fresh``: wall s, min, entries done, of, CPU s, the goal's verdict.

    Refused unless every entry finished and the command exited 0 (a partial run times nothing).
    """
    m = _SECTION_TOTAL.search(text)
    if m is None:
        raise ValueError("regenerate_timing_section.md: no total line")
    wall, minutes, done, of, cpu, status, verdict = m.groups()
    if done != of or status != "0":
        raise ValueError(f"regenerate_timing_section.md: {done} of {of} entries, exit status {status}")
    return wall, f"{float(minutes):.0f}", done, cpu, verdict


def _section_code(text: str) -> tuple[str, ...]:
    """The package hash and the 1-minute loads recorded with the section's timing."""
    m = re.search(r"code ([0-9a-f]{12}); 1-minute load ([\d.]+) before, ([\d.]+) after", text)
    if m is None:
        raise ValueError("regenerate_timing_section.md: no code and load line")
    return m.group(1), f"{float(m.group(2)):.1f}", f"{float(m.group(3)):.1f}"


CLAIMS += (
    Claim(
        "regenerate.section",
        "../regenerate_timing_section.md",
        _section_total,
        "**`jko-cvx reproduce section --fresh --workers 2` regenerated the section in {} s ({} min) of wall "
        "time, {} entries, {} s of CPU; the goal of 20 minutes is {}**",
        "the total line of the section's timing (refused unless every entry finished)",
    ),
    Claim(
        "regenerate.section.readme",
        "../regenerate_timing_section.md",
        _section_total,
        "`jko-cvx reproduce section --fresh --workers 2` regenerated it in {} s ({} min) of wall time, {} "
        "entries, {} s of CPU: the goal of 20 minutes is {}",
        "the total line of the section's timing",
        REPRODUCING_PAGE,
    ),
    Claim(
        "regenerate.section.code",
        "../regenerate_timing_section.md",
        _section_code,
        "(package sha256 {}, 1-minute load {} before and {} after",
        "the record line of the section's timing",
    ),
)


CLAIMS += (
    *(
        Claim(
            f"regenerate.section.{label}",
            f"../regenerate_timing_section_2026-12-02T{stamp}.md",
            _section_total,
            "{} s ({} min) of wall time, {} entries, {} s of CPU: the goal {}",
            f"the total line of the section's timing finished at {stamp[:2]}:{stamp[2:]} UTC",
            REPRODUCING_PAGE,
        )
        for label, stamp in (("earlier", "0549"), ("first_rerun", "0753"))
    ),
    Claim(
        "regenerate.section.earlier_load",
        "../regenerate_timing_section_2026-12-02T0549.md",
        lambda text: _section_code(text)[1:2],
        "(`regenerate_timing_section_2026-12-02T0549.md`, 1-minute load {} before it started)",
        "the record line of the 05:49 timing",
        REPRODUCING_PAGE,
    ),
)


def _tridiagonal_fix(before: pd.DataFrame, now: pd.DataFrame) -> tuple[str, ...]:
    """``tab_g2bu`` before and after the batched tridiagonal fix: rows whose max f moved, the largest
    relative change, and whether T_b and the step counts moved at all."""
    if list(before["lambda"]) != list(now["lambda"]) or list(before.n_v) != list(now.n_v):
        raise ValueError("tab_g2bu_previous_code.csv: other rows than tab_g2bu.csv")
    moved = before.max_f != now.max_f
    rel = ((before.max_f - now.max_f).abs() / now.max_f).max()
    same = (before.T_b.equals(now.T_b), before.steps.equals(now.steps))
    return (
        str(int(moved.sum())),
        str(len(now)),
        f"{rel:.0e}",
        "unchanged" if all(same) else "changed",
    )


CLAIMS += (
    Claim(
        "tab_g2bu.tridiagonal_fix",
        "tab_g2bu_previous_code.csv",
        _tridiagonal_fix,
        "max f moved in {} of the {} `tab_g2bu` runs, by at most {} relative; T_b and the step counts {}",
        "the previous code's tab_g2bu.csv (kept beside today's) against today's",
        also=("tab_g2bu.csv",),
    ),
)


def _ab_entry(d: pd.DataFrame) -> tuple[str, ...]:
    """gk2_bu from the old and the new checkout, interleaved: CPU ranges and the change of the medians."""
    rows = d[(d.entry == "gk2_bu") & (d.returncode == 0)]
    old, new = rows[rows.side == "old"].cpu_s, rows[rows.side == "new"].cpu_s
    if len(old) < 2 or len(new) < 2:
        raise ValueError("ab_entry.csv: fewer than two runs of each side")
    return (
        f"{old.min():.0f}",
        f"{old.max():.0f}",
        f"{new.min():.0f}",
        f"{new.max():.0f}",
        f"{100 * (1 - new.median() / old.median()):.0f}",
    )


CLAIMS += (
    Claim(
        "regenerate.ab",
        "../ab_entry.csv",
        _ab_entry,
        "side by side, interleaved (`results/ab_entry.csv`), the old and the new code's `gk2_bu` took {}-{} and "
        "{}-{} s of CPU ({} % less)",
        "cpu_s of the gk2_bu runs by side; 1 - median(new)/median(old)",
    ),
)
# the NAME table of studies/README.md: each entry's measured wall time (fresh full form, 2 workers)
CLAIMS += tuple(
    Claim(f"wall.{entry}", file, _wall(entry), f"| `{entry}` | {{}} s |", "wall_s of the entry")
    for entry, file in _TIMED.items()
)


def _gc_collapse(d: pd.DataFrame, case: str, grid: str) -> tuple[str, ...]:
    """The density-collapse times of one case and grid kind on n = 121, 241, 481 (a dash where none)."""
    rows = d[(d.case == case) & (d.grid == grid)].set_index("n")["t(sigma_v < 0.05)"]
    return tuple("-" if n not in rows.index or np.isnan(rows[n]) else f"{rows[n]:.3f}" for n in (121, 241, 481))


def _gc_certified(d: pd.DataFrame) -> tuple[str, ...]:
    """The gamma = 3/2 runs that stop on the density criterion and the continued ones that go on to t_end; refused
    unless every run has no failed slice and stopped where its kind says."""
    continued = d.grid == "continued uniform"
    if (d["failed slices"] > 0).any() or not d[~continued].stop.str.startswith("min spread_v").all():
        raise ValueError("grid_convergence.csv: a run with failed slices or another stop than the density collapse")
    if not (d[continued].stop == "reached t_end").all():
        raise ValueError("grid_convergence.csv: a continued run that stopped before t_end")
    return str(int((~continued).sum())), str(int(continued.sum()))


def _gc_g2bu(d: pd.DataFrame) -> tuple[str, ...]:
    """lambda = 310 on the three grids; the ranges of |T_b(401) - T_b(201)| and |T_b(801) - T_b(401)|; T_b at 801."""
    r = d.set_index("lambda")
    t = [f"{r.loc[310, f'T_b (N_v = {n})']:.5f}" for n in (201, 401, 801)]
    d1 = (r["T_b (N_v = 401)"] - r["T_b (N_v = 201)"]).abs()
    d2 = (r["T_b (N_v = 801)"] - r["T_b (N_v = 401)"]).abs()
    fine = r["T_b (N_v = 801)"]
    ranges = (f"{d1.min():.4f}-{d1.max():.4f}", f"{d2.min():.4f}-{d2.max():.4f}")
    return (*t, *ranges, f"{fine.min():.4f}", f"{fine.max():.4f}")


CLAIMS += (
    Claim(
        "grid_convergence.before",
        "grid_convergence.csv",
        lambda d: (*_gc_collapse(d, "before", "mapped"), *_gc_collapse(d, "before", "uniform")),
        "lambda = 10: {}, {}, {} on the mapped grids and {}, {}, {} on the uniform ones",
        "t(sigma_v < 0.05), n = 121, 241, 481",
    ),
    Claim(
        "grid_convergence.after",
        "grid_convergence.csv",
        lambda d: (*_gc_collapse(d, "after", "mapped"), *_gc_collapse(d, "after", "uniform")),
        "lambda = 5: {}, {}, {} on the mapped grids and {}, {}, {} on the uniform ones",
        "t(sigma_v < 0.05), n = 121, 241, 481",
    ),
    Claim(
        "grid_convergence.certified",
        "grid_convergence.csv",
        _gc_certified,
        "all {} gamma = 3/2 runs reach the density collapse with every collision step certified (and the {} "
        "continued uniform runs reach t = 0.7 so)",
        "rows of grid_convergence.csv (failed slices 0; stop = the density criterion, or t_end for the continued runs)",
    ),
    Claim(
        "grid_convergence.g2bu",
        "grid_convergence_g2bu.csv",
        _gc_g2bu,
        "lambda = 310 gives {}, {}, {} on N_v = 201, 401, 801; over the nine lambda T_b moves by {} from 201 to "
        "401 and by {} from 401 to 801, and lies in [{}, {}] at 801",
        "T_b columns of grid_convergence_g2bu.csv",
    ),
)


def _gc_wall(text: str) -> tuple[str, ...]:
    """The sweep's wall time in minutes, from the report's last line."""
    found = re.search(r"Sweep wall time (\d+) s", text)
    if found is None:
        raise ValueError("grid_convergence.md: no sweep wall time (a report built from a stopped sweep)")
    return (f"{float(found.group(1)) / 60:.0f}",)


def _gc_gap(d: pd.DataFrame) -> tuple[str, ...]:
    """lambda = 10: |mapped - uniform| collapse time at n = 121 and 481."""
    t = d[d.case == "before"].pivot(index="n", columns="grid", values="t(sigma_v < 0.05)")
    gap = (t["uniform"] - t["mapped"]).abs()
    return (f"{gap[121]:.3f}", f"{gap[481]:.3f}")


def _gc_sigma(d: pd.DataFrame) -> tuple[str, ...]:
    r = d[(d.case == "before") & (d.grid == "mapped") & (d.quantity == "sigma_v(t=0.1)")].iloc[0]
    return (*(f"{r[f'n = {n}']:.3f}" for n in (121, 241, 481)), f"{r.order:.1f}")


def _gc_failure_detail(text: str) -> tuple[str, ...]:
    import json

    fail = json.loads(text)["failed solves"][-1]
    if not fail["largest certified kkt_residual"] < 1e-8:  # the prose says "every other is below 1e-8"
        raise ValueError("grid_convergence_failure_before_fix.json: a certified slice above 1e-8")
    return (
        f"{fail['kkt_residual'][0]:.1e}",
        str(fail["iterations"][0]),
        f"{fail['f_star min'][0]:.1e}",
    )


CLAIMS += (
    Claim(
        "grid_convergence.gap",
        "grid_convergence.csv",
        _gc_gap,
        "for lambda = 10 the gap falls from {} at 121 to {} at 481",
        "|uniform - mapped| collapse time",
    ),
    Claim(
        "grid_convergence.sigma",
        "grid_convergence_gamma1p5.csv",
        _gc_sigma,
        "lambda = 10 mapped at t = 0.1: {}, {}, {}, observed order {}",
        "sigma_v(t=0.1) row and its order",
    ),
    Claim(
        "grid_convergence.wall",
        "grid_convergence.md",
        _gc_wall,
        "The whole sweep ran once on one code, 2 workers, {} min of wall time",
        "the report's last line, seconds / 60",
        REPRODUCING_PAGE,
    ),
    Claim(
        "inhom_gamma1p5.crawl_steps",
        "inhom_gamma1p5.csv",
        lambda d: (str(int(d[(d.case == "before") & (d.n == 121)].steps.iloc[0])),),
        "(121 x 121, lambda = 10: {} steps)",
        "steps of the lambda = 10 run on 121 x 121",
    ),
    Claim(
        "grid_convergence.wall_table",
        "grid_convergence.md",
        _gc_wall,
        "| `grid_convergence` | {} min (one sweep, below) |",
        "as grid_convergence.wall",
    ),
    Claim(
        "grid_convergence.cost481",
        "grid_convergence.csv",
        lambda d: tuple(
            f"{d[(d.case == c) & (d.grid == 'mapped') & (d.n == 481)].seconds.iloc[0] / 60:.0f}"
            for c in ("before", "after")
        ),
        "(the mapped 481 x 481 runs: {} min for lambda = 10 and {} min for lambda = 5",
        "seconds / 60 of that run",
        REPRODUCING_PAGE,
    ),
    Claim(
        "grid_convergence.failure_t",
        "../grid_convergence_failure_before_fix.json",
        lambda text: (f"{json.loads(text)['t']:.3f}",),
        "run stopped after t = {} (its last accepted step) on a collision step that Newton did not certify",
        "t of the failed run's record",
    ),
    Claim(
        "grid_convergence.failure_detail",
        "../grid_convergence_failure_before_fix.json",
        _gc_failure_detail,
        "one slice ends at KKT residual {} after {} Newton iterations while every other is below 1e-8, and its "
        "f* reaches {}",
        "the failed solve's record",
    ),
)


def _gc_no_floor(text: str) -> tuple[str, ...]:
    """The rerun without the v-floor: where it stopped, and the failed slice's smallest f* and its v-line."""
    import json

    run = json.loads(text)
    if run["v.floor_every_step"] or not run["failed solves"]:
        raise ValueError("grid_convergence_failure_no_floor.json: not a failed run without the v-floor")
    fail = run["failed solves"][0]
    return (
        f"{run['t']:.3f}",
        f"{fail['f_star min'][0]:.1e}",
        str(fail["f_star argmin v index"][0]),
        str(fail["v points"]),
        f"{fail['v-line mass at that index'][0]:.1e}",
    )


def _gc_floored(text: str) -> tuple[str, ...]:
    """The rerun with the v-floor: its collapse time; refused unless every solve was certified."""
    import json

    run = json.loads(text)
    if not run["v.floor_every_step"] or run["failed solves"] or run["collapse t (sigma_v < 0.05)"] is None:
        raise ValueError("grid_convergence_failure.json: not a certified run to the collapse with the v-floor")
    return (f"{run['collapse t (sigma_v < 0.05)']:.3f}", str(run["steps"]))


CLAIMS += (
    Claim(
        "grid_convergence.no_floor",
        "../grid_convergence_failure_no_floor.json",
        _gc_no_floor,
        "still stops, at t = {}: the failed slice's f* is smallest ({}) at v index {} of {}, an edge line whose "
        "mass over x is {}",
        "the rerun with the tilt fixed and no v-floor",
    ),
    Claim(
        "grid_convergence.floored",
        "../grid_convergence_failure.json",
        _gc_floored,
        "the same point then collapses at t = {} after {} steps, every solve certified",
        "the rerun with v.floor_every_step",
    ),
    Claim(
        "grid_convergence.uniform_order",
        "grid_convergence_gamma1p5.csv",
        lambda d: (
            f"{d[(d.case == 'after') & (d.grid == 'uniform') & (d.quantity == 't(sigma_v < 0.05)')].order.iloc[0]:.1f}",
        ),
        "observed order about {}",
        "order of the lambda = 5 uniform collapse times",
    ),
)


def _gc_g2bu_steps(d: pd.DataFrame) -> tuple[str, ...]:
    """The range of d1/d2 over lambda, and whether T_b(801) decreases strictly in lambda."""
    ratio = d["T_b d1"] / d["T_b d2"]
    fine = d.sort_values("lambda")["T_b (N_v = 801)"].to_numpy()
    monotone = "decreases monotonically" if (np.diff(fine) < 0).all() else "does not decrease monotonically"
    return (f"{ratio.min():.1f}", f"{ratio.max():.1f}", monotone)


CLAIMS += (
    Claim(
        "grid_convergence.g2bu_steps",
        "grid_convergence_g2bu.csv",
        lambda d: _gc_g2bu_steps(d)[:2],
        "The steps do not shrink (the ratios d1/d2 lie between {} and {}; `grid_convergence_g2bu.csv`)",
        "T_b d1 / T_b d2 over lambda",
    ),
    Claim(
        "grid_convergence.g2bu_monotone",
        "grid_convergence_g2bu.csv",
        lambda d: _gc_g2bu_steps(d)[2:],
        "At 801 T_b {} in lambda",
        "the signs of the differences of T_b (N_v = 801) in lambda",
    ),
)


# --- the solver guide's benchmark section (studies/bench_collision.py): every cell of its tables ----------------------

_BENCH_SIZES = (61, 121, 241, 481)
_BENCH_METHODS = {
    "perspective": ("conic", "sqp", "newton", "newton_compiled", "nlp"),
    "log": ("sqp", "newton", "newton_compiled", "nlp"),
}


def _opt(x: float, fmt: str) -> str:
    """``x`` formatted, or empty where the method has no such figure (NaN)."""
    return "" if pd.isna(x) else format(x, fmt)


def _bench_row(d: pd.DataFrame, fisher: str, n: int, method: str) -> tuple[str, ...]:
    """A row of the guides' one-step table: median s, iterations, [DC passes,] KKT, build s, in-solver s."""
    rows = d[(d.fisher == fisher) & (d.N == n) & (d.method == method)]
    if len(rows) != 1:
        raise ValueError(f"bench_collision.csv: expected one row for {fisher}, N = {n}, {method}")
    r = rows.iloc[0]
    inside = r.clarabel_s if method == "conic" else r.ipopt_s
    cells = [_g(r.median_s, 3), f"{int(r.iterations)}"]
    if fisher == "perspective":
        cells.append(_opt(r.passes, ".0f"))
    return (*cells, f"{r.kkt_residual:.1e}", _opt(r.compile_s, ".3f"), _opt(inside, ".3f"))


def _bench_ratio(d: pd.DataFrame, fisher: str, a: str, b: str) -> str:
    """The ratios of the medians a / b at N = 61, 121, 241, 481, comma-separated."""
    piv = d[d.fisher == fisher].pivot(index="N", columns="method", values="median_s")
    return ", ".join(_g(piv[a][n] / piv[b][n], 3) for n in _BENCH_SIZES)


def _bench_ratios(d: pd.DataFrame) -> tuple[str, ...]:
    return (
        _bench_ratio(d, "perspective", "conic", "newton"),
        _bench_ratio(d, "perspective", "sqp", "newton"),
        _bench_ratio(d, "log", "sqp", "newton"),
        _bench_ratio(d, "perspective", "nlp", "conic"),
        _bench_ratio(d, "perspective", "nlp", "sqp"),
        _bench_ratio(d, "log", "nlp", "sqp"),
        _bench_ratio(d, "perspective", "conic", "newton_compiled"),
        _bench_ratio(d, "perspective", "sqp", "newton_compiled"),
        _bench_ratio(d, "log", "sqp", "newton_compiled"),
        _bench_ratio(d, "perspective", "newton", "newton_compiled"),
        _bench_ratio(d, "log", "newton", "newton_compiled"),
    )


def _bench_newton_sqp(d: pd.DataFrame) -> tuple[str, ...]:
    """SQP / Newton over both Fisher forms, beta = 10 and 1000 and every N: ranges, and the compiled path's use."""
    return (
        _g(d["sqp/newton_compiled"].min(), 3),
        f"{d['sqp/newton_compiled'].max():.0f}",
        _g(d["sqp/newton"].min(), 3),
        f"{d['sqp/newton'].max():.0f}",
        f"{int(d.compiled_used.sum())}",
        f"{len(d)}",
    )


def _bench_growth(d: pd.DataFrame, fisher: str, method: str) -> str:
    """The fitted exponent p of median ~ N^p over N = 61 ... 481."""
    rows = d[(d.fisher == fisher) & (d.method == method)].sort_values("N")
    return f"{np.polyfit(np.log(rows.N), np.log(rows.median_s), 1)[0]:.1f}"


def _bench_cvxpy(d: pd.DataFrame) -> tuple[str, ...]:
    """nlp's per-solve reduction chain (ms), nlp's build and conic's compile (s): ranges over the rows."""
    nlp, conic = d[d.method == "nlp"], d[d.method == "conic"]
    return (
        f"{1e3 * nlp.canonicalize_s.min():.1f}",
        f"{1e3 * nlp.canonicalize_s.max():.1f}",
        f"{nlp.compile_s.min():.3f}",
        f"{nlp.compile_s.max():.3f}",
        f"{conic.compile_s.min():.3f}",
        f"{conic.compile_s.max():.3f}",
    )


def _bench_nlp(d: pd.DataFrame) -> tuple[str, ...]:
    """nlp's medians (both forms), nlp / Newton (both forms) and nlp / conic (perspective): ranges over N."""
    piv = d.pivot_table(index=["fisher", "N"], columns="method", values="median_s")
    nlp_newton = piv.nlp / piv.newton
    nlp_conic = (piv.nlp / piv.conic).dropna()
    return (
        _g(piv.nlp.min(), 2),
        _g(piv.nlp.max(), 2),
        f"{nlp_newton.min():.0f}",
        f"{nlp_newton.max():.0f}",
        f"{nlp_conic.min():.1f}",
        f"{nlp_conic.max():.1f}",
    )


def _single_path(text: str) -> tuple[str, ...]:
    """The range of branch/main over the one-problem table of ``newton_single_path.md``."""
    section = text.split("## One problem", 1)[1].split("\n## ", 1)[0]
    ratios = [float(line.split("|")[6]) for line in section.splitlines() if re.match(r"\| \d", line)]
    return (f"{min(ratios):.1f}", f"{max(ratios):.1f}")


def _bench_beta_row(d: pd.DataFrame, beta: float) -> tuple[str, ...]:
    r = d.set_index("beta").loc[beta]
    return (
        _g(r.conic_s, 3),
        f"{r.conic_kkt:.1e}",
        _g(r.sqp_s, 3),
        f"{int(r.sqp_it)}",
        _g(r.newton_s, 3),
        f"{int(r.newton_it)}",
        _g(r["conic/newton"], 3),
        _g(r["sqp/newton"], 3),
        _g(r.newton_compiled_s, 3),
        _g(r["conic/newton_compiled"], 3),
    )


def _bench_batch(d: pd.DataFrame) -> tuple[str, ...]:
    r = d.iloc[0]
    return (
        f"{r.batched_s:.4f}",
        f"{int(r.converged)}",
        f"{int(r.slices)}",
        f"{r.max_kkt:.1e}",
        f"{r.one_at_a_time_s:.3f}",
    )


def _bench_growth_newton(d: pd.DataFrame) -> tuple[str, ...]:
    d = d.sort_values("N")
    return (
        ", ".join(f"{1e3 * t:.2f}" for t in d.newton_s),
        f"{np.polyfit(np.log(d.N), np.log(d.newton_s), 1)[0]:.2f}",
    )


def _bench_claims() -> tuple[Claim, ...]:
    claims = []
    for fisher, methods in _BENCH_METHODS.items():
        cols = 6 if fisher == "perspective" else 5
        for n in _BENCH_SIZES:
            for method in methods:
                claims.append(
                    Claim(
                        f"bench.{fisher}.{n}.{method}",
                        "../bench_collision.csv",
                        lambda d, f=fisher, n=n, m=method: _bench_row(d, f, n, m),
                        f"| {n} | {method} |" + " {} |" * cols,
                        f"{fisher} Fisher, N = {n}, {method}: median s, iterations, "
                        + ("DC passes, " if fisher == "perspective" else "")
                        + "KKT, build s, in-solver s",
                        SOLVERS_PAGE,
                    )
                )
    claims += [
        Claim(
            "bench.ratios",
            "../bench_collision.csv",
            _bench_ratios,
            "Ratios of the medians at N = 61, 121, 241, 481: conic / Newton {} (perspective); SQP / Newton {} "
            "(perspective) and {} (log); nlp / conic {} (perspective); nlp / SQP {} (perspective) and {} (log). "
            "With the compiled Newton iteration (`newton_compiled`): conic / Newton {} (perspective); SQP / Newton "
            "{} (perspective) and {} (log); NumPy Newton / compiled Newton {} (perspective) and {} (log).",
            "medians per solve, bench_collision.csv",
            SOLVERS_PAGE,
        ),
        Claim(
            "bench.growth",
            "../bench_collision.csv",
            lambda d: tuple(
                _bench_growth(d, f, m) for f, m in (("perspective", "nlp"), ("log", "nlp"), ("perspective", "sqp"))
            ),
            "nlp's time grows like N^{} (perspective) and N^{} (log) over N = 61 ... 481, the SQP's like N^{}",
            "least-squares slope of log median against log N",
            SOLVERS_PAGE,
        ),
        Claim(
            "bench.cvxpy",
            "../bench_collision.csv",
            _bench_cvxpy,
            "CVXPY's reduction chain costs nlp {}-{} ms per solve (`canonicalize_s`); nlp's build ({}-{} s) is "
            "cheaper than conic's compile ({}-{} s)",
            "ranges over the N and Fisher forms",
            SOLVERS_PAGE,
        ),
        Claim(
            "bench.nlp",
            "../bench_collision.csv",
            _bench_nlp,
            "{}-{} s per solve at N = 61-481, {}-{}x Newton and {}-{}x the conic re-solve (benchmark below)",
            "ranges over N = 61 ... 481 and both Fisher forms (conic: perspective only)",
            SOLVERS_PAGE,
        ),
        Claim(
            "bench.nlp_iterations",
            "../bench_collision.csv",
            lambda d: (f"{d[d.method == 'nlp'].iterations.min()}", f"{d[d.method == 'nlp'].iterations.max()}"),
            "nlp's iteration count stays between {} and {}",
            "nlp's iterations over N and both Fisher forms",
            SOLVERS_PAGE,
        ),
        Claim(
            "bench.sqp_iterations",
            "../bench_newton.csv",
            lambda d: tuple(f"{int(x)}" for x in d.sort_values("beta").sqp_it),
            "SQP iterations {} / {} / {} / {} for beta = 1 / 3 / 10 / 30",
            "sqp_it of bench_newton.csv",
            PAPER_CHOICES_PAGE,
        ),
        *(
            Claim(
                f"bench.beta.{beta:g}",
                "../bench_newton.csv",
                lambda d, b=beta: _bench_beta_row(d, b),
                f"| {beta:g} |" + " {} |" * 10,
                f"beta = {beta:g}: conic s, KKT, sqp s, iterations, newton s, iterations, ratios, compiled newton s "
                "and conic / compiled newton",
                SOLVERS_PAGE,
            )
            for beta in (1.0, 3.0, 10.0, 30.0)
        ),
        Claim(
            "bench.newton_sqp",
            "../bench_newton_sqp.csv",
            _bench_newton_sqp,
            "over both Fisher forms, beta = 10 and 1000 and N = 61 ... 481 the SQP takes {}-{}x the compiled "
            "Newton's time per solve ({}-{}x the NumPy iteration's); the compiled iteration returned the point in {} "
            "of the {} cells",
            "min and max of sqp/newton_compiled and sqp/newton; compiled_used summed",
            SOLVERS_PAGE,
        ),
        Claim(
            "bench.cli_compiled",
            "../bench_cli_run.csv",
            lambda d: tuple(
                f"{d.set_index('what').loc[w, 'tree_cpu_s']:.2f}"
                for w in ("jko-cvx run", "jko-cvx run, compiled Newton", "jko-cvx run, compiled Newton, cold cache")
            ),
            "the default `jko-cvx run` (48 steps) takes {} s of CPU as it is, {} s with "
            "`--set collision.options.compiled=true` and a warm cache, and {} s on a cold one",
            "tree_cpu_s of bench_cli_run.csv (medians of fresh interpreters)",
            SOLVERS_PAGE,
        ),
        Claim(
            "bench.batch",
            "../bench_newton_batch.csv",
            _bench_batch,
            "Batched Newton, 121 slices of N = 121: {} s ({} of {} slices converged, max KKT {}; one slice at a "
            "time: {} s).",
            "median of the batched solve; the loop over slices",
            SOLVERS_PAGE,
        ),
        Claim(
            "bench.single_path",
            "../newton_single_path.md",
            _single_path,
            "(a batch of one, {}-{}x slower per small solve than the former scalar path",
            "branch/main over the one-problem table",
            SOLVERS_PAGE,
        ),
        Claim(
            "bench.newton_growth",
            "../bench_newton_growth.csv",
            _bench_growth_newton,
            "Newton time per solve against N = 61, 121, 241, 481: {} ms, fitted exponent {}",
            "medians; least-squares slope of log time against log N",
            SOLVERS_PAGE,
        ),
    ]
    return tuple(claims)


CLAIMS += _bench_claims()


# --- the solver guide's cost-growth paragraph and solver-table rows (jko-cvx study cost_growth) ---


def _exponent(d: pd.DataFrame, what: str) -> str:
    rows = d[d.what == what]
    if len(rows) != 1:
        raise ValueError(f"cost_growth_exponents.csv: expected one row {what!r}")
    return f"{rows.exponent.iloc[0]:.1f}"


def _step_at(d: pd.DataFrame, gamma: float, method: str, n: int = 961) -> float:
    rows = d[(d.gamma == gamma) & (d.method == method) & (d.N_v == n)]
    if len(rows) != 1:
        raise ValueError(f"cost_growth_step.csv: expected one row for gamma = {gamma}, {method}, N_v = {n}")
    return float(rows.median_s.iloc[0])


CLAIMS += (
    Claim(
        "cost.exponents",
        "../cost_growth_exponents.csv",
        lambda d: tuple(
            _exponent(d, w)
            for w in (
                "collision step, gamma=1, newton",
                "collision step, gamma=3, newton",
                "collision step, gamma=1, conic",
                "collision step, gamma=3, conic",
                "collision step, gamma=1, sqp",
                "collision step, gamma=3, sqp",
                "time step vs N_x",
                "time step vs N_v",
            )
        ),
        "one Newton step grows like N^{} for gamma = 1 (banded) and N^{} for gamma = 3 (the exact O(N) "
        "semiseparable solve); the conic re-solve like N^{} and N^{}; the paper's SQP like N^{} and N^{} (its "
        "iteration count grows with N).  A whole inhomogeneous time step (gamma = 3) grows like N_x^{} (batched "
        "collision plus transport) and N_v^{}",
        "fitted exponents, cost_growth_exponents.csv",
        SOLVERS_PAGE,
    ),
    Claim(
        "cost.at961",
        "../cost_growth_step.csv",
        lambda d: (
            _g(_step_at(d, 3.0, "sqp"), 2),
            _g(_step_at(d, 1.0, "sqp"), 2),
            _g(_step_at(d, 3.0, "newton"), 2),
            _g(_step_at(d, 1.0, "newton"), 2),
        ),
        "{} s (gamma = 3) and {} s (gamma = 1) per step at N = 961 against Newton's {} s and {} s (`cost_growth.md`)",
        "medians of one collision step at N_v = 961",
        SOLVERS_PAGE,
    ),
    Claim(
        "cost.batch",
        "../cost_growth_batch.csv",
        lambda d: (f"{d.speedup.min():.1f}", f"{d.speedup.max():.1f}", f"{d.B.min()}", f"{d.B.max()}"),
        "{}-{}x faster than B single calls (B = {}-{}, gamma = 3, N = 121): `cost_growth.md`",
        "one-at-a-time / batched over B",
        SOLVERS_PAGE,
    ),
)


# --- the bad-input guide's table (studies/misuse_probe.py): every row ---------------------------------------


_MISUSE_ROWS = 52  # rows of misuse_scene_cli.csv; _misuse_row refuses a file with another count


def _misuse_row(d: pd.DataFrame, i: int) -> tuple[str, ...]:
    """Row ``i`` of the bad-input guide's misuse table: class, input and the message.

    Pipes are escaped for Markdown; a message longer than 170 characters is cut at 167 and
    marked with an ellipsis.
    """
    if len(d) != _MISUSE_ROWS:
        raise ValueError(f"misuse_scene_cli.csv has {len(d)} rows, the guide's table {_MISUSE_ROWS}")
    r = d.iloc[i]
    msg = str(r["message (now)"]).removeprefix("jko-cvx: error: ")
    msg = msg if len(msg) <= 170 else msg[:167] + "..."
    return tuple(str(x).replace("|", "\\|") for x in (r["class"], r["input"], msg))


def _misuse_claims() -> tuple[Claim, ...]:
    return tuple(
        Claim(
            f"misuse.row{i}",
            "../misuse_scene_cli.csv",
            lambda d, i=i: _misuse_row(d, i),
            "| {} | `{}` | {} |",
            f"row {i} of misuse_scene_cli.csv: class, input, message now",
            BAD_INPUT_PAGE,
        )
        for i in range(_MISUSE_ROWS)
    )


CLAIMS += _misuse_claims()


# --- the scenes guide's measured inhom_gamma3 runs (the inhom_gamma3 entry) -------------------------------------------


def _g3_runs(d: pd.DataFrame) -> tuple[str, ...]:
    r = d.set_index("lambda")
    four = r.loc[4.0]
    return (
        f"{four.seconds:.1f}",
        f"{four['mass drift']:.1e}",
        f"{four['momentum drift']:.1e}",
        f"{int(four['moment2 increases'])}",
        ", ".join(f"{r.seconds[lam]:.1f}" for lam in (2.0, 6.0, 8.0, 10.0)),
        str(int(r["blow-up flagged"].astype(bool).sum())),
        _g(r.loc[10.0, "min dx (min)"], 2),
        _g(r.loc[10.0, "min dx at end"], 2),
        f"{r.loc[10.0, 'max f (peak)']:.1f}",
    )


CLAIMS += (
    Claim(
        "readme.inhom_gamma3_runs",
        "inhom_gamma3.csv",
        _g3_runs,
        "lambda = 4 took {} s in its run, no blow-up (the paper's conclusion), mass drift {}, momentum drift {}, "
        "second moment increasing at {} steps.  The other gamma = 3 runs (lambda = 2, 6, 8, 10): {} s; {} of the "
        "five flag blow-up; for lambda = 10 min dx falls to {} and recovers to {} at t = 4 while max f peaks at {}",
        "the lambda rows of inhom_gamma3.csv",
        SCENES_RUNS_PAGE,
    ),
    Claim(
        "readme.momentum_drift",
        "inhom_gamma3.csv",
        lambda d: (f"{d['momentum drift'].max():.1e}",),
        "Momentum drift over the `inhom_gamma3` runs (121 x 121 to t = 4): at most {}",
        "largest momentum drift of inhom_gamma3.csv",
        SCENES_RUNS_PAGE,
    ),
)


# --- the solver guide's `jko-cvx compare` paragraph and solver table (work_precision_step) ----------------------------


def _wps_ranges(d: pd.DataFrame) -> tuple[str, ...]:
    """Median ms ranges over the tolerances, gamma = 1: Newton, the SQP (banded), Clarabel; SCS's KKT at 1e-4."""
    g1 = d[d.problem == "gamma=1"]
    out = []
    for family in ("newton", "sqp:banded", "conic:CLARABEL"):
        ms = 1e3 * g1[g1.family == family].median_s
        out += [_g(ms.min(), 2), _g(ms.max(), 2)]
    scs = g1[(g1.family == "conic:SCS") & (g1.setting == "tol=0.0001")]
    if len(scs) != 1 or scs.status.iloc[0] != "NOT_CERTIFIED":
        raise ValueError("work_precision_step.csv: SCS at tol 1e-4 is no longer one NOT_CERTIFIED row")
    return (*out, f"{scs.kkt.iloc[0]:.1e}")


def _sqp_failures(d: pd.DataFrame) -> tuple[str, ...]:
    failed = d[d.failed_step >= 0]
    if set(failed.family) != {"sqp"} or failed.beta.nunique() != 1:
        raise ValueError("work_precision_run.csv: failed runs other than the SQP's at one beta")
    return (f"{failed.beta.iloc[0]:g}", f"{failed.failed_step.max()}")


def _crawl(d: pd.DataFrame) -> tuple[str, ...]:
    per_slice = d.iterations_sum / d.slices
    return (
        f"{d.iterations_max.median():.0f}",
        f"{d.iterations_max.max()}",
        f"{per_slice.median():.1f}",
        f"{d.one_iteration_slices.median():.0f}",
    )


def _default_scene_tb(d: pd.DataFrame) -> tuple[str, ...]:
    """T_b of the beta-scan run of the paper's first test (tab_bu_g1's physics) at beta = 1000."""
    row = d[(d.data == "g1") & np.isclose(d.eps_v, 2.5e-4) & np.isclose(d["dt"], 0.01) & (d.beta == 1000.0)]
    if len(row) != 1:
        raise ValueError("tab_bu_beta_scan.csv: expected one g1 row at eps_v = 2.5e-4, dt = 0.01, beta = 1000")
    return (_g(row.T_b.iloc[0], 4),)


def _default_scene_beta_range(d: pd.DataFrame) -> tuple[str, ...]:
    rows = d[(d.data == "g1") & np.isclose(d.eps_v, 2.5e-4) & np.isclose(d["dt"], 0.01) & (d.beta >= 1000.0)]
    return (f"{rows.T_b.min():.2f}", f"{rows.T_b.max():.2f}")


CLAIMS += (
    Claim(
        "readme.default_beta_range",
        "tab_bu_beta_scan.csv",
        _default_scene_beta_range,
        "beta >= 1000 gives T_b = {}-{} (`tab_bu_beta_scan.csv`)",
        "g1, eps_v = 1e-3/4, dt = 0.01 over beta >= 1000 (inf included)",
        PAPER_CHOICES_PAGE,
    ),
    Claim(
        "readme.default_tb",
        "tab_bu_beta_scan.csv",
        _default_scene_tb,
        "(measured `T_b = {}` with these settings: `tab_bu_beta_scan.csv`, beta = 1000",
        "the g1, eps_v = 1e-3/4, dt = 0.01, beta = 1000 entry of the beta scan (the paper's first test)",
        FISHER_WEIGHT_PAGE,
    ),
    Claim(
        "crawl.iterations",
        "../bench_crawl.csv",
        _crawl,
        "the slowest slice needs {} Newton iterations per solve (median; at most {}), the average slice {}, and {} of "
        "the 121 slices converge in one",
        "per-solve medians and the largest, bench_crawl.csv",
    ),
    Claim(
        "readme.sqp_failures",
        "../work_precision_run.csv",
        _sqp_failures,
        "fails on vacuum tails at weak Fisher weight (beta = {} within the first {} steps",
        "the failed runs of work_precision_run.csv (all SQP, one beta)",
        SOLVERS_PAGE,
    ),
    Claim(
        "readme.compare",
        "../work_precision_step.csv",
        _wps_ranges,
        "Newton {}-{} ms, SQP {}-{} ms, Clarabel {}-{} ms over their tolerances (`work_precision_step.csv`, the "
        'same step); SCS at tol 1e-4 returns "optimal" with KKT {}, which the package reports as NOT_CERTIFIED',
        "gamma = 1 rows of work_precision_step.csv",
        SOLVERS_PAGE,
    ),
)


# --- the paper's options left open (studies/paper_variants.py) -------------------------------------------


def _pv_row(d, delta0: float, halve_on: str, safeguard: str, max_iter: int = 20000):
    rows = d[(d.delta0 == delta0) & (d.halve_on == halve_on) & (d.safeguard == safeguard) & (d.max_iter == max_iter)]
    if len(rows) != 1:
        raise ValueError(f"paper_variants.csv: expected one row for {delta0, halve_on, safeguard, max_iter}")
    return rows.iloc[0]


_RECORD = ("first halving t", "retries", "smallest dt", "steps", "t reached", "failed MAX_ITERATIONS")


def _pv_same(d) -> str:
    """ "the same" when the four halve_on x {floor, cut} rows of each delta0 have equal records."""
    for d0 in (0.5, 0.05):
        recs = {
            tuple(_pv_row(d, d0, h, s)[list(_RECORD)].astype(float).round(12).fillna(-1))
            for h in ("any_failure", "max_iterations")
            for s in ("floor", "cut")
        }
        if len(recs) != 1:
            return "different"
    return "the same"


def _pv_only_max(d) -> str:
    """ "every" when no floor / cut row failed with another status than MAX_ITERATIONS."""
    cols = ["failed NOT_CERTIFIED", "failed NONCONVEX", "failed NUMERICAL_ERROR"]
    other = d[d.safeguard.isin(("floor", "cut"))][cols]
    return "every" if int(other.to_numpy().sum()) == 0 else "not every"


CLAIMS += (
    Claim(
        "paper_variants.halve_on",
        "paper_variants.csv",
        lambda d: (
            _pv_only_max(d),
            *(str(int(_pv_row(d, d0, "any_failure", "floor")["failed MAX_ITERATIONS"])) for d0 in (0.5, 0.05)),
            _pv_same(d),
        ),
        "on the adaptive g1 runs {} failed attempt is MAX_ITERATIONS ({} for delta0 = 0.5, {} for delta0 = 0.05), "
        "so both rules give {} records",
        "failed-attempt counts by status; records compared over halve_on x safeguard in {floor, cut}",
    ),
    Claim(
        "paper_variants.key",
        "paper_variants.csv",
        lambda d: (
            _pv_only_max(d),
            _pv_same(d),
            *(f"{_pv_row(d, d0, 'any_failure', 'floor')['first halving t']:.2f}" for d0 in (0.5, 0.05)),
            *(f"{_pv_row(d, d0, 'any_failure', 'none')['first failure t']:.2f}" for d0 in (0.5, 0.05)),
        ),
        "{} failed attempt of both runs is the exit flag (MAX_ITERATIONS), and the paper's halving rule "
        '(`time.halve_on = "max_iterations"`) and the SQP without the zeta floor (`safeguard = "cut"`) give {} '
        'records (first halving at t = {} and {}); without the cut (`safeguard = "none"`, Algorithm 1 as written) '
        "an iterate leaves f > 0 at t = {} and {}",
        "default rows, the floor/cut comparison and the safeguard = none rows",
    ),
    Claim(
        "paper_variants.imax",
        "paper_variants.csv",
        lambda d: tuple(
            f"{_pv_row(d, 0.5, 'max_iterations', 'floor', k)[c]:{fmt}}"
            for k in (2000, 200)
            for c, fmt in (("first halving t", ".2f"), ("T_b", ".4f"))
        ),
        "with I_max = 2000 the first halving comes at t = {} and the run ends on eps_t at T_b = {}, with 200 at "
        "t = {} and T_b = {}",
        "max_iter rows (delta0 = 0.5, halve_on = max_iterations)",
    ),
    Claim(
        "paper_variants.none",
        "paper_variants.csv",
        lambda d: (
            _pv_same(d),
            *(f"{_pv_row(d, d0, 'any_failure', 'none')['first failure t']:.2f}" for d0 in (0.5, 0.05)),
            *(f"{_pv_row(d, d0, 'max_iterations', 'none')['T_b']:.2f}" for d0 in (0.5, 0.05)),
            *(f"{_pv_row(d, d0, 'any_failure', 'none')['T_b']:.3f}" for d0 in (0.5, 0.05)),
        ),
        '`"cut"` gives {} records as `"floor"` on both adaptive g1 runs; `"none"` leaves the domain at t = {} '
        "(delta0 = 0.5) and {} (0.05): with the paper's halving rule the run stops there (T_b = {}, {}), with "
        "`any_failure` the step is halved to eps_t by t = {} and {}",
        "safeguard = none rows",
    ),
)


def _pc(d, case: str, n: int, rule: str, col: str, fmt: str) -> str:
    rows = d[(d.case == case) & (d.n == n) & (d.rule == rule)]
    if len(rows) != 1:
        raise ValueError(f"paper_variants_concentration.csv: expected one row for {case, n, rule}")
    return f"{rows.iloc[0][col]:{fmt}}"


def _pc_no_blowup(d) -> str:
    g3 = d[d.case == "gamma3_lambda4"]
    return "no blow-up either way" if g3.T_b.isna().all() else "blow-up in some run"


def _pc_stop(d) -> str:
    q = d[(d.rule == "quadrant") & d.case.str.startswith("gamma1p5") & (d.n == 61)]
    return "the density stop fires" if q.verdict.str.startswith("min spread_v").all() else "another rule fires"


def _pc_uniform(d) -> str:
    """ "stay uniform" when no quadrant row of inhom_gamma1p5 ever refined its v-grid."""
    q = d[(d.rule == "quadrant") & d.case.str.startswith("gamma1p5")]
    return "stay uniform" if q["first t with a refined v-grid"].isna().all() else "do not stay uniform"


CLAIMS += (
    Claim(
        "paper_variants.concentration",
        "paper_variants_concentration.csv",
        lambda d: (
            *(_pc(d, "gamma3_lambda4", 121, r, "min dx", ".2g") for r in ("quadrant", "projections")),
            *(_pc(d, "gamma3_lambda4", 121, r, "min dv", ".3g") for r in ("quadrant", "projections")),
            *(_pc(d, "gamma3_lambda4", 121, r, "max f (peak)", ".4g") for r in ("quadrant", "projections")),
            _pc_no_blowup(d),
            _pc_uniform(d),
            _pc_stop(d),
            *(_pc(d, f"gamma1p5_{c}", 61, "quadrant", "T_b", ".2f") for c in ("before", "after")),
            *(_pc(d, f"gamma1p5_{c}", 61, "projections", "T_b", ".4g") for c in ("before", "after")),
        ),
        "inhom_gamma3 lambda = 4 at 121 x 121 to t = 4: min dx {} against {} (the set's x-extent is one bump's, "
        "not the projection over v), min dv {} against {}, max f {} against {}, {}; "
        "inhom_gamma1p5 (quick form, 61 x 61): the grids {} to t = 0.6 (the bumps reach x = 0 at t = 1), and "
        "{} at t = {} (before) and {} (after), where the projections' min dv falls below "
        "eps_v at t = {} and {}",
        "quadrant against projections rows",
    ),
)

# --- Newton's second start (docs/guides/solvers.md, "A certificate is local") ----------------------------------------


def _second_start_verify(runs: pd.DataFrame, verify: pd.DataFrame) -> tuple[str, ...]:
    """Certified pairs that differ, per beta, with and without the second start; max f moved; jammed share."""
    differ = verify[verify.outcome == "differ"].groupby(["second_start", "beta"]).size()

    def counts(flag: bool) -> str:
        return " / ".join(str(int(differ.get((flag, b), 0))) for b in sorted(runs.beta.unique()))

    return counts(True), counts(False)


def _second_start_max_f(runs: pd.DataFrame) -> tuple[str, ...]:
    off = runs[runs.method == "newton (second_start=False)"]
    worst = off.loc[off.max_rel_dmax_f_vs_newton.idxmax()]
    return f"{100 * worst.max_rel_dmax_f_vs_newton:.1f}", f"{worst.beta:g}"


def _e(x: float, digits: int = 2) -> str:
    """``x`` to ``digits`` significant digits as ``9e-6``, not ``9e-06`` (trailing zeros dropped)."""
    mantissa, exponent = f"{x:.{digits - 1}e}".split("e")
    if "." in mantissa:
        mantissa = mantissa.rstrip("0").rstrip(".")
    return f"{mantissa}e{int(exponent)}"


def _second_start_minima(d: pd.DataFrame) -> tuple[str, ...]:
    ref = np.minimum(d.J_conic, d.J_nlp)
    first, now = (d.J_newton_first - ref) / ref, (d.J_newton - ref) / ref
    close = now <= 2e-8
    far = d[~close]
    return (
        str(len(d)), _e(first.min(), 1), _e(first.max(), 1), f"{d.df_first_conic.max():.2f}",
        str(int(close.sum())), _e(now[~close].max()), str(int((~close).sum())),
        f"{far.beta.iloc[0]:g}", f"{far.t.iloc[0]:.2f}", _e(far.df_newton_conic.max()),
    )  # fmt: skip


def _second_start_cost(d: pd.DataFrame) -> tuple[str, ...]:
    med = d.groupby(["beta", "second_start"]).agg(
        s=("wall_s", "median"), jam=("jammed", "first"), won=("lower_minimum", "first"), n=("slice_steps", "first")
    )
    on = med.xs(True, level="second_start")
    ratio = on.s / med.xs(False, level="second_start").s
    jam, won = 100 * on.jam / on.n, 100 * on.won / on.n
    return (f"{jam.min():.0f}", f"{jam.max():.0f}", f"{won.min():.0f}", f"{won.max():.0f}",
            f"{ratio.min():.2f}", f"{ratio.max():.2f}")  # fmt: skip


CLAIMS += (
    Claim(
        "second_start.verify",
        "../conic_scene_runs.csv",
        _second_start_verify,
        "the Newton runs have {} certified pairs that `differ` at beta = 30 / 100 / 1000, against {} without the "
        "second start;",
        "outcome counts of conic_scene_runs_verify.csv",
        SOLVERS_PAGE,
        also=("../conic_scene_runs_verify.csv",),
    ),
    Claim(
        "second_start.max_f",
        "../conic_scene_runs.csv",
        _second_start_max_f,
        "max f along the runs moves by up to {} % (beta = {}) against the runs without it;",
        "max_rel_dmax_f_vs_newton of the runs without the second start",
        SOLVERS_PAGE,
    ),
    Claim(
        "second_start.minima",
        "../conic_scene_runs_minima.csv",
        _second_start_minima,
        "on the {} slice-steps of the runs without it where both were certified and differed by more than 1e-3 in "
        "f, the first certified point lies {} to {} above the lower of the conic and IPOPT objectives (up to {} of "
        "conic's max f apart in f); the second start returns a point within 2e-8 of that objective on {} of them, "
        "and {} above it on the other {} (beta = {}, t = {}, {} of",
        "relative J gaps against min(J_conic, J_nlp)",
        SOLVERS_PAGE,
    ),
    Claim(
        "second_start.cost",
        "../bench_second_start.csv",
        _second_start_cost,
        "the second start runs on the slices that jam, {} to {} % of the slice-steps of these runs, wins on {} to {} "
        "%, and the runs take {} to {} times as long",
        "shares of the default runs' slice-steps; ratio of median wall times per beta",
        SOLVERS_PAGE,
    ),
)



# --- the paper choices page's remap paragraph (blowup_fit_convergence) ------------------------------------------------


def _remap_convergence(d: pd.DataFrame) -> tuple[str, ...]:
    """Per remap: runs within 1e-3 at dt <= 0.005, and all; bars covering; the wall-cut datum's earliest error."""
    fitted = d.dropna(subset=["error"])
    out: list[str] = []
    for remap in ("paper", "cumulative"):
        g = fitted[fitted.remap == remap]
        small = g[g["dt"] <= 0.005]
        out += [f"{int((small.error.abs() < 1e-3).sum())}", f"{len(small)}", f"{int(g.covered.sum())}", f"{len(g)}"]
    paper = fitted[(fitted.remap == "paper") & (fitted.datum == "A0.6r0.8c-0.2")]
    coarse = fitted[(fitted.remap == "cumulative") & (fitted["dt"] == fitted["dt"].max())]
    missed = int((coarse.error.abs() >= 1e-3).sum())
    return (*out, f"{-paper.error.min():.1e}", f"{coarse['dt'].iloc[0]:g}", f"{missed}", f"{len(coarse)}",
            f"{coarse.error.abs().min():.1e}", f"{coarse.error.abs().max():.1e}")  # fmt: skip


CLAIMS += (
    Claim(
        "remap.convergence",
        "../blowup_fit_convergence.csv",
        _remap_convergence,
        "T_b_fit is within 1e-3 of the exact time in {} of {} runs at dt <= 0.005 with the paper's remap (its "
        "bar covering {} of {} runs) and in {} of {} with the cumulative one (covering {} of {}); with the paper's "
        "remap the datum cut by the walls comes up to {} early, and finer grids and steps do not remove it; at "
        "dt = {} the cumulative remap misses 1e-3 in {} of {} runs (by {} to {}: the step's own error, second order "
        "in dt)",
        "the runs of blowup_fit_convergence.csv per remap: |T_b_fit - T| < 1e-3 at dt <= 0.005, bar covering, "
        "the wall-cut datum's most negative error with the paper's remap, the largest dt's range",
        PAPER_CHOICES_PAGE,
    ),
)


def _certificate_weights(step: pd.DataFrame, runs: pd.DataFrame) -> tuple[str, ...]:
    """The default Newton answer of certificate_weights.csv against the tight one; the runs' dual shares."""
    default, nlp = step.iloc[0], step.iloc[2]
    cells = [c for c in step.columns if c.startswith("f[")]
    held = " and ".join(_e(float(step.iloc[1][c])) for c in sorted(cells, key=lambda c: -step.iloc[1][c]))
    share = runs.loc[runs.run.str.startswith("default"), "share above 1e-3"].iloc[0]
    return (
        _e(default.kkt), str(len(cells)), held, _e(default["max |f - f_tight| / max f"]),
        _e(nlp["max |f - f_tight| / max f"]), _e(default["J - J_tight (relative)"]), _e(default.f_error_estimate),
        f"{100 * share:.0f} %",
    )  # fmt: skip


CLAIMS += (
    Claim(
        "certificate.weights",
        "../certificate_weights.csv",
        _certificate_weights,
        "Newton at its default `tol` is certified (KKT {}) with {} cells emptied where the minimiser holds\n{} "
        "of max f: its f is {} of max f from the tight answer (Newton at `tol=1e-13` and IPOPT agree to\n{}), "
        "J {} too high (relative), while `f_error_estimate`, weighted alike, says {}.  Where the tails\nmatter, "
        "tighten `tol` or verify against IPOPT.  An unweighted test (every cell's residual\nr^f_j >= 0, relative "
        "to its own terms) cannot replace the weights: at {} of the certified steps of",
        "rows 0-2 of certificate_weights.csv; share above 1e-3 of the default run in certificate_weights_run.csv",
        SOLVERS_PAGE,
        also=("../certificate_weights_run.csv",),
    ),
)


def claim_values(results: Path, claims: Iterable[Claim] = CLAIMS) -> dict[str, tuple[str, ...]]:
    """Every claim's formatted number(s), computed from its declared files under ``results``.

    Parameters
    ----------
    results : Path
        The directory the claims' files are relative to (laid out like ``studies/results/reproduce``).
    claims : iterable of Claim
        Default: every claim.
    """
    cache: dict[str, Any] = {}
    out = {}
    for c in claims:
        for name in c.files:
            if name not in cache:
                cache[name] = _load(results, name)
        out[c.key] = tuple(c.compute(*(cache[name] for name in c.files)))
    return out


def write_summary(results: Path) -> pd.DataFrame:
    """Write ``summary.md`` in ``results``: every quoted number, from the result files there.

    Returns the table written (key, value, file, how, readme).
    """
    results = Path(results)
    values = claim_values(results)
    rows = [
        {"key": c.key, "value": ", ".join(values[c.key]), "file": c.file, "how": c.how, "readme": c.readme}
        for c in CLAIMS
    ]
    lines = [
        "# The numbers studies/README.md quotes, computed from the result files",
        "",
        "Generated by `python studies/readme_claims.py` (the claims: `tests/readme_claims.py`); "
        "`tests/docs/test_quoted_numbers.py` checks the pages against them.  Tolerances on T_b "
        "are applied to |ours - paper| rounded to 5 decimals.",
        "",
        "| key | value | file | how | quoted in |",
        "|:--|:--|:--|:--|:--|",
    ]
    lines += [f"| {r['key']} | {r['value']} | `{r['file']}` | {r['how']} | {r['readme']} |" for r in rows]
    (results / "summary.md").write_text("\n".join(lines) + "\n")
    return pd.DataFrame(rows)
