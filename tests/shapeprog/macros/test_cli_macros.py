"""The discover-macros, refactor and table1 commands on tiny inputs."""
import pytest

from shapeprog.__main__ import main
from shapeprog.macros import Library
from shapeprog.macros.api import header_split


def test_discover_macros_writes_a_library_and_resumes(tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["macros", "discover", "--category", "chair", "--limit", "15", "--rounds", "1", "--proposal-steps", "5",
            "--subsample", "30", "--out", str(out), "--quiet"]
    assert main(argv) == 0
    text = (out / "library.txt").read_text()
    assert "# command: python -m shapeprog macros discover --category chair --limit 15" in text
    assert "of split 'train'" in text  # the default: the val split (the models' test split) takes no part
    assert header_split(text) == "train"  # what discover writes, the tables' notes read back
    Library.from_text(text)
    assert (out / "state.json").exists()
    argv[argv.index("--rounds") + 1] = "1"
    assert main(argv) == 0  # a finished run: resumes after round 1 and writes the same library
    assert (out / "library.txt").read_text().split("# time")[0] == text.split("# time")[0]


def test_refactor_command(tmp_path, capsys):
    lib = tmp_path / "lib.txt"
    lib.write_text("def slab(h: float):\n    c = Cuboid(bb_x, h, bb_z, True)\n"
                   "    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n")
    assert main(["macros", "refactor", "chair/173", "--library", str(lib), "-o", str(tmp_path / "out.txt")]) == 0
    out = capsys.readouterr().out
    assert "# chair/173/Program_0: f " in out and "total: f " in out
    assert (tmp_path / "out.txt").read_text().startswith("# chair/173/Program_0\n")


def test_refactor_bad_library_file(tmp_path, capsys):
    lib = tmp_path / "lib.txt"
    lib.write_text("def slab(h: float):\n    c = Cubiod(bb_x, h, bb_z, True)\n")
    assert main(["macros", "refactor", "chair/173", "--library", str(lib)]) == 2
    err = capsys.readouterr().err
    assert f"{lib}:2:" in err and "unknown function 'Cubiod'" in err


def test_table1_library_option_form(tmp_path):
    import pytest

    with pytest.raises(SystemExit, match=r"--library 'lib.txt': expected CATEGORY=FILE"):
        main(["macros", "tables", "--category", "chair", "--limit", "2", "--library", "lib.txt", "--quiet"])


def test_discover_macros_continues_from_a_library(tmp_path, capsys):
    first, second = tmp_path / "one", tmp_path / "two"
    common = ["discover-macros", "--category", "chair", "--limit", "15", "--proposal-steps", "5", "--subsample", "30",
              "--quiet"]
    assert main(common + ["--rounds", "1", "--out", str(first)]) == 0
    text = (first / "library.txt").read_text()
    f1 = text.split("(subsample): ")[1].split("\n")[0]
    assert main(common + ["--rounds", "2", "--out", str(second), "--start-from", str(first / "library.txt")]) == 0
    text2 = (second / "library.txt").read_text()
    # the first round is the library's, recorded in its header; the second is this run's
    assert "# rounds: 2," in text2 and f"(subsample): {f1}, " in text2
    assert "--start-from" in text2.split("\n")[1]
    names = [m.name for m in Library.from_text(text).macros]
    assert [m.name for m in Library.from_text(text2).macros][:len(names)] == names
    # the state folder belongs to that start: another start is refused
    assert main(common + ["--rounds", "2", "--out", str(second), "--start-from", "chair"]) == 2
    assert "another starting library" in capsys.readouterr().err
    with pytest.raises(SystemExit, match="--start-from: sofa: neither a ShapeMOD library file nor a shipped ShapeMOD library"):
        main(common + ["--rounds", "2", "--out", str(tmp_path / "x"), "--start-from", "sofa"])
    assert not (tmp_path / "x").exists()


def test_discover_baseline_writes_the_baseline_library_of_the_same_shapes(tmp_path):
    from shapeprog.macros.api import collection
    from shapeprog.macros.baseline import baseline_library

    out = tmp_path / "base"
    assert main(["macros", "discover", "--category", "storage", "--split", "train", "--limit", "12", "--baseline",
                 "--quiet", "--out", str(out)]) == 0
    text = (out / "library.txt").read_text()
    assert text.startswith("# ShapeMOD Baseline macros (storage), ")
    assert "# shapes: 12 of split 'train' (seed 0)" in text
    nodes, _ = collection("storage", "train", 12, 0)
    expected = baseline_library([ls[0] for ls in nodes.lines])
    written = Library.from_text(text)
    assert written.to_text() == expected.to_text() and len(written.macros) > 0
    # the library file is never overwritten: a second run into the same folder is refused
    with pytest.raises(SystemExit, match="library.txt"):
        main(["macros", "discover", "--category", "storage", "--limit", "12", "--baseline", "--out", str(out)])
