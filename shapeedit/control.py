"""What the editors' controls share: the kinds of control, :class:`BaseControl` (a control's name, kind, value,
range and choices, and the check of a value against them) and :func:`page_value` (a value as a page's widget
sent it, made what the check takes). Standard library only.

Each editor's control adds where its value stands in the program text and the located error that a refused
value raises (:class:`shapeprog.editor.control.Control`, :class:`csgnet.editor.Control`).

Example:
    >>> c = BaseControl("r", INT, 20, low=0, high=64)
    >>> c.checked(12.0, ValueError), page_value(c, 12.4)
    (12, 12)
    >>> c.checked(65, ValueError)
    Traceback (most recent call last):
    ...
    ValueError: value 65 is outside [0, 64]
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Union

__all__ = ["BOOL", "CHOICE", "FLOAT", "INT", "KINDS", "PAGE_DECIMALS", "BaseControl", "Value", "page_value"]

FLOAT, INT, BOOL, CHOICE = "float", "int", "bool", "choice"
#: The kinds of control.
KINDS = (FLOAT, INT, BOOL, CHOICE)
#: Decimals a float slider's value keeps (a browser's 0.30000000000000004 arrives as 0.3).
PAGE_DECIMALS = 9

Value = Union[float, int, bool, str]


@dataclass(frozen=True)
class BaseControl:
    """One free parameter of a program, as both editors describe it.

    Attributes:
        name: unique within the program.
        kind: one of :data:`KINDS`.
        value: the current value.
        low, high: the range of a float or int (None otherwise), both included.
        choices: the values of a choice (empty otherwise).
        label: a short description for people.
    """

    name: str
    kind: str
    value: Value
    low: float | None = None
    high: float | None = None
    choices: tuple = ()
    label: str = ""

    def checked(self, value, bad: Callable[[str], Exception]) -> Value:
        """``value`` in this control's type; otherwise ``bad(reason)`` is raised: a wrong type, a number that is
        not finite or out of range, a value that is not one of the choices."""
        if self.kind == FLOAT:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise bad(f"expected a number, got {type(value).__name__} {value!r}")
            v = float(value)
            if not math.isfinite(v) or not self.low <= v <= self.high:
                raise bad(f"value {value!r} is outside [{self.low!r}, {self.high!r}]")
            return v
        if self.kind == INT:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or (
                    isinstance(value, float) and not (math.isfinite(value) and value.is_integer())):
                raise bad(f"expected an integer, got {type(value).__name__} {value!r}")
            v = int(value)
            if not self.low <= v <= self.high:
                raise bad(f"value {value!r} is outside [{int(self.low)}, {int(self.high)}]")
            return v
        if self.kind == BOOL:
            if not isinstance(value, bool):
                raise bad(f"expected True or False, got {type(value).__name__} {value!r}")
            return value
        if not isinstance(value, str) or value not in self.choices:
            raise bad(f"{value!r} is not one of {', '.join(map(str, self.choices))}")
        return value


def page_value(control: BaseControl | None, value):
    """A value as a page's widget sent it, made what a control's check takes: a float slider's number rounded
    to :data:`PAGE_DECIMALS` decimals, an int slider's to the nearest integer. Anything else (a drop-down's
    choice, another type, a non-finite number, a control the page does not know) is passed on unchanged, for
    the check to refuse with its located error.

    Example:
        >>> c = BaseControl("h", FLOAT, 0.5, low=0.01, high=4.0)
        >>> page_value(c, 0.30000000000000004), page_value(c, float("nan")) != page_value(c, float("nan"))
        (0.3, True)
        >>> page_value(BaseControl("r", INT, 20, low=0, high=64), "12")
        '12'
    """
    if control is None or isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return value
    if control.kind == FLOAT:
        return round(float(value), PAGE_DECIMALS)
    if control.kind == INT:
        return int(round(value))
    return value
