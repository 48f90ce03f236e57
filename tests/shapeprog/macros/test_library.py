"""The macro library: base functions, nesting, expansion to base lines, value errors at their line."""
import pytest

from shapeprog.errors import ParseError
from shapeprog.macros.grammar import BBOX, AttachLine, CuboidLine, ReflectLine, SqueezeLine, TranslateLine
from shapeprog.macros.lang import (Call, Linear, Literal, MacroDef, MacroError, MacroProgram, Name, Param, def_text,
                                   from_lines, parameters, to_text)
from shapeprog.macros.library import Affine, Library, parse

LIB = """def leg(s: float, b: bool, t: float):
    c = Cuboid(s, bb_y, s, b)
    squeeze(bbox, bbox, bot, 0.5 * s, t)
    reflect(X)

def four_legs(s: float, b: bool, t: float):
    c1 = leg(s, b, t)
    c2 = leg(2.0 * s, b, 1.0 - t)

def hang(c0: cube, x: float):
    attach(c0, 0.5, 1.0, 0.5, x, 0.0, 0.5)
"""
PROG = """bbox = Cuboid(1.2, 0.9, 1.0, True)
front, back = four_legs(0.1, True, 0.25)
top = Cuboid(1.2, 0.1, 1.0, True)
hang(front, 0.5)
"""


@pytest.fixture
def lib():
    return Library.from_text(LIB)


def test_library_holds_base_functions_and_macros(lib):
    assert len(Library()) == 5 and list(Library()) == ["Cuboid", "attach", "squeeze", "reflect", "translate"]
    assert len(lib) == 8 and [m.name for m in lib.macros] == ["leg", "four_legs", "hang"]
    assert lib["Cuboid"].is_base and not lib["leg"].is_base and "hang" in lib and "nope" not in lib
    assert lib["four_legs"].n_cuboids == 2 and lib["four_legs"].structure == ("Cuboid", "squeeze", "reflect") * 2
    assert not lib["four_legs"].info.needs_subject and lib["hang"].info.needs_subject and lib["hang"].n_cuboids == 0
    assert lib.to_text() == LIB and Library.from_text(lib.to_text()).macros == lib.macros
    with pytest.raises(KeyError, match="no function 'nope'"):
        lib["nope"]
    bigger = lib.add(MacroDef("two", (), (Call("four_legs", (Linear.const(0.1), Literal(True), Linear.const(0.2)),
                                                ("a", "b")),)))
    assert len(bigger) == 9 and len(lib) == 8  # add returns a new library
    assert repr(lib) == "Library(3 macros: leg, four_legs, hang)"


def test_library_refuses_bad_definitions(lib):
    with pytest.raises(MacroError, match="already defined"):
        lib.add(lib.macros[0])
    with pytest.raises(MacroError, match="unknown function 'later'"):
        Library([MacroDef("early", (), (Call("later", ()),)), MacroDef("later", (), (Call("reflect", (Name("X"),)),))])
    bad = MacroDef("m", (Param("s", "float"),), (Call("Cuboid", (Linear.var("s"), Linear.var("q"), Linear.var("s"),
                                                                   Literal(True)), ("c",)),))
    with pytest.raises(MacroError, match="'q' is not a float parameter") as e:
        Library([bad])
    assert (e.value.macro, e.value.index, e.value.arg) == ("m", 0, 1)
    with pytest.raises(ParseError, match="definitions only"):
        Library.from_text(LIB + "bbox = Cuboid(1.0, 1.0, 1.0, True)\n")


def test_expand_macro_inlines_nested_calls(lib):
    e = lib.expand_macro("four_legs")
    assert e.params == lib["four_legs"].params
    assert def_text(e) == """def four_legs(s: float, b: bool, t: float):
    c0 = Cuboid(s, bb_y, s, b)
    squeeze(bbox, bbox, bot, 0.5 * s, t)
    reflect(X)
    c1 = Cuboid(2.0 * s, bb_y, 2.0 * s, b)
    squeeze(bbox, bbox, bot, s, 1.0 - t)
    reflect(X)
"""
    assert lib.expand_macro("four_legs") is e  # cached
    assert def_text(lib.expand_macro("hang")) == "def hang(c0: cube, x: float):\n" \
                                                 "    attach(c0, 0.5, 1.0, 0.5, x, 0.0, 0.5)\n"
    clash = lib.add(MacroDef("m", (Param("c0", "float"),), (Call("leg", (Linear.var("c0"), Literal(True),
                                                                          Linear.const(0.5)), ("x",)),)))
    assert def_text(clash.expand_macro("m")).splitlines()[1] == "    c0_ = Cuboid(c0, bb_y, c0, True)"
    assert def_text(lib.expand_macro("attach")) == "def attach(target: cube, x1: float, y1: float, z1: float, " \
        "x2: float, y2: float, z2: float):\n    attach(target, x1, y1, z1, x2, y2, z2)\n"


def test_expand_program_to_base_lines(lib):
    p = lib.parse(PROG)
    e = lib.expand(p)
    assert e.lines == (
        CuboidLine(1.2, 0.9, 1.0, True),
        CuboidLine(0.1, 0.9, 0.1, True), SqueezeLine(BBOX, BBOX, "bot", 0.05, 0.25), ReflectLine("X"),
        CuboidLine(0.2, 0.9, 0.2, True), SqueezeLine(BBOX, BBOX, "bot", 0.1, 0.75), ReflectLine("X"),
        CuboidLine(1.2, 0.1, 1.0, True), AttachLine(0, 0.5, 1.0, 0.5, 0.5, 0.0, 0.5))
    assert e.source == (0, 1, 1, 1, 1, 1, 1, 2, 3) and e.names == ("front", "back", "top")
    # parameters: bbox 0-2, four_legs s 3 and t 4 (its bool is not a float), top 5-7, hang 8
    assert e.floats[4] == (Affine(0.0, ((3, 2.0),)), Affine(0.0, ((1, 1.0),)), Affine(0.0, ((3, 2.0),)))
    assert e.floats[5] == (Affine(0.0, ((3, 1.0),)), Affine(1.0, ((4, -1.0),)))
    values = parameters(p)
    for line, forms in zip(e.lines, e.floats):
        nums = [getattr(line, f) for f in line.__slots__ if f not in ("target", "t1", "t2", "face", "axis", "aligned")]
        assert [f.evaluate(values) for f in forms] == pytest.approx(nums)
    inl = lib.inline(p)
    assert inl == from_lines(e.lines, e.names) and inl.defs == ()
    assert to_text(inl).splitlines()[1:3] == ["front = Cuboid(0.1, 0.9, 0.1, True)",
                                              "squeeze(bbox, bbox, bot, 0.05, 0.25)"]
    assert Library().expand(inl).lines == e.lines


def test_program_definitions_join_the_library(lib):
    text = LIB.split("def hang")[0] + PROG.split("hang(")[0]
    p = parse(text)  # base library + the text's own definitions
    assert [d.name for d in p.defs] == ["leg", "four_legs"] and p.lines[1].func == "four_legs"
    assert Library().expand(p).lines == lib.expand(lib.parse(PROG.split("hang(")[0])).lines
    assert parse(to_text(p)) == p


@pytest.mark.parametrize("line, message, col, token", [
    ("hang(top, 0.5)", "targets its own subject", 1, "hang"),
    ("attach(top, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)", "targets its own subject", 1, "attach"),
    ("translate(X, 2.5, 0.5)", "translate count 2.5 is not a whole number", 1, "translate"),
    ("translate(X, 0.0, 0.5)", "translate count 0.0 is not a whole number", 1, "translate"),
])
def test_expansion_errors_are_located(lib, line, message, col, token):
    with pytest.raises(ParseError, match=message) as e:
        lib.parse(PROG + line + "\n", "p.txt")
    assert (e.value.file, e.value.line, e.value.column, e.value.token) == ("p.txt", 5, col, token)
    with pytest.raises(MacroError, match=message) as e2:
        lib.expand(MacroProgram((), lib.parse(PROG).lines + (lib.parse(PROG + line + "\n", check=False).lines[-1],)))
    assert e2.value.index == 4


def test_translate_count_from_a_parameter(lib):
    more = lib.add(MacroDef("row", (Param("n", "float"), Param("d", "float")),
                            (Call("translate", (Literal("Z"), Linear.var("n"), Linear.var("d"))),)))
    p = more.parse(PROG + "row(3.0, 0.4)\n")
    assert more.expand(p).lines[-1] == TranslateLine("Z", 3, 0.4)
