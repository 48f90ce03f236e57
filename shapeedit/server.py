"""The editors' web server: the lazy import of ``viser`` (the ``editor`` extra), the port check, a server
that answers only this machine's pages (:func:`refused_request`), and the command's start and stop.

Importing this module imports neither ``viser`` nor ``websockets``.
"""
from __future__ import annotations

import argparse
import http
import ipaddress
import re
import signal
import threading
import time
import webbrowser
from pathlib import Path

__all__ = ["EDITOR_EXTRA", "MAX_PORT", "MAX_STEM_CHARS", "check_port", "editor_preflight", "export_stem",
           "import_viser", "port_argument", "refused_request", "serve_until_interrupted", "viser_server"]

#: The optional extra that installs the editors' browser library.
EDITOR_EXTRA = "editor"


def import_viser():
    """The ``viser`` module, imported on first use.

    Raises:
        ImportError: viser is not installed; the message names the extra that installs it.
    """
    try:
        # lazy: viser is the optional `editor` extra; importing this module must not need it
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
    # lazy: websockets comes with viser (the optional `editor` extra)
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


#: Characters an export's file stem keeps (a file name holds 255 bytes; ``_edit001.txt`` and the like follow).
MAX_STEM_CHARS = 100


def export_stem(name: str, default: str) -> str:
    """The stem of an editor's exported files from a name: runs of characters other than ASCII letters,
    digits, ``_``, ``.`` and ``-`` become ``_``, at most :data:`MAX_STEM_CHARS` are kept, and ``default``
    stands in for an empty result.

    Example:
        >>> export_stem("chair/173 (copy)", "program"), export_stem("", "csg"), len(export_stem("x" * 999, "p"))
        ('chair_173_copy_', 'csg', 100)
    """
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name))[:MAX_STEM_CHARS] or default


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
    if threading.current_thread() is threading.main_thread():
        # A parent process can hand SIGINT down ignored (SIG_IGN survives exec) or blocked (so does the signal
        # mask); Ctrl-C must stop the editor either way.
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if hasattr(signal, "pthread_sigmask"):
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    try:  # an interrupt that comes while the address is still being printed ends it cleanly too
        print(f"editing {what} at {app.url} (exports go to {Path(export_dir).resolve()}); Ctrl-C stops", flush=True)
        if open_browser:
            webbrowser.open(app.url)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        app.stop()
    return 0
