"""Option checks shared by the collision solvers: each names the option and its allowed range.

NumPy scalars count as numbers (``tol=np.float32(1e-8)`` is accepted); booleans are not
numbers, and only ``True``/``False`` are booleans (``check_convexity="no"`` is refused).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from numbers import Integral
from typing import Any

import numpy as np

from jko_cvx._numbers import is_real

__all__ = ["check_bool", "check_callable", "check_choice", "check_int", "check_options_dict", "check_unit"]


def check_unit(name: str, value: object) -> float:
    """``value`` as a float in the open interval (0, 1), else ``ValueError`` naming ``name``."""
    if not is_real(value) or not 0 < float(value) < 1:
        raise ValueError(f"{name} must lie in (0, 1) (a real number), got {value!r}")
    return float(value)


def check_int(name: str, value: object, minimum: int = 1) -> int:
    """``value`` as an int ``>= minimum``, else ``ValueError`` naming ``name``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, Integral) or int(value) < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def check_bool(name: str, value: object) -> bool:
    """``value`` as a bool (``True``/``False`` or a NumPy bool), else ``TypeError`` naming ``name``."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def check_callable(name: str, value: object, signature: str | None = None) -> Callable[..., Any] | None:
    """``value`` if it is None or callable, else ``TypeError`` naming ``name``.

    With ``signature`` (``"callback(l, f, m, zeta)"``), the callable must accept that many
    positional arguments: a wrong signature is refused here, naming the option and the
    expected call, not by Python's own ``TypeError`` in the middle of a solve.
    """
    if value is not None and not callable(value):
        raise TypeError(f"{name} must be None or a callable, got {value!r}")
    if value is not None and signature is not None:
        nargs = signature.count(",") + 1
        try:
            inspect.signature(value).bind(*range(nargs))
        except TypeError as exc:
            raise TypeError(
                f"{name} is called as {signature}; {value!r} cannot take those {nargs} arguments ({exc})"
            ) from None
        except ValueError:  # no signature to inspect (some builtins): let the call decide
            pass
    return value  # type: ignore[return-value]


def check_options_dict(name: str, value: object) -> dict[str, Any]:
    """``value`` as a dict with string keys (None gives ``{}``), else ``TypeError`` naming ``name``."""
    if value is None:
        return {}
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise TypeError(f"{name} must be None or a dict of keyword options, got {value!r}")
    return dict(value)


def check_choice(name: str, value: object, allowed: tuple[str, ...]) -> str:
    """``value`` if it is one of ``allowed``, else ``ValueError`` naming ``name``."""
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name} must be one of {allowed}, got {value!r}")
    return value
