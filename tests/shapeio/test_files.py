import os
from pathlib import Path

import pytest

from shapeio import atomic_write, write_new
from shapeio.files import NotShippedError, resolve_shipped


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


def test_defect10_written_files_respect_the_umask_and_keep_their_mode(tmp_path):
    old = os.umask(0o022)
    try:
        new = atomic_write(tmp_path / "new.txt", "x")
        assert new.stat().st_mode & 0o777 == 0o644
        kept = tmp_path / "kept.txt"
        kept.write_text("old")
        kept.chmod(0o640)
        atomic_write(kept, "new")
        assert kept.stat().st_mode & 0o777 == 0o640
        os.umask(0o077)
        assert atomic_write(tmp_path / "private.txt", "x").stat().st_mode & 0o777 == 0o600
    finally:
        os.umask(old)


def test_defect10_stale_temp_of_a_killed_write_is_removed(tmp_path):
    import subprocess
    import sys

    from shapeio import remove_stale_temps

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    pid = int(dead.stdout)
    stale = tmp_path / f".a.txt.atomic-{pid}-xyz.tmp"
    stale.write_text("partial")
    live = tmp_path / f".b.txt.atomic-{os.getpid()}-xyz.tmp"  # a write in progress in this process
    live.write_text("partial")
    atomic_write(tmp_path / "a.txt", "done")  # a later write to the same target cleans up
    assert not stale.exists() and live.exists()
    other = tmp_path / f".c.txt.atomic-{pid}-abc.tmp"
    other.write_text("partial")
    assert remove_stale_temps(tmp_path) == [other]
    assert sorted(os.listdir(tmp_path)) == [live.name, "a.txt"]


def test_parse_json_is_strict_and_locates_its_errors():
    from shapeio.files import MAX_JSON_DEPTH, InputError, parse_json

    assert parse_json('{"a": [1, 2.5, "[{"], "b": null}', "x.json") == {"a": [1, 2.5, "[{"], "b": None}
    assert parse_json("[" * MAX_JSON_DEPTH + "]" * MAX_JSON_DEPTH, "x.json") == parse_json("[" * 64 + "]" * 64, "y")
    cases = [('{"a": 1,}', "x.json:1:9: not JSON: Expecting property name"),
             ("[\n" + "[" * MAX_JSON_DEPTH, f"x.json:2:{MAX_JSON_DEPTH}: nested more than {MAX_JSON_DEPTH} levels"),
             ('{"a": "NaN",\n "b": NaN}', "x.json:2:7: not JSON: NaN is not a JSON number"),
             ("[0, -Infinity]", "x.json:1:5: not JSON: -Infinity is not a JSON number"),
             ('["1e400", 1e400]', "x.json:1:11: not JSON: 1e400 is out of the range of a float"),
             ("[0,\n " + "1" * 5000 + "]", "x.json:2:2: not JSON: Exceeds the limit")]
    for text, message in cases:
        with pytest.raises(InputError, match=message.replace("[", r"\[")):
            parse_json(text, "x.json")
    # a format's own error type
    with pytest.raises(KeyError, match="bad 1 9"):
        parse_json('{"a": 1,}', "x.json", lambda why, line, col: KeyError(f"bad {line} {col}"))


def test_write_new_set_writes_all_or_none(tmp_path):
    from shapeio.files import write_new_set

    assert write_new_set([(tmp_path / "a.txt", "a"), (tmp_path / "b.bin", b"b")]) == [tmp_path / "a.txt", tmp_path / "b.bin"]
    assert (tmp_path / "a.txt").read_text() == "a" and (tmp_path / "b.bin").read_bytes() == b"b"
    (tmp_path / "d.txt").write_text("mine")
    with pytest.raises(FileExistsError, match=r"d\.txt: the file exists"):
        write_new_set([(tmp_path / "c.txt", "c"), (tmp_path / "d.txt", "d")])
    assert not (tmp_path / "c.txt").exists() and (tmp_path / "d.txt").read_text() == "mine"

    def broken(f):
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_new_set([(tmp_path / "e.txt", "e"), (tmp_path / "f.txt", broken)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.bin", "d.txt"]  # no temporary left either


def test_defect_held_checks_pickles_refused_outputs_never_overwritten_umask_respected(tmp_path):
    """Issue 50's re-check: every .npy / .npz reader refuses a pickled (object) array without running it; a new
    file is never written over an existing one; written files follow the umask."""
    import numpy as np

    from shapeio import InputError
    from shapeio.arrays import read_grid
    from shapeio.files import atomic_write, write_new
    from shapeio.points import read_cloud, read_points
    from shapeio.silhouettes import read_silhouettes

    ran = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (open, (str(ran), "w"))

    obj = np.empty((4, 3), dtype=object)
    obj[0, 0] = Payload()
    np.save(tmp_path / "p.npy", obj, allow_pickle=True)
    np.savez(tmp_path / "p.npz", train_images=obj)
    for read in (read_grid, read_points, read_cloud):
        with pytest.raises(InputError, match="p.npy"):
            read(tmp_path / "p.npy")
    with pytest.raises(Exception, match="p.npz") as e:
        read_silhouettes(tmp_path / "p.npz", "train")
    assert isinstance(e.value, (InputError, ValueError)) and not ran.exists()
    # outputs never overwritten
    write_new(tmp_path / "out.txt", "a")
    with pytest.raises(FileExistsError, match="not replaced"):
        write_new(tmp_path / "out.txt", "b")
    assert (tmp_path / "out.txt").read_text() == "a"
    # the umask
    old = os.umask(0o027)
    try:
        mode_new = os.stat(write_new(tmp_path / "u1.txt", "x")).st_mode & 0o777
        mode_atomic = os.stat(atomic_write(tmp_path / "u2.txt", "x")).st_mode & 0o777
    finally:
        os.umask(old)
    assert mode_new == mode_atomic == 0o640


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


def test_an_existing_file_wins_over_a_shipped_name(tmp_path, monkeypatch):
    shipped = {"chair": tmp_path / "shipped_chair.txt"}
    assert resolve_shipped("chair", shipped, "library") == shipped["chair"]
    monkeypatch.chdir(tmp_path)
    Path("chair").write_text("mine")
    assert resolve_shipped("chair", shipped, "library") == Path("chair")
    with pytest.raises(NotShippedError, match=r"^lamp: neither a library file nor a shipped library "
                                              r"\(shipped: chair\)$") as e:
        resolve_shipped("lamp", shipped, "library")
    assert isinstance(e.value, FileNotFoundError) and isinstance(e.value, ValueError)
