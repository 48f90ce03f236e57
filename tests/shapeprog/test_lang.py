"""Language tests: corpus round trip, located errors, the flat format."""
import dataclasses
import warnings

import pytest

from shapeprog import corpus
from shapeprog.lang import (Attach, Cuboid, ParseError, ParseWarning, Program, Reflect, Squeeze, Translate,
                            numbers, parse, replace_numbers, statement_lines, to_text)

GOOD = """Assembly Program_0 {
\tbbox = Cuboid(1.0, 1.2, 0.8, True)
\tProgram_1 = Cuboid(0.5, 0.4, 0.3, False)
\tcube1 = Cuboid(0.2, 0.1, 0.2, True)
\tattach(Program_1, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)
\tsqueeze(cube1, bbox, Program_1, top, 0.25, 0.75)
\treflect(cube1, X)
\ttranslate(cube2, Z, 2, 0.5)
}
Assembly Program_1 {
\tbbox = Cuboid(0.5, 0.4, 0.3, False)
\tcube0 = Cuboid(0.1, 0.1, 0.1, True)
\tattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)
}
"""


def test_whole_corpus_round_trips_byte_for_byte():
    n = 0
    for cat in corpus.CATEGORIES:
        for i in corpus.ids(cat, "all"):
            text = corpus.read(cat, i)
            assert to_text(parse(text, f"{cat}/{i}.txt")) == text, f"{cat}/{i}"
            n += 1
    assert n == 11922


def test_ast_structure_and_round_trip():
    p = parse(GOOD)
    assert not p.flat and [b.name for b in p.blocks] == ["Program_0", "Program_1"]
    st = p.root.statements
    assert st[1] == Cuboid("Program_1", 0.5, 0.4, 0.3, False)
    assert st[3] == Attach("Program_1", "bbox", 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)
    assert st[4] == Squeeze("cube1", "bbox", "Program_1", "top", 0.25, 0.75)
    assert st[5] == Reflect("cube1", "X") and st[6] == Translate("cube2", "Z", 2, 0.5)
    assert p.children(p.root) == [None, p.blocks[1], None]
    assert to_text(p) == GOOD and parse(to_text(p)) == p
    assert statement_lines(p) == [[1, 2, 3, 4, 5, 6, 7], [10, 11, 12]]
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.blocks[0].statements[0].l = 3.0


def test_numbers_replace_and_rounding():
    p = parse(GOOD)
    vals = numbers(p)
    assert len(vals) == 3 * 5 + 6 * 2 + 2 + 1
    q = replace_numbers(p, [v + 0.00049 for v in vals])
    assert to_text(q, decimals=3) == GOOD
    assert "0.50049" in to_text(q)


def test_flat_example_with_trailing_comma_warns_with_location():
    text = corpus.example_text("ex-0.txt")
    with pytest.warns(ParseWarning, match=r"ex-0.txt:7: ignoring a stray ','"):
        p = parse(text, "ex-0.txt")
    assert p.flat and len(p.blocks) == 1 and len(p.root.statements) == 12
    # printed back without the comma; otherwise identical
    assert to_text(p) == text.replace("),\n", ")\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert parse(to_text(p)) == p


ERRORS = [
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = cubiod(0.1, 0.1, 0.1, True)\n", 2, 9, "cubiod",
     "unknown command 'cubiod'"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\nattch(cube0, bbox)\n", 2, 1, "attch", "unknown command"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, True)\n", 2, 9, "Cuboid",
     "Cuboid expects 4 arguments, got 3"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, 0.1, True)\n"
     "attach(cube0, cube9, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)\n", 3, 15, "cube9", "unknown cuboid 'cube9'"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, 0.1, True)\n"
     "squeeze(cube0, bbox, bbox, up, 0.5, 0.5)\n", 3, 28, "up", "unknown face 'up'"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, 0.1, True)\nreflect(cube0, W)\n",
     3, 16, "W", "unknown axis 'W'"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, 0.1, True)\n"
     "attach(bbox, cube0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)\n", 3, 8, "bbox", "bbox cannot be moved"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\nreflect(bbox, X)\n", 2, 9, "bbox", "bbox cannot be moved"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\nCuboid(0.1, 0.1, 0.1, True)\n", 2, 1, "Cuboid", "Cuboid needs a name"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, 0.1, True)\n"
     "squeeze(cube0, bbox, cube0, top, 0.5, 0.5)\n", 3, 9, "cube0", "cannot be squeezed against itself"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, 0.1, True)\ntranslate(cube0, X, 0, 0.5)\n",
     3, 21, "0", "positive integer"),
    ("bbox = Cuboid(1.0, 1.0, 1.0, Maybe)\n", 1, 30, "Maybe", "expected True or False"),
    ("cube0 = Cuboid(1.0, 1.0, 1.0, True)\n", 1, 1, "cube0", "must start with 'bbox = Cuboid(...)'"),
    ("Assembly Program_0 {\n\tbbox = Cuboid(1.0, 1.0, 1.0, True)\n\tProgram_1 = Cuboid(0.5, 0.5, 0.5, True)\n}\n",
     3, 2, "Program_1", "missing sub-program block 'Assembly Program_1'"),
    ("Assembly Program_0 {\n\tbbox = Cuboid(1.0, 1.0, 1.0, True)\n", 2, 36, "", "missing '}'"),
]


@pytest.mark.parametrize("text,line,col,token,msg", ERRORS)
def test_errors_name_file_line_column_token(text, line, col, token, msg):
    with pytest.raises(ParseError) as ei:
        parse(text, "chair_12.txt")
    e = ei.value
    assert (e.file, e.line, e.column, e.token) == ("chair_12.txt", line, col, token)
    assert msg in str(e) and str(e).startswith(f"chair_12.txt:{line}:{col}: ")
    assert isinstance(e, ValueError)


def test_error_message_format_example():
    with pytest.raises(ParseError, match=r"^chair_12\.txt:2:9: unknown command 'cubiod'$"):
        parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = cubiod(0.1, 0.1, 0.1, True)\n", "chair_12.txt")


def test_macro_created_names_are_known():
    p = parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, 0.1, True)\n"
              "attach(cube0, bbox, 0.5, 0.5, 0.5, 0.1, 0.5, 0.5)\nreflect(cube0, X)\nreflect(cube1, Z)\n")
    assert isinstance(p, Program) and p.root.statements[-1] == Reflect("cube1", "Z")
