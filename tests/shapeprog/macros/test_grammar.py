"""The modified grammar: signatures, checks, attributes and the ShapeAssembly form."""
import pytest
import torch

from shapeprog.execute import execute
from shapeprog.lang import parse, to_text
from shapeprog.macros.grammar import (BBOX, BBOX_BOT, BBOX_TOP, AttachLine, CuboidLine, LineError, ReflectLine,
                                      SqueezeLine, TranslateLine, attributes, bbox_side, check_lines, cuboid_names,
                                      float_params, signature, squeeze_sides, to_shapeassembly)

BOX = CuboidLine(1.0, 1.0, 1.0, True)


def test_bbox_sides():
    assert bbox_side(0.5) == BBOX_TOP and bbox_side(0.49) == BBOX_BOT and bbox_side(1.0) == BBOX_TOP
    assert squeeze_sides(SqueezeLine(BBOX, BBOX, "top", 0.1, 0.9)) == (BBOX_TOP, BBOX_BOT)
    assert squeeze_sides(SqueezeLine(BBOX, BBOX, "bot", 0.1, 0.9)) == (BBOX_BOT, BBOX_TOP)
    assert squeeze_sides(SqueezeLine(BBOX, 0, "left", 0.9, 0.1)) == (BBOX_TOP, BBOX_TOP)  # u is y
    assert squeeze_sides(SqueezeLine(BBOX, 0, "back", 0.9, 0.1)) == (BBOX_BOT, BBOX_BOT)  # v is y


def test_signature_names_subjects_and_targets():
    lines = (BOX, CuboidLine(0.2, 0.2, 0.2, True), AttachLine(BBOX, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5),
             CuboidLine(0.2, 0.2, 0.2, False), AttachLine(0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5),
             AttachLine(BBOX, 0.5, 1.0, 0.5, 0.5, 0.9, 0.5), TranslateLine("X", 3, 0.5),
             CuboidLine(0.2, 0.2, 0.2, True), SqueezeLine(1, BBOX, "bot", 0.5, 0.5), ReflectLine("Z"))
    assert signature(lines) == (("att", 0, -2), ("att", 1, 0), ("att", 1, -1), ("trans", 1),
                                ("squeeze", 2, 1, -1), ("ref", 2))


def test_check_lines_names_the_line():
    ok = (BOX, CuboidLine(0.2, 0.2, 0.2, True), AttachLine(BBOX, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5))
    check_lines(ok)
    bad = [
        ((), 0, "must start with the bbox"),
        ((ReflectLine("X"),), 0, "must start with the bbox"),
        ((BOX, ReflectLine("X")), 1, "no subject"),
        (ok + (AttachLine(0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5),), 3, "its own subject"),
        (ok + (AttachLine(3, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5),), 3, "not declared"),
        (ok + (SqueezeLine(BBOX, BBOX, "up", 0.5, 0.5),), 3, "unknown face"),
        (ok + (ReflectLine("W"),), 3, "unknown axis"),
        (ok + (TranslateLine("X", 0, 0.5),), 3, "translate count"),
        (ok + (AttachLine(BBOX, float("nan"), 0.5, 0.5, 0.5, 0.5, 0.5),), 3, "non-finite"),
        (ok + ("attach",), 3, "not a line"),
    ]
    for lines, index, text in bad:
        with pytest.raises(LineError, match=text) as e:
            check_lines(lines)
        assert e.value.index == index


def test_shapeassembly_names_never_collide_with_copies():
    lines = (BOX, CuboidLine(0.2, 0.5, 0.2, True), AttachLine(BBOX, 0.5, 0.0, 0.5, 0.2, 0.0, 0.2),
             TranslateLine("X", 2, 0.5), CuboidLine(0.3, 0.3, 0.3, True), AttachLine(0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5),
             ReflectLine("X"), CuboidLine(0.1, 0.1, 0.1, True), AttachLine(1, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5))
    assert cuboid_names(lines) == ["cube0", "cube3", "cube5"]
    prog = to_shapeassembly(lines)
    text = to_text(prog)
    assert "attach(cube5, cube3, " in text and parse(text) == prog
    shape = execute(prog)
    assert len(shape) == 6  # 3 declared, 2 translate copies, 1 reflect copy
    assert shape.line.tolist() == [1, 3, 3, 4, 6, 7]  # statement index = line index
    # cube5 sits on cube3, which sits on cube0 (centre at x = z = 0.2 - 0.5)
    assert torch.allclose(shape.centers[5], torch.tensor([-0.3, -0.5 + 0.5 + 0.3 + 0.05, -0.3]), atol=1e-6)


def test_attributes_follow_the_reference_tuples():
    lines = (BOX, CuboidLine(0.123456, 0.2, 0.3, False), AttachLine(BBOX, 0.5, 0.0, 0.5, 0.5, 0.1, 0.5),
             TranslateLine("Y", 3, 0.45), CuboidLine(0.1, 0.1, 0.1, True), SqueezeLine(0, BBOX, "top", 0.25, 0.75),
             ReflectLine("X"))
    a = attributes(lines)
    assert a[1] == ("Cuboid", 0.1235, 0.2, 0.3, False)
    assert a[2] == ("attach", "bbox", 0.5, 0.0, 0.5, 0.5, 0.1, 0.5)
    assert a[3] == ("translate", "Y", 0.3, 0.45)
    assert a[5] == ("squeeze", "cube0", "bbox", "top", 0.25, 0.75) and a[6] == ("reflect", "X")
    assert attributes(lines, flip_bbox_y=True)[2][6] == 0.9
    assert float_params(lines)[:6] == [1.0, 1.0, 1.0, 0.1235, 0.2, 0.3]
    assert len(float_params(lines)) == 3 + 3 + 6 + 2 + 3 + 2
