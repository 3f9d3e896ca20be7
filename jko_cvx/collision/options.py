"""Solver options as data: one frozen dataclass per method, each field carrying what it accepts.

Every option of a collision method is a field of that method's options dataclass
(:class:`~jko_cvx.collision.conic.ConicOptions`, :class:`~jko_cvx.collision.newton.NewtonOptions`,
:class:`~jko_cvx.collision.sqp.SqpOptions`, :class:`~jko_cvx.collision.nlp.NlpOptions`), declared
with :func:`option`: its default and a :class:`Spec` (type, range, choices, and whether a
scene may set it).  :class:`Options` validates every field once, on construction, with the
checks of :mod:`jko_cvx.collision._checks`; the scene layer derives its allow-list from the same
specs (:func:`scene_specs`), so the two cannot drift apart.

Examples
--------
>>> Spec("float", lo=0.0, hi=1.0, lo_open=True).check("step", 1.0)
1.0
>>> Spec("float", lo=0.0, hi=1.0, lo_open=True).check("step", 0)
Traceback (most recent call last):
...
ValueError: step must lie in (0, 1], got 0
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from jko_cvx._numbers import is_real
from jko_cvx.collision._checks import check_bool, check_callable, check_choice, check_int, check_unit

__all__ = ["KINDS", "Options", "Spec", "option", "scene_specs"]

KINDS = ("float", "int", "bool", "str", "table", "callable", "array")
"""The kinds of value an option takes; a scene may set only the first five (data)."""


@dataclass(frozen=True)
class Spec:
    """What one option accepts.

    Parameters
    ----------
    kind : {"float", "int", "bool", "str", "table", "callable", "array"}
        ``"float"``: a finite real number in the range; ``"int"``: an integer ``>= lo``;
        ``"str"``: one of ``choices``; ``"table"``: a dict of keyword options;
        ``"callable"`` / ``"array"``: a function or a warm start (never from a scene).
    lo, hi : float, optional
        Bounds of a number, open where ``lo_open`` / ``hi_open``.
    choices : tuple of str, optional
        The closed enumeration of a string option.
    scene : bool, default True
        Whether a scene may set the option (only data: never a callable, a warm start or a
        file name).
    label : str, optional
        The option as error messages name it, where that says more than its name.
    text : str, optional
        What error messages say the value must be, where the range alone says too little.
    check : callable, optional
        ``check(label, value) -> value``: the option's own validation, used instead of the
        generic one of ``kind`` (the range and choices then describe what a scene may set).
    """

    kind: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] | None = None
    scene: bool = True
    label: str | None = None
    text: str | None = None
    check_with: Callable[[str, Any], Any] | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if self.scene and self.kind in ("callable", "array"):
            raise ValueError(f"a {self.kind} option is never set by a scene (scene=False)")

    def contains(self, x: float) -> bool:
        """Whether the number ``x`` is finite and in the range."""
        if not math.isfinite(x):
            return False
        if self.lo is not None and (x < self.lo or (self.lo_open and x == self.lo)):
            return False
        return not (self.hi is not None and (x > self.hi or (self.hi_open and x == self.hi)))

    def describe(self) -> str:
        """What the value must be, as the error message says it (after "must")."""
        if self.text is not None:
            return self.text
        if self.lo is not None and self.hi is not None:
            lb, rb = "(" if self.lo_open else "[", ")" if self.hi_open else "]"
            return f"lie in {lb}{self.lo:g}, {self.hi:g}{rb}"
        if self.lo is not None:
            return f"be a finite number {'>' if self.lo_open else '>='} {self.lo:g}"
        return "be a finite number"

    def check(self, name: str, value: Any) -> Any:
        """``value`` checked (and made a plain Python value), else ``ValueError``/``TypeError`` naming it."""
        label = self.label or name
        if self.check_with is not None:
            return self.check_with(label, value)
        if self.kind == "float":
            if (self.lo, self.hi, self.lo_open, self.hi_open) == (0.0, 1.0, True, True):
                return check_unit(label, value)
            if not is_real(value) or not self.contains(float(value)):
                raise ValueError(f"{label} must {self.describe()}, got {value!r}")
            return float(value)
        if self.kind == "int":
            return check_int(label, value, 1 if self.lo is None else int(self.lo))
        if self.kind == "bool":
            return check_bool(label, value)
        if self.kind == "str":
            return check_choice(label, value, self.choices or ())
        if self.kind == "callable":
            return check_callable(label, value)
        return value  # "table" and "array" options have a check_with or are checked by the solver


def option(default: Any, spec: Spec) -> Any:
    """A dataclass field with ``default`` that carries its :class:`Spec` (``metadata["spec"]``)."""
    return dataclasses.field(default=default, metadata={"spec": spec}, compare=spec.kind != "array")


class Options:
    """Base of the options dataclasses: every field checked by its :class:`Spec` on construction.

    A field whose default is ``None`` accepts ``None`` (a default the solver resolves); a
    subclass resolves what it can in its own ``__post_init__`` after calling this one.
    Fields are checked in their declared order, so the first bad one is the one reported.
    """

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # type: ignore[arg-type]
            value = getattr(self, f.name)
            if value is None and f.default is None:
                continue
            object.__setattr__(self, f.name, f.metadata["spec"].check(f.name, value))


def scene_specs(cls: type) -> dict[str, Spec]:
    """The fields of the options dataclass ``cls`` that a scene may set, with their specs, in order."""
    return {f.name: f.metadata["spec"] for f in dataclasses.fields(cls) if f.metadata["spec"].scene}
