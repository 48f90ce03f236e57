"""What the two program editors (``shapeprog.editor``, ``csgnet.editor``) share: an undo / redo history
of immutable states, and the lazy import of the browser library. Standard library only.

Example:
    >>> h = History("a")
    >>> h.push("b"); h.push("c")
    >>> h.undo(), h.undo(), h.can_undo
    ('b', 'a', False)
    >>> h.redo(), h.current
    ('b', 'b')
    >>> h.push("d"); h.can_redo   # a new state drops the redo branch
    False
"""
from __future__ import annotations

import ipaddress
import threading
from pathlib import Path
from typing import Generic, TypeVar

__all__ = ["EDITOR_EXTRA", "History", "MAX_HISTORY", "MAX_PORT", "UndoableSession", "check_port", "editor_preflight",
           "import_viser", "port_argument", "refused_request", "serve_until_interrupted", "viser_server"]

T = TypeVar("T")

#: The optional extra that installs the editors' browser library.
EDITOR_EXTRA = "editor"


def import_viser():
    """The ``viser`` module, imported on first use.

    Raises:
        ImportError: viser is not installed; the message names the extra that installs it.
    """
    try:
        import viser
    except ImportError as e:
        raise ImportError(f"the editor needs viser, which is not installed: pip install -e '.[{EDITOR_EXTRA}]' "
                          f"(or pip install 'viser>=1.0')") from e
    return viser

#: The largest TCP port number (ports are 16-bit; 0 lets the system pick a free one).
MAX_PORT = 65535
_SERVE_LOCK = threading.Lock()


def check_port(port) -> int:
    """``port`` when it is an int in ``[0, MAX_PORT]``; otherwise ValueError naming it."""
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= MAX_PORT:
        raise ValueError(f"port {port!r} is not a TCP port (an integer from 0 to {MAX_PORT})")
    return port


def port_argument(text: str) -> int:
    """An argparse type: a TCP port (:func:`check_port`)."""
    import argparse

    try:
        return check_port(int(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"port {text[:20]!r} is not a TCP port (an integer from 0 to "
                                         f"{MAX_PORT})") from None


def _host_name(authority: str) -> str:
    """The host of a ``host[:port]`` authority (an IPv6 address in brackets loses them), lower-case."""
    authority = authority.strip().lower()
    if authority.startswith("["):
        return authority[1:authority.find("]")] if "]" in authority else ""
    return authority.rpartition(":")[0] if authority.count(":") == 1 else authority


def _is_local_name(host: str) -> bool:
    """``localhost`` or an IP address literal (no DNS name an outside site could point at this machine)."""
    if host == "localhost":
        return True
    try:
        ipaddress.ip_address(host)
    except ValueError:
        return False
    return True


def refused_request(host: str | None, origin: str | None) -> str | None:
    """Why the editor refuses an HTTP or websocket request with these ``Host`` and ``Origin`` headers, or None.

    ``Host`` must be ``localhost`` or an IP address (a page of another site that rebinds its DNS name to this
    machine sends its own name); ``Origin``, which browsers send with every websocket, must be absent or the
    page's own ``http://`` address (another site's page may not drive the editor).

    Example:
        >>> refused_request("127.0.0.1:8080", "http://127.0.0.1:8080") is None, refused_request("localhost:8080", None)
        (True, None)
        >>> refused_request("127.0.0.1:8080", "http://evil.example")
        "origin 'http://evil.example' is not this editor's page"
    """
    if host is None or not _is_local_name(_host_name(host)):
        return f"host {(host or '')[:100]!r} is not this machine's address"
    if origin is not None and origin.strip().lower() != f"http://{host.strip().lower()}":
        return f"origin {origin[:100]!r} is not this editor's page"
    return None


def _guarded(process_request):
    """A websockets ``process_request`` that answers 403 to a request :func:`refused_request` refuses, else
    hands it to ``process_request``."""
    import http

    def one(request, name: str) -> str | None:  # a repeated header counts as a wrong one
        values = request.headers.get_all(name)
        return values[0] if len(values) == 1 else None if not values else "repeated"

    def guard(connection, request):
        reason = refused_request(one(request, "Host"), one(request, "Origin"))
        if reason is not None:
            return connection.respond(http.HTTPStatus.FORBIDDEN, f"refused: {reason}\n")
        return None if process_request is None else process_request(connection, request)

    return guard


def viser_server(host: str, port: int):
    """A started ``viser.ViserServer`` on ``host:port`` whose HTTP and websocket requests pass
    :func:`refused_request` (answered 403 otherwise), so that no page of another site can read or drive it.

    Raises:
        ValueError: ``port`` is not in ``[0, MAX_PORT]``.
        ImportError: viser is missing (:func:`import_viser`).
        RuntimeError: this viser does not start its server through ``websockets.asyncio.server.serve`` (the
            check could not be installed; nothing is served).
    """
    check_port(port)
    viser = import_viser()
    import websockets.asyncio.server as ws_server

    original, installed = ws_server.serve, []

    def serve(*args, process_request=None, **kwargs):
        installed.append(True)
        return original(*args, process_request=_guarded(process_request), **kwargs)

    with _SERVE_LOCK:  # viser calls serve in its server thread before the constructor returns
        ws_server.serve = serve
        try:
            server = viser.ViserServer(host=host, port=port, verbose=False)
        finally:
            ws_server.serve = original
    if not installed:
        server.stop()
        raise RuntimeError("this viser version does not serve through websockets.asyncio.server.serve; the "
                           "editor cannot check the requests' origin and does not start")
    return server


#: States kept; the oldest are dropped beyond it (a slider drag pushes one state per move).
MAX_HISTORY = 2000


class History(Generic[T]):
    """A line of states with a cursor: :meth:`push` adds a state after the cursor (dropping the states
    that :meth:`redo` could have brought back), :meth:`undo` and :meth:`redo` move the cursor.

    Invariants: ``current`` is always a pushed state (or the initial one); ``undo`` then ``redo`` returns
    to the same state; at most ``limit`` states are kept.

    Args:
        initial: the first state.
        limit: states kept (at least 1).
    """

    def __init__(self, initial: T, limit: int = MAX_HISTORY):
        if isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
            raise ValueError(f"`limit` must be an int >= 1, got {limit!r}")
        self._states: list[T] = [initial]
        self._i = 0
        self.limit = limit

    @property
    def current(self) -> T:
        return self._states[self._i]

    @property
    def initial(self) -> T:
        """The oldest state kept (the first one unless ``limit`` dropped it)."""
        return self._states[0]

    @property
    def can_undo(self) -> bool:
        return self._i > 0

    @property
    def can_redo(self) -> bool:
        return self._i < len(self._states) - 1

    def __len__(self) -> int:
        return len(self._states)

    def push(self, state: T) -> None:
        """Make ``state`` the current state; the redo branch is dropped."""
        del self._states[self._i + 1:]
        self._states.append(state)
        if len(self._states) > self.limit:
            del self._states[: len(self._states) - self.limit]
        self._i = len(self._states) - 1

    def undo(self) -> T:
        """Step back; returns the new current state. IndexError when there is nothing to undo."""
        if not self.can_undo:
            raise IndexError("nothing to undo")
        self._i -= 1
        return self.current

    def redo(self) -> T:
        """Step forward again; returns the new current state. IndexError when there is nothing to redo."""
        if not self.can_redo:
            raise IndexError("nothing to redo")
        self._i += 1
        return self.current


class UndoableSession:
    """Undo / redo / reset of an edit session over a :class:`History` of states.

    A subclass keeps ``self.history`` (None while nothing valid was loaded) and ``self.error``, and defines
    ``_sync()``, which sets its attributes from ``self.history.current``. Each move returns False when it
    cannot be made; a move that is made clears ``error`` (the last operation succeeded).
    """

    history: "History | None"
    error: "Exception | None"

    def _sync(self) -> None:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def _record(self, state) -> None:
        """Make ``state`` current: the first state of a new history, or pushed onto the existing one."""
        if self.history is None:
            self.history = History(state)
        else:
            self.history.push(state)
        self._sync()

    def _moved(self) -> bool:
        self._sync()
        self.error = None
        return True

    def undo(self) -> bool:
        """Step back (False when there is nothing to undo)."""
        if self.history is None or not self.history.can_undo:
            return False
        self.history.undo()
        return self._moved()

    def redo(self) -> bool:
        """Step forward again (False when there is nothing to redo)."""
        if self.history is None or not self.history.can_redo:
            return False
        self.history.redo()
        return self._moved()

    def reset(self) -> bool:
        """Back to the first state (an undoable step). False when already there."""
        if self.history is None or self.history.current is self.history.initial:
            return False
        self.history.push(self.history.initial)
        return self._moved()


def editor_preflight(export_dir) -> str | None:
    """Why an editor command cannot start (viser missing, no export folder), or None when it can."""
    try:
        import_viser()
    except ImportError as e:
        return str(e)
    if not Path(export_dir).is_dir():
        return f"{export_dir}: the export folder does not exist"
    return None


def serve_until_interrupted(app, what: str, export_dir, open_browser: bool) -> int:
    """Print where the editor page of ``what`` is served, optionally open it in a browser, and keep it
    served until Ctrl-C; returns the exit status 0."""
    import signal
    import threading
    import time

    if threading.current_thread() is threading.main_thread():
        # A parent process can hand SIGINT down ignored (SIG_IGN survives exec) or blocked (so does the signal
        # mask); Ctrl-C must stop the editor either way.
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if hasattr(signal, "pthread_sigmask"):
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    try:  # an interrupt that comes while the address is still being printed ends it cleanly too
        print(f"editing {what} at {app.url} (exports go to {Path(export_dir).resolve()}); Ctrl-C stops", flush=True)
        if open_browser:
            import webbrowser

            webbrowser.open(app.url)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        app.stop()
    return 0
