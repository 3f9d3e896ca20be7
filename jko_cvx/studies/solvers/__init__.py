"""Solver studies: ``jko-cvx study NAME [--quick]``.

Each entry writes a CSV and a Markdown table and PNG figures into the output directory
(the repository's ``studies/results/`` holds the shipped ones):

* ``work_precision_step``: error against time for one collision step, every solver family
  over its tolerance sweep (:mod:`.workprecision`);
* ``work_precision_run``: error against time for whole homogeneous runs against the exact
  solutions, sweeping dt, N, the tolerance and the Fisher weight (:mod:`.workprecision`);
* ``cost_growth``: time per collision step and per time step against N_v and N_x, batched
  and one at a time, with fitted exponents (:mod:`.cost`);
* ``work_precision_peer``: error against time for the JKO methods (first and second order in
  time, with and without mesh refinement) and the finite-volume peer, smooth and into blow-up;
  the measured order in time (:mod:`.peer`);
* ``extremes``: the matrix of hard cases against every solver, outcomes classified as
  certified, flagged or silently wrong (:mod:`.extremes`).
"""

from __future__ import annotations

from jko_cvx.studies.solvers.cost import cost_growth
from jko_cvx.studies.solvers.extremes import extremes, extremes_matrix
from jko_cvx.studies.solvers.peer import work_precision_peer
from jko_cvx.studies.solvers.workprecision import work_precision_run, work_precision_step

STUDIES = {
    "work_precision_step": work_precision_step,
    "work_precision_run": work_precision_run,
    "cost_growth": cost_growth,
    "extremes": extremes,
    "work_precision_peer": work_precision_peer,
}

__all__ = [
    "STUDIES",
    "cost_growth",
    "extremes",
    "extremes_matrix",
    "work_precision_peer",
    "work_precision_run",
    "work_precision_step",
]
