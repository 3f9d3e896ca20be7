"""Scenes: everything a run needs, as a dataclass loaded from TOML (data, never code).

A scene file (see ``studies/scenes/*.toml``)::

    name = "tab_bu_g1"
    gamma = 1.0
    strength = 1.0          # lambda/2 of eqn: gke; 1 for eqn: gke_hom
    t_end = 1.0

    [v]                      # velocity grid [-L, L], n points
    L = 2.0
    n = 121

    [x]                      # optional: omit for a homogeneous scene (no x-grid, no transport)
    L = 4.0
    n = 121
    conserve_moment = true   # restore each v-line's first x-moment after transport and x-remap
                             # (false: the paper's mass-only eqn:semi_update)

    [initial]                # a parametric library: never evaluated strings
    kind = "gaussians"       # "gaussians" | "two_bump_phase" (eqn:f0) | "gamma2" (eqn:ic_g2)
    amplitudes = [1.0]
    rates = [2.0]
    centres = [0.0]

    [time]
    policy = "fixed"         # "fixed" | "halving" | "cfl"
    dt = 0.01
    eps_t = 1e-6             # halving only

    [refine.v]               # and [refine.x]; omit for a fixed grid
    bumps = 1                # 1 (mu1) or 2 (mu2)
    delta0 = 0.5
    delta = 0.5
    tol = 0.0                # 0: remesh every step (paper); > 0: when the set moved by tol x width

    [collision]
    method = "newton"
    beta = inf               # Fisher weight (TOML inf)
    fisher = "perspective"
    conserve_momentum = true # per-slice momentum constraint (default: true, false for sqp)
    options = {}

    [stop]
    eps_v = 2.5e-4           # blow-up threshold on min dv
    eps_x = 2.5e-4
    spread_v = 0.0           # > 0: also stop when min_spread_v (a density criterion) falls below it
    on_solver_failure = true # stop (and flag blow-up) when the collision solve fails

    [output]
    every = 10               # snapshot every K steps
    times = []               # and at the first step reaching each of these times
    checkpoint_every = 10
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .grid import Grid, PeriodicGrid
from .stepping import CFLStep, FixedStep, HalvingStep

__all__ = ["Scene", "default_scene", "load_scene", "scene_from_dict"]

_INITIAL_KINDS = {
    "gaussians": {"amplitudes", "rates", "centres"},
    "two_bump_phase": {"a", "b", "c", "d"},
    "gamma2": {"a", "b", "x1"},
}
_TOP_KEYS = {
    "name",
    "description",
    "gamma",
    "strength",
    "t_end",
    "v",
    "x",
    "initial",
    "time",
    "refine",
    "collision",
    "stop",
    "output",
}


class SceneError(ValueError):
    """A scene that does not validate; the message names the key and the allowed values."""


@dataclass(frozen=True)
class RefineSpec:
    """Mesh refinement on one axis: map type, delta0, delta, and the remeshing tolerance.

    ``tol = 0`` remeshes every step (the paper's Algorithm ``alg:one_step_MR_JKO``); ``tol > 0``
    remeshes only when the concentration set's extent has moved by more than ``tol`` times
    its width.  Measured (``ibu_gamma3``): remeshing every step moves the bumps inward by as
    much as their own motion per step (PCHIP remap bias), so the peaks ran ahead of the
    point-mass law 1/(2Mt) after t ~ 5; with ``tol = 0.1`` they follow it to t = 20.
    """

    bumps: int = 1
    delta0: float = 0.5
    delta: float = 0.5
    tol: float = 0.0


@dataclass(frozen=True)
class Scene:
    """A validated scene (see the module docstring for the TOML layout)."""

    name: str
    gamma: float
    t_end: float
    v_L: float
    v_n: int
    initial: dict[str, Any]
    dt: float
    policy: str = "fixed"
    eps_t: float = 1e-6
    strength: float = 1.0
    x_L: float | None = None
    x_n: int | None = None
    conserve_x_moment: bool = True
    refine_v: RefineSpec | None = None
    refine_x: RefineSpec | None = None
    method: str = "newton"
    beta: float = math.inf
    fisher: str | None = "perspective"
    conserve_momentum: bool = True
    options: dict[str, Any] = field(default_factory=dict)
    eps_v: float = 0.0
    eps_x: float = 0.0
    spread_v: float = 0.0
    stop_on_solver_failure: bool = True
    every: int = 10
    snapshot_times: tuple[float, ...] = ()
    checkpoint_every: int = 10
    description: str = ""

    @property
    def homogeneous(self) -> bool:
        """True when the scene has no x-grid (no transport)."""
        return self.x_n is None

    def vgrid(self) -> Grid:
        return Grid.uniform(-self.v_L, self.v_L, self.v_n)

    def xgrid(self) -> PeriodicGrid | None:
        return None if self.homogeneous else PeriodicGrid.uniform(self.x_L, self.x_n)

    def step_policy(self):
        if self.policy == "fixed":
            return FixedStep(self.dt)
        if self.policy == "halving":
            return HalvingStep(self.dt, self.eps_t)
        return CFLStep(self.dt)

    def initial_density(self, xgrid: PeriodicGrid | None, vgrid: Grid) -> NDArray[np.float64]:
        """f0 on the grids, shape (Nv,) or (Nx, Nv)."""
        p = self.initial
        v = vgrid.points
        if p["kind"] == "gaussians":
            fv = sum(
                A * np.exp(-a * (v - c) ** 2) for A, a, c in zip(p["amplitudes"], p["rates"], p["centres"], strict=True)
            )
            return fv if xgrid is None else np.tile(fv, (xgrid.n, 1))
        x = xgrid.points[:, None]
        if p["kind"] == "two_bump_phase":  # eqn:f0
            a, b, c, d = p["a"], p["b"], p["c"], p["d"]
            return np.exp(-a * (x + c) ** 2) * np.exp(-b * (v - d) ** 2) + np.exp(-a * (x - c) ** 2) * np.exp(
                -b * (v + d) ** 2
            )
        a, b, x1 = p["a"], p["b"], p["x1"]  # eqn:ic_g2
        base = np.exp(-a * (b * x + v) ** 2) / np.sqrt(2 * np.pi)
        cut = np.where(np.abs(x) <= x1, 1.0, np.exp(-1000 * (np.abs(x) - x1) ** 2))
        return base * cut

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        return d


def _get(d: dict, key: str, where: str, kind, default=None, required=False, check=None, allowed=None):
    if key not in d:
        if required:
            raise SceneError(f"{where}{key} is required")
        return default
    val = d[key]
    try:
        if kind is bool:
            if not isinstance(val, bool):
                raise TypeError
        elif kind is int:
            if isinstance(val, bool) or int(val) != val:
                raise TypeError
            val = int(val)
        elif kind is float:
            if isinstance(val, bool):
                raise TypeError
            val = float(val)
        elif kind is str:
            if not isinstance(val, str):
                raise TypeError
    except (TypeError, ValueError):
        raise SceneError(f"{where}{key} must be of type {kind.__name__}, got {val!r}") from None
    if allowed is not None and val not in allowed:
        raise SceneError(f"{where}{key} must be one of {sorted(allowed)}, got {val!r}")
    if check is not None and not check[0](val):
        raise SceneError(f"{where}{key} must be {check[1]}, got {val!r}")
    return val


_POS = (lambda x: math.isfinite(x) and x > 0, "a finite number > 0")
_FRAC = (lambda x: 0 < x < 1, "in (0, 1)")
_NPTS = (lambda n: n >= 3, "an integer >= 3")


def scene_from_dict(d: dict[str, Any]) -> Scene:
    """Validate a scene given as nested dicts (as parsed from TOML)."""
    unknown = set(d) - _TOP_KEYS
    if unknown:
        raise SceneError(f"unknown top-level key(s) {sorted(unknown)}; allowed: {sorted(_TOP_KEYS)}")
    name = _get(d, "name", "", str, default="scene")
    gamma = _get(d, "gamma", "", float, required=True, check=_POS)
    t_end = _get(d, "t_end", "", float, required=True, check=_POS)
    strength = _get(d, "strength", "", float, default=1.0, check=_POS)
    v = d.get("v")
    if not isinstance(v, dict):
        raise SceneError("[v] is required: a table with L (> 0) and n (>= 3)")
    v_L = _get(v, "L", "v.", float, required=True, check=_POS)
    v_n = _get(v, "n", "v.", int, required=True, check=_NPTS)
    x_L = x_n = None
    if "x" in d:
        x = d["x"]
        x_L = _get(x, "L", "x.", float, required=True, check=_POS)
        x_n = _get(x, "n", "x.", int, required=True, check=_NPTS)
    conserve_x_moment = _get(d.get("x", {}), "conserve_moment", "x.", bool, default=True)
    init = d.get("initial")
    if not isinstance(init, dict):
        raise SceneError(f"[initial] is required, with kind one of {sorted(_INITIAL_KINDS)}")
    kind = _get(init, "kind", "initial.", str, required=True, allowed=set(_INITIAL_KINDS))
    need = _INITIAL_KINDS[kind]
    missing, extra = need - set(init), set(init) - need - {"kind"}
    if missing or extra:
        raise SceneError(
            f"initial (kind={kind!r}) needs exactly the keys {sorted(need)}; missing {sorted(missing)}, "
            f"unknown {sorted(extra)}"
        )
    if kind == "gaussians":
        lens = {len(init[k]) for k in need if isinstance(init[k], list)}
        if len(lens) != 1 or not all(isinstance(init[k], list) for k in need):
            raise SceneError("initial.amplitudes, rates and centres must be lists of the same length")
        if any(r <= 0 for r in init["rates"]) or any(a < 0 for a in init["amplitudes"]):
            raise SceneError("initial.rates must be > 0 and initial.amplitudes >= 0")
    else:
        for k in need:
            _get(init, k, "initial.", float, required=True)
        if kind != "gaussians" and x_n is None:
            raise SceneError(f"initial.kind = {kind!r} is a phase-space datum and needs an [x] grid")
    initial = {k: (list(map(float, val)) if isinstance(val, list) else val) for k, val in init.items()}
    t = d.get("time", {})
    policy = _get(t, "policy", "time.", str, default="fixed", allowed={"fixed", "halving", "cfl"})
    dt = _get(t, "dt", "time.", float, required=True, check=_POS)
    eps_t = _get(t, "eps_t", "time.", float, default=1e-6, check=_POS)
    refine = d.get("refine", {})
    specs = {}
    for axis in ("v", "x"):
        if axis in refine:
            r = refine[axis]
            specs[axis] = RefineSpec(
                bumps=_get(r, "bumps", f"refine.{axis}.", int, default=1, allowed={1, 2}),
                delta0=_get(r, "delta0", f"refine.{axis}.", float, default=0.5, check=_FRAC),
                delta=_get(r, "delta", f"refine.{axis}.", float, default=0.5, check=_FRAC),
                tol=_get(r, "tol", f"refine.{axis}.", float, default=0.0, check=(lambda x: 0 <= x < 1, "in [0, 1)")),
            )
    if "x" in specs and x_n is None:
        raise SceneError("refine.x needs an [x] grid")
    c = d.get("collision", {})
    method = _get(c, "method", "collision.", str, default="newton", allowed={"newton", "sqp", "conic", "nlp"})
    beta = _get(c, "beta", "collision.", float, default=math.inf, check=(lambda b: b > 0, "> 0 (inf allowed)"))
    fisher = _get(c, "fisher", "collision.", str, default="perspective", allowed={"perspective", "log", "none"})
    # Momentum: the collision operator conserves it on each x-slice; the constrained step
    # does so exactly (CollisionProblem.conserve_momentum).  The paper's SQP has no such
    # constraint, so it defaults to false there.
    conserve_momentum = _get(c, "conserve_momentum", "collision.", bool, default=method != "sqp")
    if conserve_momentum and method == "sqp":
        raise SceneError(
            "collision.conserve_momentum = true needs method 'newton' or 'conic' (sqp has no such constraint)"
        )
    options = c.get("options", {})
    if not isinstance(options, dict):
        raise SceneError(f"collision.options must be a table, got {options!r}")
    s = d.get("stop", {})
    eps_v = _get(s, "eps_v", "stop.", float, default=0.0, check=(lambda e: e >= 0, ">= 0"))
    eps_x = _get(s, "eps_x", "stop.", float, default=0.0, check=(lambda e: e >= 0, ">= 0"))
    spread_v = _get(s, "spread_v", "stop.", float, default=0.0, check=(lambda e: math.isfinite(e) and e >= 0, ">= 0"))
    on_fail = _get(s, "on_solver_failure", "stop.", bool, default=True)
    o = d.get("output", {})
    every = _get(o, "every", "output.", int, default=10, check=(lambda k: k >= 1, ">= 1"))
    ck = _get(o, "checkpoint_every", "output.", int, default=10, check=(lambda k: k >= 1, ">= 1"))
    times = o.get("times", [])
    if not isinstance(times, list | tuple) or not all(
        isinstance(tk, int | float) and not isinstance(tk, bool) and 0 <= tk <= t_end for tk in times
    ):
        raise SceneError(f"output.times must be a list of numbers in [0, t_end = {t_end:g}], got {times!r}")
    return Scene(
        name=name,
        gamma=gamma,
        t_end=t_end,
        v_L=v_L,
        v_n=v_n,
        initial=initial,
        dt=dt,
        policy=policy,
        eps_t=eps_t,
        strength=strength,
        x_L=x_L,
        x_n=x_n,
        conserve_x_moment=conserve_x_moment,
        refine_v=specs.get("v"),
        refine_x=specs.get("x"),
        method=method,
        beta=beta,
        fisher=None if fisher == "none" else fisher,
        conserve_momentum=conserve_momentum,
        options=dict(options),
        eps_v=eps_v,
        eps_x=eps_x,
        spread_v=spread_v,
        stop_on_solver_failure=on_fail,
        every=every,
        snapshot_times=tuple(sorted(float(tk) for tk in times)),
        checkpoint_every=ck,
        description=_get(d, "description", "", str, default=""),
    )


def load_scene(path: str | Path) -> Scene:
    """Read and validate a TOML scene file (parsed as data with ``tomllib``)."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise SceneError(f"scene file not found: {p}") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{p} is not valid TOML: {exc}") from None
    return scene_from_dict(data)


def default_scene() -> Scene:
    """The built-in default: homogeneous gamma = 1, g1 = exp(-2 v^2), Table tab:bu set-up (dt = 0.01,
    N_v = 121, delta = delta0 = 0.5, eps_v = 1e-3/4), run to blow-up (exact T = 0.5)."""
    return scene_from_dict(
        {
            "name": "default_tab_bu_g1",
            "description": "homogeneous gamma = 1, g1 = exp(-2 v^2), mesh refinement, fixed dt (Table tab:bu)",
            "gamma": 1.0,
            "strength": 1.0,
            "t_end": 1.0,
            "v": {"L": 2.0, "n": 121},
            "initial": {"kind": "gaussians", "amplitudes": [1.0], "rates": [2.0], "centres": [0.0]},
            "time": {"policy": "fixed", "dt": 0.01},
            "refine": {"v": {"bumps": 1, "delta0": 0.5, "delta": 0.5}},
            # log-Fisher (the paper's form: a barrier that keeps Newton's iterates interior) with
            # beta = 1000: weak enough not to cap the concentration (beta = 10 / 100 saturate
            # max f at 9.6 / 42); measured T_b = 0.51, as in Table tab:bu.
            "collision": {"method": "newton", "beta": 1000.0, "fisher": "log"},
            "stop": {"eps_v": 1e-3 / 4, "on_solver_failure": False},
            "output": {"every": 5, "checkpoint_every": 5},
        }
    )
