"""shapeedit: the editors' undo / redo history and session moves, the lazy viser import, the port check and
the request guard (which pages may reach an editor)."""
import argparse
import sys

import pytest

from shapeedit import (EDITOR_EXTRA, History, UndoableSession, check_port, import_viser, port_argument,
                       refused_request)


def test_history_limit_keeps_the_newest():
    h = History("a", limit=2)
    for x in "bcd":
        h.push(x)
    assert len(h) == 2 and h.initial == "c" and h.current == "d"
    assert h.undo() == "c" and not h.can_undo


def test_undoable_session_moves_sync_and_clear_the_error():
    class Counter(UndoableSession):
        def __init__(self):
            self.history, self.error, self.value = None, None, None

        def _sync(self):
            self.value = self.history.current

    s = Counter()
    assert not s.undo() and not s.redo() and not s.reset()  # nothing loaded yet
    s._record(1)
    s._record(2)
    assert s.value == 2
    s.error = "last edit failed"
    assert s.undo() and s.value == 1 and s.error is None and not s.undo()
    assert s.redo() and s.value == 2 and not s.redo()
    assert s.reset() and s.value == 1 and s.history.can_undo
    assert not s.reset()  # already at the first state
    assert s.undo() and s.value == 2


def test_import_viser_names_the_extra_when_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "viser", None)  # an import of viser now fails
    with pytest.raises(ImportError, match=rf"pip install -e '\.\[{EDITOR_EXTRA}\]'"):
        import_viser()


@pytest.mark.parametrize("port", [-1, 65536, 70000, True, 8080.0, "8080"])
def test_check_port_refuses_what_is_not_a_tcp_port(port):
    with pytest.raises(ValueError, match="is not a TCP port \\(an integer from 0 to 65535\\)"):
        check_port(port)


def test_port_argument_reads_a_port_or_names_the_text():
    assert port_argument("0") == 0 and port_argument("65535") == 65535
    with pytest.raises(argparse.ArgumentTypeError, match="port 'x' is not a TCP port"):
        port_argument("x")


@pytest.mark.parametrize("host, origin, reason", [
    ("127.0.0.1:8080", None, None),
    ("localhost:8080", "http://localhost:8080", None),
    ("[::1]:8080", "http://[::1]:8080", None),
    ("LOCALHOST:8080", "http://localhost:8080", None),
    (None, None, "host '' is not this machine's address"),
    ("evil.example", None, "host 'evil.example' is not this machine's address"),
    ("localhost.evil.example:80", None, "host 'localhost.evil.example:80' is not this machine's address"),
    ("127.0.0.1:8080", "null", "origin 'null' is not this editor's page"),
    ("127.0.0.1:8080", "https://127.0.0.1:8080", "origin 'https://127.0.0.1:8080' is not this editor's page"),
    ("127.0.0.1:8080", "http://127.0.0.1:9090", "origin 'http://127.0.0.1:9090' is not this editor's page"),
])
def test_refused_request(host, origin, reason):
    assert refused_request(host, origin) == reason
