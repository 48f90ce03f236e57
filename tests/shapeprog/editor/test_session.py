"""shapeprog.editor.session and shapeio.editing: undo / redo invariants, failed edits keeping the last good
geometry, parse errors at open, plan reuse equal to fresh execution, target distance, exports."""
import random

import numpy as np
import pytest
import torch
from PIL import Image

from shapeio import write_new
from shapeio.editing import History
from shapeprog import corpus
from shapeprog.editor import EditSession, apply, controls, corner_distance
from shapeprog.editor.controls import FLOAT
from shapeprog.errors import EditError, ExecutionError, ParseError
from shapeprog.execute import execute
from shapeprog.io import obj_text
from shapeprog.lang import parse, to_text

CHAIR = corpus.read("chair", 173)


def test_history_against_a_model():
    """Random pushes, undos and redos agree with a plain list-and-cursor model; undo then redo is a no-op."""
    rng = random.Random(0)
    for limit in (1, 3, 50):
        h, model, i = History(0, limit=limit), [0], 0
        for step in range(400):
            op = rng.choice("puuur")
            if op == "p":
                del model[i + 1:]
                model.append(step + 1)
                model = model[-limit:]
                i = len(model) - 1
                h.push(step + 1)
            elif op == "u":
                if i == 0:
                    assert not h.can_undo
                    with pytest.raises(IndexError):
                        h.undo()
                else:
                    i -= 1
                    assert h.undo() == model[i]
            else:
                if i == len(model) - 1:
                    assert not h.can_redo
                    with pytest.raises(IndexError):
                        h.redo()
                else:
                    i += 1
                    assert h.redo() == model[i]
            assert h.current == model[i] and len(h) == len(model) <= limit
            if h.can_undo:
                before = h.current
                h.undo()
                assert h.redo() == before
    with pytest.raises(ValueError, match="`limit` must be an int >= 1, got 0"):
        History(0, limit=0)


def test_session_undo_redo_reset():
    s = EditSession(CHAIR, "chair/173.txt")
    floats = [c for c in s.controls() if c.kind == FLOAT]
    rng = random.Random(2)
    texts = [s.text]
    for c in rng.sample(floats, 6):
        assert s.set({c.name: round(rng.uniform(c.low, c.high), 3)})
        texts.append(s.text)
    for t in reversed(texts[:-1]):
        assert s.undo() and s.text == t
    assert not s.undo()
    for t in texts[1:]:
        assert s.redo() and s.text == t
    assert not s.redo()
    assert s.reset() and s.text == CHAIR and s.history.can_undo
    assert s.undo() and s.text == texts[-1]
    # the geometry always belongs to the program (plan reuse equals a fresh execution)
    assert torch.equal(s.shape.corners, execute(s.program).corners)


def test_failed_edits_keep_the_last_good_geometry():
    s = EditSession(CHAIR, "chair/173.txt")
    before, text = s.shape.corners.clone(), s.text
    c = next(c for c in s.controls() if c.kind == FLOAT)
    assert not s.set({c.name: c.high + 1})
    assert isinstance(s.error, EditError) and s.error.file == "chair/173.txt" and s.error.line == c.line
    assert torch.equal(s.shape.corners, before) and s.text == text and not s.history.can_undo
    # an execution that fails: a zero bbox extent
    flat = "bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\n" \
           "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
    s = EditSession(flat, "f.txt")
    assert not s.set_text(flat.replace("Cuboid(1.0, 1.0, 1.0", "Cuboid(0.0, 1.0, 1.0"))
    assert isinstance(s.error, ExecutionError) and "f.txt" in str(s.error)
    assert s.text == flat
    assert s.set({"Program_0:1:cuboid.l": 0.7}) and s.error is None


def test_float_edits_equal_fresh_execution():
    """The session reuses the compiled plan while only numbers change; the geometry equals execute()."""
    s = EditSession(corpus.read("chair", 42220), "chair/42220.txt")
    rng = random.Random(3)
    cs = s.controls()
    for _ in range(15):
        c = rng.choice(cs)
        v = round(rng.uniform(c.low, c.high), 3) if c.kind == FLOAT else c.value
        if s.set({c.name: v}):
            assert torch.equal(s.shape.corners, execute(s.program).corners)


def test_parse_error_at_open_then_fixed():
    bad = CHAIR.replace("attach(", "atach(", 1)
    s = EditSession(bad, "chair/173.txt")
    assert s.program is None and s.shape is None and isinstance(s.error, ParseError)
    assert (s.error.file, s.error.line) == ("chair/173.txt", bad.split("\n").index(
        next(l for l in bad.split("\n") if "atach(" in l)) + 1)
    assert s.error.column == 2 and s.controls() == [] and s.text == ""
    assert not s.set({"x": 1.0}) and isinstance(s.error, EditError)
    assert s.set_text(CHAIR) and s.text == CHAIR and s.error is None


def test_target_distance():
    s = EditSession(CHAIR, "chair/173.txt")
    s.set_target(CHAIR)
    assert s.distance() == 0.0
    s.set_target(corpus.read("chair", 42220))
    d0 = s.distance()
    assert d0 > 0.05
    a, b = execute(parse(CHAIR)), execute(parse(corpus.read("chair", 42220)))
    assert corner_distance(a, b) == corner_distance(b, a) == pytest.approx(d0)
    # the definition: mean nearest-corner distance both ways
    x, y = a.corners.reshape(-1, 3).double(), b.corners.reshape(-1, 3).double()
    d = torch.cdist(x, y)
    assert d0 == pytest.approx(float(d.min(1).values.mean() + d.min(0).values.mean()), rel=1e-12)
    with pytest.raises(ParseError):
        s.set_target("nonsense", "t.txt")


def test_exports_never_replace(tmp_path):
    s = EditSession(CHAIR, "chair/173.txt")
    s.set({"Program_0:1:cuboid.h": 0.3})
    (tmp_path / "chair_173_edit001.obj").write_text("mine")
    paths = s.export(tmp_path)
    assert [p.name for p in paths] == ["chair_173_edit002.txt", "chair_173_edit002.obj", "chair_173_edit002.png"]
    assert (tmp_path / "chair_173_edit001.obj").read_text() == "mine"
    assert parse(paths[0].read_text()) == s.program
    assert paths[1].read_text() == obj_text(s.shape.corners, lines=s.shape.line)
    img = np.asarray(Image.open(paths[2]))
    assert img.shape == (512, 512, 3) and (img != 255).any()
    assert [p.name for p in s.export(tmp_path, ["txt"])] == ["chair_173_edit003.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["chair_173_edit001.obj", "chair_173_edit002.txt", "chair_173_edit002.obj", "chair_173_edit002.png",
         "chair_173_edit003.txt"])  # no temporary file left
    with pytest.raises(ValueError, match="unknown export"):
        s.export(tmp_path, ["stl"])
    with pytest.raises(FileNotFoundError):
        s.export(tmp_path / "missing")
    with pytest.raises(FileExistsError):
        write_new(paths[0], "x")
    assert parse(paths[0].read_text()) == s.program


def test_macro_session_and_expansion():
    from shapeprog.macros.library import Library

    from editor_testutil import MACROS

    s = EditSession(MACROS, "m.txt")
    assert s.is_macro and s.error is None
    assert s.set({"1:four_legs.s": 0.15})
    assert s.shape.dims[0, 0].item() == pytest.approx(0.15)
    expanded = s.expanded_text()
    e = EditSession(expanded, "m_expanded.txt")
    assert not e.is_macro and torch.equal(e.shape.corners, s.shape.corners)
    assert len(e.controls()) > len(s.controls())
    assert s.undo() and s.shape.dims[0, 0].item() == pytest.approx(0.1)
    bad = EditSession(MACROS.replace("four_legs(0.1", "four_legs(bbox"), "m.txt", library=Library())
    assert isinstance(bad.error, ParseError) and bad.error.line == 11


def test_importing_the_editor_does_not_import_viser():
    import subprocess
    import sys

    code = ("import sys, shapeprog, shapeprog.editor, shapeprog.editor.server, shapeio.editing; "
            "assert 'viser' not in sys.modules, 'viser imported'")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr


def _edit_args(**kw):
    import argparse

    base = dict(program=None, sample=False, category="chair", seed=0, library=None, target=None)
    base.update(kw)
    return argparse.Namespace(**base)


def test_the_edit_command_opens_samples_macro_files_and_targets(tmp_path):
    from shapeprog.commands import open_for_edit

    from editor_testutil import MACROS

    s, text, file = open_for_edit(_edit_args(sample=True, category="chair", seed=1))
    assert s.error is None and s.program is not None and file == "chair_sample_seed1.txt" and s.text == text
    lib = tmp_path / "lib.txt"
    lib.write_text(MACROS.split("\nbbox")[0])
    prog = tmp_path / "legs.txt"
    prog.write_text("bbox" + MACROS.split("\nbbox", 1)[1])
    s, _, _ = open_for_edit(_edit_args(program=str(prog), library=str(lib), target="chair/173"))
    assert s.is_macro and s.error is None and s.distance() > 0
    assert [c.name for c in s.controls()][3:6] == ["1:four_legs.s", "1:four_legs.b", "1:four_legs.t"]
    with pytest.raises(SystemExit, match="--target"):
        open_for_edit(_edit_args(program="chair/173", target="chair/1"))
    with pytest.raises(SystemExit, match="not both"):
        open_for_edit(_edit_args(program="chair/173", sample=True))
