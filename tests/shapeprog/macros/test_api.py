"""Public entry points: refactor, expand, load_library; the baseline macros; Table 1 figures; the CLI."""
import pytest
import torch

from shapeprog import corpus, parse
from shapeprog.execute import execute as sa_execute
from shapeprog.macros import Library, convert_program, expand, load_library, refactor
from shapeprog.macros import execute as macro_execute
from shapeprog.macros.api import LIBRARIES
from shapeprog.macros.baseline import baseline_library
from shapeprog.macros.grammar import BBOX, AttachLine, CuboidLine, ReflectLine, SqueezeLine, to_shapeassembly
from shapeprog.macros.objective import ABS_MAX_ERROR
from shapeprog.macros.table1 import library_rows

LEG = ("def leg(s: float, b: bool, t: float):\n    c = Cuboid(s, bb_y, s, b)\n"
       "    squeeze(bbox, bbox, top, 0.6 * s, t)\n    reflect(X)\n")


def _corners(program):
    with torch.no_grad():
        return sa_execute(program).corners


@pytest.mark.parametrize("ident", [173, 44017, 36880])
def test_refactor_expands_to_the_original_cuboids(ident):
    lib = load_library("chair")
    prog = parse(corpus.read("chair", ident))
    subs = convert_program(prog, "chair", ident).subprograms
    r = refactor(subs, lib)
    # f(p) carries the |L| term in every sub-program; the calls alone never cost more than base calls
    assert r.stats["f"] - len(subs) * len(lib.macros) <= r.stats["f_base"] + 1e-9
    assert r.stats["blocks"] == len(subs)
    for b, s in zip(r.blocks, subs):
        # the text parses standalone (it carries the definitions it uses) and round-trips
        again = Library().parse(b.text)
        assert again == b.program
        base = expand(b.program)
        got = _corners(base)
        # the same cuboids as one of the sub-program's orderings, up to the fit tolerance (scaled by the
        # lever arms of a unit bbox)
        want = [_corners(to_shapeassembly(s.lines(o))) for o in s.orders[:1000]]
        errs = [float((got - w).abs().max()) for w in want if w.shape == got.shape]
        assert errs and min(errs) <= 4 * ABS_MAX_ERROR
        # execution through the macro executor equals the expanded program's
        assert torch.allclose(macro_execute(b.program, Library()).corners, got, atol=1e-5)


def test_refactor_with_a_hand_made_library_is_exact():
    lib = Library.from_text(LEG)
    prog = parse("Assembly Program_0 {\n  bbox = Cuboid(1.0, 0.8, 1.0, True)\n"
                 "  cube0 = Cuboid(0.1, 0.8, 0.1, False)\n  squeeze(cube0, bbox, bbox, top, 0.06, 0.3)\n"
                 "  reflect(cube0, X)\n}\n")
    r = refactor(prog, lib)
    assert r.program.lines[1].func == "leg"
    assert r.stats["f"] == pytest.approx(1 + 8 + 2 + 0.25)
    assert r.stats["f_base"] == pytest.approx(11.25 + 26.5 + 8.5)
    assert r.stats["lines"] == 1 and r.stats["float"] == 2 and r.stats["bool"] == 1
    assert torch.allclose(_corners(expand(r.program)), _corners(prog), atol=1e-6)
    assert r.text.startswith("# /0/Program_0\ndef leg(")


def test_load_library_unknown_category():
    with pytest.raises(ValueError, match=r"^sofa: neither a ShapeMOD library file nor a shipped ShapeMOD library "
                                         r"\(shipped: chair, storage, table\)$"):
        load_library("sofa")


def test_load_library_an_existing_file_wins(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "chair").write_text("def slab(h: float):\n    c = Cuboid(bb_x, h, bb_z, True)\n", encoding="utf-8")
    assert [m.name for m in load_library("chair").macros] == ["slab"]
    assert [m.name for m in load_library("table").macros] == [m.name for m in load_library(str(LIBRARIES["table"])).macros]


def test_shipped_library_files_agree_with_their_headers():
    """Every library file under shapeprog/macros/libs parses, and its header's macro count, |L| and rounds
    (one f per round) are those of its definitions."""
    import re
    from pathlib import Path

    from shapeprog.macros.discover import prior_rounds

    import shapeprog.macros

    files = sorted((Path(shapeprog.macros.__file__).parent / "libs").glob("*.txt"))
    assert {f.stem for f in files} >= {"chair", "table", "storage"}
    for f in files:
        text = f.read_text(encoding="utf-8")
        lib = Library.from_text(text, str(f))
        head = re.match(r"# ShapeMOD (library|Baseline macros) \((\w+)\), (\d+) macros, \|L\| = (\d+)\n", text)
        assert head, f
        assert (int(head[3]), int(head[4])) == (len(lib.macros), len(lib)), f
        if head[1] == "library":  # a discovered library records its rounds; the Baseline macros have none
            rounds = int(re.search(r"^# rounds: (\d+),", text, re.M)[1])
            assert len(prior_rounds(text)) == rounds, f
        else:
            assert f.stem.endswith("_baseline") and "# rounds:" not in text, f


def test_baseline_macros_constants_and_share():
    progs = []
    for k in range(10):
        side = "top" if k < 9 else "bot"
        progs.append((CuboidLine(1.0, 1.0, 1.0, True), CuboidLine(0.1 + 0.01 * k, 1.0, 0.1, True),
                      SqueezeLine(BBOX, BBOX, side, 0.2, 0.1 * k), ReflectLine("X")))
    lib = baseline_library(progs)
    names = [m.name for m in lib.macros]
    assert names == ["base_0", "base_1", "base_2"]
    cub, sq = lib.macros[0].body
    # widths 0.10..0.19: 9 of 10 within 0.05 of the mean 0.145 -> the constant 0.14 (rounded mean)
    assert str(cub.args[0]) == "0.14" and str(cub.args[1]) == "1.0"
    assert str(sq.args[2]) == "top" and str(sq.args[3]) == "0.2" and str(sq.args[4]) == "x0"
    # a sequence in at most 10% of the programs is no macro
    assert baseline_library(progs, min_share=1.0).macros == ()


def test_library_rows_hand_computed():
    lines = (CuboidLine(1.0, 0.8, 1.0, True), CuboidLine(0.1, 0.8, 0.1, False),
             SqueezeLine(BBOX, BBOX, "top", 0.06, 0.3), ReflectLine("X"),
             CuboidLine(0.5, 0.1, 0.5, True), AttachLine(0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5))
    items = [[lines], [lines[:4]]]
    shapes = ["s/1", "s/1"]
    r = library_rows(Library(), items, shapes)
    # per shape: f = (46.25 + 33.25) + 46.25; calls 5 + 3, plus 1 bbox line and 2 tokens per sub-program
    assert r["f"] == pytest.approx(46.25 + 33.25 + 46.25)
    assert r["fn"] == 8 + 3 + 3 and r["fn_calls"] == 8
    # d: squeeze (2 ids, 1 face), reflect (1 axis), attach (1 id); then squeeze and reflect again
    assert r["d"] == (3 + 1 + 1) + (3 + 1) and r["floats"] == (3 + 2 + 3 + 6) + 3 + (3 + 2) + 3
    assert r["b"] == 2 + 1 + 1 + 1 and r["L"] == 5
    r = library_rows(Library.from_text(LEG), items, shapes)
    assert r["f"] == pytest.approx((10.25 + 33.25) + 10.25 + 1)
    assert r["L"] == 6 and r["f_sub"] == pytest.approx(((11.25 + 33.25) + 11.25) / 2)
