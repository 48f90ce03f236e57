"""The editor on hierarchical macro programs: corpus chairs refactored with the shipped chair library."""
import argparse

import pytest
import torch

from shapeprog import corpus, parse
from shapeprog.editor import EditSession, apply, controls
from shapeprog.errors import EditError
from shapeprog.execute import execute
from shapeprog.macros import hierarchy as H
from shapeprog.macros import load_library, refactor
from shapeprog.macros.execute import execute_hierarchy
from shapeprog.macros.objective import ABS_MAX_ERROR

LIB = load_library("chair")
CHAIRS = (173, 42220, 44017)


def _refactored(ident):
    return H.parse(refactor(parse(corpus.read("chair", ident)), LIB, category="chair", shape_id=ident).text,
                   f"chair/{ident}_macros.txt", LIB)


@pytest.fixture(scope="module")
def programs():
    return {i: _refactored(i) for i in CHAIRS}


def _leaf_distance(a, b) -> float:
    """Largest distance from a leaf of one shape to the nearest leaf of the other (max corner offset)."""
    d = (a[:, None] - b[None]).abs().amax((2, 3))
    return float(max(d.amin(1).max(), d.amin(0).max()))


@pytest.mark.parametrize("ident", CHAIRS)
def test_current_values_reproduce_the_base_program(programs, ident):
    h = programs[ident]
    cs = controls(h, LIB)
    assert len({c.name for c in cs}) == len(cs)
    same = apply(h, {c.name: c.value for c in cs}, LIB)
    assert same == h and H.to_text(same) == H.to_text(h)
    base = execute(parse(corpus.read("chair", ident)))
    got = execute_hierarchy(same, LIB)
    assert got.corners.shape == base.corners.shape
    assert _leaf_distance(got.corners, base.corners) <= ABS_MAX_ERROR


def test_fewer_controls_with_macros(programs):
    p = parse(corpus.read("chair", 173))
    assert (len(controls(programs[173], LIB, cuboids=False)), len(controls(p, cuboids=False))) == (15, 54)
    for i in CHAIRS:
        assert len(controls(programs[i], LIB, cuboids=False)) < len(controls(parse(corpus.read("chair", i)),
                                                                             cuboids=False))


def test_a_macro_parameter_moves_every_cuboid_it_makes(programs):
    h = programs[173]
    legs = h.programs[1].lines[1]
    assert len(legs.rets) == 2  # two legs, each reflected: four cuboids from one call
    name = f"Program_1:1:{legs.func}.x0"  # the legs' width
    c = {c.name: c for c in controls(h, LIB)}[name]
    before = execute_hierarchy(h, LIB)
    leaves = [k for k in range(before.corners.shape[0]) if int(before.node[k]) == 1]
    assert len(leaves) == 4 and c.cuboids == tuple(leaves)
    after = execute_hierarchy(apply(h, {name: c.value + 0.05}, LIB), LIB)
    moved = (after.corners - before.corners).abs().amax((1, 2)) > 1e-4
    assert moved.nonzero().flatten().tolist() == leaves
    assert torch.allclose(after.dims[leaves, 0], after.dims[leaves[0], 0])  # all legs equally wide


def test_edit_errors_name_the_control(programs):
    h = programs[173]
    name = next(c.name for c in controls(h, LIB, cuboids=False) if c.name.startswith("Program_1:"))
    with pytest.raises(EditError, match=f"control '{name}'") as e:
        apply(h, {name: -1.0}, LIB, "m.txt")
    assert e.value.line > H.block_line_offsets(h)[1]  # located in the sub-program's block
    # a sub-program's bbox dims are set by its parent's cuboid: no control of their own
    assert not any(c.name.startswith("Program_1:0:") for c in controls(h, LIB, cuboids=False))


def test_session_reads_the_refactor_file_and_expands(programs, tmp_path):
    text = H.to_text(programs[173])
    s = EditSession(text, "m.txt")  # no library: each block carries its definitions
    assert s.error is None and s.is_macro and s.text == text
    name = "Program_0:1:" + programs[173].programs[0].lines[1].func + ".x3"
    assert s.set({name: 0.25}) and s.undo() and s.text == text
    flat = EditSession(s.expanded_text(), "m.txt (expanded)")
    assert flat.error is None
    assert torch.allclose(flat.shape.corners, s.shape.corners, atol=1e-5)


def test_edit_command_refactors_a_corpus_program_with_a_shipped_library():
    from shapeprog.commands import open_for_edit

    args = argparse.Namespace(library="chair", sample=False, program="chair/173", target=None, seed=0)
    s, text, file = open_for_edit(args)
    assert s.error is None and file == "chair/173_macros.txt" and text.startswith("# chair/173/Program_0\n")
    assert len(s.controls(cuboids=False)) == 15
    with pytest.raises(SystemExit, match=r"sofa: neither a ShapeMOD library file nor a shipped ShapeMOD library "
                                         r"\(shipped: chair, storage, table\)"):
        open_for_edit(argparse.Namespace(library="sofa", sample=False, program="chair/173", target=None, seed=0))
