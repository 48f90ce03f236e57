"""Line vectors: the layout, the clamps, the slot renaming, the corpus round trip and located errors."""
import random
import warnings

import pytest
import torch

from shapeprog import corpus
from shapeprog.errors import ParseError
from shapeprog.execute import execute_batch
from shapeprog.lang import Attach, Block, Cuboid, Program, parse, to_text
from shapeprog.vae.vectors import (ALIGNED, ATTACH, AXIS, COUNT, CUBE1, CUBE2, CUBE3, DIMS, DIST, FACE, UV,
                                   VectorNode, l1_mask, program_to_tree, tree_to_program)

def _onehot(row, part):
    return row[part].nonzero().flatten().tolist()


def test_layout_of_every_statement_in_code_order(two_levels):
    tree = program_to_tree(parse(two_levels), dtype=torch.float64)
    x = tree.lines
    assert x.shape == (6, 63) and x.dtype == torch.float64
    assert x[:, :7].argmax(1).tolist() == [1, 1, 1, 2, 5, 3]  # Cuboid, attach, squeeze=5, reflect=3
    assert x[0, DIMS].tolist() == [1.2, 1.0, 0.8] and x[0, ALIGNED] == 1 and x[1, ALIGNED] == 0
    # Program_1 is the first non-bbox Cuboid line: slot 1 (cube0) in every reference
    assert _onehot(x[3], CUBE1) == [1] and _onehot(x[3], CUBE2) == [0]
    assert x[3, ATTACH].tolist() == [0.5, 0.0, 0.5, 0.2, 0.0, 0.5]
    assert (_onehot(x[4], CUBE1), _onehot(x[4], CUBE2), _onehot(x[4], CUBE3)) == ([2], [0], [1])
    assert _onehot(x[4], FACE) == [2] and x[4, UV].tolist() == [0.5, 0.25]  # top
    assert _onehot(x[5], CUBE1) == [1] and _onehot(x[5], AXIS) == [0]  # X
    child = tree.children[1]
    assert tree.children[0] is None and tree.children[2] is None and isinstance(child, VectorNode)
    assert child.name == "Program_1" and child.lines[3, :7].argmax() == 4  # translate
    assert _onehot(child.lines[3], AXIS) == [2] and child.lines[3, COUNT] == 2 and child.lines[3, DIST] == 0.8
    assert [d for _, d in tree.nodes()] == [0, 1] and tree.bbox_dims.tolist() == [1.2, 1.0, 0.8]
    assert tree.cuboid_rows.tolist() == [0, 1, 2]
    # only the rows' own nonzero entries are set
    # Cuboid 5 (4 when not aligned), attach 1 + 2 + 4 nonzero coordinates, squeeze 1 + 3 + 1 + 2, reflect 3
    assert int((x != 0).sum()) == 5 + 4 + 5 + 7 + 7 + 3


def test_sequences_and_l1_mask(two_levels):
    tree = program_to_tree(parse(two_levels)).children[1]
    inp, tar = tree.input_seq(), tree.target_seq()
    assert inp.shape == tar.shape == (5, 63)
    assert inp[0, :7].argmax() == 0 and torch.equal(inp[1:], tree.lines)
    assert tar[-1, :7].argmax() == 6 and torch.equal(tar[:-1], tree.lines)
    m = l1_mask(tar)
    assert [m[i].nonzero().flatten().tolist() for i in range(5)] == [
        [40, 41, 42], [40, 41, 42], list(range(43, 49)), [52, 53], []]


def test_clamps():
    p = Program((Block("Program_0", (
        Cuboid("bbox", 1.0, 1.0, 1.0, True), Cuboid("cube0", 0.001, -2.0, 0.5, True),
        Attach("cube0", "bbox", -0.5, 1.5, 0.5, 0.5, 2.0, -1.0))),), flat=True)
    x = program_to_tree(p).lines
    assert x[1, DIMS].tolist() == pytest.approx([0.01, 0.01, 0.5])
    assert x[2, ATTACH].tolist() == [0.0, 1.0, 0.5, 0.5, 1.0, 0.0]
    text = to_text(tree_to_program(program_to_tree(p), decimals=3))
    assert "cube0 = Cuboid(0.01, 0.01, 0.5, True)" in text
    assert "attach(cube0, bbox, 0.0, 1.0, 0.5, 0.5, 1.0, 0.0)" in text


def test_tree_to_program_names_slots_and_numbers_blocks_breadth_first(two_levels):
    tree = program_to_tree(parse(two_levels))
    assert to_text(tree_to_program(tree, decimals=3)) == two_levels
    # logits work as well as one-hots: scale and shift every row
    noisy = VectorNode(tree.lines * 3 - 1, tree.children, tree.name)
    text = to_text(tree_to_program(noisy, decimals=3))
    assert "squeeze(cube1, bbox, Program_1, top," in text and "reflect(Program_1, X)" in text
    # a stop row ends a node; predictions after it are ignored
    stop = torch.zeros(1, 63)
    stop[0, 6] = 1
    leaf = tree.children[1]
    cut = VectorNode(torch.cat([leaf.lines[:3], stop, leaf.lines[3:]]), (), "x")
    assert [type(s).__name__ for s in tree_to_program(cut).root.statements] == ["Cuboid", "Cuboid", "Attach"]


def test_flat_example_program():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the example's stray comma
        p = parse(corpus.example_text())
    back = tree_to_program(program_to_tree(p), decimals=3)
    assert back.root.statements == p.root.statements


def _sample(n, seed=0):
    names = [(c, i) for c in corpus.CATEGORIES for i in corpus.ids(c, "all")]
    return random.Random(seed).sample(names, n)


def test_corpus_round_trip_sample():
    """300 seeded corpus programs (the whole corpus: ``bench/bench_vae_vectors.py``)."""
    names = _sample(300)
    texts = [corpus.read(c, i) for c, i in names]
    progs = [parse(t, f"{c}/{i}.txt") for t, (c, i) in zip(texts, names)]
    trees32 = [program_to_tree(p) for p in progs]
    # float32 vectors rounded to the corpus's 3 decimals, and float64 vectors as they are: the same text
    assert [to_text(tree_to_program(t, decimals=3)) for t in trees32] == texts
    assert [to_text(tree_to_program(program_to_tree(p, dtype=torch.float64))) for p in progs] == texts
    # float32 vectors as they are: text -> parse -> execute gives the same cuboids
    back = [parse(to_text(tree_to_program(t))) for t in trees32]
    for a, b in zip(execute_batch(progs), execute_batch(back)):
        assert a.corners.shape == b.corners.shape
        assert torch.allclose(a.corners, b.corners, atol=1e-4, rtol=0)


def test_to_moves_every_tensor(two_levels):
    tree = program_to_tree(parse(two_levels)).to(dtype=torch.float64)
    assert {n.lines.dtype for n, _ in tree.nodes()} == {torch.float64}


# ------------------------------------------------------------------------ errors


def test_more_than_ten_cuboid_lines_is_a_located_error():
    cubes = "".join(f"\tcube{k} = Cuboid(0.1, 0.1, 0.1, True)\n" for k in range(10))
    text = "Assembly Program_0 {\n\tbbox = Cuboid(1.0, 1.0, 1.0, True)\n" + cubes + "}\n"
    with pytest.raises(ParseError, match=r"^big\.txt:12:2: more than 10 Cuboid lines in block Program_0") as e:
        program_to_tree(parse(text), file="big.txt")
    assert e.value.token == "cube9"


def test_slot_beyond_the_vector_is_a_located_error():
    cubes = "".join(f"cube{k} = Cuboid(0.1, 0.1, 0.1, True)\n" for k in range(9))
    atts = "".join(f"attach(cube{k}, bbox, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)\n" for k in range(9))
    # the reflect creates cube9 (slot 10, fine), the next one cube10 (slot 11: no room)
    text = ("bbox = Cuboid(1.0, 1.0, 1.0, True)\n" + cubes + atts + "reflect(cube0, X)\nreflect(cube1, X)\n"
            "attach(cube10, bbox, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)\n")
    p = parse(text)
    with pytest.raises(ParseError, match=r"^p\.txt:22:8: cuboid 'cube10' is slot 11 of block Program_0; the line "
                       r"vector has 11 slots"):
        program_to_tree(p, file="p.txt")
    assert program_to_tree(parse(text.replace("cube10", "cube9"))).lines[-1, CUBE1].argmax() == 10


def test_unknown_cuboid_and_duplicate_declaration_are_located_errors():
    p = Program((Block("Program_0", (Cuboid("bbox", 1, 1, 1, True), Attach("cube3", "bbox", 0, 0, 0, 0, 0, 0))),))
    with pytest.raises(ParseError, match=r"^q\.txt:3:9: unknown cuboid 'cube3' in block Program_0"):
        program_to_tree(p, file="q.txt")
    p = Program((Block("Program_0", (Cuboid("bbox", 1, 1, 1, True), Cuboid("bbox", 1, 1, 1, True))),))
    with pytest.raises(ParseError, match=r":3:2: cuboid 'bbox' is declared twice"):
        program_to_tree(p)


def test_tree_to_program_rejects_bad_trees(two_levels):
    with pytest.raises(ValueError, match=r"root: lines must be \(L, 63\) with L >= 1, got \(2, 62\)"):
        tree_to_program(VectorNode(torch.zeros(2, 62), ()))
    tree = program_to_tree(parse(two_levels))
    bad = tree.children[1].lines.clone()
    bad[0, :7] = 0
    bad[0, 2] = 1
    with pytest.raises(ValueError, match=r"root.children\[1\]: row 0 is a attach line"):
        tree_to_program(VectorNode(tree.lines, (None, VectorNode(bad, ()), None)))
    bad = tree.lines.clone()
    bad[1, :7] = 0
    bad[1, 0] = 1
    with pytest.raises(ValueError, match=r"root: row 1 is a start command"):
        tree_to_program(VectorNode(bad, ()))
