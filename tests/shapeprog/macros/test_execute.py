"""Executing macro programs: equal to their expansions, batched as single, gradients as finite differences."""
import random

import pytest
import torch

from shapeprog import corpus
from shapeprog.execute import execute as execute_sa
from shapeprog.execute import execute_batch as execute_batch_sa
from shapeprog.lang import numbers
from shapeprog.lang import parse as parse_sa
from shapeprog.macros.data import convert_program
from shapeprog.macros.execute import MacroPlan, compile_program, execute, execute_batch, program_parameters
from shapeprog.macros.grammar import AttachLine, CuboidLine, ReflectLine, SqueezeLine, to_shapeassembly
from shapeprog.macros.lang import Call, Linear, Literal, MacroProgram, Name, from_lines
from shapeprog.macros.library import Library

F6 = "x1: float, y1: float, z1: float, x2: float, y2: float, z2: float"
BOX = "l: float, h: float, w: float, al: bool"
# general PBlock macros: every value a parameter, nested twice
PBLOCKS = Library.from_text(f"""def pa({BOX}, t: cube, {F6}):
    c = Cuboid(l, h, w, al)
    attach(t, x1, y1, z1, x2, y2, z2)

def pa2({BOX}, t: cube, {F6}, u: cube, p1: float, p2: float, p3: float, p4: float, p5: float, p6: float):
    c = pa(l, h, w, al, t, x1, y1, z1, x2, y2, z2)
    attach(u, p1, p2, p3, p4, p5, p6)

def ps({BOX}, t1: cube, t2: cube, f: face, u: float, v: float):
    c = Cuboid(l, h, w, al)
    squeeze(t1, t2, f, u, v)

def psr({BOX}, t1: cube, t2: cube, f: face, u: float, v: float, a: axis):
    c = ps(l, h, w, al, t1, t2, f, u, v)
    reflect(a)
""")


def _rewrite(lines) -> MacroProgram:
    """An ordering's lines as calls of the PBLOCKS macros (reflect/translate after pa/pa2 stay base calls)."""
    c = Linear.const
    ref = lambda t: Name("bbox" if t < 0 else f"cube{t}")  # noqa: E731
    out = [Call("Cuboid", (c(lines[0].l), c(lines[0].h), c(lines[0].w), Literal(True)), ("bbox",))]
    i, k = 1, 0
    while i < len(lines):
        cub = lines[i]
        box = (c(cub.l), c(cub.h), c(cub.w), Literal(cub.aligned))
        moves = []
        i += 1
        while i < len(lines) and type(lines[i]) in (AttachLine, SqueezeLine):
            moves.append(lines[i])
            i += 1
        sym = lines[i] if i < len(lines) and type(lines[i]) is not CuboidLine else None
        name = (f"cube{k}",)
        k += 1
        if type(moves[0]) is SqueezeLine:
            s = moves[0]
            args = box + (ref(s.t1), ref(s.t2), Literal(s.face), c(s.u), c(s.v))
            if type(sym) is ReflectLine:
                out.append(Call("psr", args + (Literal(sym.axis),), name))
                i += 1
                continue
            out.append(Call("ps", args, name))
        else:
            att = lambda a: (ref(a.target),) + tuple(c(getattr(a, f)) for f in ("x1", "y1", "z1", "x2", "y2", "z2"))  # noqa
            out.append(Call("pa" if len(moves) == 1 else "pa2", box + sum((att(a) for a in moves), ()), name))
        if sym is not None:
            out.append(from_lines((lines[0], lines[1], sym)).lines[2])
            i += 1
    return MacroProgram((), tuple(out))


def test_macro_programs_execute_as_their_base_lines_over_corpus_orderings():
    rng = random.Random(1)
    progs, plain = [], []
    for cat in corpus.CATEGORIES:
        for i in rng.sample(corpus.ids(cat, "all"), 8):
            for sub in convert_program(parse_sa(corpus.read(cat, i)), cat, i).subprograms:
                for o in (sub.orders[0], sub.orders[-1]):
                    lines = sub.lines(o)
                    mp = _rewrite(lines)
                    assert PBLOCKS.inline(mp) == from_lines(lines)  # same names, numbers and order
                    assert PBLOCKS.expand(mp).lines == lines
                    progs.append(mp)
                    plain.append(to_shapeassembly(lines))
    assert len(progs) > 40 and {c.func for p in progs for c in p.lines} >= {"pa", "pa2", "ps", "psr", "reflect"}
    got = execute_batch(progs, PBLOCKS)
    want = execute_batch_sa(plain)
    for g, w in zip(got, want):
        assert torch.equal(g.corners, w.corners) and torch.equal(g.line, w.line)


CHAIR = """def post(h: float, x: float, z: float):
    c = Cuboid(0.08, h, 0.1, False)
    attach(bbox, 0.5, 0.0, 0.5, x, 0.0, z)
    attach(bbox, 0.5, 1.0, 0.5, x + 0.15, 0.9, 0.5 * z + 0.1)

def pair(h: float, x: float, z: float):
    p = post(h, x, z)
    reflect(X)

def shelf(s: float, t: cube, d: float):
    c = Cuboid(bb_x - 0.3, s, 0.5 * bb_z + 0.1 * d, False)
    squeeze(bbox, t, top, 0.5, 0.3 + d)
    translate(Z, 2.0, d)

bbox = Cuboid(1.0, 1.2, 0.8, True)
legs = pair(0.9, 0.2, 0.3)
board = shelf(0.05, legs, 0.3)
top = Cuboid(0.9, 0.1, 0.7, False)
attach(board, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)
"""


def test_macro_program_equals_its_inlined_text():
    lib = Library()
    p = lib.parse(CHAIR)
    inl = lib.with_program(p).inline(p)
    a, b = execute(p), execute(inl)
    assert len(a) == 6 and torch.equal(a.corners, b.corners)
    # its first line written by hand in ShapeAssembly
    sa = parse_sa("bbox = Cuboid(1.0, 1.2, 0.8, True)\ncube0 = Cuboid(0.08, 0.9, 0.1, False)\n"
                  "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.2, 0.0, 0.3)\n"
                  "attach(cube0, bbox, 0.5, 1.0, 0.5, 0.35, 0.9, 0.25)\nreflect(cube0, X)\n")
    assert torch.equal(execute_sa(sa).corners, a.corners[:2])
    # ExecutedShape.line indexes the expansion; its source maps back to program lines
    comp = compile_program(p)
    assert [comp.expansion.source[ln] for ln in a.line.tolist()] == [1, 1, 2, 2, 2, 3]


def test_batch_equals_single_and_plans_are_reusable():
    lib = Library()
    p = lib.parse(CHAIR)
    q = lib.parse(CHAIR.replace("pair(0.9, 0.2, 0.3)", "pair(0.7, 0.25, 0.2)"))
    both = execute_batch([p, q])
    assert torch.equal(both[0].corners, execute(p).corners) and torch.equal(both[1].corners, execute(q).corners)
    plan = MacroPlan([p, q])
    x = program_parameters(q)
    again = plan.run([None, x])
    assert torch.equal(again[1].corners, both[1].corners) and len(plan) == 2
    with pytest.raises(ValueError, match="shape"):
        plan.run([None, x[:-1]])
    with pytest.raises(TypeError):
        MacroPlan(p)
    assert execute_batch([]) == []


def test_gradients_match_finite_differences():
    lib = Library()
    p = lib.parse(CHAIR)
    x0 = program_parameters(p, torch.float64)
    comp = compile_program(p)
    assert comp.matrix.shape == (len(numbers(comp.program)), len(x0))
    weights = torch.randn(6, 8, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))

    def f(x):
        return (execute(p, lib, params=x, dtype=torch.float64).corners * weights).sum()

    x = x0.clone().requires_grad_(True)
    f(x).backward()
    grad = x.grad
    eps = 1e-6
    fd = torch.zeros_like(x0)
    for i in range(len(x0)):
        e = torch.zeros_like(x0)
        e[i] = eps
        with torch.no_grad():
            fd[i] = (f(x0 + e) - f(x0 - e)) / (2 * eps)
    assert torch.allclose(grad, fd, rtol=1e-4, atol=1e-6), (grad - fd).abs().max()
    # the macros' free parameters (pair's h, x, z at 3-5; shelf's s, d at 6, 7) all get gradients
    assert (grad[3:8] != 0).all()
    assert torch.autograd.gradcheck(lambda v: execute(p, lib, params=v, dtype=torch.float64).corners,
                                    (x0.clone().requires_grad_(True),), eps=1e-6, atol=1e-5, fast_mode=True)


def test_translate_count_is_structure():
    lib = Library()
    p = lib.parse(CHAIR.replace("translate(Z, 2.0, d)", "translate(Z, n, d)").replace("shelf(s: float, t: cube, d: float)",
                  "shelf(s: float, t: cube, d: float, n: float)").replace("shelf(0.05, legs, 0.3)",
                                                                           "shelf(0.05, legs, 0.3, 3.0)"))
    x = program_parameters(p).requires_grad_(True)
    shape = execute(p, params=x)
    assert len(shape) == 7  # 2 posts, the shelf and 3 copies, the top
    shape.corners.sum().backward()
    n_index = 3 + 3 + 1 + 1  # bbox, pair, shelf's s and d, then n
    assert x.grad[n_index] == 0
