import os

import pytest

from shapeio import atomic_write


def test_write_is_atomic_on_failure(tmp_path):
    target = tmp_path / "m.ply"
    target.write_text("old\n")

    def boom(f):
        f.write(b"partial")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        atomic_write(target, boom)
    assert target.read_text() == "old\n"
    assert os.listdir(tmp_path) == ["m.ply"]


def test_bytes_text_and_missing_directory(tmp_path):
    assert atomic_write(tmp_path / "a.bin", b"\x00\x01").read_bytes() == b"\x00\x01"
    assert atomic_write(tmp_path / "a.txt", "x\ny\n").read_text() == "x\ny\n"
    with pytest.raises(FileNotFoundError, match="does not exist"):
        atomic_write(tmp_path / "no" / "a.txt", "x")
    assert atomic_write(tmp_path / "no" / "a.txt", "x", mkdir=True).read_text() == "x"
    assert sorted(os.listdir(tmp_path)) == ["a.bin", "a.txt", "no"]


def test_refuse_overwrite_compares_resolved_paths(tmp_path, monkeypatch):
    from shapeio import refuse_overwrite

    monkeypatch.chdir(tmp_path)
    refuse_overwrite(["out/a.png", None], ["a.png", None])  # different files: fine
    with pytest.raises(FileExistsError, match=r"\./a\.png: this output would overwrite an input file"):
        refuse_overwrite(["b.txt", "./a.png"], [tmp_path / "a.png"])
