"""Reproductions of the paper's tables and figures: ``jko-cvx reproduce NAME [--quick]``.

Each entry writes a CSV and a Markdown table (our numbers beside the paper's and the
analytic values) and PNG figures into the output directory; sweeps cache per point and
run on a local process pool or a Dask cluster (:mod:`jko_cvx.sweep`).
"""

from __future__ import annotations

from .beta_scan import reproduce_tab_bu_beta_scan
from .blowup_tables import reproduce_tab_bu, reproduce_tab_bu_tb2
from .explicit import reproduce_explicit
from .explicit_figures import reproduce_explicit_figures
from .explicit_sketch import reproduce_explicit2_sketch
from .fisher_width import reproduce_fisher_width
from .g2bu import reproduce_tab_g2bu
from .gamma1p5 import reproduce_inhom_gamma1p5
from .gk1_final import reproduce_gk1_final
from .gk2_bu import reproduce_gk2_bu
from .gk3_panels import reproduce_gk3_panels
from .grid_convergence import reproduce_grid_convergence
from .ibu import reproduce_ibu
from .inhomogeneous import reproduce_inhom_gamma3
from .mesh_maps import reproduce_mesh_maps
from .panels import reproduce_g2bu_loglog, reproduce_g2bu_records, reproduce_ibu_panels
from .property_budget import reproduce_property_budget
from .records import reproduce_gk1_records
from .summary import reproduce_summary
from .tab_bu_traces import reproduce_tab_bu_traces

REPRODUCTIONS = {
    "tab_bu": reproduce_tab_bu,
    "tab_bu_tb2": reproduce_tab_bu_tb2,
    "ibu": reproduce_ibu,
    "gk1_records": reproduce_gk1_records,
    "inhom_gamma3": reproduce_inhom_gamma3,
    "explicit": reproduce_explicit,
    "mesh_maps": reproduce_mesh_maps,
    "inhom_gamma1p5": reproduce_inhom_gamma1p5,
    "tab_g2bu": reproduce_tab_g2bu,
    "tab_bu_traces": reproduce_tab_bu_traces,
    "property_budget": reproduce_property_budget,
    "summary": reproduce_summary,
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
}

__all__ = [
    "REPRODUCTIONS",
    "reproduce_explicit",
    "reproduce_explicit2_sketch",
    "reproduce_explicit_figures",
    "reproduce_fisher_width",
    "reproduce_g2bu_loglog",
    "reproduce_g2bu_records",
    "reproduce_gk1_final",
    "reproduce_gk1_records",
    "reproduce_gk2_bu",
    "reproduce_gk3_panels",
    "reproduce_grid_convergence",
    "reproduce_ibu",
    "reproduce_ibu_panels",
    "reproduce_inhom_gamma1p5",
    "reproduce_inhom_gamma3",
    "reproduce_mesh_maps",
    "reproduce_property_budget",
    "reproduce_summary",
    "reproduce_tab_bu",
    "reproduce_tab_bu_beta_scan",
    "reproduce_tab_bu_tb2",
    "reproduce_tab_bu_traces",
    "reproduce_tab_g2bu",
]
