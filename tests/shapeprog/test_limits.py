"""The language's limits (shapeprog.limits): each is a ParseError naming file, line and column."""
import time

import pytest

from shapeprog import limits
from shapeprog.compile import compile_program
from shapeprog.errors import ParseError
from shapeprog.execute import execute
from shapeprog.lang import parse

HEAD = ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.5, 0.1, 0.5, True)\n"
        "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n")


def _error(text: str) -> ParseError:
    with pytest.raises(ParseError) as ei:
        parse(text, "p.txt")
    return ei.value


def test_defect1_huge_translate_count_is_refused_fast_with_location():
    t0 = time.perf_counter()
    e = _error(HEAD + "translate(cube0, X, 100000000, 0.5)\n")
    assert time.perf_counter() - t0 < 0.5
    assert (e.line, e.column, e.token) == (4, 21, "100000000")
    assert "exceeds the limit of 256 (MAX_TRANSLATE_COPIES)" in str(e)
    e = _error(HEAD + "translate(cube0, X, " + "9" * 900 + ", 0.5)\n")  # no int conversion of 900 digits
    assert (e.line, e.column) == (4, 21) and "(900 digits)" in e.reason
    e = _error(HEAD + "translate(cube0, X, " + "9" * 5000 + ", 0.5)\n")
    assert (e.line, e.column) == (4, limits.MAX_LINE_LENGTH + 1) and "MAX_LINE_LENGTH" in e.reason
    assert len(execute(parse(HEAD + f"translate(cube0, X, {limits.MAX_TRANSLATE_COPIES}, 0.5)\n"))) == 257
    assert "exceeds" in _error(HEAD + f"translate(cube0, X, {limits.MAX_TRANSLATE_COPIES + 1}, 0.5)\n").reason
    assert "positive integer" in _error(HEAD + "translate(cube0, X, 000, 0.5)\n").reason


@pytest.mark.parametrize("text", ["1e999", "1e308", "-1e308", "1000.5", "-2e3"])
def test_defect3_out_of_range_numbers_are_refused(text):
    e = _error(HEAD.replace("0.5, 0.1, 0.5", f"{text}, 0.1, 0.5"))
    assert (e.file, e.line, e.column, e.token) == ("p.txt", 2, 16, text)
    assert f"number {text} is out of range" in str(e)


def test_numbers_at_the_limit_and_ascii_digits_only():
    p = parse(HEAD.replace("0.5, 0.1, 0.5", "1000.0, -1000, 0.5"))
    cube = [s for s in p.blocks[0].statements if getattr(s, "l", None) == 1000.0]
    assert len(cube) == 1 and (cube[0].l, cube[0].h, cube[0].w) == (1000.0, -1000.0, 0.5)
    e = _error(HEAD.replace("0.5, 0.1", "\u0663, 0.1"))  # an Arabic-Indic digit is no number
    assert (e.line, e.column) == (2, 16)


def test_line_count_and_length():
    e = _error(HEAD + "\n" * limits.MAX_LINES)
    assert (e.line, e.column) == (limits.MAX_LINES + 1, 1) and "MAX_LINES" in e.reason
    long = "bbox = Cuboid(1.0, 1.0, 1.0, True)" + " " * limits.MAX_LINE_LENGTH + "\n"
    assert (_error(long).line, _error(long).column) == (1, limits.MAX_LINE_LENGTH + 1)


def _tree(depth: int, copies: int = 1) -> str:
    """Program_0 -> Program_1 -> ... -> Program_depth, each holding the next (``copies`` times)."""
    out = []
    for k in range(depth + 1):
        out += [f"Assembly Program_{k} {{", "\tbbox = Cuboid(1.0, 1.0, 1.0, True)"]
        name = f"Program_{k + 1}" if k < depth else "cube0"
        out += [f"\t{name} = Cuboid(0.5, 0.5, 0.5, False)", f"\tattach({name}, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)"]
        if copies > 1:
            out.append(f"\ttranslate({name}, X, {copies - 1}, 0.5)")
        out.append("}")
    return "\n".join(out) + "\n"


def test_depth_blocks_and_cuboids_after_expansion():
    assert len(execute(parse(_tree(limits.MAX_DEPTH)))) == 1
    e = _error(_tree(limits.MAX_DEPTH + 1))
    assert e.line == 5 * (limits.MAX_DEPTH + 1) + 1 and e.token == f"Program_{limits.MAX_DEPTH + 1}"
    assert "MAX_DEPTH" in e.reason
    # 10 copies per level: 10**3 leaves fit, 10**4 do not; the error names the outermost translate
    assert len(execute(parse(_tree(2, copies=10)))) == 1000
    e = _error(_tree(3, copies=10))
    assert (e.line, e.token) == (5, "translate") and "MAX_CUBOIDS" in e.reason
    many = "".join(f"Assembly Program_{k} {{\n\tbbox = Cuboid(1.0, 1.0, 1.0, True)\n}}\n" for k in range(300))
    e = _error(many)
    assert (e.line, e.token) == (3 * limits.MAX_BLOCKS + 1, f"Program_{limits.MAX_BLOCKS}")


def test_attach_operations_after_expansion():
    atts = "".join(f"attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.{k}, 0.5)\n" for k in range(9))
    e = _error(HEAD + atts + "translate(cube0, X, 250, 0.5)\n")  # 10 attaches repeated by 250 copies
    assert (e.line, e.token) == (13, "translate") and "MAX_ATTACHES" in e.reason


def test_macro_names_follow_the_executor_on_collisions():
    # reflect(cube0) names its copy cube2, which exists: the executor re-uses it, so the next copy
    # is cube2 again and cube3 never exists
    text = ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, 0.1, True)\ncube2 = Cuboid(0.1, 0.1, 0.1, True)\n"
            "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.2, 0.0, 0.5)\nreflect(cube0, X)\nreflect(cube0, X)\n")
    assert compile_program(parse(text)).blocks[0].slots == ["bbox", "cube0", "cube2"]
    e = _error(text + "attach(cube3, bbox, 0.5, 0.0, 0.5, 0.2, 0.0, 0.5)\n")
    assert (e.line, e.token) == (7, "cube3") and "unknown cuboid" in e.reason


def test_decode_names_the_bad_byte():
    with pytest.raises(ParseError) as ei:
        limits.decode(b"bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = \xc3\xa9\xff\n", "p.txt")
    e = ei.value
    assert (e.file, e.line, e.column) == ("p.txt", 2, 10) and "not UTF-8" in e.reason
    assert limits.decode("é\n".encode(), "p.txt") == "é\n"


def test_a_long_chain_of_copies_within_the_limits_parses_and_executes():
    """Each reflect copies the previous copy: the copy chain is as long as the program (no recursion limit)."""
    n = limits.MAX_LINES - 3
    text = HEAD + "".join(f"reflect(cube{k}, X)\n" for k in range(n))
    cubes = execute(parse(text, "p.txt"))
    assert len(cubes) == n + 1
    compile_program(parse(text, "p.txt"))
