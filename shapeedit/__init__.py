"""What the two program editors (``shapeprog.editor``, ``csgnet.editor``) share, in one place that both
import (they do not import each other, and the file-format layer ``shapeio`` holds no editor code):

* :mod:`shapeedit.history`: the undo / redo :class:`History` of immutable states and the session moves
  over it (:class:`UndoableSession`). Standard library only.
* :mod:`shapeedit.server`: the lazy import of the browser library ``viser`` (the ``editor`` extra), the
  port check, a server that answers only this machine's pages, the command's start and stop.
* :mod:`shapeedit.camera`: a camera pose that frames a shape's bounding box in the 3D view.
* :mod:`shapeedit.control`: the kinds of control, the check of a value against a control's kind, range and
  choices (:class:`~shapeedit.control.BaseControl`) and a page widget's value made what it takes
  (:func:`~shapeedit.control.page_value`). Standard library only.
* :mod:`shapeedit.page`: :class:`~shapeedit.page.EditorPage`, what both browser pages do: the page's head
  (status, error, undo / redo / reset and export buttons), the history moves, export, "Run text", the address.

Importing this package imports neither ``viser`` nor ``websockets``; what each page shows and its controls
live in each system's ``editor`` package.
"""
from .camera import CameraPose, frame_box, show_pose
from .history import MAX_HISTORY, History, UndoableSession
from .server import (EDITOR_EXTRA, MAX_PORT, check_port, editor_preflight, export_stem, import_viser,
                     port_argument, refused_request, serve_until_interrupted, viser_server)

__all__ = ["EDITOR_EXTRA", "MAX_HISTORY", "MAX_PORT", "CameraPose", "History", "UndoableSession", "check_port",
           "editor_preflight", "export_stem", "frame_box", "import_viser", "port_argument",
           "refused_request", "serve_until_interrupted", "show_pose", "viser_server"]
