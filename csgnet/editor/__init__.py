"""The CSG program editor's core: controls on a program's primitives and operators, edits, a session with
undo / redo and exports. The browser page is :mod:`csgnet.editor.server` (``viser``, the ``editor``
extra), run by ``python -m csgnet edit PROGRAM``.

Controls (``index:primitive.parameter`` for the i-th draw of the program, ``index:op`` for the i-th
operator):

* one int per primitive parameter: a position in [0, 63] (the canvas), a radius or height in [0, 64];
  both widened to hold the current value (the language allows positions down to -1000 and anything up
  to :data:`csgnet.lang.MAX_PARAM`);
* one choice per draw among the primitives of its dimension with as many parameters, by their names in
  the table of primitives (circle, square, triangle in 2D; sphere, cube in 3D; cylinder alone); the
  vocabulary letters (``c``, ``p``, ``u``, ``y``) stay inside the language;
* one choice per operator: ``+``, ``*``, ``-``.

:func:`apply` prints the edited program and parses it back with :func:`csgnet.lang.parse`, and the
session renders it with :func:`csgnet.render`; no second interpreter.

Example:
    >>> p = parse("c(32,32,28)s(32,32,20)-")
    >>> [c.name for c in controls(p)]
    ['0:circle.kind', '0:circle.x', '0:circle.y', '0:circle.r', '1:square.kind', '1:square.x', '1:square.y', \
'1:square.r', '0:op']
    >>> apply(p, {"1:square.r": 12, "0:op": "+"}).text()
    'c(32,32,28)s(32,32,12)+'
    >>> apply(p, {"0:circle.kind": "triangle"}).text()
    't(32,32,28)s(32,32,20)-'
"""
from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Union

import numpy as np
from PIL import Image

from shapeedit import History, UndoableSession, export_stem
from shapeedit.control import CHOICE, INT, BaseControl, page_value
from shapeio.files import write_new_set
from shapeio.mesh import obj_text

from .. import primitives as P
from .. import render
from ..export import voxels_to_mesh
from ..lang import OPERATORS, Draw, Op, ParseError, Program, parse

__all__ = ["CHOICE", "INT", "CSGEditError", "CSGEditSession", "Control", "apply", "controls", "page_value",
           "render_png_bytes"]

#: Side of exported PNGs: the 64-pixel canvas upscaled by this factor.
PNG_SCALE = 4

Value = Union[int, str]


class CSGEditError(ParseError):
    """An edit that cannot be made: an unknown control, a value of the wrong type or out of range, or an
    edited program that the language refuses; located at the token in the printed program.

    Attributes:
        control: the control's name (None when not one control's fault).
        value: the value asked for.
    """

    def __init__(self, message: str, program: str = "", position: int | None = None, token: str | None = None,
                 control: str | None = None, value=None, file: str | None = None):
        self.control, self.value = control, value
        super().__init__(message if control is None else f"control {control!r}: {message}", program, position,
                         token, file, None if file is None else 1)


@dataclass(frozen=True)
class Control(BaseControl):
    """One free parameter of a CSG program (:class:`shapeedit.control.BaseControl`: kind, value, range, choices
    and the check of a value) and its place in the printed program.

    Attributes:
        name: ``'1:square.r'`` (draw index, primitive, parameter), ``'1:square.kind'``, ``'0:op'``.
        kind: ``'int'`` or ``'choice'``.
        value: the current value (an int, a primitive's name such as ``'sphere'``, or an operator).
        low, high: the range of an int (both included, ints).
        choices: the values of a choice.
        position: 0-based character offset of the value's token in the printed program.
        token: the index in ``program.tokens`` of the draw or operator it changes.
    """

    position: int = 0
    token: int = 0

    def check(self, value, program_text: str = "") -> Value:
        """``value`` in this control's type, or :class:`CSGEditError` at the token (wrong type, not an integer,
        out of range, not a choice)."""
        return self.checked(value, lambda reason: CSGEditError(reason, program_text, self.position, str(self.value),
                                                               control=self.name, value=value))


def _specs(program: Program) -> list[Control]:
    text = ""
    draws, ops = [], []
    di = oi = 0
    for ti, t in enumerate(program.tokens):
        start = len(text)
        piece = t.text()
        text += piece
        if isinstance(t, Op):
            ops.append(Control(f"{oi}:op", CHOICE, t.op, choices=tuple(OPERATORS), label=f"operator {oi + 1}",
                               position=start, token=ti))
            oi += 1
            continue
        row = P.primitive(t.kind)
        same = tuple(r.name for r in P.primitives(program.dim) if len(r.params) == len(row.params))
        head = f"{di}:{row.name}"
        draws.append(Control(f"{head}.kind", CHOICE, row.name, choices=same, label=f"{row.name} {di + 1}: primitive",
                             position=start, token=ti))
        offs = [m.start() + 1 for m in re.finditer(r"[(,]", piece)]
        for k, (pname, v) in enumerate(zip(row.params, t.params)):
            size = pname in ("r", "h")
            lo, hi = (0, P.SIZE) if size else (0, P.SIZE - 1)
            draws.append(Control(f"{head}.{pname}", INT, v, low=min(lo, v), high=max(hi, v),
                                 label=f"{row.name} {di + 1}: {pname}", position=start + offs[k], token=ti))
        di += 1
    return draws + ops


def controls(program: Program) -> list[Control]:
    """One :class:`Control` per primitive parameter, per draw's primitive and per operator (draws first,
    in program order, then operators)."""
    if not isinstance(program, Program):
        raise TypeError(f"expected a csgnet Program, got {type(program).__name__}")
    return _specs(program)


def apply(program: Program, values: Mapping[str, Value]) -> Program:
    """The program with the named controls set; printed and parsed back by the language.

    Raises:
        CSGEditError: an unknown control, a bad value (type, range, choice), or an edited text that the
            language refuses; located at the token in the printed program.
    """
    if not isinstance(values, Mapping):
        raise TypeError(f"`values` must be a mapping of control names to values, got {type(values).__name__}")
    text = program.text()
    specs = {c.name: c for c in controls(program)}
    kinds = {r.name: r.kind for r in P.primitives(program.dim)}
    toks = list(program.tokens)
    for name, v in values.items():
        c = specs.get(name)
        if c is None:
            raise CSGEditError(f"no such control (they are named like {', '.join(list(specs)[:3])})", text, 0, "",
                               control=str(name), value=v)
        v = c.check(v, text)
        t = toks[c.token]
        if isinstance(t, Op):
            toks[c.token] = Op(v)
        elif name.endswith(".kind"):
            toks[c.token] = Draw(kinds[v], t.params)
        else:
            k = P.primitive(t.kind).params.index(name.rsplit(".", 1)[1])
            toks[c.token] = Draw(t.kind, t.params[:k] + (v,) + t.params[k + 1:])
    try:
        new_text = "".join(t.text() for t in toks)
        return parse(new_text, program.dim)
    except ParseError as e:
        raise CSGEditError(e.reason, e.program, e.position, e.token) from None
    except ValueError as e:
        raise CSGEditError(str(e), text, 0, "") from None


def render_png_bytes(canvas: np.ndarray, scale: int = PNG_SCALE) -> bytes:
    """A ``(64, 64) bool`` canvas as PNG bytes, black on white, upscaled by nearest neighbour."""
    img = np.where(np.asarray(canvas, bool), 0, 255).astype(np.uint8)
    img = np.repeat(np.repeat(img, scale, 0), scale, 1)
    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG")
    return buf.getvalue()


class CSGEditSession(UndoableSession):
    """A CSG program being edited: its render, errors, undo / redo, exports.

    Args:
        text: the program text.
        dim: 2 or 3 (default: 3 when the text parses as 3D and not as 2D).
        name: stem of exported files.

    Attributes:
        program: the current program (None when the text did not parse).
        canvas: the render, ``(64, 64)`` bool in 2D, ``(64, 64, 64)`` in 3D (None without a program).
        error: the last operation's error (None after a success).
    """

    def __init__(self, text: str, dim: int | None = None, name: str = "csg"):
        self.dim = dim if dim is not None else self._guess_dim(text)
        self.name = export_stem(name, "csg")
        self.error: Exception | None = None
        self.history: History | None = None
        self.program = self.canvas = None
        try:
            program = parse(text, self.dim)
        except ParseError as e:
            self.error = e
            return
        self._record((program, self._render(program)))

    @staticmethod
    def _guess_dim(text: str) -> int:
        try:
            parse(text, 2)
            return 2
        except ParseError:
            try:
                parse(text, 3)
                return 3
            except ParseError:
                return 2

    def _render(self, program: Program) -> np.ndarray:
        return render(program, self.dim)[0]

    def _sync(self) -> None:
        self.program, self.canvas = self.history.current

    @property
    def text(self) -> str:
        return "" if self.program is None else self.program.text()

    def controls(self) -> list[Control]:
        return [] if self.program is None else controls(self.program)

    def set(self, values: Mapping[str, Value]) -> bool:
        """Set controls and render; False (and :attr:`error`) when the edit is refused."""
        if self.program is None:
            self.error = CSGEditError("there is no program to edit (it did not parse)")
            return False
        try:
            program = apply(self.program, values)
        except CSGEditError as e:
            self.error = e
            return False
        self.error = None
        if program != self.program:
            self.history.push((program, self._render(program)))
            self._sync()
        return True

    def set_text(self, text: str) -> bool:
        """Replace the program by a new text; False (and :attr:`error`) when it does not parse."""
        try:
            program = parse(text, self.dim)
        except ParseError as e:
            self.error = e
            return False
        self.error = None
        self._record((program, self._render(program)))
        return True

    def export(self, folder) -> list[Path]:
        """Write ``<name>_edit<NNN>.txt`` and the render (``.png`` in 2D, marching-cubes ``.obj`` in 3D) as new
        files in ``folder`` (NNN one more than the largest there; never replacing a file)."""
        if self.program is None:
            raise ValueError("there is no program to export (it did not parse)")
        folder = Path(folder)
        if not folder.is_dir():
            raise FileNotFoundError(f"{folder}: the export folder does not exist")
        data = {"txt": self.text + "\n"}
        if self.dim == 2:
            data["png"] = render_png_bytes(self.canvas)
        else:
            data["obj"] = obj_text(*voxels_to_mesh(self.canvas), digits=6,
                                   comment="csgnet voxel mesh: vertices in voxel units, vol[x, y, z] frame")
        taken = [re.fullmatch(re.escape(self.name) + r"_edit(\d+)\..*", p.name) for p in folder.iterdir()]
        n = max([int(m.group(1)) for m in taken if m] + [0]) + 1
        while True:
            try:
                return write_new_set((folder / f"{self.name}_edit{n:03d}.{k}", v) for k, v in data.items())
            except FileExistsError:
                n += 1
