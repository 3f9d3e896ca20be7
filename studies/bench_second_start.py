"""What Newton's second start costs in a run: the paper's gamma = 3 scene with it and without it.

``inhom_gamma3_lambda4`` at 61 x 61, perspective form, to t = 1 (the scene of ``conic_scene_runs``),
beta = 30, 100 and 1000, Newton with ``second_start=True`` (the default) and ``False``, interleaved
over ``ROUNDS`` rounds in one process (one BLAS thread): per run the wall time, and per setting the
median and the ratio of the medians; also the slice-steps, the slices that jammed and those where
the second start returned a lower certified J, and max f at the end.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python studies/bench_second_start.py

writes ``studies/results/bench_second_start.{csv,md}``.
"""

from __future__ import annotations

import datetime
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from jko_cvx.environment import record_csv, write_markdown
from studies.conic_scene_runs import newton_run
from studies.newton_single_call import tree_label

OUT = Path(__file__).parent / "results" / "bench_second_start.csv"
BETAS = (30.0, 100.0, 1000.0)
ROUNDS = 3


def main() -> None:
    tree = tree_label()
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M")
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    rows = []
    for k in range(ROUNDS):
        for beta in BETAS:
            for second_start in ((True, False) if k % 2 == 0 else (False, True)):  # alternate the order
                t0 = time.perf_counter()
                run, counts, _ = newton_run(beta, second_start)
                rows.append({
                    "date": date, "commit": tree, "threads": threads, "round": k, "beta": beta,
                    "second_start": second_start, "wall_s": time.perf_counter() - t0, **counts,
                    "max_f_end": float(run.diagnostics["max_f"].iloc[-1]),
                })  # fmt: skip
                print(rows[-1], flush=True)
    frame = pd.DataFrame(rows)
    frame.to_csv(OUT, index=False)
    record_csv(OUT)
    med = frame.groupby(["beta", "second_start"]).agg(
        median_s=("wall_s", "median"), slice_steps=("slice_steps", "first"), jammed=("jammed", "first"),
        lower_minimum=("lower_minimum", "first"), max_f_end=("max_f_end", "first"),
    ).reset_index()  # fmt: skip
    wide = med.pivot(index="beta", columns="second_start", values="median_s")
    summary = pd.DataFrame({
        "beta": wide.index, "median_s_with": wide[True].to_numpy(), "median_s_without": wide[False].to_numpy(),
        "ratio": (wide[True] / wide[False]).to_numpy(),
    })  # fmt: skip
    on = med[med.second_start].set_index("beta")
    summary["jammed_share"] = (on.jammed / on.slice_steps).to_numpy()
    summary["lower_minimum_share"] = (on.lower_minimum / on.slice_steps).to_numpy()
    text = [
        "# What Newton's second start costs in a run (`studies/bench_second_start.py`)",
        "",
        f"{date} UTC, code {tree}, OPENBLAS_NUM_THREADS={threads}.  `inhom_gamma3_lambda4`, 61 x 61, perspective "
        f"form, to t = 1; Newton with and without `second_start`, interleaved over {ROUNDS} rounds in one process.  "
        "`ratio`: median wall time with the second start over the median without; `jammed_share`: slice-steps whose "
        "first attempt jammed (where the second start runs); `lower_minimum_share`: slice-steps where it returned a "
        "lower certified J (another minimiser, or the same one more accurately).",
        "",
        summary.to_markdown(index=False, floatfmt=".3g"),
        "",
        med.to_markdown(index=False, floatfmt=".4g"),
        "",
        f"Ratio of the medians over beta: {np.min(summary.ratio):.3g} to {np.max(summary.ratio):.3g}.",
        "",
    ]
    write_markdown(OUT.with_suffix(".md"), "\n".join(text))
    print("\n".join(text))


if __name__ == "__main__":
    main()
