"""A program being edited: the program, its execution, the last good geometry, errors, undo / redo, a
target for goal-directed editing, and exports. No browser library is needed here.

:class:`EditSession` holds the state a page shows. An edit that fails (a value outside a control's range,
an edited text that the language refuses, an execution with a non-finite cuboid) leaves the program and
the geometry as they were and sets :attr:`EditSession.error`; a text that does not parse when the
session opens gives a session with no program and the error, so a page can show it.

Example:
    >>> s = EditSession("bbox = Cuboid(1.0, 1.0, 1.0, True)\\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\\n"
    ...                 "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n", "box.txt")
    >>> s.set({"Program_0:1:cuboid.h": 0.4}), s.shape.dims[0].tolist()
    (True, [0.5, 0.4000000059604645, 0.5])
    >>> s.set({"Program_0:1:cuboid.h": 9.0}), str(s.error)
    (False, "box.txt:2:21: control 'Program_0:1:cuboid.h': value 9.0 is outside [0.01, 4.0]")
    >>> s.undo(), s.shape.dims[0].tolist()
    (True, [0.5, 0.20000000298023224, 0.5])
"""
from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from typing import Mapping

import torch

from shapeedit import History, UndoableSession, export_stem
from shapeio.files import write_new_set
from shapeio.image import png_bytes

from .. import corpus
from ..errors import EditError, ExecutionError, ParseError
from ..execute import ExecutedShape, ExecutionPlan, execute, program_parameters
from ..io import obj_text
from ..lang import Program, parse, replace_numbers, to_text
from ..limits import decode
from ..macros.api import refactor
from ..macros.execute import compile_hierarchy, compile_program, execute as macro_execute, execute_hierarchy
from ..macros.hierarchy import MacroHierarchy, is_hierarchy_text, parse as parse_hierarchy, to_text as hierarchy_text
from ..macros.lang import parameters, replace_parameters, to_text as macro_text
from ..macros.library import Library
from ..metrics import chamfer
from ..picture import render_png
from .controls import Control, apply, controls

__all__ = ["EXPORT_KINDS", "EditSession", "corner_distance", "is_corpus_text", "load_program", "read_source",
           "refactor_source"]

#: What :meth:`EditSession.export` can write: the program text, the reference OBJ, a PNG picture.
EXPORT_KINDS = ("txt", "obj", "png")
#: Side of exported pictures in pixels.
PNG_SIZE = 512


def _is_macro_text(text: str) -> bool:
    return any(line.startswith("def ") for line in text.split("\n"))


def load_program(text: str, file: str = "<string>", library=None):
    """Parse a program text: a hierarchical macro program (:func:`shapeprog.macros.hierarchy.parse`) when
    it holds ``# .../Program_k`` block headers (what ``refactor -o`` writes); a macro program
    (:meth:`shapeprog.macros.library.Library.parse`) when a ``library`` is given or a line starts with
    ``def``; else ShapeAssembly (:func:`shapeprog.lang.parse`).

    Raises:
        ParseError: naming file, line and column.
    """
    if is_hierarchy_text(text):
        return parse_hierarchy(text, file, library)
    if library is not None or _is_macro_text(text):
        return (Library() if library is None else library).parse(text, file)
    return parse(text, file)


def is_corpus_text(text: str) -> bool:
    """Whether ``text`` is a ShapeAssembly program in the corpus format (``Assembly Program_k {`` blocks)."""
    return any(re.match(r"\s*Assembly\s+Program_\d+\s*\{", line) for line in text.split("\n"))


def refactor_source(text: str, file: str, library, category: str = "", shape_id: int = 0) -> str:
    """The hierarchical macro program text of a ShapeAssembly program rewritten with ``library``
    (:func:`shapeprog.macros.refactor`, the text ``refactor -o`` writes).

    Raises:
        ParseError: the text is not ShapeAssembly.
        ValueError: a block that the modified grammar cannot hold.
    """
    return refactor(parse(text, file), library, category=category, shape_id=shape_id).text


def read_source(spec: str) -> tuple[str, str]:
    """The text and file name of a program named like the CLI does: a corpus id (``chair/173``) or a file.

    Raises:
        FileNotFoundError: neither an existing file nor a corpus id.
        KeyError: a corpus id that the corpus does not hold.
        ParseError: a file that is not UTF-8.
    """
    path = Path(spec)
    cat, _, ident = spec.partition("/")
    if path.is_file():
        return decode(path.read_bytes(), str(path)), str(path)
    if cat in corpus.CATEGORIES and ident.isascii() and ident.isdigit():
        return corpus.read(cat, int(ident)), f"{cat}/{int(ident)}.txt"
    raise FileNotFoundError(f"{spec!r} is neither a file nor a corpus id like 'chair/173'")


def corner_distance(shape: ExecutedShape, target: ExecutedShape) -> float:
    """The goal-directed editing distance: the symmetric chamfer distance between the two shapes' cuboid
    corners (every leaf's 8 corners as points; mean nearest-corner distance each way, unsquared,
    :func:`shapeprog.metrics.chamfer` with ``eps=0``). 0 for equal shapes; ``inf`` when one has no leaf."""
    a = shape.corners.detach().reshape(-1, 3).to(torch.float64)
    b = target.corners.detach().reshape(-1, 3).to(torch.float64)
    if a.shape[0] == 0 or b.shape[0] == 0:
        return math.inf
    return float(chamfer(a, b, eps=0.0, method="brute"))


class _State:
    """One history entry: a program and its geometry."""

    __slots__ = ("program", "shape")

    def __init__(self, program, shape):
        self.program, self.shape = program, shape


class EditSession(UndoableSession):
    """A program being edited.

    Args:
        text: the program text (ShapeAssembly, or a macro program: see :func:`load_program`).
        file: its name in error messages and exports.
        library: the macro :class:`~shapeprog.macros.library.Library` of a macro program.
        name: the stem of exported files (default: ``file`` without suffix, ``/`` as ``_``).

    Attributes:
        program: the current program (None when the text did not parse).
        shape: the current geometry (:class:`~shapeprog.execute.ExecutedShape`; None without a program).
        error: the error of the last operation (None when it succeeded); the page shows it.
        target: the target geometry of goal-directed editing (None without one).
        history: the undo / redo :class:`~shapeedit.History` of states.
    """

    def __init__(self, text: str, file: str = "<string>", library=None, name: str | None = None):
        self.file, self.library = file, library
        self.name = export_stem(name or str(Path(file).with_suffix("")).strip("/"), "program")
        self.error: Exception | None = None
        self.target: ExecutedShape | None = None
        self._controls: dict = {}
        self._plan = None
        self._plan_key = None
        self.history: History | None = None
        self.program = self.shape = None
        try:
            program = load_program(text, file, library)
            shape = self._execute(program)
        except (ParseError, ExecutionError) as e:
            self.error = e
            return
        self._record(_State(program, shape))

    # -- state
    @property
    def is_macro(self) -> bool:
        return self.program is not None and not isinstance(self.program, Program)

    @property
    def text(self) -> str:
        """The current program's text ('' without a program)."""
        if self.program is None:
            return ""
        if self.is_macro:
            if isinstance(self.program, MacroHierarchy):
                return hierarchy_text(self.program)
            return macro_text(self.program)
        return to_text(self.program)

    def _sync(self) -> None:
        st = self.history.current
        self.program, self.shape = st.program, st.shape

    def _execute(self, program) -> ExecutedShape:
        """Execute, reusing the compiled plan while only numbers change (ShapeAssembly)."""
        with torch.no_grad():
            if not isinstance(program, Program):
                if isinstance(program, MacroHierarchy):
                    return execute_hierarchy(program, self.library)
                return macro_execute(program, self.library)
            key = self._structure(program)
            if key != self._plan_key:
                self._plan, self._plan_key = ExecutionPlan([program]), key
            try:
                return self._plan.run([program_parameters(program)])[0]
            except ExecutionError as e:
                raise ExecutionError(e.reason, e.line, file=self.file) from None

    def _structure(self, program):
        """The program with every number zeroed: equal for programs that differ in numbers only."""
        if isinstance(program, Program):
            return replace_numbers(program, iter(lambda: 0.0, None))
        if isinstance(program, MacroHierarchy):
            return program.replace(replace_parameters(p, [0.0] * len(parameters(p))) for p in program.programs)
        return replace_parameters(program, [0.0] * len(parameters(program)))

    def controls(self, cuboids: bool = True) -> list[Control]:
        """The current program's controls with their current values. The cuboids each moves are found
        once per program structure (a change of numbers only keeps them); ``cuboids=False`` leaves them
        out (and skips finding them)."""
        if self.program is None:
            return []
        plain = controls(self.program, self.library, cuboids=False)
        if not cuboids:
            return plain
        key = self._structure(self.program)
        if key not in self._controls:
            if len(self._controls) > 64:
                self._controls.clear()
            self._controls[key] = {c.name: c.cuboids for c in controls(self.program, self.library)}
        moved = self._controls[key]
        return [dataclasses.replace(c, cuboids=moved.get(c.name, ())) for c in plain]

    def values(self) -> dict:
        """Control name -> current value."""
        return {c.name: c.value for c in controls(self.program, self.library, cuboids=False)} if self.program else {}

    # -- edits
    def set(self, values: Mapping[str, object]) -> bool:
        """Set controls (:func:`shapeprog.editor.apply`) and execute. Returns True on success; on failure the
        program and geometry stay and :attr:`error` says why (an :class:`EditError` or
        :class:`ExecutionError`)."""
        if self.program is None:
            self.error = EditError("there is no program to edit (it did not parse)", self.file, 1, 1, "")
            return False
        try:
            program = apply(self.program, values, self.library, self.file)
            shape = self._execute(program)
        except (ParseError, ExecutionError) as e:
            self.error = e
            return False
        self.error = None
        if program != self.program:
            self.history.push(_State(program, shape))
            self._sync()
        return True

    def set_text(self, text: str) -> bool:
        """Replace the program by a new text (e.g. typed in the page). On failure nothing changes and
        :attr:`error` holds the :class:`ParseError` or :class:`ExecutionError`."""
        try:
            program = load_program(text, self.file, self.library)
            shape = self._execute(program)
        except (ParseError, ExecutionError) as e:
            self.error = e
            return False
        self.error = None
        self._record(_State(program, shape))
        return True

    # -- goal-directed editing
    def set_target(self, text: str, file: str = "<target>") -> None:
        """Execute a target program (ShapeAssembly text) for :meth:`distance`.

        Raises:
            ParseError, ExecutionError: the target does not parse or execute.
        """
        with torch.no_grad():
            self.target = execute(parse(text, file))

    def distance(self) -> float | None:
        """:func:`corner_distance` from the current shape to the target (None without either)."""
        if self.target is None or self.shape is None:
            return None
        return corner_distance(self.shape, self.target)

    # -- expansion of macro programs
    def expanded_text(self) -> str:
        """The current macro program expanded to a flat ShapeAssembly program (its base-language
        parameters); the text itself for a ShapeAssembly program."""
        if not self.is_macro:
            return self.text
        if isinstance(self.program, MacroHierarchy):
            return to_text(compile_hierarchy(self.program, self.library).program)
        return to_text(compile_program(self.program, self.library).program)

    # -- exports
    def export(self, folder, kinds=EXPORT_KINDS) -> list[Path]:
        """Write the current program's text, OBJ and PNG as new files ``<name>_edit<NNN>.<kind>`` in ``folder``.

        Nothing is written outside ``folder`` and no file is replaced: NNN is one more than the largest
        number of a ``<name>_edit<NNN>.*`` file there, and each file is written atomically as a new file
        (:func:`shapeio.files.write_new_set`: all the kinds under one number, or none).

        Args:
            folder: an existing directory.
            kinds: some of :data:`EXPORT_KINDS`.

        Returns:
            The paths written.

        Raises:
            ValueError: an unknown kind, or no program.
            FileNotFoundError: ``folder`` is not a directory.
        """
        kinds = tuple(kinds)
        bad = [k for k in kinds if k not in EXPORT_KINDS]
        if bad or not kinds:
            raise ValueError(f"unknown export kind(s) {bad!r}; expected some of {', '.join(EXPORT_KINDS)}")
        if self.program is None:
            raise ValueError("there is no program to export (it did not parse)")
        folder = Path(folder)
        if not folder.is_dir():
            raise FileNotFoundError(f"{folder}: the export folder does not exist")
        data = {}
        for k in kinds:
            if k == "txt":
                data[k] = self.text
            elif k == "obj":
                data[k] = obj_text(self.shape.corners, lines=self.shape.line)
            else:
                img = render_png(self.shape.corners, None, labels=self.shape.line.numpy(), size=PNG_SIZE)
                data[k] = png_bytes(img)
        taken = [re.fullmatch(re.escape(self.name) + r"_edit(\d+)\..*", p.name) for p in folder.iterdir()]
        n = max([int(m.group(1)) for m in taken if m] + [0]) + 1
        while True:
            try:  # all the kinds under one number, or none of them
                return write_new_set((folder / f"{self.name}_edit{n:03d}.{k}", data[k]) for k in kinds)
            except FileExistsError:  # made meanwhile by someone else: the next number
                n += 1
