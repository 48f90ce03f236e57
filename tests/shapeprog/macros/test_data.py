"""Sub-programs from hand-made programs: cubes, levels, orderings, signatures, cleanup and failures."""
import dataclasses
import pickle
from collections import Counter
from concurrent.futures import ThreadPoolExecutor

import pytest

from shapeprog.lang import parse
from shapeprog.macros.data import (
    ConversionError, block_program, convert_block, convert_corpus, convert_program, order_errors,
)
from shapeprog.macros.subprogram import MAX_ORDERS, Ordering, orderings
from shapeprog.macros.grammar import BBOX, AttachLine, LineError, CuboidLine, ReflectLine, SqueezeLine, signature

HEAD = "bbox = Cuboid(1.0, 1.0, 1.0, True)\n"

# three cubes on the bbox floor (level 1), a fourth on two of them (level 2), a reflect and a translate
LEVELS = HEAD + """cube0 = Cuboid(0.2, 0.2, 0.2, True)
cube1 = Cuboid(0.2, 0.3, 0.2, True)
cube2 = Cuboid(0.2, 0.4, 0.2, False)
cube3 = Cuboid(0.8, 0.1, 0.3, True)
attach(cube0, bbox, 0.5, 0.0, 0.5, 0.2, 0.0, 0.2)
attach(cube1, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.8)
squeeze(cube2, bbox, bbox, top, 0.8, 0.2)
attach(cube3, cube0, 0.0, 0.0, 0.5, 0.5, 1.0, 0.5)
attach(cube3, cube1, 1.0, 0.0, 0.5, 0.5, 1.0, 0.5)
reflect(cube0, Z)
translate(cube2, Z, 2, 0.5)
"""


def _one(text, **kw):
    return convert_block(parse(text), "Program_0", "test", 1, **kw)


def test_cubes_levels_and_orderings():
    sub = _one(LEVELS)
    assert [c.name for c in sub.cubes] == ["cube0", "cube1", "cube2", "cube3"]
    assert sub.cubes[2].moves == (SqueezeLine(BBOX, BBOX, "top", 0.8, 0.2),)
    assert sub.cubes[0].sym == ReflectLine("Z") and sub.cubes[2].sym.n == 2
    assert sub.cubes[3].targets() == {0, 1}
    assert sub.levels == (1, 1, 1, 2) and sub.n_orders == 6
    assert [o.cubes for o in sub.orders] == [(0, 1, 2, 3), (0, 2, 1, 3), (1, 0, 2, 3), (1, 2, 0, 3), (2, 0, 1, 3),
                                             (2, 1, 0, 3)]
    assert sub.key == "test/1/Program_0" and sub.parent is None and sub.notes == ()


def test_lines_renumber_targets_canonically():
    sub = _one(LEVELS)
    order = sub.orders[3]  # cubes 1, 2, 0, 3
    lines = sub.lines(order)
    assert lines[0] == CuboidLine(1.0, 1.0, 1.0, True)
    assert [type(x).__name__ for x in lines[1:]] == ["CuboidLine", "AttachLine", "CuboidLine", "SqueezeLine",
                                                     "TranslateLine", "CuboidLine", "AttachLine", "ReflectLine",
                                                     "CuboidLine", "AttachLine", "AttachLine"]
    # cube3 attaches to cube0 (now canonical 2) and cube1 (now canonical 0)
    assert lines[-2].target == 2 and lines[-1].target == 0
    assert order.signature == signature(lines) == (
        ("att", 0, -2), ("squeeze", 1, -1, -2), ("trans", 1), ("att", 2, -2), ("ref", 2), ("att", 3, 2),
        ("att", 3, 0))
    assert sub.statement_keys(order) == [[], [(1, 0)], [], [(2, 0)], [], [(2, 1), (2, 2)], [(0, 0)], [],
                                         [(0, 1)], [(3, 0)], [], []]
    with pytest.raises(ValueError, match="not a permutation"):
        sub.lines((0, 1, 2))


def test_structural_matches_share_signatures():
    a = _one(LEVELS)
    b = _one(LEVELS.replace("0.2, 0.0, 0.2)", "0.3, 0.0, 0.1)").replace("top, 0.8", "bot, 0.7"))
    assert [o.signature for o in a.orders] != [o.signature for o in b.orders]  # bot swaps the bbox sides
    c = _one(LEVELS.replace("0.2, 0.0, 0.2)", "0.3, 0.0, 0.1)").replace("reflect(cube0, Z)", "reflect(cube0, X)"))
    assert [o.signature for o in a.orders] == [o.signature for o in c.orders]


def test_orderings_limit_and_count():
    perms, total = orderings([1, 1, 1, 1, 2, 2], limit=5)
    assert total == 48 and len(perms) == 5 and perms[0] == (0, 1, 2, 3, 4, 5) and perms[1] == (0, 1, 2, 3, 5, 4)
    assert orderings([1] * 8, limit=MAX_ORDERS)[1] == 40320
    sub = _one(LEVELS, max_orders=2)
    assert len(sub.orders) == 2 and sub.n_orders == 6
    with pytest.raises(ValueError, match="`limit` must be >= 1, got 0"):
        orderings([1], limit=0)


def test_every_ordering_executes_as_the_original():
    prog = parse(LEVELS)
    sub = convert_block(prog, "Program_0")
    assert order_errors([(sub, prog)]) == [0.0]
    # an ungrounded order (cube3 before its targets) is not executable
    bad = dataclasses.replace(sub, orders=(Ordering((3, 0, 1, 2), ()),))
    with pytest.raises(LineError, match="not declared"):
        order_errors([(bad, prog)])


def test_attach_pairs_written_as_a_squeeze():
    text = HEAD + """cube0 = Cuboid(0.2, 0.5, 0.2, False)
attach(cube0, bbox, 0.5, 1.0, 0.5, 0.3, 1.0, 0.4)
attach(cube0, bbox, 0.5, 0.0, 0.5, 0.3, 0.0, 0.4)
"""
    prog = parse(text)
    sub = convert_block(prog, "Program_0")
    assert sub.cubes[0].moves == (SqueezeLine(BBOX, BBOX, "top", 0.3, 0.4),)
    assert sub.notes == ("cube0: two attaches written as one squeeze",)
    assert order_errors([(sub, prog)]) == [0.0]
    # the same with a target point off the face is two attaches
    sub2 = _one(text.replace("0.3, 0.0, 0.4)", "0.3, 0.1, 0.4)"))
    assert [type(m) for m in sub2.cubes[0].moves] == [AttachLine, AttachLine]


CLOSE = HEAD + """cube0 = Cuboid(0.2, 0.5, 0.2, False)
cube1 = Cuboid(0.2, 0.5, 0.2, True)
attach(cube0, bbox, 0.5, 0.0, 0.5, 0.3, 0.0, 0.5)
attach(cube0, bbox, 0.5, 0.1, 0.5, 0.5, 0.3, 0.5)
attach(cube1, bbox, 0.5, 0.0, 0.5, 0.7, 0.0, 0.5)
attach(cube1, bbox, 0.5, 0.1, 0.5, 0.7, 0.1, 0.5)
"""


def test_cleanup_drops_a_close_second_attach_only_where_it_changes_nothing():
    prog = parse(CLOSE)
    sub = convert_block(prog, "Program_0")  # cleanup="exact"
    assert len(sub.cubes[0].moves) == 2 and len(sub.cubes[1].moves) == 1
    assert sub.notes == ("cube0: close second attach kept (dropping it changes the cuboids)",
                         "cube1: close second attach dropped")
    assert order_errors([(sub, prog)]) == [0.0]
    spec = convert_block(prog, "Program_0", cleanup="spec")
    assert len(spec.cubes[0].moves) == 1 and len(spec.cubes[1].moves) == 1
    assert order_errors([(spec, prog)])[0] > 1e-2  # the reference's cleanup changes cube0
    with pytest.raises(ValueError, match="cleanup"):
        convert_block(prog, "Program_0", cleanup="none")


# cube0 is used by cube1 before its own second attach, which grows it towards cube2
SENSITIVE = """bbox = Cuboid(2.0, 2.0, 2.0, True)
cube0 = Cuboid(0.2, 0.2, 0.2, True)
cube1 = Cuboid(0.1, 0.1, 0.1, True)
cube2 = Cuboid(0.2, 0.2, 0.2, True)
attach(cube2, bbox, 0.5, 0.0, 0.5, 0.9, 0.0, 0.5)
attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)
attach(cube1, cube0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)
attach(cube0, cube2, 1.0, 0.5, 0.5, 0.0, 0.5, 0.5)
"""


def test_a_text_order_that_no_pblock_order_reproduces_is_refused():
    with pytest.raises(ConversionError, match="executes differently"):
        _one(SENSITIVE)
    # the same order, with cube2 overlapping cube0 (the aligned rule then leaves cube0), converts
    same = SENSITIVE.replace("0.9, 0.0, 0.5)", "0.58, 0.0, 0.5)")
    counts = Counter()
    prog = parse(same)
    sub = convert_block(prog, "Program_0", counts=counts)
    assert counts["text order differs, same cuboids"] == 1
    assert order_errors([(sub, prog)]) == [0.0]


@pytest.mark.parametrize("body, reason", [
    ("cube0 = Cuboid(0.2, 0.2, 0.2, True)\nattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
     "reflect(cube0, X)\ntranslate(cube0, Z, 2, 0.5)\n", "more than one reflect/translate"),
    ("cube0 = Cuboid(0.2, 0.2, 0.2, True)\ncube1 = Cuboid(0.2, 0.2, 0.2, True)\n"
     "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n", "cube1 is never attached"),
    ("cube0 = Cuboid(0.2, 0.2, 0.2, False)\n" + "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n" * 3,
     "moved by 3 lines"),
    ("cube0 = Cuboid(0.2, 0.2, 0.2, False)\nattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
     "squeeze(cube0, bbox, bbox, top, 0.5, 0.5)\n", "attach, squeeze"),
    ("cube0 = Cuboid(0.2, 0.2, 0.2, True)\nattach(cube0, bbox, 0.5, 0.0, 0.5, 0.2, 0.0, 0.5)\nreflect(cube0, X)\n"
     "cube2 = Cuboid(0.1, 0.1, 0.1, True)\nattach(cube2, cube1, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)\n",
     "'cube1', a reflect/translate copy"),
    ("cube0 = Cuboid(0.2, 0.2, 0.2, True)\ncube1 = Cuboid(0.2, 0.2, 0.2, True)\n"
     "attach(cube0, cube1, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)\nattach(cube1, cube0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)\n",
     "cycle"),
])
def test_blocks_outside_the_grammar_are_refused_with_a_reason(body, reason):
    with pytest.raises(ConversionError, match=reason):
        _one(HEAD + body)
    conv = convert_program(parse(HEAD + body), "test", 7)
    assert conv.subprograms == [] and len(conv.failures) == 1
    f = conv.failures[0]
    assert (f.category, f.shape_id, f.block) == ("test", 7, "Program_0") and reason in str(f)
    assert str(f).startswith("test/7/Program_0: ")


TWO_LEVELS = """Assembly Program_0 {
\tbbox = Cuboid(1.2, 1.0, 0.8, True)
\tProgram_1 = Cuboid(0.3, 0.6, 0.7, False)
\tcube1 = Cuboid(1.2, 0.1, 0.8, True)
\tattach(Program_1, bbox, 0.5, 0.0, 0.5, 0.2, 0.0, 0.5)
\tsqueeze(cube1, bbox, Program_1, top, 0.5, 0.25)
\treflect(Program_1, X)
}
Assembly Program_1 {
\tbbox = Cuboid(0.3, 0.6, 0.7, True)
\tcube0 = Cuboid(0.05, 0.6, 0.05, False)
\tattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.1)
\ttranslate(cube0, Z, 2, 0.8)
}
"""


def test_hierarchy_parts_are_cubes_and_blocks_know_their_parent():
    prog = parse(TWO_LEVELS)
    conv = convert_program(prog, "x", 3)
    root, child = conv.subprograms
    assert root.cubes[0].name == "Program_1" and root.cubes[0].child == "Program_1" and root.cubes[1].child is None
    assert child.parent == ("Program_0", 0) and child.bbox == CuboidLine(0.3, 0.6, 0.7, True)
    flat = block_program(prog, "Program_0")
    assert flat.flat and [s.name for s in flat.root.statements[:3]] == ["bbox", "cube0", "cube1"]
    assert order_errors([(root, prog), (child, prog)]) == [0.0, 0.0]


def test_subprograms_pickle_and_corpus_conversion_runs_on_an_executor():
    serial = convert_corpus(["chair"], limit=12)
    with ThreadPoolExecutor(2) as ex:
        pooled = convert_corpus(["chair"], limit=12, executor=ex, chunk=5)
    assert [s.key for s in pooled.subprograms] == [s.key for s in serial.subprograms]
    assert pooled.subprograms == serial.subprograms and pooled.programs == {"chair": 12}
    assert pickle.loads(pickle.dumps(serial.subprograms)) == serial.subprograms
    sigs = {}
    for s in pooled.subprograms:  # equal signatures are one object across the result
        for o in s.orders:
            assert sigs.setdefault(o.signature, o.signature) is o.signature
    assert "chair: 12 programs" in serial.summary()
    with pytest.raises(ValueError, match="cleanup"):
        convert_corpus(["chair"], cleanup="bad")


def test_a_program_built_in_code_that_moves_the_bbox_is_refused():
    from shapeprog.lang import Attach, Block, Cuboid, Program

    prog = Program((Block("Program_0", (Cuboid("bbox", 1.0, 1.0, 1.0, True), Cuboid("cube0", 0.2, 0.2, 0.2, True),
                                        Attach("bbox", "cube0", 0.5, 0.0, 0.5, 0.5, 0.0, 0.5))),), flat=True)
    with pytest.raises(ConversionError, match="statement 3 moves the bbox"):
        convert_block(prog, "Program_0")
