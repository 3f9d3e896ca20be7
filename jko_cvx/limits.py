"""Run-size limits: the largest step count and memory estimate a run may have.

The defaults :data:`DEFAULT_MAX_STEPS` and :data:`DEFAULT_MAX_GIB` are overridden by the
environment variables ``JKO_CVX_MAX_STEPS`` and ``JKO_CVX_MAX_GIB``.  Scenes are checked
against them by :func:`jko_cvx.scene.limits.check_limits`, fixed-grid runs by
:func:`jko_cvx.evolve.evolve_fixed_grid`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

__all__ = ["DEFAULT_MAX_GIB", "DEFAULT_MAX_STEPS", "GIB_ENV", "STEPS_ENV", "Limits"]

DEFAULT_MAX_STEPS = 10_000_000
DEFAULT_MAX_GIB = 16.0
STEPS_ENV = "JKO_CVX_MAX_STEPS"
GIB_ENV = "JKO_CVX_MAX_GIB"



@dataclass(frozen=True)
class Limits:
    """The largest step count and memory estimate (GiB) a run may have."""

    max_steps: float = DEFAULT_MAX_STEPS
    max_gib: float = DEFAULT_MAX_GIB

    @classmethod
    def from_env(cls) -> Limits:
        """The defaults, overridden by ``JKO_CVX_MAX_STEPS`` / ``JKO_CVX_MAX_GIB`` where set."""
        return cls(_env_number(STEPS_ENV, DEFAULT_MAX_STEPS), _env_number(GIB_ENV, DEFAULT_MAX_GIB))


def _env_number(name: str, default: float) -> float:
    text = os.environ.get(name)
    if text is None or not text.strip():
        return default
    try:
        val = float(text)
    except ValueError:
        raise ValueError(f"environment variable {name} must be a number > 0, got {text!r}") from None
    if not val > 0:
        raise ValueError(f"environment variable {name} must be a number > 0, got {text!r}")
    return val
