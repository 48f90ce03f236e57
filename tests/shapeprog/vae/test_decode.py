"""Decoding with semantic validity: masks, every rule, the network step, fuzzing, and the entry points."""
import importlib
import random

import numpy as np
import pytest
import torch

import shapeprog
from shapeprog import corpus, limits
from shapeprog.errors import ParseError
from shapeprog.lang import round_numbers
from shapeprog.vae import VAE, Decoded, Decoder, InvalidSample, decode, decode_latent, encode, interpolate, sample
from shapeprog.vae.decode import decode_programs
from shapeprog.vae.decode import _Budget, _decode_tree, _decode_with, _program, _propose
from shapeprog.vae.step import _Net
from shapeprog.vae.replay import Replay
from shapeprog.vae.validity import ATTACH_CMD as ATTACH
from shapeprog.vae.validity import CUBOID, REFLECT, SQUEEZE, START, STOP, TRANSLATE
from shapeprog.vae.validity import (ATTACH_MODE, CUBOID_MODE, FORBIDDEN, START_MODE, SYM_MODE, DecodeOptions, Line,
                                    NodeState, allowed_commands, choose_attach, choose_reflect, choose_reflect_axis,
                                    choose_squeeze, choose_squeeze_face, choose_translate, clean_attach, clean_cuboid,
                                    clean_translate, line_vector, remove_ungrounded, try_line)
from shapeprog.vae.local import run_block
from shapeprog.vae.vectors import CUBES, LINE_DIM, NUM_SLOTS, program_to_tree

from .test_local import flat


# ----------------------------------------------------------------------------- hand-built states


def state_with(*cubes, bbox=(1.0, 1.0, 1.0)) -> NodeState:
    """A node after its bbox line and Cuboid lines of the given dims (aligned, at the origin)."""
    st = NodeState(bbox)
    st.accept(Line(CUBOID, nums=bbox, aligned=True))
    for d in cubes:
        st.accept(Line(CUBOID, nums=d, aligned=True))
    return st


def run(st: NodeState, line: Line, margin: float = 1.5) -> NodeState:
    """Accept ``line`` after executing it (as the decoder does)."""
    st.accept(line, try_line(st, line, margin))
    return st


def attach(a, b, x1=0.5, y1=0.0, z1=0.5, x2=0.5, y2=0.0, z2=0.5) -> Line:
    return Line(ATTACH, (a, b), (x1, y1, z1, x2, y2, z2))


def logits(n, favour=(), low=()):
    """n logits: 5 at ``favour`` (in order of decreasing preference), -5 at ``low``, else 0."""
    x = [0.0] * n
    for k, i in enumerate(favour):
        x[i] = 5.0 - 0.1 * k
    for i in low:
        x[i] = -5.0
    return x


def cube_logits(c1=(), c2=(), c3=()):
    return logits(NUM_SLOTS, c1) + logits(NUM_SLOTS, c2) + logits(NUM_SLOTS, c3)


# ----------------------------------------------------------------------------- masks


def test_the_masks_of_each_mode():
    st = NodeState((1.0, 1.0, 1.0))
    assert allowed_commands(st) == list(range(7))
    for mode, forbidden in ((CUBOID_MODE, {START, REFLECT, TRANSLATE}), (ATTACH_MODE, {START, CUBOID}),
                            (SYM_MODE, {START, CUBOID, ATTACH, SQUEEZE})):
        st.mode = mode
        assert set(allowed_commands(st)) == set(range(7)) - forbidden
    st = state_with(*[(0.1, 0.1, 0.1)] * 9)  # 10 Cuboid lines: the vector's limit
    assert CUBOID not in allowed_commands(st) and ATTACH in allowed_commands(st)


def forced_decoder(favoured, H=16):
    """A decoder whose command head ignores its input and ranks ``favoured`` first (by far)."""
    torch.manual_seed(0)
    dec = Decoder(H)
    with torch.no_grad():
        dec.cmd_net.l3.weight.zero_()
        dec.cmd_net.l3.bias.copy_(torch.tensor([100.0 if c in favoured else 0.0 for c in range(7)]))
    return dec


def states_by_mode():
    st = state_with((0.2, 0.2, 0.2), (0.2, 0.3, 0.2))
    yield START_MODE, NodeState((1.0, 1.0, 1.0))
    yield CUBOID_MODE, state_with((0.2, 0.2, 0.2), (0.2, 0.3, 0.2))
    run(st, attach(1, 0, x2=0.2, z2=0.2))
    yield ATTACH_MODE, st
    st = run(state_with((0.2, 0.2, 0.2)), attach(1, 0, x2=0.2, z2=0.2))
    run(st, Line(REFLECT, (1,), axis=0))
    yield SYM_MODE, st


@pytest.mark.parametrize("mode, state", list(states_by_mode()), ids=lambda x: x if isinstance(x, str) else "")
def test_a_decoder_step_never_emits_a_forbidden_command(mode, state):
    assert state.mode == mode
    favoured = FORBIDDEN[mode] or (START, STOP, ATTACH)
    net = _Net(forced_decoder(favoured))
    ctx = net.begin(np.zeros(16, np.float32), state.bbox_dims, 0)
    h = net.step(line_vector(Line(START)), np.zeros(16, np.float32), ctx)
    vec = [0.0] * LINE_DIM
    try:
        _propose(net, h, ctx, state, DecodeOptions(), _Budget(), vec, 1)
    except InvalidSample:
        pass
    emitted = int(np.argmax(vec[:7]))
    assert emitted not in FORBIDDEN[mode]
    if mode == START_MODE:  # nothing is forbidden: the favoured command comes out
        assert emitted == START


def test_the_cuboid_limit_is_a_mask_too():
    st = state_with(*[(0.1, 0.1, 0.1)] * 9)
    net = _Net(forced_decoder((CUBOID,)))
    ctx = net.begin(np.zeros(16, np.float32), st.bbox_dims, 0)
    vec = [0.0] * LINE_DIM
    try:
        _propose(net, np.zeros(16, np.float32), ctx, st, DecodeOptions(), _Budget(), vec, 1)
    except InvalidSample:
        pass
    assert vec[CUBOID] == 0.0 and sum(vec[:7]) == 1.0


# ----------------------------------------------------------------------------- the rules


def test_cuboid_dims_clamp_to_the_node_bbox_and_aligned_is_the_logit_sign():
    assert clean_cuboid([-1.0, 0.5, 3.0], 0.1, (1.0, 1.0, 2.0)) == ((0.01, 0.5, 2.0), True)
    assert clean_cuboid([0.2, 0.2, 0.2], 0.0, (1.0, 1.0, 1.0))[1] is False


def test_attach_never_moves_bbox_or_an_undeclared_cuboid_and_targets_only_grounded_ones():
    st = state_with((0.2, 0.2, 0.2), (0.2, 0.2, 0.2))  # slots 0 (bbox), 1, 2; nothing grounded but bbox
    # cube-1 favours bbox, then undeclared slot 5, then slot 2; cube-2 favours ungrounded slot 1
    assert choose_attach(cube_logits(c1=(0, 5, 2), c2=(1, 0)), st) == (2, 0)
    run(st, attach(2, 0, x2=0.3, z2=0.3))
    assert choose_attach(cube_logits(c1=(1,), c2=(1, 2)), st) == (1, 2)  # slot 2 is grounded now


def test_attach_with_no_declared_cuboid_is_invalid():
    with pytest.raises(InvalidSample, match="no declared cuboid"):
        choose_attach(cube_logits(c1=(1,), c2=(0,)), state_with())


def cube_slots(c1: dict, c2: dict = None, c3: dict = None):
    """33 cube logits: {slot: logit} per group, 0 elsewhere."""
    out = []
    for group in (c1, c2 or {}, c3 or {}):
        out += [group.get(i, 0.0) for i in range(NUM_SLOTS)]
    return out


def test_self_attach_knocks_down_the_lower_logit():
    st = run(state_with((0.2, 0.2, 0.2), (0.2, 0.2, 0.2)), attach(1, 0, x2=0.3, z2=0.3))
    # (1, 1): cube-2's logit is higher, so cube-1 gives way and moves on to slot 2
    assert choose_attach(cube_slots({1: 5.0, 2: 4.0}, {1: 6.0, 0: 3.0}), st) == (2, 1)
    # (1, 1): cube-1's logit is higher (or equal), so cube-2 gives way to bbox
    assert choose_attach(cube_slots({1: 5.0, 2: 4.0}, {1: 5.0, 0: 3.0}), st) == (1, 0)


def test_a_pair_is_attached_once_and_bbox_at_most_twice():
    st = state_with((0.2, 0.2, 0.2), (0.2, 0.2, 0.2))
    run(st, attach(1, 0, x2=0.3, z2=0.3))
    run(st, attach(2, 1, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5))
    # 1 -- 2 is attached (either way round): attaching them again is knocked down
    assert choose_attach(cube_slots({1: 5.0}, {2: 5.0, 0: 4.0}), st) == (1, 0)
    assert choose_attach(cube_slots({2: 5.0}, {1: 5.0, 0: 4.0}), st) == (2, 0)
    run(st, attach(1, 0, 0.5, 1.0, 0.5, 0.3, 1.0, 0.3))  # 1 is now on bbox twice
    assert choose_attach(cube_slots({1: 5.0, 2: 4.0}, {0: 6.0}), st) == (2, 0)  # 1 (lower) gives way
    # the lower logit is knocked down, not the pair searched: cube-1 = 1 outranks every cube-2, whose
    # candidates (bbox, 1, 2) all go, although (2, bbox) would have been allowed
    with pytest.raises(InvalidSample, match="no grounded cuboid"):
        choose_attach(cube_slots({1: 5.0, 2: 4.0}, {0: 4.0}), st)
    one = state_with((0.2, 0.2, 0.2))
    run(one, attach(1, 0, x2=0.3, z2=0.3))
    run(one, attach(1, 0, 0.5, 1.0, 0.5, 0.3, 1.0, 0.3))
    with pytest.raises(InvalidSample, match="no grounded cuboid"):  # neither bbox (twice) nor itself
        choose_attach(cube_slots({1: 5.0}, {0: 5.0}), one)


@pytest.mark.parametrize("y2, expected", [(0.0, 0.0), (0.05, 0.05), (0.1, 0.1), (0.1001, 0.1), (0.3, 0.1),
                                          (0.5, 0.1), (0.5001, 0.9), (0.7, 0.9), (0.8999, 0.9), (0.9, 0.9),
                                          (0.97, 0.97), (1.2, 1.0), (-0.3, 0.0)])
def test_attach_heights_on_bbox_snap(y2, expected):
    assert clean_attach([0.5, 0.0, 0.5, 0.5, y2, 0.5], 0)[4] == expected
    assert clean_attach([0.5, 0.0, 0.5, 0.5, y2, 0.5], 1)[4] == min(max(y2, 0.0), 1.0)  # not on bbox: kept


def test_attach_heights_on_bbox_with_the_paper_tolerance():
    assert clean_attach([0.5, 0.0, 0.5, 0.5, 0.04, 0.5], 0, "tolerance")[4] == 0.04
    assert clean_attach([0.5, 0.0, 0.5, 0.5, 0.96, 0.5], 0, "tolerance")[4] == 0.96
    with pytest.raises(InvalidSample, match="neither its bottom nor its top"):
        clean_attach([0.5, 0.0, 0.5, 0.5, 0.3, 0.5], 0, "tolerance")
    assert clean_attach([-1, 2, 0.5, 0.5, 0.3, 0.5], 3, "tolerance") == (0.0, 1.0, 0.5, 0.5, 0.3, 0.5)


def reflect_state():
    """Slot 1 on the negative side (x, z < 0), slot 2 on the positive side of every axis, slot 3 ungrounded."""
    st = state_with((0.2, 0.2, 0.2), (0.2, 0.2, 0.2), (0.2, 0.2, 0.2))
    run(st, attach(1, 0, x2=0.2, z2=0.2))
    run(st, attach(2, 0, 0.5, 0.0, 0.5, 0.8, 0.9, 0.8))
    assert all(x > 0 for x in st.program.boxes[2].pos) and st.program.boxes[1].pos[0] < 0
    return st


def test_reflect_refuses_a_cuboid_on_the_positive_side_bbox_and_ungrounded_ones():
    st = reflect_state()
    assert choose_reflect(cube_logits(c1=(0, 2, 3, 1)), st) == 1
    with pytest.raises(InvalidSample, match="negative side"):
        choose_reflect(cube_logits(c1=(2,)), NodeState((1.0,) * 3, st.program, {0, 2}, st.atts, ATTACH_MODE, 4))


def test_the_reflect_axis_is_one_where_the_centre_is_not_positive():
    st = reflect_state()
    pos = st.program.boxes[1].pos  # x < 0, y < 0 (on the floor), z < 0
    assert choose_reflect_axis(logits(3, (0,)), 1, st) == 0
    st.program.boxes[1] = st.program.boxes[1].replace(pos=(-0.3, 0.2, 0.4))
    assert choose_reflect_axis(logits(3, (2, 1, 0)), 1, st) == 0  # z and y are positive
    st.program.boxes[1] = st.program.boxes[1].replace(pos=pos)


def test_translate_takes_a_grounded_cuboid_and_rounds_its_count():
    st = reflect_state()
    assert choose_translate(cube_logits(c1=(0, 3, 2)), st) == 2
    with pytest.raises(InvalidSample):
        choose_translate(cube_logits(c1=(1,)), state_with((0.1, 0.1, 0.1)))
    assert clean_translate(2.4, 0.5) == (2, 0.5)
    assert clean_translate(2.5, 1.7) == (2, 1.0)  # Python's round (half to even), as the reference
    assert clean_translate(3.5, -0.2) == (4, 0.0)
    assert clean_translate(0.3, 0.5)[0] == 1 and clean_translate(-4.0, 0.5)[0] == 1
    assert clean_translate(1e9, 0.5)[0] == shapeprog.limits.MAX_TRANSLATE_COPIES
    with pytest.raises(InvalidSample):
        clean_translate(float("nan"), 0.5)


def test_squeeze_cubes_and_faces():
    st = reflect_state()
    assert choose_squeeze(cube_logits(c1=(0, 3), c2=(3, 0), c3=(3, 2)), st) == (3, 0, 2)
    assert choose_squeeze(cube_logits(c1=(3,), c2=(0,), c3=(3, 1)), st) == (3, 0, 1)  # cube-3 = cube-1 gives way
    run(st, attach(3, 1, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5))
    assert choose_squeeze(cube_logits(c1=(3,), c2=(0,), c3=(1, 2)), st) == (3, 0, 2)  # 3 -- 1 is attached
    # as in the reference, cube-3 is tested against cube-1's earlier attachments, not against cube-2
    assert choose_squeeze(cube_logits(c1=(3,), c2=(2,), c3=(2,)), st) == (3, 2, 2)
    # with bbox on either side only top and bot are allowed
    assert choose_squeeze_face(logits(6, (0, 4, 3)), 0, 2) == 3
    assert choose_squeeze_face(logits(6, (0, 4, 3)), 2, 0) == 3
    assert choose_squeeze_face(logits(6, (0, 4, 3)), 1, 2) == 0


def test_lines_are_refused_outside_one_and_a_half_bboxes():
    st = state_with((0.4, 0.4, 0.4), bbox=(1.0, 2.0, 1.0))
    # centre of the cube on the bbox's right face: it reaches x = 0.7 < 0.75 = 1.5 * 0.5
    ok = attach(1, 0, 0.5, 0.5, 0.5, 1.0, 0.5, 0.5)
    try_line(st, ok)
    with pytest.raises(InvalidSample, match="outside 1.1x"):
        try_line(st, ok, margin=1.1)
    # its left face on the right face: x up to 0.9
    with pytest.raises(InvalidSample, match="outside 1.5x"):
        try_line(st, attach(1, 0, 0.0, 0.5, 0.5, 1.0, 0.5, 0.5))
    assert st.program.boxes[1].pos == (0.0, 0.0, 0.0)  # trials run on a copy
    # a macro copy outside is refused too: a post (1) through the bbox's height and a rod (2) standing on
    # its foot; the rod's copy one bbox height up stands on the post's top and ends 0.8 above the bbox
    st = state_with((0.2, 2.0, 0.2), (0.1, 1.8, 0.1), bbox=(1.0, 2.0, 1.0))
    run(st, attach(1, 0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5))
    run(st, attach(2, 1, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5))
    try_line(st, Line(TRANSLATE, (2,), (0.2,), axis=1, count=2))  # copies up to 0.4 higher: inside
    with pytest.raises(InvalidSample, match="outside 1.5x"):
        try_line(st, Line(TRANSLATE, (2,), (1.0,), axis=1, count=1))


def test_ungrounded_cuboids_are_removed_and_slots_renumbered():
    lines = [Line(CUBOID, nums=(1.0, 1.0, 1.0), aligned=True), Line(CUBOID, nums=(0.1,) * 3),
             Line(CUBOID, nums=(0.2,) * 3), Line(CUBOID, nums=(0.3,) * 3), attach(2, 0), attach(3, 2),
             Line(SQUEEZE, (3, 0, 2), (0.5, 0.5), face=2), Line(REFLECT, (3,), axis=0), Line(TRANSLATE, (1,), (0.5,), 0, -1, 2)]
    out, kept = remove_ungrounded(lines, {0, 2, 3})
    assert kept == [0, 2, 3]
    assert [ln.nums[0] for ln in out[:3]] == [1.0, 0.2, 0.3]
    assert [ln.cubes for ln in out[3:]] == [(1, 0), (2, 1), (2, 0, 1), (2,)]  # the translate of slot 1 is gone


# ----------------------------------------------------------------------------- the network step


@pytest.mark.parametrize("backend", ["numpy", "torch"])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_step_network_is_the_decoder(dtype, backend):
    torch.manual_seed(3)
    dec = Decoder(24).to(dtype)
    g = torch.Generator().manual_seed(0)
    z = torch.randn(24, generator=g, dtype=dtype)
    bb = torch.tensor([0.9, 1.2, 0.7], dtype=dtype)
    inp = torch.rand(1, 3, LINE_DIM, generator=g, dtype=dtype)
    teacher = torch.zeros(1, 3, LINE_DIM, dtype=dtype)
    picks = [(2, 3, 5, 1), (5, 0, 9, 4), (3, 10, 2, 0)]  # command, cube-1, cube-2, cube-3 per step
    for t, (c, a, b, k) in enumerate(picks):
        teacher[0, t, c] = 1.0
        teacher[0, t, CUBES.start + a] = teacher[0, t, CUBES.start + NUM_SLOTS + b] = 1.0
        teacher[0, t, CUBES.start + 2 * NUM_SLOTS + k] = 1.0
    with torch.no_grad():
        ref = dec(inp, z.reshape(1, 1, -1), z.reshape(1, 1, -1), bb[None], 3, teacher)
        net = _Net(dec, backend)
        h = net.latent(z)
        ctx = net.begin(h, bb.tolist(), 3)
        for t, (c, a, b, k) in enumerate(picks):
            h = net.step(inp[0, t].tolist(), h, ctx)
            want = ref.lines[0, t].tolist()
            got = (net.command(h, ctx) + net.cubes(h, ctx, c) + net.cuboid(h, ctx)[0] + net.attach(h, ctx, a, b)
                   + net.sym(h, ctx, a) + net.squeeze(h, ctx, a, b, k) + [net.cuboid(h, ctx)[1]])
            tol = 1e-5 if dtype == torch.float32 else 1e-12
            assert np.allclose(got, want, atol=tol)
            assert np.allclose(net.leaf(h, ctx), ref.leaf[0, t].item(), atol=tol)
            assert np.allclose(np.asarray(net.child(h, ctx)), ref.next[0, t].numpy(), atol=tol)
        assert np.allclose(np.asarray(h), ref.h[0, 0].numpy(), atol=tol)


def test_both_backends_decode_the_same_programs():
    dec = forced_decoder(())
    with torch.no_grad():
        dec.cmd_net.l3.bias.copy_(torch.tensor([0.0, 3.0, 1.0, 0.0, 0.0, 0.0, -2.0]))
        g = torch.Generator().manual_seed(0)
        for _ in range(3):
            z = torch.randn(16, generator=g) * 3
            a, b = (_decode_with(_Net(dec, k), z, False, DecodeOptions()) for k in ("numpy", "torch"))
            assert [type(s) for s in a.program.blocks[0].statements] == [type(s) for s in b.program.blocks[0].statements]
            assert np.allclose(shapeprog.lang.numbers(a.program), shapeprog.lang.numbers(b.program), atol=1e-5)


# ----------------------------------------------------------------------------- fuzzing


class RandomNet:
    """Seeded random outputs for every head: a stand-in for the network that reaches every rule."""

    def __init__(self, seed: int):
        self.rng = np.random.default_rng(seed)

    def latent(self, z):
        return 0

    def root_bbox(self, z):
        return self.rng.uniform(0.3, 2.0, 3).tolist()

    def begin(self, h, bbox_dims, depth):
        return {"bbox": np.asarray(bbox_dims)}

    def step(self, line, h, ctx):
        return h + 1

    def command(self, h, ctx):
        # Cuboid lines first, then attaches and squeezes, then macros, then stop (with noise)
        base = np.array([-3.0, 3.5 - 0.25 * h, 1.0, 0.08 * h - 2.0, 0.07 * h - 2.0, 0.3, 0.08 * h - 5.0])
        return (base + self.rng.normal(0, 1.0, 7)).tolist()

    def cubes(self, h, ctx, cmd):
        return self.rng.normal(0, 3, 33).tolist()

    def cuboid(self, h, ctx):
        return (ctx["bbox"] * self.rng.uniform(-0.05, 0.7, 3)).tolist(), float(self.rng.normal())

    def attach(self, h, ctx, a, b):
        return self.rng.uniform(-0.2, 1.2, 6).tolist()

    def sym(self, h, ctx, a):
        return self.rng.normal(0, 1, 3).tolist() + [float(self.rng.uniform(-1, 6)), float(self.rng.uniform(-0.2, 1.2))]

    def squeeze(self, h, ctx, a, b, c):
        return self.rng.normal(0, 1, 6).tolist() + self.rng.uniform(-0.2, 1.2, 2).tolist()

    def leaf(self, h, ctx):
        return float(self.rng.normal(1.0, 1.0))

    def child(self, h, ctx):
        return 0


def check_decoded(prog) -> None:
    """Parses back identically, executes, and every block's geometry is inside 1.5 bboxes."""
    text = shapeprog.to_text(prog)
    assert shapeprog.parse(text) == prog and shapeprog.to_text(shapeprog.parse(text)) == text
    shape = shapeprog.execute(prog)
    assert torch.isfinite(shape.corners).all()
    for block in prog.blocks:
        local = run_block(flat(block).root)
        assert local.inside(range(1, len(local)), 1.5 + 1e-9)


def test_random_outputs_always_give_valid_programs():
    opts = DecodeOptions()
    kinds, nodes = set(), []
    for seed in range(40):
        root, _ = _decode_tree(RandomNet(seed), None, False, opts)
        prog = _program(root)
        check_decoded(prog)
        kinds |= {type(s).__name__ for b in prog.blocks for s in b.statements}
        nodes.append(len(prog.blocks))
        # the decoder's own local state is what the executor makes of the root block
        st = root.state
        if st.program is not None:
            keep = sorted(st.grounded) + list(range(st.cuboid_lines, len(st.program)))
            mine = torch.tensor([st.program.boxes[k].corners() for k in keep[1:]], dtype=torch.float64)
            ref = shapeprog.execute(flat(prog.root), dtype=torch.float64).corners
            assert len(mine) == len(ref) and (len(ref) == 0 or (mine - ref).abs().max() < 1e-9)
    assert kinds == {"Cuboid", "Attach", "Squeeze", "Reflect", "Translate"}
    assert max(nodes) > 1 and max(nodes) <= 11


def test_random_outputs_with_rejection_raise_invalid_sample():
    raised = 0
    for seed in range(10):
        try:
            root, skipped = _decode_tree(RandomNet(seed), None, True, DecodeOptions())
            assert skipped == 0
            check_decoded(_program(root))
        except InvalidSample as e:
            raised += 1
            assert e.node is not None and e.step is not None
    assert raised > 0


def test_the_input_after_an_accepted_line_is_its_line_vector(monkeypatch):
    decode_module = importlib.import_module("shapeprog.vae.decode")  # the attribute is the function decode
    seen = set()

    def checked(net, h, ctx, state, opts, budget, vec, placements):
        out = _propose(net, h, ctx, state, opts, budget, vec, placements)
        assert vec == line_vector(out[0])
        seen.add(out[0].cmd)
        return out

    monkeypatch.setattr(decode_module, "_propose", checked)
    for seed in range(10):
        _decode_tree(RandomNet(seed), None, False, DecodeOptions())
    assert seen >= {CUBOID, ATTACH, SQUEEZE, REFLECT, TRANSLATE, STOP}


@pytest.mark.parametrize("H", [16, 256])
def test_untrained_models_decode_valid_programs(H):
    torch.manual_seed(H)
    vae = VAE(H)
    g = torch.Generator().manual_seed(1)
    for _ in range(12):
        d = decode(vae, torch.randn(H, generator=g) * 3)
        check_decoded(d.program)
        assert d.text == shapeprog.to_text(d.program) and d.tries == 1
    with pytest.raises(InvalidSample):  # an untrained decoder breaks a rule early
        decode_latent(vae.decoder, torch.randn(H, generator=g), reject=True)


def test_decoding_several_latents_gives_the_programs_of_decoding_each():
    from shapeprog.vae.pretrained import load_pretrained

    vae = load_pretrained("chair")
    zs = torch.randn(10, vae.decoder.hidden_dim, generator=torch.Generator().manual_seed(2))
    got = decode_programs(vae.decoder, zs)
    for z, p in zip(zs, got):
        try:
            want = decode_latent(vae.decoder, z, reject=False).text
        except ValueError:
            want = None
        assert (None if p is None else shapeprog.to_text(round_numbers(p))) == want
    assert sum(p is not None for p in got) >= 8
    with pytest.raises(ValueError, match="shape"):
        decode_programs(vae.decoder, torch.zeros(2, 7))


def test_corpus_programs_replayed_through_the_rules_come_back():
    names = [(c, i) for c in corpus.CATEGORIES for i in corpus.ids(c, "all")]
    same = 0
    sample_ = random.Random(0).sample(names, 60)
    for c, i in sample_:
        prog = shapeprog.parse(corpus.read(c, i), f"{c}/{i}.txt")
        d = _decode_with(Replay(), program_to_tree(prog, dtype=torch.float64), False, DecodeOptions())
        check_decoded(d.program)
        same += d.text == shapeprog.to_text(prog)
    assert same >= 0.85 * len(sample_)


def test_the_node_limit_turns_further_sub_programs_into_leaves():
    text = "Assembly Program_0 {\n\tbbox = Cuboid(2.0, 2.0, 2.0, True)\n"
    for k in range(1, 4):
        text += f"\tProgram_{k} = Cuboid(0.3, 0.3, 0.3, True)\n"
    for k in range(1, 4):
        text += f"\tattach(Program_{k}, bbox, 0.5, 0.0, 0.5, {round(0.2 * k, 1)}, 0.0, 0.5)\n"
    text += "}\n"
    for k in range(1, 4):
        text += (f"Assembly Program_{k} {{\n\tbbox = Cuboid(0.3, 0.3, 0.3, True)\n\tcube0 = Cuboid(0.1, 0.1, 0.1, True)\n"
                 "\tattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n}\n")
    tree = program_to_tree(shapeprog.parse(text), dtype=torch.float64)
    assert _decode_with(Replay(), tree, False, DecodeOptions()).text == text
    d = _decode_with(Replay(), tree, False, DecodeOptions(max_nodes=2))
    assert [b.name for b in d.program.blocks] == ["Program_0", "Program_1"]
    assert "\tcube1 = Cuboid(0.3, 0.3, 0.3, True)" in d.text and "cube2 = Cuboid" in d.text
    check_decoded(d.program)


def test_the_size_limits_hold_for_huge_translate_counts():
    class Copier(RandomNet):
        def sym(self, h, ctx, a):
            return [1.0, 0.0, 0.0, 1e6, 0.01]

    translates = 0
    for seed in range(3):
        root, _ = _decode_tree(Copier(seed), None, False, DecodeOptions())
        prog = _program(root)
        check_decoded(prog)
        counts = [st.n for b in prog.blocks for st in b.statements if isinstance(st, shapeprog.lang.Translate)]
        # every translate the network asked 1e6 copies of got the language's maximum, and the whole
        # program stays within the line and cuboid limits
        assert counts == [limits.MAX_TRANSLATE_COPIES] * len(counts)
        translates += len(counts)
        assert len(shapeprog.to_text(prog).splitlines()) <= limits.MAX_LINES
        assert len(shapeprog.execute(prog).corners) <= limits.MAX_CUBOIDS
    assert translates > 0
    b = _Budget()
    b.charge(lines=999)
    with pytest.raises(InvalidSample, match="size limits"):
        b.charge(lines=2)


# ----------------------------------------------------------------------------- entry points


@pytest.fixture(scope="module")
def vae():
    torch.manual_seed(0)
    return VAE(32)


def test_sample_is_deterministic_under_a_seed(vae):
    a, b, c = sample(vae, 3, seed=5), sample(vae, 3, seed=5), sample(vae, 3, seed=6)
    assert [d.text for d in a] == [d.text for d in b]
    assert [d.text for d in a] != [d.text for d in c]
    assert all(isinstance(d, Decoded) and 1 <= d.tries <= 11 for d in a)
    assert all(d.tries == 11 for d in a)  # an untrained decoder: every draw refused, then the fallback
    assert sample(vae, 1, seed=5, max_tries=2)[0].tries == 3


@pytest.mark.parametrize("n, seed, tries", [(0, 0, 10), (-1, 0, 10), (1.5, 0, 10), (1, "0", 10), (1, 1.0, 10),
                                            (1, None, 10), (1, 0, 0), (True, 0, 10)])
def test_sample_refuses_bad_arguments(vae, n, seed, tries):
    with pytest.raises(ValueError, match="must be"):
        sample(vae, n, seed=seed, max_tries=tries)


def test_decode_options_are_checked(vae):
    with pytest.raises(ValueError, match="bbox_margin"):
        decode(vae, torch.zeros(32), bbox_margin=0)
    with pytest.raises(ValueError, match="bbox_attach"):
        decode(vae, torch.zeros(32), bbox_attach="near")
    with pytest.raises(TypeError):
        decode(vae, torch.zeros(32), max_line=3)
    with pytest.raises(ValueError, match=r"shape \(32,\)"):
        decode(vae, torch.zeros(1, 32))


def test_encode_gives_mu_in_eval_mode_and_restores_the_mode(vae, two_levels):
    vae.train()
    mu = encode(vae, two_levels)
    assert vae.training and mu.shape == (32,) and not mu.requires_grad
    with torch.no_grad():
        ref, _ = vae.encoder(program_to_tree(shapeprog.parse(two_levels)))
    assert torch.equal(mu, ref)
    assert torch.equal(encode(vae, shapeprog.parse(two_levels)), mu)


def test_encode_refuses_a_node_of_eleven_cuboid_lines(vae):
    lines = ["bbox = Cuboid(1.0, 1.0, 1.0, True)"] + [f"cube{k} = Cuboid(0.1, 0.1, 0.1, True)" for k in range(10)]
    lines += [f"attach(cube{k}, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)" for k in range(10)]
    with pytest.raises(ParseError, match=r"big\.txt:11:\d+: more than 10 Cuboid lines"):
        encode(vae, "\n".join(lines) + "\n", file="big.txt")


def test_interpolate_includes_both_ends(vae, two_levels):
    za, zb = torch.zeros(32), torch.ones(32)
    out = interpolate(vae, za, zb, 4)
    assert len(out) == 4 and out[0].text == decode(vae, za).text and out[-1].text == decode(vae, zb).text
    out = interpolate(vae, two_levels, zb, 2)
    assert out[0].text == decode(vae, encode(vae, two_levels)).text
    with pytest.raises(ValueError, match="steps"):
        interpolate(vae, za, zb, 1)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_decoding_on_the_gpu_matches_the_cpu(vae):
    g = torch.Generator().manual_seed(0)
    zs = [torch.randn(32, generator=g) * 3 for _ in range(4)]
    cpu = [decode(vae, z).program for z in zs]
    gpu_vae = VAE(32)
    gpu_vae.load_state_dict(vae.state_dict())
    gpu_vae.cuda()
    gpu = [decode(gpu_vae, z.cuda()).program for z in zs]
    for a, b in zip(cpu, gpu):  # the same programs up to float rounding
        assert [len(x.statements) for x in a.blocks] == [len(x.statements) for x in b.blocks]
        assert np.allclose(shapeprog.lang.numbers(a), shapeprog.lang.numbers(b), atol=1e-4)
    assert len(sample(gpu_vae, 2, seed=1)) == 2
    assert encode(gpu_vae, shapeprog.corpus.read("chair", 173)).device.type == "cuda"
