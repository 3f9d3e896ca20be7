"""The explanation pages (``docs/explanations/``) name things that exist, and state formulas the code computes.

* every label of the paper they quote is a ``\\label`` of the LaTeX source;
* every repository path and result file they quote exists;
* every code name they quote exists in the module the pages put it in, and every cross-reference
  role points at a public name of ``jko_cvx`` (the generated API documents only those; an
  unresolved role is no Sphinx warning, so the build alone would not catch it);
* the formulas the pages derive rather than copy (the gamma = 1 reduced Hessian at the start of a
  step, the SQP's tridiagonal system, the scaled constraint) agree with the code.
"""

from __future__ import annotations

import dataclasses
import importlib
import re
from pathlib import Path

import numpy as np
import pytest

import jko_cvx
from jko_cvx import CollisionProblem, Grid, PowerKernel

from ..paper_tex import paper_source

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted((ROOT / "docs" / "explanations").glob("*.md"))
TEXT = {p.name: p.read_text() for p in PAGES}
ALL = "\n".join(TEXT.values())

_ROLE = re.compile(r"\{(func|class|meth|attr|doc)\}`([^`]*)`")
_CODE = re.compile(r"(?<![}`])`([^`\n]+)`")
_LABEL = re.compile(r"^(?:eqn|alg|sec|prop|tab|fig)\s?:")
BARE_LABELS = {"JJ", "kernel", "mu1", "mu2"}  # the paper's labels without a prefix that the pages quote

# module -> the names of it that the pages quote (dotted: an attribute of a class)
NAMES = {
    "jko_cvx.kernels": [
        "DenseEnergy",
        "LowRankEnergy",
        "DenseEnergy.split",
        "LowRankEnergy.split",
        "EnergySplit",
        "EnergySplit.rho",
        "EnergySplit.truncated",
        "EnergyOperator.split",
        "EnergyOperator.flux_structure",
    ],
    "jko_cvx.collision.terms": [
        "LogFisher",
        "PerspectiveFisher",
        "FISHER_TERMS",
        "wasserstein_value",
        "wasserstein_derivatives",
    ],
    "jko_cvx.collision.conic": ["ConicOptions", "_fill", "_dc_loop"],
    "jko_cvx.collision.options": ["Spec", "option"],
    "jko_cvx.collision.sqp": ["solve_sqp", "sqp_step", "sqp_stepper", "diagonal_hessian"],
    "jko_cvx.collision.estimate": ["f_error_estimate", "solve_reference"],
    "jko_cvx.mesh.maps": [
        "OneBumpMap",
        "TwoBumpMap",
        "FollowingMap",
        "concentration_set",
        "quadrant_set",
        "periodic_map_grid",
    ],
    "jko_cvx.mesh.following": ["ClusterMap", "concentration_clusters", "periodic_following_grid"],
    "jko_cvx.mesh.remapping": ["remap", "remap_periodic"],
    "jko_cvx.mesh.moments": ["restore_moments", "restore_three_moments"],
    "jko_cvx.mesh.policy": ["RemeshPolicy", "RemeshPolicy.refine", "RefineSpec"],
    "jko_cvx.stepping": ["FixedStep", "HalvingStep", "CFLStep", "step_policy"],
    "jko_cvx.transport": ["transport_step"],
    "jko_cvx.engine.loop": ["Stepper.step", "Stepper.commit", "Stepper.solve", "Stepper.accepted", "ACCEPT_KKT"],
    "jko_cvx.engine.trackers": ["EpsV", "EpsX", "EpsT", "SpreadV", "UnresolvedV", "UnresolvedX"],
    "jko_cvx.engine.verdict": ["SolverFailureRule", "StopReason.EPS_T"],
    "jko_cvx.engine.verify": ["default_reference"],
    "jko_cvx.blowup": ["fit_blowup", "extrapolate_thresholds"],
}
# attributes a CollisionProblem sets on construction (no class attribute to find)
INSTANCE = ["wass_coef", "fisher_coef", "energy_coef", "c_fisher"]


def _quoted() -> list[str]:
    """The inline code of the pages (not the targets of roles)."""
    return [m.group(1).strip() for m in _CODE.finditer(_ROLE.sub("", ALL))]


def _resolve(module: str, dotted: str) -> object:
    """``module.dotted``; a dataclass field (an instance attribute) resolves to its ``Field``."""
    obj = importlib.import_module(module)
    for part in dotted.split("."):
        if not hasattr(obj, part) and dataclasses.is_dataclass(obj):
            obj = {f.name: f for f in dataclasses.fields(obj)}[part]
            continue
        obj = getattr(obj, part)
    return obj


def _problem(**kw) -> CollisionProblem:
    grid = Grid(2 * np.sinh(1.5 * np.linspace(-1, 1, 27)) / np.sinh(1.5))  # non-uniform
    f_star = np.exp(-2 * grid.points**2) + 0.05
    return CollisionProblem(grid, PowerKernel(kw.pop("gamma", 1.0)), f_star, **kw)


def test_the_pages_are_in_the_toctree():
    index = (ROOT / "docs" / "index.md").read_text()
    for p in PAGES:
        assert f"explanations/{p.stem}\n" in index, f"{p.name} is not in a toctree of docs/index.md"


def test_every_quoted_label_is_the_papers():
    labels = set(re.findall(r"\\label\{([^}]*)\}", paper_source()))
    quoted = {q for q in _quoted() if _LABEL.match(q) or q in BARE_LABELS}
    assert len(quoted) > 15
    missing = sorted(quoted - labels)
    assert not missing, f"labels quoted in docs/explanations but not in the paper: {missing}"


def test_every_quoted_path_and_result_file_exists():
    paths = [q for q in _quoted() if re.match(r"^(jko_cvx|studies)/", q)]
    assert len(paths) > 20
    missing = [q for q in paths if not (ROOT / q).exists()]
    files = [q for q in _quoted() if re.fullmatch(r"[\w.]+\.(py|md|csv)", q) and q != "README.md"]
    where = [ROOT / "jko_cvx" / "mesh", ROOT / "studies" / "results"]
    missing += [q for q in files if not any((d / q).exists() for d in where)]
    assert not missing, f"paths quoted in docs/explanations that do not exist: {missing}"


@pytest.mark.parametrize(("module", "name"), [(m, n) for m, names in NAMES.items() for n in names])
def test_every_code_name_exists_where_the_pages_put_it(module, name):
    assert re.search(rf"`{re.escape(name)}[`(]", ALL), f"{name} is no longer quoted: drop it from NAMES"
    _resolve(module, name)


def test_every_camel_case_or_constant_name_quoted_is_checked():
    """A code name quoted on a page is in NAMES, a public ``jko_cvx`` name, or a Status member."""
    known = {n for names in NAMES.values() for n in names}
    # CVXPY's status, named as such; and Python's None
    statuses = {s.name for s in jko_cvx.Status} | {"OPTIMAL_INACCURATE", "None"}
    unchecked = []
    for q in _quoted():
        if not re.fullmatch(r"[A-Za-z_][\w]*(\.[A-Za-z_]\w*)*", q):
            continue
        head = q.split(".")[0]
        camel = re.fullmatch(r"[A-Z][A-Za-z0-9]*[a-z][A-Za-z0-9]*", head)
        constant = re.fullmatch(r"[A-Z][A-Z0-9]*_[A-Z0-9_]+", head)
        if not (camel or constant) or q in known or q in statuses:
            continue
        if head in jko_cvx.__all__:
            try:
                _resolve("jko_cvx", q)
                continue
            except (AttributeError, KeyError):
                if head == "CollisionProblem" and q.split(".")[-1] in INSTANCE:
                    continue
        unchecked.append(q)
    assert not unchecked, f"code names quoted in docs/explanations that no test resolves: {unchecked}"


def test_the_instance_attributes_quoted_exist():
    p = _problem(dt=0.1, beta=3.0)
    for name in INSTANCE:
        assert f"CollisionProblem.{name}" in ALL
        assert hasattr(p, name)


def test_every_role_points_at_a_public_name():
    bad = []
    for role, text in _ROLE.findall(ALL):
        target = text.split("<")[-1].rstrip(">").strip().lstrip("~")
        if role == "doc":
            page = (ROOT / "docs" / "explanations" / target).resolve()
            if not page.with_suffix(".md").exists() and not page.with_suffix(".rst").exists():
                bad.append(text)
            continue
        parts = target.split(".")
        if parts[0] != "jko_cvx" or parts[1] not in jko_cvx.__all__:
            bad.append(text)
            continue
        try:
            _resolve("jko_cvx", ".".join(parts[1:]))
        except (AttributeError, KeyError):
            bad.append(text)
    assert not bad, f"roles in docs/explanations that the generated API does not document: {bad}"


def test_the_gamma1_reduced_hessian_at_the_start_is_the_pages_diagonal():
    """dc_split.md: without Fisher term, at (f*, 0), Z' grad^2 J Z = diag(4 dv (1/s - dt sigma))."""
    p = _problem(gamma=1.0, dt=0.3, strength=1.7)
    f, m = p.initial_point()
    s = f[:-1] + f[1:]
    expected = np.diag(4 * p.grid.dv * (1 / s - p.dt * p.strength))
    np.testing.assert_allclose(p.reduced_hessian(f, m), expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    # positive definite exactly when dt sigma max s < 1
    assert (p.convexity_margin(f, m) > 0) == (p.dt * p.strength * s.max() < 1)
    q = _problem(gamma=1.0, dt=0.3, strength=0.5)
    assert q.convexity_margin(*q.initial_point()) > 0 and 0.3 * 0.5 * s.max() < 1


def test_the_constraint_is_the_papers_row_times_h():
    """discrete_problem.md: f_j - f*_j + (m_{j+1/2} - m_{j-1/2}) / h_j = 0 with zero end fluxes."""
    p = _problem(dt=0.1)
    m = np.random.default_rng(0).normal(size=p.n - 1) * 1e-3
    f = p.density_from_flux(m)
    ends = np.r_[0.0, m, 0.0]
    np.testing.assert_allclose(f - p.f_star + np.diff(ends) / p.grid.h, 0.0, atol=1e-15)
    np.testing.assert_allclose(p.constraint_residual(f, m), 0.0, atol=1e-15)


@pytest.mark.parametrize("fisher", ["log", "perspective"])
def test_the_objective_is_the_pages_formula(fisher):
    """discrete_problem.md: J = sum_k [2 m^2/s + c/dv^2 psi] dv + dt sigma f'Kf, c = dt^2/beta^2."""
    p = _problem(gamma=1.5, dt=0.2, strength=1.3, beta=2.5, fisher=fisher)
    m = np.random.default_rng(1).normal(size=p.n - 1) * 1e-3
    f = p.density_from_flux(m)
    x, y, v, h, dv = f[:-1], f[1:], p.grid.points, p.grid.h, p.grid.dv
    s, c = x + y, (0.2 / 2.5) ** 2
    psi = 0.5 * (np.log(y) - np.log(x)) ** 2 * s if fisher == "log" else (y - x) ** 2 / (s / 2)
    K = np.abs(v[:, None] - v[None, :]) ** 1.5 / 1.5 * np.outer(h, h)
    J = np.sum((2 * m**2 / s + c / dv**2 * psi) * dv) + 0.2 * 1.3 * f @ K @ f
    assert p.objective(f, m) == pytest.approx(J, rel=1e-13)


def test_the_sqp_step_solves_the_pages_tridiagonal_system():
    """algorithms.md: (D' diag(H_f/h^2) D + diag(H_m)) p_m = -(grad_m J - D'(grad_f J / h)), p_f = -D p_m/h."""
    from jko_cvx.collision.sqp import diagonal_hessian, sqp_step

    p = _problem(gamma=2.0, dt=0.05, beta=4.0)
    m = np.random.default_rng(2).normal(size=p.n - 1) * 1e-3
    f = p.density_from_flux(m)
    gf, gm = p.gradient(f, m)
    pf, pm = sqp_step(p, f, m, gf, gm)
    hf, hm = diagonal_hessian(p, f, m)
    n, h = p.n, p.grid.h
    D = np.eye(n, n - 1) - np.eye(n, n - 1, k=-1)
    lhs = D.T @ np.diag(hf / h**2) @ D + np.diag(hm)
    np.testing.assert_allclose(lhs @ pm, -(gm - D.T @ (gf / h)), rtol=1e-9, atol=1e-12 * np.abs(gm).max())
    np.testing.assert_allclose(pf, -(D @ pm) / h, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(hm, 4 * p.grid.dv / (f[:-1] + f[1:]), rtol=1e-12)
