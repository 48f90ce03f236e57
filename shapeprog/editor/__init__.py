"""The program editor: controls on a program's free parameters, edits, history and exports.

The core (this package without :mod:`~shapeprog.editor.server`) needs no browser library:

* :mod:`~shapeprog.editor.controls`: :func:`controls` (one :class:`Control` per free parameter of a
  ShapeAssembly or macro program) and :func:`apply` (the edited program, through the language's printer
  and parser).
* :mod:`~shapeprog.editor.session`: :class:`EditSession`, a program being edited: execution, the last
  good geometry, errors, undo / redo, a goal-directed target and exports (text, OBJ, PNG).
* :mod:`~shapeprog.editor.server`: the browser page (``viser``, the ``editor`` extra:
  ``pip install -e '.[editor]'``), imported only by ``python -m shapeprog assembly edit``.

The page and its use: ``docs/editor.md``.
"""
from __future__ import annotations

from .controls import BOOL, CHOICE, FLOAT, INT, Control, apply, controls
from .session import EditSession, corner_distance, load_program

__all__ = ["BOOL", "CHOICE", "FLOAT", "INT", "Control", "EditSession", "apply", "controls", "corner_distance",
           "load_program"]
