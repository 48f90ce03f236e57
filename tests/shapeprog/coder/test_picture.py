"""Pictures of abstraction usages: the labelled corners are those of the executed primitives."""
import numpy as np
import pytest

from shapeprog.coder.execute import corners, execute
from shapeprog.coder.lang import Library, parse, parse_abstraction
from shapeprog.coder.picture import labelled_corners, usage_sheet


def test_labelled_corners_are_the_primitives_corners_and_the_sheet_renders(tmp_path):
    lib = Library().add(parse_abstraction("P(w: Float, x: Float) = SymRef(Move(Cuboid(w,0.5,w),x,0.0,0.0),AX)"))
    prog = parse("Union(P(0.1,-0.4),Rotate(Move(Cuboid(1.0,0.1,0.6),0.0,0.3,0.0),AY,0.4))", lib)
    got, labels = labelled_corners(prog, lib, "P")
    want = corners(execute(prog, lib, prec=6))
    key = lambda c: sorted(map(tuple, np.round(c, 4)))  # noqa: E731
    assert sorted(key(c) for c in got) == sorted(key(c) for c in want)
    assert labels.tolist() == [1, 1, 0]
    img = usage_sheet([prog, prog], lib, "P", tmp_path / "p.png", count=2, size=64)
    assert img.shape == (64, 128, 3) and (tmp_path / "p.png").stat().st_size > 0
    with pytest.raises(ValueError, match="no program calls"):
        usage_sheet([parse("Cuboid(1.0,1.0,1.0)")], lib, "P")
