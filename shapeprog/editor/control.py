"""The editors' controls: :class:`Control` (one free parameter of a program: kind, range, value, place in the
text) and what the control builders of :mod:`shapeprog.editor.controls` and
:mod:`shapeprog.editor.macro_controls` share. The kinds of control and :func:`page_value` (a value from the
browser page, made what the check takes) are :mod:`shapeedit.control`'s, which the CSG editor shares."""
from __future__ import annotations

import re
from dataclasses import dataclass

import torch

from shapeedit.control import BOOL, CHOICE, FLOAT, INT, KINDS, PAGE_DECIMALS, BaseControl, Value, page_value

from ..errors import EditError
from ..lang import Attach, Cuboid, Reflect, Squeeze, Translate

__all__ = ["BOOL", "CHOICE", "FLOAT", "INT", "KINDS", "MAX_DIM", "MIN_DIM", "PAGE_DECIMALS", "Control", "Value",
           "page_value"]

#: Smallest cuboid extent a control offers (the executor's valid range, as :func:`shapeprog.fit.fit`).
MIN_DIM = 0.01
#: Largest cuboid extent a control offers (corpus maximum: 2.788); a larger current value widens it.
MAX_DIM = 4.0


@dataclass(frozen=True)
class Control(BaseControl):
    """One free parameter of a program (:class:`shapeedit.control.BaseControl`: kind, value, range, choices
    and the check of a value) and its place in the text.

    Attributes:
        name: unique within the program (``Program_1:3:attach.y2``; ``2:four_legs.s`` for macro programs).
        kind: ``'float'``, ``'int'``, ``'bool'`` or ``'choice'``.
        label: a short description for people (``'line 5 attach(cube0, bbox) y2'``).
        line, column: 1-based place of the value's token in the printed program.
        lines: 1-based lines whose text the control changes (two for a shared sub-program bbox).
        cuboids: indices (executed leaf order) of the leaf cuboids the control moves: those whose
            corners have a non-zero derivative with respect to it (float and int), or those that the
            same line's floats move or the line creates (bool and choice). Empty when not computed.

    Example:
        >>> c = Control("Program_0:1:cuboid.h", FLOAT, 0.5, low=0.01, high=4.0)
        >>> page_value(c, 0.30000000000000004), c.check(page_value(c, 0.30000000000000004))
        (0.3, 0.3)
    """

    line: int = 1
    column: int = 1
    lines: tuple[int, ...] = ()
    cuboids: tuple[int, ...] = ()

    def check(self, value, file: str = "<edit>") -> Value:
        """``value`` in this control's type, or :class:`EditError` (wrong type, not finite, out of range,
        not a choice)."""
        return self.checked(value, lambda reason: EditError(reason, file, self.line, self.column, str(self.value),
                                                            control=self.name, value=value))


@dataclass(frozen=True)
class _Spec:
    """A control and the places it writes: ``slots`` of (block index, statement index, field) for
    ShapeAssembly, (line index, argument index) for macro programs; ``params`` its indices in the
    executor's parameter vector."""

    control: Control
    slots: tuple
    params: tuple[int, ...] = ()


# ----------------------------------------------------------------------------- text positions

_ARG_FIELDS = {
    Cuboid: ("l", "h", "w", "aligned"),
    Attach: ("a", "b", "x1", "y1", "z1", "x2", "y2", "z2"),
    Squeeze: ("a", "b", "c", "face", "u", "v"),
    Reflect: ("a", "axis"),
    Translate: ("a", "axis", "n", "d"),
}
#: The statement fields that hold cuboid names.
_NAME_FIELDS = ("a", "b", "c")
_FLOAT_RANGE = {"l": (MIN_DIM, MAX_DIM), "h": (MIN_DIM, MAX_DIM), "w": (MIN_DIM, MAX_DIM)}


def _arg_columns(text: str) -> list[int]:
    """0-based offsets of the arguments of ``f(a, b, ...)`` in ``text`` (the printer's ', ' separators)."""
    start = text.index("(") + 1
    out = [start]
    for m in re.finditer(r", ", text[start:]):
        out.append(start + m.end())
    return out


def _range(lo: float, hi: float, v: float) -> tuple[float, float]:
    return (min(lo, v), max(hi, v))


def _head(s) -> str:
    """A statement without its values: ``cube0 = Cuboid``, ``attach(cube0, bbox)``, ``reflect(cube1)``: its
    cuboid-name arguments, in :data:`_ARG_FIELDS` order."""
    if isinstance(s, Cuboid):
        return f"{s.name} = Cuboid"
    names = [f for f in _ARG_FIELDS[type(s)] if f in _NAME_FIELDS]
    return f"{type(s).__name__.lower()}({', '.join(getattr(s, f) for f in names)})"


# ----------------------------------------------------------------------------- ShapeAssembly


#: Derivatives below this share of a leaf's largest one count as zero when finding the cuboids a control moves.
_GRAD_TOL = 1e-6


def _moved(corners, x):
    """(L, P) derivatives of each leaf's randomly weighted corner sum with respect to each parameter, and
    (L,) the size below which a leaf's derivative counts as zero."""
    L, P = corners.shape[0], x.shape[0]
    grads = torch.zeros(L, P, dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    for leaf in range(L if P else 0):
        w = torch.rand(8, 3, generator=g, dtype=corners.dtype) + 0.5  # no cancellation between corners
        (grad,) = torch.autograd.grad((corners[leaf] * w).sum(), x, retain_graph=True, allow_unused=True)
        if grad is not None:
            grads[leaf] = grad.detach().to(torch.float64)
    # a path that cancels exactly (a squeeze overriding a declared extent) leaves rounding noise
    tol = _GRAD_TOL * grads.abs().amax(1).clamp_min(1e-6) if P else torch.zeros(L, dtype=torch.float64)
    return grads, tol


def _influence(specs, moved, made, line_of, key_of) -> list[tuple[int, ...]]:
    """Leaves per control: a number's by its derivative (the sum over the numbers it sets); a discrete
    one's are its line's numbers' leaves and the leaves its line created."""
    grads, tol = moved

    def leaves_of(params) -> set[int]:
        d = grads[:, list(params)].sum(1)
        return set(_nonzero(d.abs() > tol))

    by_line: dict = {}
    for spec in specs:
        if spec.params:
            by_line.setdefault(key_of(spec), set()).update(leaves_of(spec.params))
    out = []
    for spec in specs:
        if spec.params and spec.control.kind == FLOAT:
            leaves = leaves_of(spec.params)
        else:
            ln = line_of(spec)
            leaves = by_line.get(key_of(spec), set()) | {k for k, m in enumerate(made) if m == ln}
        out.append(tuple(sorted(leaves)))
    return out


def _nonzero(mask) -> list[int]:
    return mask.nonzero().flatten().tolist()


# ----------------------------------------------------------------------------- macro programs
