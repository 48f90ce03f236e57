"""The macro-program text: round trips, the AST, located errors, and a small fuzz."""
import random

import pytest

from shapeprog import corpus
from shapeprog.errors import ParseError
from shapeprog.lang import parse as parse_sa
from shapeprog.macros.data import convert_program
from shapeprog.macros.library import parse as parse_checked
from shapeprog.macros.lang import (BASE, Call, Linear, Literal, MacroDef, MacroError, MacroProgram, Name, Param,
                                   check_def, from_lines, parameters, parse, replace_parameters, to_text)

CHAIR = """def leg(s: float, b: bool, t: float):
    c = Cuboid(s, bb_y, s, b)
    squeeze(bbox, bbox, bot, 0.6 * s, t)
    reflect(X)

def four_legs(s: float, b: bool, t: float):
    c1 = leg(s, b, t)
    c2 = leg(0.95 * s, b, 1.0 - t)

def on(t: cube, f: face, a: axis, x: float, z: float):
    c = Cuboid(bb_x - 0.1 * x, 0.5 * bb_y + 0.25, z, True)
    squeeze(t, bbox, f, x, -z)
    translate(a, 2.0, 0.5 * x)

bbox = Cuboid(1.2, 0.9, 1.0, True)
leg0, leg1 = four_legs(0.1, True, 0.2)
seat = Cuboid(1.2, 0.1, 1.0, True)
attach(leg0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)
top = on(seat, bot, Z, 0.3, -0.25)
"""


def test_round_trip_and_ast():
    p = parse(CHAIR)
    text = CHAIR
    assert to_text(p) == text and parse(to_text(p)) == p
    leg, four, on = p.defs
    assert leg.params == (Param("s", "float"), Param("b", "bool"), Param("t", "float"))
    assert leg.body[0] == Call("Cuboid", (Linear(((1.0, "s"),)), Linear(((1.0, "bb_y"),)), Linear(((1.0, "s"),)),
                                          Name("b")), ("c",))
    assert leg.body[1].args == (Name("bbox"), Name("bbox"), Literal("bot"), Linear(((0.6, "s"),)),
                                Linear(((1.0, "t"),)))
    assert four.body[1].args[2] == Linear(((1.0, None), (-1.0, "t")))
    assert on.body[0].args[0] == Linear(((1.0, "bb_x"), (-0.1, "x")))
    assert on.body[1].args[4] == Linear(((-1.0, "z"),))
    assert p.lines[1] == Call("four_legs", (Linear.const(0.1), Literal(True), Linear.const(0.2)), ("leg0", "leg1"))
    assert p.lines[4].args[1] == Literal("bot") and p.lines[4].args[4] == Linear.const(-0.25)
    assert parameters(p) == [1.2, 0.9, 1.0, 0.1, 0.2, 1.2, 0.1, 1.0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5, 0.3, -0.25]
    q = replace_parameters(p, [float(i) for i in range(16)])
    assert parameters(q) == list(range(16)) and q.defs == p.defs
    with pytest.raises(ValueError, match=r"^1 value\(s\) more than the program's parameters$"):
        replace_parameters(p, range(17))


def test_cuboids_may_be_named_like_faces_and_axes():
    p = parse(CHAIR + "attach(top, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)\nX = Cuboid(0.1, 0.1, 0.1, True)\n"
              "squeeze(top, seat, top, 0.5, 0.5)\n")
    assert p.lines[5].args[0] == Name("top") and p.lines[5].rets == ()
    assert p.lines[7].args[:3] == (Name("top"), Name("seat"), Literal("top")) and p.lines[6].rets == ("X",)
    assert parse(to_text(p)) == p
    with pytest.raises(ParseError, match="parameter 'top' is a reserved word"):
        parse("def f(top: face):\n    reflect(X)\n" + CHAIR.split("\n\n")[-1])


def test_linear_text_and_helpers():
    e = Linear(((0.5, "bb_x"), (-1.0, "s"), (0.25, None), (2.0, "s")))
    assert str(e) == "0.5 * bb_x - s + 0.25 + 2.0 * s"
    assert e.coefficients() == {"bb_x": 0.5, "s": 1.0, None: 0.25} and e.variables() == ["bb_x", "s"]
    assert e.evaluate({"bb_x": 2.0, "s": 3.0}) == 4.25 and e.value is None and Linear.const(-0.0).value == 0.0
    assert str(Linear(((-0.5, None),))) == "-0.5" and str(Linear(((-1.0, "t"), (1.0, None)))) == "-t + 1.0"


def test_comments_blank_lines_and_tabs_are_tolerated():
    text = "# a comment\n\ndef f(h: float):  # trailing\n\tc = Cuboid(1.0, h, 1.0, True)\n\n\tattach(bbox, 0.5, 0.0, " \
           "0.5, 0.5, 0.0, 0.5)\nbbox = Cuboid(2.0, 2.0, 2.0, True)\n\nx = f(3)\n"
    p = parse(text)
    assert to_text(p) == ("def f(h: float):\n    c = Cuboid(1.0, h, 1.0, True)\n    attach(bbox, 0.5, 0.0, 0.5, 0.5, "
                          "0.0, 0.5)\n\nbbox = Cuboid(2.0, 2.0, 2.0, True)\nx = f(3.0)\n")


def test_corpus_orderings_print_and_parse_back():
    prog = parse_sa(corpus.read("storage", 46436))
    conv = convert_program(prog, "storage", 46436)
    n = 0
    for sub in conv.subprograms:
        for o in sub.orders[:20]:
            mp = from_lines(sub.lines(o))
            text = to_text(mp)
            assert parse(text) == mp and to_text(parse(text)) == text
            n += 1
    assert n > 3


def test_check_def_returns_the_interface():
    info = check_def(parse(CHAIR.split("bbox =")[0] + "bbox = Cuboid(1.0, 1.0, 1.0, True)\n").defs[0], BASE)
    assert info.n_cuboids == 1 and not info.needs_subject and info.structure == ("Cuboid", "squeeze", "reflect")
    pre = MacroDef("pre", (Param("t", "cube"),), (Call("attach", (Name("t"),) + (Linear.const(0.5),) * 6),))
    assert check_def(pre, BASE).needs_subject
    with pytest.raises(MacroError, match="unknown type"):
        check_def(MacroDef("m", (Param("x", "int"),), pre.body), BASE)
    with pytest.raises(MacroError, match="empty body"):
        check_def(MacroDef("m", (), ()), BASE)
    with pytest.raises(MacroError, match="is a base function"):
        check_def(MacroDef("attach", (), pre.body), BASE)


B = "bbox = Cuboid(1.0, 1.0, 1.0, True)\n"
D = "def f(s: float, t: cube, a: axis):\n    c = Cuboid(s, s, s, True)\n    attach(t, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)\n"


@pytest.mark.parametrize("text, line, col, token, message", [
    (B + "c = Cubiod(1.0, 1.0, 1.0, True)\n", 2, 5, "Cubiod", "unknown function 'Cubiod'"),
    (B + "c = Cuboid(1.0, 1.0, True)\n", 2, 5, "Cuboid", "expects 4 arguments, got 3"),
    (B + "c = Cuboid(1.0, 1.0, 1.0, maybe)\n", 2, 27, "maybe", "expected a bool"),
    (B + "c = Cuboid(1.0, s, 1.0, True)\n", 2, 17, "s", "a program's float arguments are numbers"),
    (B + "c = Cuboid(1.0, 2 * bb_x, 1.0, True)\n", 2, 17, "2", "a program's float arguments are numbers"),
    (B + "attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n", 2, 1, "attach", "there is none"),
    (B + "c = Cuboid(1.0, 1.0, 1.0, True)\nattach(d, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n", 3, 8, "d",
     "unknown cuboid 'd'"),
    (B + "c = Cuboid(1.0, 1.0, 1.0, True)\nattach(top, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n", 3, 8, "top",
     "unknown cuboid 'top'"),
    (B + "c = Cuboid(1.0, 1.0, 1.0, True)\nsqueeze(bbox, bbox, up, 0.5, 0.5)\n", 3, 21, "up", "expected a face"),
    (B + "c = Cuboid(1.0, 1.0, 1.0, True)\nreflect(top)\n", 3, 9, "top", "expected a axis"),
    (B + "c = Cuboid(1.0, 1.0, 1.0, True)\nc = Cuboid(1.0, 1.0, 1.0, True)\n", 3, 1, "c", "already used"),
    (B + "c, d = Cuboid(1.0, 1.0, 1.0, True)\n", 2, 8, "Cuboid", "creates 1 cuboid(s), the line names 2"),
    (B + "c, bbox = Cuboid(1.0, 1.0, 1.0, True)\n", 2, 11, "Cuboid", "creates 1 cuboid(s), the line names 2"),
    (B + "c = Cuboid(1.0, 1.0, 1.0, True)\nbb_x = Cuboid(1.0, 1.0, 1.0, True)\n", 3, 1, "bb_x", "reserved word"),
    (B + "Cuboid(1.0, 1.0, 1.0, True)\n", 2, 1, "Cuboid", "creates 1 cuboid(s), the line names 0"),
    ("c = Cuboid(1.0, 1.0, 1.0, True)\n", 1, 5, "Cuboid", "must start with 'bbox = Cuboid"),
    ("", 1, 1, "", "needs at least its bbox line"),
    (B + "c = Cuboid(1.0, 1.0, 1.0, True\n", 2, 31, "", "expected ',' or ')', got the end of the line"),
    (B + "c = Cuboid(1.0, 1.0, 1.0, True) x\n", 2, 33, "x", "unexpected 'x' after the line"),
    (B + "c = Cuboid(1.0, 1.0 $ 2, 1.0, True)\n", 2, 21, "$", "expected '+', '-', ',' or ')', got '$'"),
    (B + "c = Cuboid(1e9, 1.0, 1.0, True)\n", 2, 12, "1e9", "out of range"),
    (B + "    c = Cuboid(1.0, 1.0, 1.0, True)\n", 2, 5, "c", "unexpected indentation"),
    (D + B + "def g(s: float):\n    c = f(s)\n", 5, 1, "def", "definitions must come before"),
    (D + "\n" + B + "x = f(0.5, bbox, Q)\n", 6, 18, "Q", "expected a axis"),
    (D + "\n" + B + "x = f(0.5, top, X)\n", 6, 12, "top", "unknown cuboid 'top'"),
    (D + "\n" + B + "x = f(0.5, True, X)\n", 6, 12, "True", "expected a cuboid"),
    ("def f(s: float, s: cube):\n    c = Cuboid(s, s, s, True)\n" + B, 1, 17, "s", "appears twice"),
    ("def f(bb_x: float):\n    c = Cuboid(1.0, 1.0, 1.0, True)\n" + B, 1, 7, "bb_x", "reserved word"),
    ("def f(s: int):\n    c = Cuboid(s, s, s, True)\n" + B, 1, 10, "int", "unknown type 'int'"),
    ("def f(s: float):\n" + B, 1, 5, "f", "needs an indented body"),
    ("def f(s: float):\n    c = Cuboid(s, t, s, True)\n" + B, 2, 19, "t", "'t' is not a float parameter"),
    ("def f(s: float):\n    c = f(s)\n" + B, 2, 9, "f", "unknown function 'f'"),
    ("def f(s: float):\n    c = Cuboid(s, s, s, s)\n" + B, 2, 25, "s", "expected a bool"),
    (D + D + B, 4, 5, "f", "already defined"),
    ("def reflect(a: axis):\n    reflect(a)\n" + B, 1, 5, "reflect", "is a base function"),
])
def test_errors_name_line_column_and_token(text, line, col, token, message):
    with pytest.raises(ParseError) as e:
        parse(text, file="m.txt")
    err = e.value
    assert message in err.reason, err
    assert (err.file, err.line, err.column, err.token) == ("m.txt", line, col, token), str(err)
    assert str(err).startswith(f"m.txt:{line}:{col}: ")


def _mutate(text: str, rng: random.Random) -> str:
    i = rng.randrange(len(text))
    kind = rng.randrange(4)
    pieces = ["(", ")", ",", "=", ":", "*", "-", "+", "#", "\n", "    ", "def ", "bbox", "0.5", "x", "1e400", "top",
              "True", "cube", "Cuboid(", "attach", "f("]
    if kind == 0:
        return text[:i] + text[i + 1:]
    if kind == 1:
        return text[:i] + rng.choice(pieces) + text[i:]
    if kind == 2:
        return text[:i] + rng.choice(pieces) + text[i + 1:]
    j = rng.randrange(len(text))
    a, b = sorted((i, j))
    return text[:a] + text[b:]


def test_fuzz_only_our_errors_and_round_trips():
    """Mutated texts either parse (and expand: the library's parse) and round-trip, or raise ParseError."""
    rng = random.Random(0)
    valid = CHAIR
    parsed = raised = 0
    for _ in range(1500):
        text = _mutate(valid, rng)
        for _ in range(rng.randrange(3)):
            text = _mutate(text, rng)
        try:
            p = parse_checked(text)
        except ParseError as e:
            raised += 1
            assert 1 <= e.line <= max(1, text.count("\n") + 1) and e.column >= 1
            continue
        parsed += 1
        assert isinstance(p, MacroProgram) and parse(to_text(p)) == p
    assert raised > 1000 and parsed > 10
