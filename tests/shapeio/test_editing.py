"""shapeio.write_new (never replaces a file) and shapeio.editing (the editors' history, the lazy viser import)."""
import os

import pytest

from shapeio import write_new
from shapeio.editing import EDITOR_EXTRA, History, import_viser


def test_write_new(tmp_path):
    p = write_new(tmp_path / "a.txt", "one\n")
    assert p.read_text() == "one\n" and sorted(os.listdir(tmp_path)) == ["a.txt"]
    with pytest.raises(FileExistsError, match="a.txt: the file exists"):
        write_new(tmp_path / "a.txt", "two\n")
    assert p.read_text() == "one\n" and sorted(os.listdir(tmp_path)) == ["a.txt"]  # no temporary file left
    write_new(tmp_path / "b.bin", lambda f: f.write(b"\x00\x01"))
    assert (tmp_path / "b.bin").read_bytes() == b"\x00\x01"
    (tmp_path / "link").symlink_to(tmp_path / "missing")
    with pytest.raises(FileExistsError):  # a dangling link is a file name in use
        write_new(tmp_path / "link", "x")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_new(tmp_path / "no" / "c.txt", "x")
    with pytest.raises(RuntimeError):
        write_new(tmp_path / "d.txt", lambda f: (_ for _ in ()).throw(RuntimeError("writer failed")))
    assert not (tmp_path / "d.txt").exists() and not [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]


def test_history_limit_keeps_the_newest():
    h = History("a", limit=2)
    for x in "bcd":
        h.push(x)
    assert len(h) == 2 and h.initial == "c" and h.current == "d"
    assert h.undo() == "c" and not h.can_undo


def test_import_viser_names_the_extra(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "viser", None)  # an import of viser now fails
    with pytest.raises(ImportError, match=rf"pip install -e '\.\[{EDITOR_EXTRA}\]'"):
        import_viser()


def test_undoable_session_moves_sync_and_clear_the_error():
    from shapeio.editing import UndoableSession

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
