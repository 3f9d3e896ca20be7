"""Strict conversion of user numbers and arrays: each refusal names the argument.

``float(value)`` and ``np.asarray(value, dtype=float)`` accept too much for a numerical
package whose inputs are physics: ``float("10")`` parses a string, ``float(True)`` is 1,
a complex array loses its imaginary part with only a warning, a masked array drops its
mask, an object array of numbers hides whatever it holds.  The helpers here accept real
numbers (Python or NumPy, bool excluded) and arrays whose dtype is integer or floating,
and raise ``TypeError`` naming the argument otherwise.  Ranges are the caller's concern.
"""

from __future__ import annotations

from numbers import Real

import numpy as np
from numpy.typing import NDArray

__all__ = ["is_real", "real_array", "real_scalar"]


def is_real(value: object) -> bool:
    """A real number (Python or NumPy), not a bool or a string that ``float()`` would parse."""
    return isinstance(value, Real) and not isinstance(value, (bool, np.bool_))


def real_scalar(name: str, value: object) -> float:
    """``value`` as a float if it is a real number, else ``TypeError`` naming ``name``.

    A zero-dimensional NumPy array of a real dtype counts as a number (``np.float64(1)``
    and ``np.array(1.0)`` alike); strings, booleans, complex numbers and ``None`` do not.
    """
    if isinstance(value, np.ndarray) and value.ndim == 0 and _real_dtype(value.dtype):
        return float(value)
    if not is_real(value):
        raise TypeError(f"{name} must be a real number, got {value!r} ({type(value).__name__})")
    return float(value)  # type: ignore[arg-type]


def real_array(name: str, value: object) -> NDArray[np.float64]:
    """``value`` as a new float64 array, else ``TypeError`` naming ``name``.

    Accepted: NumPy arrays of integer or floating dtype and (nested) sequences of real
    numbers.  Refused: masked arrays (the mask would be ignored), arrays of bool, complex,
    object or string dtype, and sequences holding anything but real numbers.
    """
    if isinstance(value, np.ma.MaskedArray):
        raise TypeError(f"{name} must be a plain array of real numbers, got a masked array (its mask would be ignored)")
    if isinstance(value, np.ndarray):
        arr = value
    else:
        try:
            arr = np.array(value)
        except (TypeError, ValueError) as exc:  # ragged nesting
            raise TypeError(f"{name} must be an array of real numbers, got {type(value).__name__}") from exc
    if arr.dtype == object and arr.size:
        # a list mixing ints and floats gives a numeric dtype; object means something else is inside
        raise TypeError(f"{name} must be an array of real numbers, got {_object_contents(arr)}")
    if arr.size and not _real_dtype(arr.dtype):
        raise TypeError(f"{name} must be an array of real numbers, got dtype {arr.dtype}")
    return np.array(arr, dtype=np.float64, copy=True)


def _real_dtype(dtype: np.dtype) -> bool:
    return np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)


def _object_contents(arr: np.ndarray) -> str:
    for item in arr.ravel():
        if not is_real(item):
            return f"an element of type {type(item).__name__}"
    return "dtype object (convert it with .astype(float))"
