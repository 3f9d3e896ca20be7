"""Size limits of a scene: refuse, before anything is allocated or written, a run that cannot fit.

Two estimates, both cheap arithmetic on the scene:

* **steps**: ``t_end / dt`` for the fixed and halving policies (halving only adds steps);
  for the CFL rule of ``alg:SPMCSL-JKO``, ``t_end / min(dt, 0.9 dv / L_v, 0.9 dx / L_x)`` on
  the uniform grids (refinement makes the cells, hence the steps, smaller still).
* **memory** (bytes): ``8 (4 B N_v^2 + 40 B N_v + S B N_v)`` with ``B = N_x`` (1 when
  homogeneous): the dense N_v x N_v blocks of the energy and of the (batched) Newton
  Hessians and their factors, about forty work arrays of the density's size, and the
  ``S`` snapshots a run keeps (``steps / output.every`` plus ``output.times``).  For
  gamma = 1, 2 and 3 Newton forms no dense Hessian (banded, rank one, or the exact
  banded-plus-rank-two solve of :mod:`jko_cvx.collision._structured`), so the dense part is
  the energy matrix and one factor per thread, ``8 (4 N_v^2)``: measured 0.57 GiB at
  1025 x 1025, gamma = 3 (the scale benchmark), where the per-slice count
  gave 32 GiB.  The CVXPY methods hold far more per slice they solve at once (``W`` slice
  threads, ``JKO_CVX_THREADS``, at most ``B``): ``conic`` ``8 c N_v^2 W`` more, with ``c = 800``
  where the energy's positive part has full rank (2 < gamma, not an even integer: Clarabel's
  factorisation of the dense block and CVXPY's copies of it; peak RSS over the interpreter's
  measured 515 N_v^2 doubles at gamma = 3 and 775 at gamma = 2.5, N_v = 300-1200) and
  ``c = 120`` otherwise (78-110 measured at gamma = 1, 1.5, 2, 4); ``nlp`` ``c = 60`` (48
  measured).

The limits are :data:`DEFAULT_MAX_STEPS` steps and :data:`DEFAULT_MAX_GIB` GiB, raised
(or lowered) with the environment variables ``JKO_CVX_MAX_STEPS`` and ``JKO_CVX_MAX_GIB``
or a :class:`Limits` passed to :func:`jko_cvx.scene.scene_from_dict`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from jko_cvx.limits import GIB_ENV, STEPS_ENV, Limits
from jko_cvx.scene.schema import SceneError

if TYPE_CHECKING:
    from jko_cvx.scene.model import Scene

__all__ = ["SizeEstimate", "check_limits", "check_step_size", "estimate_size", "method_blocks"]

_GIB = 2.0**30

@dataclass(frozen=True)
class SizeEstimate:
    """Estimated steps and bytes of a run, with the parts of the memory estimate."""

    steps: float
    dense_bytes: float
    work_bytes: float
    snapshot_bytes: float

    @property
    def bytes(self) -> float:
        return self.dense_bytes + self.work_bytes + self.snapshot_bytes


def estimate_size(scene: Scene) -> SizeEstimate:
    """Steps and memory of ``scene`` (see the module docstring for the formulas)."""
    dt = scene.time.dt
    if scene.time.policy == "cfl":
        dt = min(dt, 0.9 * (2 * scene.v.L / (scene.v.n - 1)) / scene.v.L)
        if scene.x is not None:
            dt = min(dt, 0.9 * (2 * scene.x.L / scene.x.n) / scene.x.L)
    steps = math.ceil(scene.t_end / dt) if scene.t_end / dt < 1e300 else math.inf
    B, N = float(1 if scene.x is None else scene.x.n), float(scene.v.n)
    snapshots = min(steps + 1, steps / scene.output.every + 2) + len(scene.output.times)
    return SizeEstimate(
        steps=float(steps),
        dense_bytes=8 * (4 * (1.0 if scene.gamma in (1.0, 2.0, 3.0) else B) + _cvxpy_blocks(scene, B)) * N * N,
        work_bytes=8 * 40 * B * N,
        snapshot_bytes=8 * snapshots * B * N,
    )


def _cvxpy_blocks(scene: Scene, B: float) -> float:
    """N_v^2 doubles the CVXPY methods hold for the slices they solve at once (module docstring)."""
    return method_blocks(scene.collision.method, scene.gamma) * _slices_at_once(scene)


def _slices_at_once(scene: Scene) -> int:
    """The x-slices a run solves at once: the slice threads (``JKO_CVX_THREADS``), at most the x-grid's."""
    from jko_cvx.threads import slice_workers

    return min(1 if scene.x is None else scene.x.n, slice_workers())


def method_blocks(method: str, gamma: float) -> float:
    """N_v^2 doubles a collision method holds per slice beyond the energy matrix (0 for newton and sqp)."""
    if method == "conic":
        full_rank = gamma > 2 and not (gamma == int(gamma) and int(gamma) % 2 == 0)
        return 800.0 if full_rank else 120.0
    return 60.0 if method == "nlp" else 0.0


def check_step_size(n: int, gamma: float, methods: list[str], limits: Limits | None = None) -> None:
    """Refuse one collision step on ``n`` velocity points whose memory estimate (the energy matrix and the
    largest of ``methods``' blocks) exceeds ``limits``: ValueError naming ``--n``."""
    limits = Limits.from_env() if limits is None else limits
    nbytes = 8 * (4 + max((method_blocks(m, gamma) for m in methods), default=0.0)) * float(n) ** 2
    if nbytes > limits.max_gib * _GIB:
        raise ValueError(
            f"--n = {n} needs an estimated {_size(nbytes)} for one collision step ({', '.join(methods)}), above the "
            f"limit of {limits.max_gib:g} GiB; raise it with the environment variable {GIB_ENV} if the machine "
            "has the memory"
        )


def _size(nbytes: float) -> str:
    for unit, scale in (("TiB", 2.0**40), ("GiB", _GIB), ("MiB", 2.0**20)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{nbytes / 1024:.3g} KiB"


def check_limits(scene: Scene, limits: Limits | None = None) -> SizeEstimate:
    """Refuse ``scene`` when its step count or memory estimate exceeds ``limits`` (default: from the environment)."""
    if limits is None:
        try:
            limits = Limits.from_env()
        except ValueError as exc:
            raise SceneError(str(exc)) from None
    est = estimate_size(scene)
    if est.steps > limits.max_steps:
        raise SceneError(
            f"time.dt = {scene.time.dt:g} with t_end = {scene.t_end:g} (policy {scene.time.policy!r}) needs about "
            f"{est.steps:.3g} steps, above the limit of {limits.max_steps:.3g}; raise it with the environment "
            f"variable {STEPS_ENV} if that is intended"
        )
    if est.bytes > limits.max_gib * _GIB:
        grid = f"v.n = {scene.v.n}" + ("" if scene.x is None else f", x.n = {scene.x.n}")
        method = scene.collision.method
        at_once = ""
        if method_blocks(method, scene.gamma) > 0:
            from jko_cvx.threads import THREADS_ENV

            slices = _slices_at_once(scene)
            at_once = f"; method {method!r} holds its blocks for each of the {slices} slice(s) it solves at once"
            at_once += f" ({THREADS_ENV})" if scene.x is not None else ""
        raise SceneError(
            f"{grid} needs an estimated {_size(est.bytes)} (dense N_v x N_v blocks {_size(est.dense_bytes)}, "
            f"snapshots {_size(est.snapshot_bytes)}{at_once}), above the limit of {limits.max_gib:g} GiB; raise it "
            f"with the environment variable {GIB_ENV} if the machine has the memory"
        )
    return est
