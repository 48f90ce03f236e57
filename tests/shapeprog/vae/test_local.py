"""The incremental single-block executor of the validity decoder agrees with shapeprog.execute."""
import dataclasses
import random

import pytest
import torch

import shapeprog
from shapeprog import corpus
from shapeprog.lang import Attach, Block, Cuboid, Program, Squeeze
from shapeprog.vae.local import LocalProgram, run_block


def flat(block: Block) -> Program:
    """``block`` as a flat program: its ``Program_<m>`` parts renamed to their slot names ``cube<k>``."""
    names, k = {}, 0
    for s in block.statements:
        if isinstance(s, Cuboid) and s.name != "bbox":
            names[s.name] = f"cube{k}"
            k += 1
    r = lambda n: names.get(n, n)  # noqa: E731
    out = []
    for s in block.statements:
        if isinstance(s, Cuboid):
            s = dataclasses.replace(s, name=r(s.name))
        elif isinstance(s, Attach):
            s = dataclasses.replace(s, a=r(s.a), b=r(s.b))
        elif isinstance(s, Squeeze):
            s = dataclasses.replace(s, a=r(s.a), b=r(s.b), c=r(s.c))
        else:
            s = dataclasses.replace(s, a=r(s.a))
        out.append(s)
    return Program((Block("Program_0", tuple(out)),), flat=True)


def assert_same_as_executor(block: Block, tol: float = 1e-9) -> None:
    prog = flat(block)
    ref = shapeprog.execute(prog, dtype=torch.float64).corners
    mine = torch.tensor([b.corners() for b in run_block(prog.root).boxes[1:]], dtype=torch.float64)
    assert mine.shape == ref.shape
    if len(ref):
        assert (mine - ref).abs().max().item() < tol, shapeprog.to_text(prog)


def test_corpus_blocks_execute_as_the_executor_does():
    names = [(c, i) for c in corpus.CATEGORIES for i in corpus.ids(c, "all")]
    for c, i in random.Random(1).sample(names, 40):
        for block in shapeprog.parse(corpus.read(c, i), f"{c}/{i}.txt").blocks:
            assert_same_as_executor(block)


GENERAL = """bbox = Cuboid(1.0, 1.0, 1.0, True)
cube0 = Cuboid(0.2, 0.2, 0.2, True)
cube1 = Cuboid(0.3, 0.1, 0.2, True)
cube2 = Cuboid(0.1, 0.5, 0.1, False)
cube3 = Cuboid(0.1, 0.4, 0.3, False)
attach(cube0, bbox, 0.5, 0.0, 0.5, 0.2, 0.0, 0.2)
attach(cube1, bbox, 0.5, 1.0, 0.5, 0.7, 1.0, 0.6)
attach(cube2, bbox, 0.5, 0.0, 0.5, 0.4, 0.0, 0.4)
attach(cube2, cube0, 0.5, 1.0, 0.5, 0.5, 0.0, 0.5)
attach(cube2, cube1, 0.5, 0.5, 0.5, 0.5, 0.5, 0.9)
attach(cube3, cube0, 0.0, 0.5, 0.5, 1.0, 0.5, 0.5)
attach(cube3, cube1, 1.0, 0.5, 0.5, 0.0, 0.2, 0.5)
attach(cube3, bbox, 0.5, 0.0, 0.5, 0.8, 0.0, 0.1)
squeeze(cube0, bbox, cube1, top, 0.3, 0.6)
reflect(cube2, X)
translate(cube3, Z, 3, 0.4)
reflect(cube1, Y)
"""


def test_every_attach_rule_and_macro_matches_the_executor():
    """Second, general (three records, rotated targets), aligned growth and the macros."""
    assert_same_as_executor(shapeprog.parse(GENERAL).root)


def test_copies_are_independent_and_inside_tests_the_given_slots():
    p = LocalProgram((1.0, 2.0, 1.0))
    a = p.add_cuboid((0.2, 0.2, 0.2), aligned=True)
    q = p.copy()
    q.attach(a, 0, (0.5, 0.5, 0.5), (1.0, 0.5, 0.5))  # centre on the right face: half outside
    assert p.boxes[a].pos == (0.0, 0.0, 0.0) and q.boxes[a].pos[0] == pytest.approx(0.5)
    assert q.inside([a], margin=1.5) and not q.inside([a], margin=1.1)
    assert len(p.boxes[0].records) == 0 and len(q.boxes[0].records) == 1
