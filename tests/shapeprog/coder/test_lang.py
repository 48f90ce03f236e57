"""The ShapeCoder language: text round trips, type checking, errors with their place, abstractions."""
import random

import pytest

from shapeprog.coder import data, limits
from shapeprog.coder.lang import (LANG_2D, LANG_3D, Abstraction, AxisConst, Call, IntConst, Library, Num, Param,
                                  ParseError, ProgramError, Type, Var, check, expand, parse, parse_abstraction,
                                  size, to_text, variables)

LEG = "Leg(w: Float, x: Float, z: Float) = Move(Cuboid(w,0.5,w),x,-0.25,z)"
PAIR = "Pair(w: Float, x: Float, a: Axis) = SymRef(Union(Leg(w,x,x),Leg(w,x,Mul(x,2.0))),a)"


def _lib() -> Library:
    lib = Library().add(parse_abstraction(LEG))
    return lib.add(parse_abstraction(PAIR, lib))


def test_data_programs_print_back_byte_for_byte():
    for cat in data.CATEGORIES:
        lines = data.read_lines(cat)
        for rec in data.load(cat)[::10]:
            assert to_text(rec.program) == lines[rec.line - 1].split(":", 1)[1]


def test_parse_builds_typed_nodes():
    e = parse("SymTrans(Rotate(Move(Cuboid(a, 0.5, 2), x, -0.0, 1e-2), AY, t), AZ, INT#3#, Add(d, 1))")
    assert e == Call("SymTrans", (
        Call("Rotate", (Call("Move", (Call("Cuboid", (Var("a"), Num(0.5), Num(2.0))), Var("x"), Num(0.0),
                                      Num(0.01))), AxisConst("AY"), Var("t"))),
        AxisConst("AZ"), IntConst(3), Call("Add", (Var("d"), Num(1.0)))))
    assert check(e) is Type.SHAPE and size(e) == 17
    assert variables(e) == {"a": Type.FLOAT, "x": Type.FLOAT, "t": Type.FLOAT, "d": Type.FLOAT}
    assert parse("Add(a,Inv(b))", expect=Type.FLOAT) == Call("Add", (Var("a"), Call("Inv", (Var("b"),))))
    assert parse("k", expect=Type.INT) == Var("k", Type.INT) and parse("x", expect=None) == Var("x")
    assert parse("SymRef(Cuboid(1,1,1),ax)") == Call("SymRef", (Call("Cuboid", (Num(1.0),) * 3), Var("ax", Type.AXIS)))


def _random_expr(rng: random.Random, lib: Library, want: Type, depth: int):
    if want is Type.FLOAT:
        r = rng.random()
        if r < 0.4:
            return Num(rng.choice([0.0, 1.0, 2.0, -0.0, round(rng.uniform(-2, 2), 2), 1e-5, 123.456]))
        if r < 0.7 or depth > 4:
            return Var(rng.choice(["a", "b", "S_0_1_", "P_F_2_"]))
        op = rng.choice(["Add", "Sub", "Mul", "Div", "Inv"])
        n = 1 if op == "Inv" else 2
        return Call(op, tuple(_random_expr(rng, lib, Type.FLOAT, depth + 1) for _ in range(n)))
    if want is Type.AXIS:
        return AxisConst(rng.choice(lib.lang.axes)) if rng.random() < 0.8 else Var("P_C_0_", Type.AXIS)
    if want is Type.INT:
        return IntConst(rng.randint(1, 6)) if rng.random() < 0.8 else Var("n", Type.INT)
    names = [s.name for s in lib.lang.functions if s.returns is Type.SHAPE] + [ab.name for ab in lib]
    if depth > 5:
        names = [lib.lang.functions[0].name] + [ab.name for ab in lib]
    sig = lib.signature(rng.choice(names))
    return Call(sig.name, tuple(_random_expr(rng, lib, t, depth + 1) for t in sig.params))


@pytest.mark.parametrize("lang", [LANG_3D, LANG_2D])
def test_random_trees_round_trip(lang):
    rng = random.Random(0)
    lib = _lib() if lang is LANG_3D else Library(LANG_2D).add(
        parse_abstraction("Post(h: Float) = Move(Rectangle(0.1,h),0,h)", LANG_2D))
    for _ in range(200):
        e = _random_expr(rng, lib, Type.SHAPE, 0)
        assert check(e, lib) is Type.SHAPE
        assert parse(to_text(e), lib) == e
        spaced = to_text(e).replace(",", ", ").replace("(", "(\n ")
        assert parse(spaced, lib) == e


@pytest.mark.parametrize("text, line, col, token, reason", [
    ("Cubiod(1,1,1)", 1, 1, "Cubiod", "unknown function 'Cubiod'"),
    ("Union(Cuboid(1,1,1))", 1, 20, ")", "Union takes 2 argument(s), got 1"),
    ("Cuboid(1,1,1,1)", 1, 13, ",", "takes 3 argument(s), got more"),
    ("Move(Cuboid(1,1,1),0,AX,0)", 1, 22, "AX", "expected Float, got the axis AX"),
    ("Rotate(Cuboid(1,1,1),0.5,AX)", 1, 22, "0.5", "expected Axis, got the number 0.5"),
    ("SymTrans(Cuboid(1,1,1),AX,3,1)", 1, 27, "3", "expected Int"),
    ("SymTrans(Cuboid(1,1,1),AX,INT#0#,1)", 1, 27, "INT#0#", "count INT#0# must be from 1 to 256"),
    ("SymTrans(Cuboid(1,1,1),AX,INT#3,1)", 1, 27, "INT#3", "malformed count"),
    ("Cuboid(1,1,1", 1, 13, "", "expected ')' closing Cuboid, got the end of the text"),
    ("Cuboid(1,1,1) x", 1, 15, "x", "unexpected 'x' after the expression"),
    ("Union(Cuboid(1,1,1),\n  Cuboid(1;1,1))", 2, 11, ";", "unexpected character ';'"),
    ("Move(Cuboid(1,1,1),0,0,1e9)", 1, 24, "1e9", "out of range"),
    ("Move(Add(1,2),0,0,0)", 1, 6, "Add", "expected Shape, got Add, a Float function"),
    ("Union(x,Cuboid(1,1,1))", 1, 7, "x", "a variable ('x') cannot stand for a Shape"),
    ("Move(Cuboid,0,0,0)", 1, 6, "Cuboid", "needs its arguments in parentheses"),
    ("", 1, 1, "", "unexpected end of the text"),
    ("Cuboid(1,,1)", 1, 10, ",", "expected an expression, got ','"),
    ("Cuboid(1 1,1)", 1, 10, "1", "expected ',' in Cuboid(...), got '1'"),
])
def test_parse_errors_name_the_place(text, line, col, token, reason):
    with pytest.raises(ParseError) as err:
        parse(text, file="p.txt")
    e = err.value
    assert (e.file, e.line, e.column, e.token) == ("p.txt", line, col, token)
    assert reason in e.reason and str(e).startswith(f"p.txt:{line}:{col}: ")


def test_parse_errors_2d_and_offsets():
    with pytest.raises(ParseError, match="unknown function 'Rotate'"):
        parse("Rotate(Rectangle(1,1),AX,0.1)", LANG_2D)
    with pytest.raises(ParseError, match=r"^f:7:14: axis AZ is not in the 2d language"):
        parse("SymRef(Rectangle(1,1),AZ)", LANG_2D, file="f", line=7, column=-8)
    with pytest.raises(ParseError, match=r"^<string>:1:32: unknown function"):
        parse("Union(Cuboid(1,1,1),Move(Cubo(1,1,1),0,0,0))", column=7)


def test_limits():
    deep = "Move(" * limits.MAX_DEPTH + "Cuboid(1,1,1)" + ",0,0,0)" * limits.MAX_DEPTH
    with pytest.raises(ParseError, match="nested deeper than 256"):
        parse(deep)
    assert size(parse("Move(" * 200 + "Cuboid(1,1,1)" + ",0,0,0)" * 200)) == 4 * 200 + 4
    with pytest.raises(ParseError, match="MAX_TEXT_LENGTH"):
        parse("Cuboid(1,1," + " " * limits.MAX_TEXT_LENGTH + "1)")
    with pytest.raises(ProgramError, match="out of range"):
        Num(1e4)
    with pytest.raises(ProgramError, match="count"):
        IntConst(limits.MAX_COUNT + 1)


def test_fuzzed_text_gives_parse_errors_only():
    """Mutated program texts either parse to a well-typed Shape or raise a ParseError whose column and token
    point into the text."""
    rng = random.Random(1)
    lib = _lib()
    seeds = [to_text(_random_expr(rng, lib, Type.SHAPE, 0)) for _ in range(20)]
    alphabet = "(),.-#0123456789 AXYZINTCuboidMveUnS_\n;:=é\t"
    for _ in range(1500):
        text = list(rng.choice(seeds))
        for _ in range(rng.randint(1, 3)):
            i = rng.randrange(len(text) + 1)
            op = rng.random()
            if op < 0.4 and i < len(text):
                del text[i]
            elif op < 0.7:
                text.insert(i, rng.choice(alphabet))
            elif i < len(text):
                text[i] = rng.choice(alphabet)
        text = "".join(text)
        try:
            e = parse(text, lib)
        except ParseError as err:
            lines = text.split("\n")
            assert 1 <= err.line <= len(lines) and 1 <= err.column <= len(lines[err.line - 1]) + 1
            if err.token:
                row = lines[err.line - 1]
                assert row[err.column - 1:].startswith(err.token[:len(row) - err.column + 1])
        else:
            assert check(e, lib) is Type.SHAPE and parse(to_text(e), lib) == e


def test_check_rejects_ill_typed_trees():
    cub = Call("Cuboid", (Num(1.0),) * 3)
    for bad, msg in [(Call("Cuboid", (Num(1.0),)), "Cuboid takes 3"),
                     (Call("Move", (Num(1.0), Num(0.0), Num(0.0), Num(0.0))), "expected Shape, got Float"),
                     (Call("SymRef", (cub, Var("a"))), "expected Axis, got Float"),
                     (Call("Foo", ()), "unknown function 'Foo'"),
                     (Call("Rotate", (cub, AxisConst("AX"), Num(0.1))), "unknown function 'Rotate'")]:
        with pytest.raises(ProgramError, match=msg):
            check(bad, LANG_2D if "Rotate" in msg else LANG_3D, Type.SHAPE)
    with pytest.raises(ProgramError):
        Var("AX")
    with pytest.raises(ProgramError):
        Var("s", Type.SHAPE)
    with pytest.raises(ProgramError):
        AxisConst("AW")
    with pytest.raises(ProgramError):
        Num(float("nan"))


def test_library_and_expansion():
    lib = _lib()
    assert len(lib) == 2 and lib.size == 8 and "Pair" in lib and lib["Leg"].params[0] == Param("w", Type.FLOAT)
    assert Library.from_text("# two abstractions\n" + lib.to_text()) == lib
    e = parse("Union(Pair(0.1,-0.4,AX),Leg(0.2,0.3,-0.3))", lib)
    flat = expand(e, lib)
    assert to_text(flat) == ("Union(SymRef(Union(Move(Cuboid(0.1,0.5,0.1),-0.4,-0.25,-0.4),"
                             "Move(Cuboid(0.1,0.5,0.1),-0.4,-0.25,Mul(-0.4,2.0))),AX),"
                             "Move(Cuboid(0.2,0.5,0.2),0.3,-0.25,-0.3))")
    assert check(flat, LANG_3D) is Type.SHAPE
    partial = expand(e, lib, names=["Pair"])
    assert "Leg(0.1,-0.4,-0.4)" in to_text(partial) and "Pair" not in to_text(partial)
    # removing Leg inlines it into Pair; programs that call Pair expand the same
    smaller = lib.remove("Leg")
    assert len(smaller) == 1 and "Leg" not in smaller
    assert expand(parse("Pair(0.1,-0.4,AX)", smaller), smaller) == expand(parse("Pair(0.1,-0.4,AX)", lib), lib)
    with pytest.raises(KeyError):
        lib.remove("Nope")


@pytest.mark.parametrize("text, msg", [
    ("Cuboid(a: Float) = Cuboid(a,a,a)", "already a function"),
    ("Box(a: Float, b: Float) = Cuboid(a,a,a)", "parameter 'b' is not used"),
    ("Box(a: Float) = Cuboid(a,c,a)", "'c' is not a parameter"),
    ("Box(a: Axis) = Cuboid(a,a,a)", "parameter 'a' is Axis, expected Float here"),
    ("Box(a: Shape) = Cuboid(1,1,1)", "unknown parameter type 'Shape'"),
    ("Box(a: Float, a: Float) = Cuboid(a,a,a)", "declared twice"),
    ("Box(a: Float) Cuboid(a,a,a)", "expected '='"),
    ("Box(a: Float) = Add(a,a)", "expected Shape"),
])
def test_bad_abstractions(text, msg):
    with pytest.raises(ParseError, match=msg):
        parse_abstraction(text, file="lib.txt")


def test_library_validates_constructed_abstractions():
    body = Call("Cuboid", (Var("a"), Var("a"), Var("a")))
    with pytest.raises(ProgramError, match="already has"):
        Library(LANG_3D, (Abstraction("A", (Param("a"),), body), Abstraction("A", (Param("a"),), body)))
    with pytest.raises(ProgramError, match="not used"):
        Library().add(Abstraction("A", (Param("a"), Param("b")), body))
    with pytest.raises(ProgramError, match="base function"):
        Library().add(Abstraction("Move", (Param("a"),), body))
    with pytest.raises(ProgramError, match="'z' is not a parameter"):
        Library().add(Abstraction("A", (Param("a"),), Call("Cuboid", (Var("a"), Var("z"), Var("a")))))
    with pytest.raises(ProgramError, match="unknown function 'B'"):  # no forward references
        Library().add(Abstraction("A", (Param("a"),), Call("B", (Var("a"),))))


def test_library_limits_hold_after_expansion_and_are_located():
    from shapeprog.errors import ParseError

    def nest(inner: str, n: int = 100) -> str:
        return "Move(" * n + inner + ",0.0,0.0,0.0)" * n

    lines = ["A0(F0: Float) = " + nest("Cuboid(F0,F0,F0)")]  # depth 102
    lines.append("A1(F0: Float) = " + nest("A0(F0)"))  # 202 when expanded
    lib = Library.from_text("\n".join(lines) + "\n")
    assert [lib.expanded_depth(a.body) for a in lib] == [102, 202]
    lines.append("A2(F0: Float) = " + nest("A1(F0)"))  # 302: over MAX_DEPTH although each line is shallow
    with pytest.raises(ParseError) as e:
        Library.from_text("\n".join(lines) + "\n", file="lib.txt")
    assert (e.value.file, e.value.line, e.value.column, e.value.token) == ("lib.txt", 3, 1, "A2")
    assert "MAX_DEPTH" in e.value.reason
    many = "".join(f"B{k}(F0: Float) = Cuboid(F0,F0,F0)\n" for k in range(limits.MAX_ABSTRACTIONS + 1))
    with pytest.raises(ParseError) as e:
        Library.from_text(many, file="lib.txt")
    assert e.value.line == limits.MAX_ABSTRACTIONS + 1 and "MAX_ABSTRACTIONS" in e.value.reason


def _doubling_library(levels: int) -> str:
    """``A0 = Cuboid(F0, F0, F0)``, ``Ak = Union(A{k-1}(F0), A{k-1}(F0))``: 2.4 KB for 60 levels, 2**k leaves."""
    lines = ["A0(F0: Float) = Cuboid(F0, F0, F0)"]
    lines += [f"A{k}(F0: Float) = Union(A{k - 1}(F0), A{k - 1}(F0))" for k in range(1, levels)]
    return "\n".join(lines) + "\n"


def test_defect_exponential_abstraction_library_is_refused_at_load():
    from shapeprog.coder.lang import expand, size

    with pytest.raises(ParseError) as e:
        Library.from_text(_doubling_library(60), file="lib.txt")
    assert str(e.value) == "lib.txt:16:1: A15: its body expands to more than 100000 nodes (MAX_NODES)"
    lib = Library.from_text(_doubling_library(15))  # Ak expands to 5 * 2**k - 1 nodes
    assert [lib.expanded_nodes(a.body) for a in lib] == [size(expand(a.body, lib)) for a in lib]
    assert lib.expanded_nodes(lib["A14"].body) == 81919
    mixed = Library.from_text("B(F0: Float, F1: Float) = Move(Cuboid(F0, F0, F1), F0, 0.0, F1)\n"
                              "C(F0: Float) = B(Add(F0, 1.0), Mul(F0, F0))\n")
    assert [mixed.expanded_nodes(a.body) for a in mixed] == [size(expand(a.body, mixed)) for a in mixed] == [8, 18]


def test_defect_exponential_abstraction_library_rules_walk_each_body_once(monkeypatch):
    import importlib

    rules = importlib.import_module("shapeprog.coder.rules")
    lib = Library.from_text(_doubling_library(15))
    walked = []
    real = rules.walk
    monkeypatch.setattr(rules, "walk", lambda e: walked.append(e) or real(e))
    rules._bookkeeping(lib)
    assert walked == [a.body for a in lib]
