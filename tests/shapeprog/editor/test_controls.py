"""shapeprog.editor.controls: the control list, edits equal to text edits, round trips, range edges, fuzzed
values, the cuboids a control moves, macro programs."""
import math
import random

import pytest
import torch

from shapeprog import corpus
from shapeprog.editor import BOOL, CHOICE, FLOAT, INT, apply, controls
from shapeprog.errors import EditError, ExecutionError, ParseError
from shapeprog.execute import execute, execute_batch
from shapeprog.lang import FACES, parse, to_text
from shapeprog.limits import MAX_TRANSLATE_COPIES
from shapeprog.macros.execute import execute as macro_execute
from shapeprog.macros.lang import to_text as macro_text
from shapeprog.macros.library import Library

from editor_testutil import EVERY, MACROS


def _sample(stride=20):
    """Every ``stride``-th program of every category (all splits)."""
    out = []
    for cat in corpus.CATEGORIES:
        for k, i in enumerate(corpus.ids(cat, "all")):
            if k % stride == 0:
                out.append((f"{cat}/{i}", parse(corpus.read(cat, i), f"{cat}/{i}.txt")))
    return out


SAMPLE = _sample(40)


def test_control_list_of_every_statement_kind():
    p = parse(EVERY, "every.txt")
    cs = controls(p)
    by = {c.name: c for c in cs}
    # bbox: 3 dims (no aligned); 3 cuboids x (3 dims + aligned); attach 1 choice + 6; squeeze 2 choices, face, u, v;
    # attach 1 + 6; reflect axis; translate axis, n, d
    assert len(cs) == 3 + 3 * 4 + 7 + 5 + 7 + 1 + 3
    assert [c.kind for c in cs].count(FLOAT) == 3 + 9 + 6 + 2 + 6 + 1
    assert [c.kind for c in cs].count(BOOL) == 3
    assert [c.kind for c in cs].count(INT) == 1
    assert [c.kind for c in cs].count(CHOICE) == 1 + 3 + 1 + 2
    c = by["Program_0:0:cuboid.l"]
    assert (c.kind, c.low, c.high, c.value, c.line, c.column) == (FLOAT, 0.01, 4.0, 1.0, 1, 15)
    c = by["Program_0:4:attach.y1"]
    assert (c.low, c.high, c.value, c.line) == (0.0, 1.0, 0.5, 5)
    assert EVERY.split("\n")[c.line - 1][c.column - 1:].startswith("0.5, 0.5, 0.5, 0.5")
    assert by["Program_0:4:attach.b"].choices == ("bbox", "cube0", "cube2")  # not the subject cube1
    assert by["Program_0:5:squeeze.face"].choices == FACES
    assert by["Program_0:5:squeeze.c"].value == "cube1"
    assert by["Program_0:7:reflect.axis"].choices == ("X", "Y", "Z")
    n = by["Program_0:8:translate.n"]
    assert (n.kind, n.low, n.high, n.value) == (INT, 1, MAX_TRANSLATE_COPIES, 2)
    assert "Program_0:0:cuboid.aligned" not in by
    assert len({c.name for c in cs}) == len(cs)
    # every control's token is where it says: the printed value starts at (line, column)
    for c in cs:
        text = EVERY.split("\n")[c.line - 1][c.column - 1:]
        assert text.startswith(repr(c.value) if c.kind == FLOAT else str(c.value)), c.name


def test_cuboids_moved_match_finite_changes():
    """A float control's cuboids are exactly the leaves whose corners change when it changes a little."""
    for name, p in [("every", parse(EVERY))] + SAMPLE[:4]:
        base = execute(p, dtype=torch.float64).corners
        for c in controls(p):
            if c.kind != FLOAT:
                continue
            v = c.value + 1e-3 if c.value + 1e-3 <= c.high else c.value - 1e-3
            new = execute(apply(p, {c.name: v}), dtype=torch.float64).corners
            changed = tuple(torch.nonzero((new - base).abs().flatten(1).amax(1) > 1e-9).flatten().tolist())
            assert changed == c.cuboids, (name, c.name)


def test_discrete_controls_move_their_lines_cuboids():
    p = parse(EVERY)
    by = {c.name: c for c in controls(p)}
    s = execute(p)
    reflect_made = tuple(k for k, ln in enumerate(s.line.tolist()) if ln == 7)
    assert by["Program_0:7:reflect.axis"].cuboids == reflect_made and reflect_made
    assert by["Program_0:1:cuboid.aligned"].cuboids == by["Program_0:1:cuboid.l"].cuboids


def test_corpus_round_trip_and_child_bbox_tie():
    """Current values give the same text back (every 40th corpus program); a sub-program's bbox dims follow
    their parent line."""
    tied = 0
    for name, p in SAMPLE:
        cs = controls(p, cuboids=False)
        assert len({c.name for c in cs}) == len(cs), name
        assert to_text(apply(p, {c.name: c.value for c in cs})) == to_text(p), name
        for b in p.blocks[1:]:
            assert not any(c.name.startswith(f"{b.name}:0:cuboid.") and c.kind == FLOAT for c in cs)
        for c in cs:
            if c.kind == FLOAT and len(c.lines) == 2:
                q = apply(p, {c.name: c.value * 0.9})
                f = c.name[-1]
                parent_line, child_line = c.lines
                t = to_text(q).split("\n")
                assert t[parent_line - 1].split("Cuboid(")[1].split(", ")["lhw".index(f)] == repr(c.value * 0.9)
                assert t[child_line - 1].split("Cuboid(")[1].split(", ")["lhw".index(f)] == repr(c.value * 0.9)
                tied += 1
    assert tied > 50


def test_edit_equals_text_edit():
    """apply() gives the program of the text edited at the control's token, and the same geometry."""
    rng = random.Random(0)
    for name, p in SAMPLE[::8]:
        text = to_text(p)
        for c in rng.sample(controls(p, cuboids=False), 5):
            if c.kind == FLOAT:
                v = round(rng.uniform(c.low, c.high), 3)
            elif c.kind == INT:
                v = rng.randint(1, 4)
            elif c.kind == BOOL:
                v = not c.value
            else:
                v = rng.choice(c.choices)
            lines = text.split("\n")
            old = repr(c.value) if c.kind == FLOAT else str(c.value)
            row = lines[c.line - 1]
            lines[c.line - 1] = row[:c.column - 1] + (repr(v) if c.kind == FLOAT else str(v)) + row[c.column - 1 + len(old):]
            if len(c.lines) == 2:  # the tied child bbox line
                row = lines[c.lines[1] - 1]
                k = "lhw".index(c.name[-1])
                args = row.split("Cuboid(")[1].split(", ")
                args[k] = repr(v)
                lines[c.lines[1] - 1] = row.split("Cuboid(")[0] + "Cuboid(" + ", ".join(args)
            try:
                by_text = parse("\n".join(lines), "t.txt")
            except ParseError:
                with pytest.raises(EditError):
                    apply(p, {c.name: v})
                continue
            q = apply(p, {c.name: v})
            assert q == by_text, (name, c.name)
            try:
                a = execute(q).corners
            except ExecutionError:
                continue
            assert torch.equal(a, execute(by_text).corners)


def test_range_edges_execute():
    """Every float control at its low and at its high end executes to finite cuboids (15 corpus programs)."""
    for name, p in SAMPLE[::30]:
        edited = []
        for c in controls(p, cuboids=False):
            if c.kind == FLOAT:
                edited += [apply(p, {c.name: c.low}), apply(p, {c.name: c.high})]
        for s in execute_batch(edited):
            assert bool(s.corners.isfinite().all()), name


def test_bad_values_are_edit_errors_at_the_token():
    p = parse(EVERY, "every.txt")
    with pytest.raises(EditError, match=r"every.txt:5:26: control 'Program_0:4:attach.y1': value 1.5 is outside"):
        apply(p, {"Program_0:4:attach.y1": 1.5}, file="every.txt")
    with pytest.raises(EditError, match="no such control"):
        apply(p, {"Program_0:99:attach.y1": 0.5})
    with pytest.raises(EditError, match="expected True or False"):
        apply(p, {"Program_0:1:cuboid.aligned": 1})
    with pytest.raises(EditError, match="is not one of"):
        apply(p, {"Program_0:5:squeeze.face": "up"})
    with pytest.raises(EditError, match="expected an integer"):
        apply(p, {"Program_0:8:translate.n": 2.5})
    with pytest.raises(EditError, match="outside"):
        apply(p, {"Program_0:1:cuboid.l": float("nan")})
    # a value the language refuses once printed: a translate that makes too many cuboids (a limit)
    big = parse("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.1, 0.1, 0.1, True)\n"
                "attach(cube0, bbox, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)\n" + "translate(cube0, X, 190, 0.5)\n" * 5)
    with pytest.raises(EditError, match="MAX_CUBOIDS") as e:
        apply(big, {"Program_0:3:translate.n": 256})
    assert e.value.line >= 4 and e.value.control == "Program_0:3:translate.n"


def _fuzz_value(rng, c):
    return rng.choice([
        rng.uniform(-2, 6), rng.choice([float("nan"), float("inf"), -0.0, 1e308, -1e-320]), rng.randint(-3, 300),
        True, False, None, "X", "top", "bbox", "cube1", rng.choice(c.choices) if c.choices else 0.5, [0.5], b"1",
        c.low if c.low is not None else 1, c.high if c.high is not None else 2,
    ])


def test_fuzzed_values_raise_only_edit_errors():
    rng = random.Random(1)
    progs = [parse(EVERY)] + [p for _, p in SAMPLE[::12]]
    ok = bad = 0
    for _ in range(600):
        p = rng.choice(progs)
        cs = controls(p, cuboids=False)
        values = {}
        for c in rng.sample(cs, rng.randint(1, 4)):
            values[c.name] = _fuzz_value(rng, c)
        if rng.random() < 0.05:
            values[rng.choice(["", "x", "Program_0:0:cuboid.q", 3])] = 1.0
        try:
            q = apply(p, values)
        except EditError as e:
            assert e.line >= 1 and e.column >= 1
            bad += 1
            continue
        ok += 1
        assert parse(to_text(q)) == q
        try:
            s = execute(q)
        except ExecutionError:
            continue
        assert bool(s.corners.isfinite().all())
    assert ok > 20 and bad > 100


def test_macro_program_controls():
    lib = Library()
    p = lib.parse(MACROS, "m.txt")
    cs = controls(p, lib)
    by = {c.name: c for c in cs}
    # bbox 3 dims; four_legs s, b, t; seat 3 dims + aligned; attach target + 6 floats
    assert len(cs) == 3 + 3 + 4 + 7
    s = by["1:four_legs.s"]
    assert (s.kind, s.value, s.low, s.high, s.line) == (FLOAT, 0.1, 0.0, 4.0, 11)
    assert MACROS.split("\n")[s.line - 1][s.column - 1:].startswith("0.1, True")
    assert by["1:four_legs.b"].kind == BOOL
    assert by["3:attach.target"].choices == ("bbox", "leg0", "leg1", "seat")
    assert by["3:attach.x1"].high == 1.0
    assert macro_text(apply(p, {c.name: c.value for c in cs}, lib)) == macro_text(p)
    q = apply(p, {"1:four_legs.s": 0.2}, lib)
    assert macro_text(q) == MACROS.replace("four_legs(0.1,", "four_legs(0.2,")
    legs = execute_shape = macro_execute(q, lib)
    assert legs.dims[0, 0].item() == pytest.approx(0.2)
    assert s.cuboids == (0, 1, 2, 3, 4)  # the four legs and the seat attached to leg0
    assert by["2:Cuboid.l"].cuboids == (4,)
    with pytest.raises(EditError, match="m.txt:11"):
        apply(p, {"1:four_legs.t": 7.0}, lib, file="m.txt")
    del execute_shape
