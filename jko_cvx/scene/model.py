"""The scene: a validated dataclass built from a TOML document, and the ways to load one."""

from __future__ import annotations

import copy
import dataclasses
import difflib
import math
import tomllib
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from jko_cvx.grid import Grid, PeriodicGrid
from jko_cvx.mesh.maps import VALLEY, bump_about_maximum
from jko_cvx.mesh.policy import RefineSpec
from jko_cvx.scene.initial import INITIAL_KINDS, Initial
from jko_cvx.scene.limits import Limits, check_limits
from jko_cvx.scene.options import parse_options
from jko_cvx.scene.schema import (
    CollisionTable,
    OutputTable,
    RefineAxisTable,
    RefineTable,
    Rule,
    SceneError,
    SceneTable,
    StopTable,
    TimeTable,
    VTable,
    XTable,
    check_known,
    parse_table,
    require_table,
    unknown_keys_message,
)
from jko_cvx.stepping import StepPolicy, step_policy

__all__ = [
    "Scene",
    "SceneError",
    "default_scene",
    "load_scene",
    "scene_from_dict",
    "shipped_scene",
    "shipped_scene_names",
    "with_overrides",
]


@dataclass(frozen=True)
class Scene:
    """A validated scene, nested as its TOML document: a dotted key is an attribute path.

    ``scene.v.n`` is ``v.n``, ``scene.time.dt`` is ``time.dt``, ``scene.refine.v`` the
    ``[refine.v]`` table (a :class:`RefineSpec`, None for a fixed grid), ``scene.x`` None for a
    homogeneous scene; ``scene.initial`` is the initial condition's kind
    (:mod:`jko_cvx.scene.initial`).  Defaults are filled in and resolved at parse time
    (``collision.conserve_momentum``, ``collision.options``, ``output.times`` sorted); see the
    module docstring of :mod:`jko_cvx.scene` for the layout.

    Two switches between the paper's algorithms as written and this package's rule (both measured
    in the paper-variants study):

    * ``time.halve_on`` (halving policies): ``"any_failure"`` (default) halves the
      step after any collision solve the engine does not accept (not certified, non-convex,
      numerical error, iteration limit); ``"max_iterations"`` follows ``alg:MR_JKO_ver2`` /
      ``alg:non_uni_JKO``: only the exit flag ``e_f`` (``MAX_ITERATIONS``) halves it, and any
      other failure stops the run as a solver failure (``e_f``, whatever
      ``stop.on_solver_failure`` says: an uncertified step is never used as a solution).
    * ``refine.concentration_set`` (inhomogeneous scenes):
      ``"projections"`` (default) builds the v-map from the post-collision f maximised over x
      and the x-map from it maximised over v; ``"quadrant"`` follows ``alg:SPMCSL-JKO`` step 4:
      one set :math:`S = \\{f^* > \\delta_0 \\max f^*, x > 0, v > 0\\}` from the density entering
      the collision step (:func:`jko_cvx.mesh.maps.quadrant_set`), each map from its extent on
      its axis (with the one-bump map's ``r = max`` rule of :mod:`jko_cvx.mesh.maps`); where S is
      empty (``eqn:f0`` at t = 0; the paper is silent) both refined axes take the uniform grid.

    Examples
    --------
    >>> from jko_cvx import shipped_scene
    >>> scene = shipped_scene("tab_bu_g1")
    >>> scene.gamma, scene.v.n, scene.time.dt, scene.collision.method, scene.x is None
    (1.0, 121, 0.01, 'newton', True)
    >>> coarse = scene.replace({"v.n": 41, "time.dt": 0.02})  # a validated copy
    >>> coarse.v.n, coarse.time.dt, scene.v.n
    (41, 0.02, 121)
    """

    name: str
    gamma: float
    strength: float
    t_end: float
    description: str
    v: VTable
    x: XTable | None
    initial: Initial
    time: TimeTable
    refine: RefineTable
    collision: CollisionTable
    stop: StopTable
    output: OutputTable

    @property
    def homogeneous(self) -> bool:
        """True when the scene has no x-grid (no transport)."""
        return self.x is None

    def vgrid(self) -> Grid:
        return Grid.uniform(-self.v.L, self.v.L, self.v.n)

    def xgrid(self) -> PeriodicGrid | None:
        return None if self.x is None else PeriodicGrid.uniform(self.x.L, self.x.n)

    def step_policy(self) -> StepPolicy:
        """The time-step policy of ``[time]`` (:func:`jko_cvx.stepping.step_policy`)."""
        return step_policy(self.time.policy, self.time.dt, self.time.eps_t, self.time.halve_on)

    def initial_density(self, xgrid: PeriodicGrid | None, vgrid: Grid) -> NDArray[np.float64]:
        """f0 on the grids, shape (Nv,) or (Nx, Nv): :meth:`Initial.density` of ``initial``."""
        return self.initial.density(xgrid, vgrid)

    def replace(self, changes: Mapping[str, Any]) -> Scene:
        """A copy with the attributes at the dotted paths of ``changes`` set, validated as a whole.

        The nested counterpart of :func:`dataclasses.replace` (``{"v.n": 41, "time.dt": 0.02}``).
        The result is the scene :func:`scene_from_dict` makes of the changed document (its
        normal form: ``output.times`` sorted, ...; ``replace({})`` is that form of the scene
        itself), of the scene's own class, with any table of a class of the caller's own (a
        subclass of ``Initial``, say) kept as it is; a change that makes the scene
        inconsistent (``{"collision.method": "sqp"}`` on a scene whose momentum constraint or
        options belong to Newton) raises :class:`SceneError` naming the key, before any work.
        What the loader resolved stays resolved: ``refine.<axis>.centre = "auto"`` became ``"origin"`` or
        ``"follow"`` for the scene's own f0, so a new datum off v = 0 needs ``{"refine.v.centre": "follow"}``
        beside it, or the scene built again with overrides (``shipped_scene(name, overrides)``,
        ``default_scene(overrides)``), which resolves it for the new f0.

        >>> default_scene().replace({"time.dt": 0.005, "t_end": 0.5}).time.dt
        0.005
        """
        _check_overlap(changes)
        out: Any = self
        for dotted, val in changes.items():
            out = _replace_path(out, str(dotted).split("."), val, str(dotted))
        try:  # the loader's form (output.times sorted, ...): what the run's scene.json rebuilds
            loaded = scene_from_dict(out.to_dict())
        except SceneError as exc:
            raise SceneError(f"replace({dict(changes)!r}) gives an invalid scene: {exc}") from None
        return _in_class_of(out, loaded)

    def to_dict(self) -> dict[str, Any]:
        """The scene as its canonical TOML-shaped document: nested by table, every default filled in,
        keys sorted at every level, tuples as lists, no ``x`` / ``refine.v`` / ``refine.x`` where the
        scene has none.  ``scene_from_dict(scene.to_dict()) == scene``; equal scenes give equal dicts.

        >>> d = default_scene().to_dict()
        >>> d["time"]["dt"], d["refine"]["v"]["delta0"], scene_from_dict(d) == default_scene()
        (0.01, 0.5, True)
        """
        d = asdict(self)
        d["initial"] = {"kind": self.initial.kind, **d["initial"]}
        if self.x is None:
            del d["x"]
        for axis in ("v", "x"):
            if d["refine"][axis] is None:
                del d["refine"][axis]
        return _canonical(d)


def _in_class_of(mine: Any, theirs: Any) -> Any:
    """The loader's value ``theirs`` in the class of the caller's ``mine``, at every level of the tables.

    Where ``mine`` is of a subclass of the loader's class that adds no fields (its own methods: an initial datum
    with a density of its own, say), the result is of that class with the loader's values (``output.times``
    sorted, ``centre = "auto"`` resolved, ...); a class the loader does not make, or one with fields of its own,
    is kept as the caller's object.  Replace never swaps a caller's physics for the stock one silently.
    """
    if not (dataclasses.is_dataclass(mine) and dataclasses.is_dataclass(theirs)) or isinstance(mine, type):
        return theirs
    values = {f.name: _in_class_of(getattr(mine, f.name, None), getattr(theirs, f.name))
              for f in dataclasses.fields(theirs)}  # fmt: skip
    if type(mine) is type(theirs):
        same = all(values[k] is getattr(theirs, k) for k in values)
        return theirs if same else dataclasses.replace(theirs, **values)
    if isinstance(mine, type(theirs)) and {f.name for f in dataclasses.fields(mine)} == set(values):
        return type(mine)(**values)
    return mine


def _replace_path(obj: Any, path: list[str], val: Any, dotted: str) -> Any:
    head, *rest = path
    if not dataclasses.is_dataclass(obj) or head not in {f.name for f in dataclasses.fields(obj)}:
        raise SceneError(f"replace: the scene has no key {dotted!r} (jko-cvx scene keys lists them)")
    if rest:
        val = _replace_path(getattr(obj, head), rest, val, dotted)
    return dataclasses.replace(obj, **{head: val})


def _canonical(obj: Any) -> Any:
    if isinstance(obj, Mapping):
        return {str(k): _canonical(obj[k]) for k in sorted(obj, key=str)}
    if isinstance(obj, list | tuple):
        return [_canonical(v) for v in obj]
    return obj


def scene_from_dict(d: Mapping[str, Any], limits: Limits | None = None) -> Scene:
    """Validate a scene given as nested dicts (as parsed from TOML) and build it.

    Parameters
    ----------
    d : mapping
        The TOML document: top-level keys and the tables ``v``, ``x``, ``initial``,
        ``time``, ``refine``, ``collision``, ``stop``, ``output``.
    limits : Limits, optional
        Step and memory limits (default: :meth:`Limits.from_env`).

    Raises
    ------
    SceneError
        Naming the dotted key, for an unknown key anywhere, a section that is not a table,
        a value of the wrong type or range, an inconsistent combination, or a scene
        beyond the limits.
    """
    if limits is not None and not isinstance(limits, Limits):
        raise TypeError(f"limits must be a jko_cvx.scene.limits.Limits or None, got {type(limits).__name__}")
    _unknown_keys(require_table(d, "scene"))  # typos in several tables are named in one error
    top = parse_table(SceneTable, d, "")
    v = parse_table(VTable, top.v, "v")
    x = None if top.x is None else parse_table(XTable, top.x, "x")
    initial = _parse_initial(top.initial, x is not None)
    t = parse_table(TimeTable, top.time, "time")
    refine, centre_auto = _parse_refine(top.refine, x is not None)
    c = parse_table(CollisionTable, {} if top.collision is None else top.collision, "collision")
    s = parse_table(StopTable, {} if top.stop is None else top.stop, "stop")
    o = parse_table(OutputTable, {} if top.output is None else top.output, "output")
    _check_combinations(top, v, x, t, c, s, o)
    collision = dataclasses.replace(
        c,
        # Momentum: the collision operator conserves it on each x-slice; the constrained step
        # does so exactly (CollisionProblem.conserve_momentum).  The paper's SQP has no such
        # constraint, so it defaults to false there.
        conserve_momentum=c.method != "sqp" if c.conserve_momentum is None else c.conserve_momentum,
        options={} if c.options is None else parse_options(c.method, c.options),
    )
    scene = Scene(
        name=top.name,
        gamma=top.gamma,
        strength=top.strength,
        t_end=top.t_end,
        description=top.description,
        v=v,
        x=x,
        initial=initial,
        time=t,
        refine=refine,
        collision=collision,
        stop=s,
        output=dataclasses.replace(o, times=tuple(sorted(o.times))),
    )
    check_limits(scene, limits)  # before anything of the run's size is allocated
    xgrid, vgrid = scene.xgrid(), scene.vgrid()
    f0 = scene.initial_density(xgrid, vgrid)
    _check_initial_density(scene, f0, xgrid, vgrid)
    return _resolve_centre(scene, f0, centre_auto) if centre_auto else scene


def _check_initial_density(scene: Scene, f0: np.ndarray, xgrid: PeriodicGrid | None, vgrid: Grid) -> None:
    """Refuse, before any file is written, an f0 that makes the first collision step fail from the data alone."""
    if not (np.all(np.isfinite(f0)) and f0.max() > 0):
        raise SceneError("initial: f0 is zero or not finite on the grid (check its parameters against v.L and x.L)")
    tiny = np.finfo(float).tiny
    if f0.max() < tiny:
        raise SceneError(
            f"initial: max f0 = {f0.max():.3g} is below the smallest normal float ({tiny:.3g}): the density "
            "underflows; scale initial.amplitudes up (the equation is invariant under mass scaling with time)"
        )
    # the mass and the moments the remeshing restores (up to the energy, v^2 f) must stay finite, with room
    dv = float(vgrid.dv.max())
    dx = 1.0 if xgrid is None else float(xgrid.dx.max())
    with np.errstate(over="ignore"):
        mass = float(np.sum(f0, dtype=float)) * dv * dx
    if not mass * max(scene.v.L, 1.0) ** 2 < 1e290:
        raise SceneError(
            f"initial: the mass of f0 on the grid ({mass:.3g}) or its energy overflows the floating-point range; "
            "scale initial.amplitudes down (the equation is invariant under mass scaling with time)"
        )
    # homogeneous only: with an x-grid the transport's floor makes every f* positive before a collision
    if scene.collision.fisher == "log" and scene.homogeneous and f0.min() <= 0:
        zeros = int(np.sum(f0 <= 0))
        raise SceneError(
            f"initial: with collision.fisher = 'log' f0 must be > 0 at every grid point (the log Fisher term is "
            f"undefined at 0), but it is 0 at {zeros} of {f0.size} points (exp underflow): widen the bumps "
            "(smaller initial.rates / initial.a, initial.b) or use collision.fisher = 'perspective'"
        )


_SECTIONS = {"v": VTable, "x": XTable, "time": TimeTable, "collision": CollisionTable, "stop": StopTable,
             "output": OutputTable}  # fmt: skip
_REFINE_KEYS = ("v", "x", "concentration_set")  # the [refine] table: one sub-table per axis, and the set


def _unknown_keys(d: Mapping[str, Any]) -> None:
    """Every unknown key of the document's tables, refused in one :class:`SceneError` (before the
    values are parsed: a misspelt required key is then reported as the typo, not as missing).
    Sections that are not tables are left to the parser, which names them."""

    def fields(cls) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    tables: list[tuple[Mapping[str, Any], Any, str]] = [(d, fields(SceneTable), "")]
    tables += [(d[name], fields(cls), name) for name, cls in _SECTIONS.items() if isinstance(d.get(name), Mapping)]
    refine = d.get("refine")
    if isinstance(refine, Mapping):
        tables.append((refine, _REFINE_KEYS, "refine"))
        tables += [(refine[a], fields(RefineAxisTable), f"refine.{a}") for a in ("v", "x")
                   if isinstance(refine.get(a), Mapping)]  # fmt: skip
    initial = d.get("initial")
    kind = initial.get("kind") if isinstance(initial, Mapping) else None
    if isinstance(kind, str) and kind in INITIAL_KINDS:
        tables.append(({k: val for k, val in initial.items() if k != "kind"}, fields(INITIAL_KINDS[kind]), "initial"))
    refusals = [m for m in (unknown_keys_message(*table) for table in tables) if m is not None]
    if refusals:
        raise SceneError("; and ".join(refusals))


def _parse_initial(data: Any, has_x: bool) -> Initial:
    data = require_table(data, "initial")
    if "kind" not in data:
        raise SceneError(f"initial.kind is required, one of {sorted(INITIAL_KINDS)}")
    kind = Rule("str", choices=tuple(INITIAL_KINDS)).parse(data["kind"], "initial.kind")
    initial = parse_table(INITIAL_KINDS[kind], {k: val for k, val in data.items() if k != "kind"}, "initial")
    if initial.phase_space and not has_x:
        raise SceneError(f"initial.kind = {kind!r} is a phase-space datum and needs an [x] grid")
    return initial


def _parse_refine(data: Any, has_x: bool) -> tuple[RefineTable, tuple[str, ...]]:
    """The ``[refine]`` table (a :class:`RefineSpec` per axis the scene refines, and the concentration set) and
    the axes whose ``centre`` is ``"auto"``."""
    if data is None:
        return RefineTable(), ()
    data = require_table(data, "refine")
    check_known(data, _REFINE_KEYS, "refine")
    if "x" in data and not has_x:
        raise SceneError("refine.x needs an [x] grid")
    specs: dict[str, Any] = {}
    for axis in ("v", "x"):
        if axis in data:
            table = asdict(parse_table(RefineAxisTable, data[axis], f"refine.{axis}"))
            if table["junction"] != "paper" and table["bumps"] != 1:
                raise SceneError(
                    f"refine.{axis}.junction = {table['junction']!r} is built for one-bump maps: refine.{axis}.bumps "
                    f"must be 1, got {table['bumps']}"
                )
            # "auto" is resolved against f0 once the scene is built (_resolve_centre); a RefineSpec holds
            # only what the run does
            specs[axis] = RefineSpec(**{**table, "centre": "origin" if table["centre"] == "auto" else table["centre"]})
            specs[f"_{axis}_auto"] = table["centre"] == "auto"
    if "x" in specs and specs["x"].conserve_energy:
        raise SceneError("refine.x.conserve_energy must be false: the kinetic energy is a moment in v (refine.v only)")
    auto = {axis: specs.pop(f"_{axis}_auto") for axis in ("v", "x") if f"_{axis}_auto" in specs}
    if "concentration_set" in data:
        rule = RefineTable.__dataclass_fields__["concentration_set"].metadata["rule"]
        specs["concentration_set"] = rule.parse(data["concentration_set"], "refine.concentration_set")
        if specs["concentration_set"] == "quadrant" and not has_x:
            raise SceneError(
                'refine.concentration_set = "quadrant" is the phase-space set of alg:SPMCSL-JKO and needs an '
                '[x] grid (a homogeneous scene uses "projections", the set of eqn:Sr)'
            )
        if specs["concentration_set"] == "quadrant" and not ("v" in specs or "x" in specs):
            raise SceneError('refine.concentration_set = "quadrant" needs [refine.v] or [refine.x] (a map to build)')
    if specs.get("concentration_set") == "quadrant":
        for axis in ("v", "x"):
            if axis in specs and specs[axis].centre == "follow":
                raise SceneError(
                    f"refine.{axis}.centre = 'follow' places the map on the projections' sets; "
                    'refine.concentration_set = "quadrant" builds both maps from one quadrant set '
                    "(use 'origin' or 'auto' there)"
                )
    return RefineTable(**specs), tuple(axis for axis, is_auto in auto.items() if is_auto)


def _even(profile: np.ndarray) -> bool:
    """The profile is even on a grid symmetric about 0 (the scenes' v- and x-grids are)."""
    return bool(np.allclose(profile, profile[::-1], rtol=1e-12, atol=1e-14 * profile.max()))


def _bump_about_zero(profile: np.ndarray, delta0: float) -> bool:
    """The bump about the profile's maximum (the run of points above ``VALLEY * delta0`` times it, as
    :meth:`~jko_cvx.mesh.maps.FollowingMap.from_density` delimits it) reaches the middle of the symmetric grid."""
    lo, hi = bump_about_maximum(profile, VALLEY * delta0)
    n = profile.size
    return lo <= (n - 1) // 2 <= hi or lo <= n // 2 <= hi


def _resolve_centre(scene: Scene, f0: np.ndarray, axes: tuple[str, ...]) -> Scene:
    """``refine.<axis>.centre = "auto"``: the paper's map at 0 where f0's projection on the axis is even (max_x f0
    in v, max_v f0 in x) and, on a homogeneous scene with a one-bump map, the bump about f0's maximum reaches 0;
    the map that follows the concentration elsewhere; always the paper's map where the sets are the quadrant's.

    Without transport nothing but the collision moves mass, and the concentration forms about f0's maxima
    (gamma = 1: at the argmax, T = 1/(2 max f0)): an even datum whose maxima sit apart from 0 (bumps at -c and
    c) concentrates there, and the paper's one-bump map, centred at 0, would spread its set over both and
    refine neither.  On inhomogeneous scenes transport carries the bumps together (eqn:f0's meet at x = 0),
    and the paper's maps of its symmetric data stay the default."""
    if scene.refine.concentration_set != "projections":
        return scene
    refine = scene.refine
    for axis in axes:
        profile = (f0 if f0.ndim == 1 else f0.max(axis=0)) if axis == "v" else f0.max(axis=1)
        spec = getattr(refine, axis)
        apart = scene.x is None and spec.bumps == 1 and not _bump_about_zero(profile, spec.delta0)
        if not _even(profile) or apart:
            refine = dataclasses.replace(refine, **{axis: dataclasses.replace(getattr(refine, axis), centre="follow")})
    return scene if refine is scene.refine else dataclasses.replace(scene, refine=refine)


def _check_combinations(top, v, x, t, c, s, o) -> None:
    """Cross-table checks: values fine alone that are wrong together."""
    # W(v) = |v|^gamma / gamma on |v| <= 2 L_v (differences of grid points) must be finite:
    # at most max((2 L_v)^gamma, 1) / gamma
    log_w = max(top.gamma * math.log(2 * v.L), 0.0) - math.log(top.gamma)
    if log_w > math.log(1e300):
        raise SceneError(
            f"gamma = {top.gamma:g} makes the kernel |v|^gamma/gamma overflow on the velocity grid "
            f"(|v| up to 2 v.L = {2 * v.L:g})"
        )
    # the energy term of a step, dt * strength * W(v), finite on the grid
    if math.log(t.dt) + math.log(top.strength) + log_w > math.log(1e300):
        raise SceneError(
            f"strength = {top.strength:g} with time.dt = {t.dt:g}: the interaction term dt * strength * W(v) "
            f"overflows on the velocity grid (W up to {math.exp(min(log_w, 700.0)):.3g}); strength or time.dt "
            "must be smaller"
        )
    for axis, grid in (("v", v), ("x", x)):
        spacing = 2 * grid.L / grid.n if grid is not None else 1.0
        if not 1e-90 <= spacing <= 1e90:  # PCHIP's coefficients divide by its cube
            raise SceneError(
                f"{axis}.L = {grid.L:g} with {axis}.n = {grid.n}: the grid spacing 2 L / n = {spacing:.3g} must lie in "
                "[1e-90, 1e90] (its cube, in the cubic interpolation of the transport and the remaps, must stay "
                "floating-point)"
            )
    if math.isfinite(c.beta) and t.dt / c.beta > 1e150:
        raise SceneError(
            f"collision.beta = {c.beta:g} with time.dt = {t.dt:g}: the Fisher weight (dt/beta)^2 overflows; "
            "beta must be a number > 0 well above dt * 1e-150 (inf allowed)"
        )
    try:  # the policy checks its parameters (eps_t < dt, halve_on only where the step halves)
        step_policy(t.policy, t.dt, t.eps_t, t.halve_on, prefix="time.")
    except ValueError as exc:
        raise SceneError(str(exc)) from None
    if t.policy == "fixed" and t.dt > top.t_end:  # (other policies take dt as a cap or a first try)
        raise SceneError(
            f"time.dt = {t.dt:g} is larger than t_end = {top.t_end:g} with time.policy = 'fixed': the run would take "
            "one step of t_end, not of the time.dt asked for; time.dt must be at most t_end"
        )
    if x is None and s.eps_x > 0:
        raise SceneError("stop.eps_x needs an [x] grid (a homogeneous scene has no x-cells)")
    if any(tk > top.t_end for tk in o.times):
        raise SceneError(f"output.times must be a list of numbers in [0, t_end = {top.t_end:g}], got {list(o.times)!r}")


def _check_overlap(overrides: Mapping[str, Any]) -> None:
    """SceneError where one dotted key is a table and another one of its keys: one would drop the other."""
    keys = {str(k) for k in overrides}
    for b in sorted(keys):
        parts = b.split(".")
        for a in (".".join(parts[:i]) for i in range(1, len(parts))):
            if a in keys:
                raise SceneError(
                    f"overrides {a!r} and {b!r} overlap: {a!r} sets the whole table, so one would silently drop the "
                    f"other; give the keys of {a} one by one"
                )


def with_overrides(data: Mapping[str, Any], overrides: Mapping[str, Any] | None) -> dict[str, Any]:
    """A deep copy of the scene document ``data`` with dotted keys set (``{"time.dt": 0.005}``).

    A value ``None`` removes the key (``{"x": None}`` drops the x-grid).  A table and one of its
    keys (``"v"`` and ``"v.n"``) are refused: one would drop the other.  The result is not
    validated here; :func:`scene_from_dict` does that, so a misspelt override is refused
    like a misspelt key in a file.
    """
    if overrides is not None and not isinstance(overrides, Mapping):
        raise TypeError(
            f"overrides must be a mapping of dotted scene keys to values ({{'v.n': 41}}), "
            f"got {type(overrides).__name__}"
        )
    out = copy.deepcopy(dict(data))
    _check_overlap(overrides or {})
    for dotted, val in (overrides or {}).items():
        *parents, leaf = str(dotted).split(".")
        node = out
        for i, part in enumerate(parents):
            nxt = node.setdefault(part, {})
            if not isinstance(nxt, dict):
                raise SceneError(f"override {dotted!r}: {'.'.join(parents[: i + 1])} is not a table")
            node = nxt
        if val is None:
            node.pop(leaf, None)
        else:
            node[leaf] = copy.deepcopy(val)
    return out


MAX_SCENE_BYTES = 1 << 20
"""The largest scene file read (1 MiB; the shipped scenes are under 4 kB)."""


def _read_toml(path: Path) -> dict[str, Any]:
    if path.is_dir():
        raise SceneError(f"scene path {str(path)!r} is a directory, not a TOML file")
    if path.exists() and not path.is_file():  # a FIFO or a device would block the read or never end
        raise SceneError(f"scene path {str(path)!r} is not a regular file")
    try:
        with path.open("rb") as fh:
            raw = fh.read(MAX_SCENE_BYTES + 1)
    except FileNotFoundError:
        names = shipped_scene_names()
        close = difflib.get_close_matches(path.name, names, n=4)
        hint = "" if path.suffix == ".toml" else f" (shipped scenes: {', '.join(names)})"
        if close and path.suffix != ".toml":
            hint = f" (did you mean the shipped scene {' or '.join(map(repr, close))}?)"
        raise SceneError(f"scene file not found: {str(path)!r}{hint}") from None
    except OSError as exc:
        raise SceneError(f"cannot read scene file {str(path)!r}: {exc.strerror or exc}") from None
    if len(raw) > MAX_SCENE_BYTES:
        raise SceneError(f"scene file {str(path)!r} is larger than {MAX_SCENE_BYTES} bytes: not a scene")
    try:
        # a UTF-8 byte-order mark (some editors write one) is not part of the TOML document
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise SceneError(f"scene file {str(path)!r} is not UTF-8 text: {exc.reason} at byte {exc.start}") from None
    return parse_toml(text, repr(str(path)))


def parse_toml(text: str, source: str = "scene") -> dict[str, Any]:
    """The TOML document ``text`` as a dict; any syntax error is a :class:`SceneError` naming ``source``."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"scene file {source} is not valid TOML: {exc}") from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise SceneError(f"scene file {source} is not a scene: its arrays or tables are nested too deeply") from None


def load_scene(path: str | Path, overrides: Mapping[str, Any] | None = None, limits: Limits | None = None) -> Scene:
    """Read and validate a TOML scene file (parsed as data with ``tomllib``).

    ``path`` may also be the name of a shipped scene (``"tab_bu_g1"``) when no such file
    exists.  ``overrides`` sets dotted keys before validation (:func:`with_overrides`).

    Examples
    --------
    A minimal homogeneous scene (every other key takes its default; ``jko-cvx scene keys`` and the
    scene reference list them all):

    >>> import tempfile
    >>> from pathlib import Path
    >>> from jko_cvx import load_scene
    >>> text = '''
    ... name = "my_scene"
    ... gamma = 1.0
    ... t_end = 0.05
    ... [v]
    ... L = 2.0
    ... n = 41
    ... [initial]
    ... kind = "gaussians"
    ... amplitudes = [1.0]
    ... rates = [2.0]
    ... centres = [0.0]
    ... [time]
    ... dt = 0.01
    ... '''
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     path = Path(tmp) / "my_scene.toml"
    ...     _ = path.write_text(text)
    ...     scene = load_scene(path, {"v.n": 61})
    >>> scene.name, scene.v.n, scene.collision.method, scene.collision.beta
    ('my_scene', 61, 'newton', inf)
    >>> load_scene("tab_bu_g1").name  # a shipped scene by name
    'tab_bu_g1'
    """
    p = Path(path)
    if not p.exists() and str(path) in shipped_scene_names():
        return shipped_scene(str(path), overrides, limits)
    return scene_from_dict(with_overrides(_read_toml(p), overrides), limits)


_SHIPPED = resources.files("jko_cvx.scene") / "shipped"


def shipped_scene_names() -> list[str]:
    """Names of the scenes shipped as package data (``jko_cvx/scene/shipped/*.toml``)."""
    return sorted(p.name[: -len(".toml")] for p in _SHIPPED.iterdir() if p.name.endswith(".toml"))


def shipped_scene(name: str, overrides: Mapping[str, Any] | None = None, limits: Limits | None = None) -> Scene:
    """A shipped scene (package data) by name, with dotted-key ``overrides`` applied before validation.

    Examples
    --------
    >>> from jko_cvx import shipped_scene
    >>> from jko_cvx.scene import shipped_scene_names
    >>> "tab_bu_g1" in shipped_scene_names()
    True
    >>> scene = shipped_scene("tab_bu_g1", {"time.dt": 0.005})
    >>> scene.name, scene.time.dt, scene.t_end
    ('tab_bu_g1', 0.005, 1.0)
    """
    return scene_from_dict(with_overrides(shipped_document(name), overrides), limits)


def shipped_document(name: str) -> dict[str, Any]:
    """The TOML document of a shipped scene as its file writes it: the keys it sets, nothing the loader
    fills in or resolves (``refine.v.centre = "auto"`` stays ``"auto"``; absent keys stay absent).
    An unknown name raises :class:`SceneError` naming the shipped scenes."""
    names = shipped_scene_names()
    if name not in names:
        close = difflib.get_close_matches(str(name), names, n=4)
        hint = f" (did you mean {' or '.join(map(repr, close))}?)" if close else ""
        raise SceneError(f"no shipped scene {name!r}{hint}; shipped: {names}")
    return tomllib.loads((_SHIPPED / f"{name}.toml").read_text(encoding="utf-8"))


def default_scene(overrides: Mapping[str, Any] | None = None, limits: Limits | None = None) -> Scene:
    """The built-in default: homogeneous gamma = 1, g1 = exp(-2 v^2), Table tab:bu set-up (dt = 0.01,
    N_v = 121, delta = delta0 = 0.5, eps_v = 1e-3/4, log Fisher beta = 6000: the physics of the shipped
    ``tab_bu_g1``), run to blow-up (exact T = 0.5).  ``overrides`` sets dotted keys before validation,
    as for :func:`shipped_scene` (the limits are checked on the scene that runs).

    Examples
    --------
    >>> from jko_cvx import default_scene
    >>> scene = default_scene()
    >>> scene.name, scene.gamma, scene.v.n, scene.time.dt, scene.stop.eps_v
    ('default_tab_bu_g1', 1.0, 121, 0.01, 0.00025)
    >>> default_scene({"t_end": 0.05}).t_end
    0.05
    """
    return scene_from_dict(with_overrides(default_document(), overrides), limits)


def default_document() -> dict[str, Any]:
    """The document of :func:`default_scene` as written: the keys it sets, nothing the loader fills in
    or resolves (the scene template's example)."""
    return {
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
        # beta = 6000, the weight of the package's tab:bu (tab_bu_g1; the paper states none): weak
        # enough that the fitted blow-up time lands on the exact one with a tight bar.  A stronger
        # term slows the final narrowing: beta = 1000 meets the table's T_b = 0.51 but its fit comes
        # late with a wide bar; beta = 10 / 100 cap max f at 9.6 / 42.
        "collision": {"method": "newton", "beta": 6000.0, "fisher": "log"},
        "stop": {"eps_v": 1e-3 / 4, "on_solver_failure": False},
        "output": {"every": 5, "checkpoint_every": 5},
    }
