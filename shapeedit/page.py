"""What the editors' browser pages share: :class:`EditorPage`, a ``viser`` server over an edit session with the
page's head (title, status, error, the undo / redo / reset buttons and the export button), the moves over the
session's history, the export, "Run text" and the page's address.

``viser`` is imported when a page is made (:func:`shapeedit.server.import_viser`), never when this module is
imported. The pages themselves are :class:`shapeprog.editor.server.EditorApp` and
:class:`csgnet.editor.server.CSGEditorApp`.
"""
from __future__ import annotations

import contextlib
import threading
import time
from pathlib import Path

from .server import check_port, import_viser, viser_server

__all__ = ["EditorPage"]


class EditorPage:
    """A running editor page over ``session`` (an :class:`~shapeedit.history.UndoableSession` with ``text``,
    ``error``, ``set_text`` and ``export``).

    A page fills in what it shows: :meth:`_rebuild_controls` (the controls made anew for a new program),
    :meth:`_sync_values` (the session's values put into the controls), :meth:`_set` (a control's new value
    from the page), :meth:`_redraw` (the render and the texts after the program changed), :meth:`_show` (the
    error and status texts) and :meth:`frame` (the view pointed at the shape); it sets ``text_box``, the
    program text's widget.

    Args:
        session: the program to edit.
        host: the address to bind (``127.0.0.1``: this machine only).
        port: the port (0 lets the system pick a free one).
        export_dir: the folder exports are written to (nothing is written elsewhere).
        source_text: the text as given (shown when it does not parse; default: the session's text).

    Attributes:
        server: the ``viser.ViserServer``.
        lock: held while the page handles one change.
        state: what the page shows (for tests and benchmarks); ``"version"`` counts the redraws.

    Raises:
        ValueError: ``port`` is not a TCP port.
        ImportError: viser is missing.
        FileNotFoundError: ``export_dir`` is not a folder.
    """

    def __init__(self, session, host: str, port: int, export_dir, source_text: str | None):
        check_port(port)
        import_viser()
        self.export_dir = Path(export_dir)
        if not self.export_dir.is_dir():
            raise FileNotFoundError(f"{export_dir}: the export folder does not exist")
        self.session = session
        self.source_text = session.text if source_text is None else source_text
        self.lock = threading.RLock()
        self._syncing = False
        self._handles: dict[str, object] = {}
        self.state: dict = {"version": 0}
        self.server = viser_server(host, port)

    def _add_head(self, title: str, export_label: str) -> None:
        """The title, the status and error texts, the Undo / Redo / Reset buttons and the export button."""
        gui = self.server.gui
        gui.add_markdown(title)
        self.status = gui.add_markdown("")
        self.error_md = gui.add_markdown("")
        row = gui.add_button_group("Edit", ("Undo", "Redo", "Reset"))
        row.on_click(lambda e: {"Undo": self.undo, "Redo": self.redo, "Reset": self.reset}[e.target.value]())
        self.export_button = gui.add_button(export_label, hint=f"into {self.export_dir}")
        self.export_button.on_click(lambda _: self.export())

    # -- what a page shows
    def _rebuild_controls(self) -> None:
        raise NotImplementedError

    def _sync_values(self) -> None:
        raise NotImplementedError

    def _set(self, name: str, value, t0: float) -> None:
        """Control ``name`` set to ``value`` in the page at ``time.perf_counter()`` ``t0`` (under the lock)."""
        raise NotImplementedError

    def _redraw(self) -> None:
        raise NotImplementedError

    def _show(self) -> None:
        raise NotImplementedError

    def frame(self) -> None:
        raise NotImplementedError

    # -- the controls
    @contextlib.contextmanager
    def _quiet(self):
        """While the page itself makes or sets its controls: their update callbacks do nothing."""
        self._syncing = True
        try:
            yield
        finally:
            self._syncing = False

    def _put_values(self, controls) -> None:
        """Set each control's widget to the control's value (call within :meth:`_quiet`)."""
        for c in controls:
            h = self._handles.get(c.name)
            if h is not None and h.value != c.value:
                h.value = c.value

    def _changed(self, name: str, value) -> None:
        """A control's widget changed: :meth:`_set` unless the page itself set it."""
        if self._syncing:
            return
        with self.lock:
            self._set(name, value, time.perf_counter())

    # -- the buttons
    def _step(self, move) -> bool:
        with self.lock:
            done = move()
            self._sync_values()
            self._redraw()
            return done

    def undo(self) -> bool:
        """The Undo button: False when there is nothing to undo."""
        return self._step(self.session.undo)

    def redo(self) -> bool:
        """The Redo button: False when there is nothing to redo."""
        return self._step(self.session.redo)

    def reset(self) -> bool:
        """The Reset button: back to the program as opened (undoable), framed again."""
        with self.lock:
            done = self._step(self.session.reset)
            self.frame()
            return done

    def export(self) -> list[Path]:
        """The export button: the session's export files as new files in the export folder (the page shows
        their names or the error)."""
        with self.lock:
            try:
                paths = self.session.export(self.export_dir)
            except (OSError, ValueError) as e:
                self.session.error = e
                self._show()
                return []
            self.state["exported"] = [str(p) for p in paths]
            self.status.content = "wrote " + ", ".join(f"`{p.name}`" for p in paths)
            return paths

    def run_text(self, text: str | None = None) -> bool:
        """The Run text button: replace the program by the text box's text (or ``text``, put in the box);
        False (the error shown) when it does not parse."""
        with self.lock:
            if text is not None:
                self.text_box.value = text
            if self.session.set_text(self.text_box.value):
                self._rebuild_controls()
                self._redraw()
                self.frame()
                return True
            self._show()
            return False

    # -- control from code
    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    def handle(self, name: str):
        """The GUI handle of control ``name`` (setting its ``value`` acts as a change in the page)."""
        return self._handles[name]

    def stop(self) -> None:
        self.server.stop()
