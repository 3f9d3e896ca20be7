"""Reproductions of the paper's tables and figures: ``jko-cvx reproduce NAME [--quick]``.

Each entry writes a CSV and a Markdown table (our numbers beside the paper's and the
analytic values) and PNG figures into the output directory; sweeps cache per point and
run on a local process pool or a Dask cluster (:mod:`jko_cvx.studies.sweep`).
"""

from __future__ import annotations

from jko_cvx.studies.reproduce.beta_scan import reproduce_tab_bu_beta_scan
from jko_cvx.studies.reproduce.blowup_tables import reproduce_tab_bu, reproduce_tab_bu_tb2
from jko_cvx.studies.reproduce.conclusions import reproduce_conclusions
from jko_cvx.studies.reproduce.criterion_control import reproduce_criterion_control
from jko_cvx.studies.reproduce.discrimination import reproduce_discrimination
from jko_cvx.studies.reproduce.dt_probe import reproduce_g3_dt_probe
from jko_cvx.studies.reproduce.explicit import reproduce_explicit
from jko_cvx.studies.reproduce.explicit_figures import reproduce_explicit_figures
from jko_cvx.studies.reproduce.explicit_sketch import reproduce_explicit2_sketch
from jko_cvx.studies.reproduce.fisher_width import reproduce_fisher_width
from jko_cvx.studies.reproduce.g2bu import reproduce_tab_g2bu
from jko_cvx.studies.reproduce.g2bu_control import reproduce_tab_g2bu_control
from jko_cvx.studies.reproduce.gamma1p5 import reproduce_inhom_gamma1p5
from jko_cvx.studies.reproduce.gamma1p5_events import reproduce_inhom_gamma1p5_events
from jko_cvx.studies.reproduce.gk1_final import reproduce_gk1_final
from jko_cvx.studies.reproduce.gk2_bu import reproduce_gk2_bu
from jko_cvx.studies.reproduce.gk3_panels import reproduce_gk3_panels
from jko_cvx.studies.reproduce.grid_convergence import reproduce_grid_convergence
from jko_cvx.studies.reproduce.ibu import reproduce_ibu
from jko_cvx.studies.reproduce.inhomogeneous import reproduce_inhom_gamma3
from jko_cvx.studies.reproduce.mesh_maps import reproduce_mesh_maps
from jko_cvx.studies.reproduce.panels import reproduce_g2bu_loglog, reproduce_g2bu_records, reproduce_ibu_panels
from jko_cvx.studies.reproduce.property_budget import reproduce_property_budget
from jko_cvx.studies.reproduce.records import reproduce_gk1_records
from jko_cvx.studies.reproduce.tab_bu_traces import reproduce_tab_bu_traces

REPRODUCTIONS = {
    "tab_bu": reproduce_tab_bu,
    "tab_bu_tb2": reproduce_tab_bu_tb2,
    "ibu": reproduce_ibu,
    "gk1_records": reproduce_gk1_records,
    "inhom_gamma3": reproduce_inhom_gamma3,
    "explicit": reproduce_explicit,
    "mesh_maps": reproduce_mesh_maps,
    "inhom_gamma1p5": reproduce_inhom_gamma1p5,
    "inhom_gamma1p5_events": reproduce_inhom_gamma1p5_events,
    "tab_g2bu": reproduce_tab_g2bu,
    "tab_g2bu_control": reproduce_tab_g2bu_control,
    "criterion_control": reproduce_criterion_control,
    "tab_bu_traces": reproduce_tab_bu_traces,
    "property_budget": reproduce_property_budget,
    "tab_bu_beta_scan": reproduce_tab_bu_beta_scan,
    "explicit_figures": reproduce_explicit_figures,
    "gk1_final": reproduce_gk1_final,
    "fisher_width": reproduce_fisher_width,
    "ibu_panels": reproduce_ibu_panels,
    "g2bu_loglog": reproduce_g2bu_loglog,
    "g2bu_records": reproduce_g2bu_records,
    "gk3_panels": reproduce_gk3_panels,
    "gk2_bu": reproduce_gk2_bu,
    "explicit2_sketch": reproduce_explicit2_sketch,
    "grid_convergence": reproduce_grid_convergence,
    "g3_dt_probe": reproduce_g3_dt_probe,
    "discrimination": reproduce_discrimination,
    "conclusions": reproduce_conclusions,
}

__all__ = [
    "REPRODUCTIONS",
    "reproduce_conclusions",
    "reproduce_criterion_control",
    "reproduce_discrimination",
    "reproduce_explicit",
    "reproduce_explicit2_sketch",
    "reproduce_explicit_figures",
    "reproduce_fisher_width",
    "reproduce_g2bu_loglog",
    "reproduce_g2bu_records",
    "reproduce_g3_dt_probe",
    "reproduce_gk1_final",
    "reproduce_gk1_records",
    "reproduce_gk2_bu",
    "reproduce_gk3_panels",
    "reproduce_grid_convergence",
    "reproduce_ibu",
    "reproduce_ibu_panels",
    "reproduce_inhom_gamma1p5",
    "reproduce_inhom_gamma1p5_events",
    "reproduce_inhom_gamma3",
    "reproduce_mesh_maps",
    "reproduce_property_budget",
    "reproduce_tab_bu",
    "reproduce_tab_bu_beta_scan",
    "reproduce_tab_bu_tb2",
    "reproduce_tab_bu_traces",
    "reproduce_tab_g2bu",
    "reproduce_tab_g2bu_control",
]
