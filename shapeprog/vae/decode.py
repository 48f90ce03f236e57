"""Decoding latents into ShapeAssembly programs with semantic validity, and the model's entry points.

:func:`decode_latent` writes a program from a latent one line at a time (greedy argmax), breadth first
over the sub-programs, and repairs or refuses every line that would not make sense: the reference's
``run_eval_decoder`` with ``sem_valid.semValidGen`` (spec section (d), "Decoding with semantic
validity"). Each rule is a function of the logits and of the block written so far, in
:mod:`shapeprog.vae.validity`, so that it can be tested on its own.

A refused line raises :class:`InvalidSample`; with ``reject=True`` (unconditional generation) that ends
the sample, otherwise the decoder re-feeds its previous input and tries again. :func:`sample`,
:func:`encode`, :func:`decode` and :func:`interpolate` are the model's entry points. Where this follows
the reference code, where the paper, and the decisions the specification leaves open:
``docs/shapeassembly_vae.md`` ("Decoding with semantic validity").

Example:
    >>> import torch
    >>> import shapeprog
    >>> from shapeprog.vae import VAE
    >>> vae = VAE(hidden_dim=32)
    >>> out = sample(vae, 2, seed=0)
    >>> [isinstance(d.program, shapeprog.lang.Program) and shapeprog.parse(d.text) == d.program for d in out]
    [True, True]
    >>> d = decode(vae, torch.zeros(32))
    >>> d.text.startswith("Assembly Program_0 {")
    True
"""
from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from .. import limits
from ..lang import (AXES, CORPUS_DECIMALS, FACES, Attach, Block, Cuboid, Program, Reflect, Squeeze, Translate, parse,
                    round_numbers, to_text)
from .model import VAE, Decoder
from .validity import (ATTACH_CMD, CUBOID, MIN_DIM, REFLECT, SQUEEZE, START, STOP, TRANSLATE, DecodeOptions,
                       InvalidSample, Line, NodeState, allowed_commands, argmax_allowed, choose_attach, choose_reflect,
                       choose_reflect_axis, choose_squeeze, choose_squeeze_face, choose_translate, clean_attach,
                       clean_cuboid, clean_translate, remove_ungrounded, try_line)
from .vectors import (
    ALIGNED, ATTACH, AXIS, COUNT, CUBE1, CUBE2, CUBE3, DIMS, DIST, FACE, LINE_DIM, UV, program_to_tree,
)
from .step import _Net

__all__ = [
    "MAX_SAMPLES",
    "MAX_TRIES",
    "DecodeOptions",
    "Decoded",
    "InvalidSample",
    "decode",
    "decode_latent",
    "decode_programs",
    "encode",
    "interpolate",
    "sample",
]


@dataclass
class Decoded:
    """A decoded program.

    Attributes:
        program: the decoded program (corpus format), executable by :func:`shapeprog.execute`; its numbers
            are rounded to the corpus's :data:`~shapeprog.lang.CORPUS_DECIMALS` (3) decimals.
        text: ``shapeprog.to_text(program)``; ``shapeprog.parse(text) == program``.
        skipped: lines refused and skipped (non-rejecting decoding; 0 with rejection).
        tries: latents drawn for this sample (:func:`sample`); ``max_tries + 1`` marks a sample that
            was refused ``max_tries`` times and then decoded without rejection from its last latent.
    """

    program: Program
    text: str
    skipped: int
    tries: int = 1


def _finite(values: Sequence[float], what: str) -> list[float]:
    values = list(values)
    if not all(math.isfinite(v) for v in values):
        raise InvalidSample(f"{what}: the network gives a non-finite value")
    return values


# ----------------------------------------------------------------------------- decoding


class _Budget:
    """The size limits of :mod:`shapeprog.limits`, charged as lines are accepted so that every decoded
    text parses: text lines, attach operations, and an upper bound on the executed leaf cuboids (every
    non-bbox slot counts as a leaf, times the number of placements of its node)."""

    def __init__(self):
        self.lines = self.attaches = self.leaves = 0

    def check(self, lines: int = 0, attaches: int = 0, leaves: int = 0) -> None:
        """Raise :class:`InvalidSample` if charging this much would break a limit."""
        if (self.lines + lines > limits.MAX_LINES or self.attaches + attaches > limits.MAX_ATTACHES
                or self.leaves + leaves > limits.MAX_CUBOIDS):
            raise InvalidSample("the program would exceed the language's size limits (shapeprog.limits)")

    def charge(self, lines: int = 0, attaches: int = 0, leaves: int = 0) -> None:
        self.check(lines, attaches, leaves)
        self.lines += lines
        self.attaches += attaches
        self.leaves += leaves


class _Node:
    """One program node while decoding: its inputs, then its lines and children."""

    def __init__(self, latent, bbox_dims, depth: int, placements: int):
        self.latent, self.bbox_dims, self.depth, self.placements = latent, tuple(bbox_dims), depth, placements
        self.index = -1  # breadth-first decode order; -1 when never decoded
        self.lines: list[Line] = []
        self.kids: list[_Node | None] = []  # per accepted Cuboid line (bbox: None)
        self.state: NodeState | None = None
        self.skipped = 0


def _propose(net: _Net, h, ctx: dict, state: NodeState, opts: DecodeOptions, budget: _Budget, vec: list,
             placements: int):
    """The line the decoder proposes at this step, with every rule applied.

    ``vec`` is filled with the line vector as the line is built: the accepted line's vector
    (:func:`~shapeprog.vae.validity.line_vector`), or the partial vector of a refused line.

    Returns:
        (line, local program after it or None, leaf logit or None)

    Raises:
        InvalidSample: the line breaks a rule.
    """
    cmd = argmax_allowed(net.command(h, ctx), allowed_commands(state, opts.max_cuboid_lines))
    vec[cmd] = 1.0
    if cmd == START:
        return Line(START), None, None
    if cmd == STOP:
        if state.program is None:
            raise InvalidSample("stop before the bbox line")
        return Line(STOP), None, None
    if cmd == CUBOID:
        dims, align = net.cuboid(h, ctx)
        dims, aligned = clean_cuboid(_finite(dims, "Cuboid"), align, state.bbox_dims)
        vec[DIMS], vec[ALIGNED] = dims, float(aligned)
        line = Line(CUBOID, nums=dims, aligned=aligned)
        if state.program is None:  # the bbox line (charged with its block)
            return line, None, None
        budget.charge(lines=1, leaves=placements)
        return line, None, net.leaf(h, ctx)
    if state.program is None:
        raise InvalidSample(f"{('attach', 'reflect', 'translate', 'squeeze')[cmd - 2]} before the bbox line")
    cube = net.cubes(h, ctx, cmd)
    if cmd == ATTACH_CMD:
        a, b = choose_attach(cube, state)
        vec[CUBE1.start + a] = vec[CUBE2.start + b] = 1.0
        coords = _finite(net.attach(h, ctx, a, b), "attach")
        line = Line(ATTACH_CMD, (a, b), clean_attach(coords, b, opts.bbox_attach, opts.bbox_tolerance))
        vec[ATTACH] = line.nums
        cost = dict(lines=1, attaches=1)
    elif cmd == SQUEEZE:
        a, b, c = choose_squeeze(cube, state)
        vec[CUBE1.start + a] = vec[CUBE2.start + b] = vec[CUBE3.start + c] = 1.0
        sq = net.squeeze(h, ctx, a, b, c)
        face = choose_squeeze_face(sq[:6], b, c)
        u, v = (min(max(x, 0.0), 1.0) for x in _finite(sq[6:8], "squeeze"))
        line = Line(SQUEEZE, (a, b, c), (u, v), face=face)
        vec[FACE.start + face] = 1.0
        vec[UV] = line.nums
        cost = dict(lines=1, attaches=2)
    else:
        a = choose_reflect(cube, state) if cmd == REFLECT else choose_translate(cube, state)
        vec[CUBE1.start + a] = 1.0
        sym = net.sym(h, ctx, a)
        moves = len(state.program.boxes[a].moves)
        if cmd == REFLECT:
            k = choose_reflect_axis(sym[:3], a, state)
            line = Line(REFLECT, (a,), axis=k)
            cost = dict(lines=1, attaches=moves, leaves=placements)
        else:
            k = argmax_allowed(sym[:3], range(3))
            n, d = clean_translate(sym[3], sym[4])
            line = Line(TRANSLATE, (a,), (d,), axis=k, count=n)
            vec[COUNT], vec[DIST] = float(n), d
            cost = dict(lines=1, attaches=n * moves, leaves=n * placements)
        vec[AXIS.start + k] = 1.0
    budget.check(**cost)  # before executing: a translate may make many copies
    trial = try_line(state, line, opts.bbox_margin)
    budget.charge(**cost)
    return line, trial, None


def _decode_node(net: _Net, node: _Node, reject: bool, opts: DecodeOptions, budget: _Budget) -> None:
    """Decode one node's lines from its latent (``semValidGen``); fills ``node.lines``/``kids``/``state``."""
    state = node.state = NodeState(node.bbox_dims)
    h = node.latent
    ctx = net.begin(h, node.bbox_dims, node.depth)
    inp = [0.0] * LINE_DIM
    inp[START] = 1.0
    budget.charge(lines=3)  # the block's header, bbox line and closing brace
    refused = 0
    for step in range(opts.max_lines):
        h = net.step(inp, h, ctx)
        vec = [0.0] * LINE_DIM
        try:
            line, trial, leaf = _propose(net, h, ctx, state, opts, budget, vec, node.placements)
        except InvalidSample as e:
            if reject:
                raise InvalidSample(e.reason, node.index, step) from None
            node.skipped += 1
            refused += 1
            if refused >= opts.max_refeed:  # the reference then feeds the refused line
                refused = 0
                inp = vec
            continue
        inp = vec  # the accepted line's vector, built by _propose
        if line.cmd == START:
            continue
        if line.cmd == STOP:
            break
        first = state.program is None
        state.accept(line, trial)
        node.lines.append(line)
        if line.cmd == CUBOID:
            child = None
            if not first and leaf < 0.0:
                child = _Node(net.child(h, ctx), line.nums, node.depth + 1, 0)
            node.kids.append(child)


def _decode_tree(net: _Net, z: torch.Tensor, reject: bool, opts: DecodeOptions) -> tuple[_Node, int]:
    """Decode every node breadth first (``run_eval_decoder``). Returns the root and the lines skipped."""
    bb = [min(max(x, MIN_DIM), limits.MAX_ABS_NUMBER) if math.isfinite(x) else 1.0 for x in net.root_bbox(z)]
    root = _Node(net.latent(z), bb, 0, 1)
    budget = _Budget()
    queue, decoded, skipped = [root], 0, 0
    while queue:
        node = queue.pop(0)
        if decoded == opts.max_nodes:
            break  # the rest stay leaves
        node.index = decoded
        decoded += 1
        _decode_node(net, node, reject, opts, budget)
        skipped += node.skipped
        st = node.state
        for slot, kid in enumerate(node.kids):
            if kid is not None and slot in st.grounded:  # an ungrounded cuboid is removed with its child
                kid.placements = node.placements * (1 + st.copies.get(slot, 0))
                queue.append(kid)
    return root, skipped


def _program(root: _Node) -> Program:
    """The decoded tree as a program: ungrounded Cuboid lines removed, blocks numbered breadth first,
    the j-th Cuboid line named ``bbox``, ``Program_<m>`` (a decoded child) or ``cube<j-1>``."""
    blocks, queue, count = [], [(root, "Program_0")], 1
    while queue:
        node, name = queue.pop(0)
        lines, kept = remove_ungrounded(node.lines, node.state.grounded)
        if not lines:  # no bbox line was decoded: the node's own bbox dims
            lines, kept = [Line(CUBOID, nums=node.bbox_dims, aligned=True)], [0]
        names = []
        for j, old in enumerate(kept):
            kid = node.kids[old] if old < len(node.kids) else None
            if j == 0:
                names.append("bbox")
            elif kid is not None and kid.index >= 0:
                names.append(f"Program_{count}")
                queue.append((kid, f"Program_{count}"))
                count += 1
            else:
                names.append(f"cube{j - 1}")
        stmts, j = [], 0
        for ln in lines:
            n = [names[c] for c in ln.cubes]
            if ln.cmd == CUBOID:
                stmts.append(Cuboid(names[j], *ln.nums, True if j == 0 else ln.aligned))
                j += 1
            elif ln.cmd == ATTACH_CMD:
                stmts.append(Attach(n[0], n[1], *ln.nums))
            elif ln.cmd == SQUEEZE:
                stmts.append(Squeeze(n[0], n[1], n[2], FACES[ln.face], *ln.nums))
            elif ln.cmd == REFLECT:
                stmts.append(Reflect(n[0], AXES[ln.axis]))
            else:
                stmts.append(Translate(n[0], AXES[ln.axis], ln.count, ln.nums[0]))
        blocks.append(Block(name, tuple(stmts)))
    return Program(tuple(blocks))


@contextlib.contextmanager
def _inference(module: torch.nn.Module):
    """Eval mode and no gradients for the duration; the module's mode is restored after."""
    was = module.training
    module.eval()
    try:
        with torch.no_grad():
            yield
    finally:
        module.train(was)


def _check_latent(z, H: int) -> torch.Tensor:
    if not isinstance(z, torch.Tensor):
        raise TypeError(f"z must be a torch.Tensor of shape ({H},), got {type(z).__name__}")
    if tuple(z.shape) != (H,):
        raise ValueError(f"z must have shape ({H},) (the model's hidden_dim), got {tuple(z.shape)}")
    return z


def _decode_with(net: _Net, z: torch.Tensor, reject: bool, opts: DecodeOptions) -> Decoded:
    root, skipped = _decode_tree(net, z, reject, opts)
    program = round_numbers(_program(root), CORPUS_DECIMALS)  # numbers as the corpus writes them
    return Decoded(program, to_text(program), skipped)


def decode_latent(decoder: Decoder, z: torch.Tensor, *, reject: bool = False,
                  generator: torch.Generator | None = None, **options) -> Decoded:
    """Decode a latent into a program, greedily (argmax), with the rules of semantic validity.

    Args:
        decoder: the model's decoder (any hidden size; its device and dtype are used).
        z: (H,) float, the latent.
        reject: refuse the whole sample at the first invalid line (raise :class:`InvalidSample`), as
            unconditional generation does; otherwise skip invalid lines (re-feeding the previous input).
        generator: accepted for stochastic decoders; greedy decoding draws no random numbers.
        **options: the fields of :class:`DecodeOptions` (e.g. ``bbox_margin=1.1`` for the paper's rule).

    Returns:
        The :class:`Decoded` program (``tries`` = 1).

    Raises:
        InvalidSample: ``reject`` and an invalid line.
        ValueError: ``z`` is not (H,), or a bad option.
    """
    opts = DecodeOptions(**options)
    _check_latent(z, decoder.hidden_dim)
    with _inference(decoder):
        return _decode_with(_Net(decoder), z, reject, opts)


def decode_programs(decoder: Decoder, zs: torch.Tensor, **options) -> list[Program | None]:
    """:func:`decode_latent` without rejection for each latent of ``zs`` ``(B, H)``: the programs, None where a
    latent decodes to no program (``ValueError``). The network is set up once for the batch and no text is
    written, so this is faster than calling :func:`decode_latent` per latent (the same programs before
    :func:`decode_latent` rounds them to the corpus's decimals, tested); the numbers keep the network's precision
    (point-cloud inference scales and fits them further)."""
    opts = DecodeOptions(**options)
    out: list[Program | None] = []
    with _inference(decoder):
        net = _Net(decoder)
        for z in zs:
            _check_latent(z, decoder.hidden_dim)
            try:
                root, _ = _decode_tree(net, z, False, opts)
                out.append(_program(root))
            except ValueError:
                out.append(None)
    return out


# ----------------------------------------------------------------------------- entry points


#: The most programs one :func:`sample` call generates (each one is kept in memory).
MAX_SAMPLES = 100_000
#: The most draws per sample.
MAX_TRIES = 1000


def _check_int(name: str, v, low: int, high: int | None = None) -> int:
    if not isinstance(v, (int, np.integer)) or isinstance(v, bool):
        raise ValueError(f"{name} must be an integer, got {v!r} ({type(v).__name__})")
    if v < low:
        raise ValueError(f"{name} must be at least {low}, got {v}")
    if high is not None and v > high:
        raise ValueError(f"{name} must be at most {high}, got {v}")
    return int(v)


def sample(vae: VAE, n: int, seed: int = 0, max_tries: int = 10, **options) -> list[Decoded]:
    """Unconditional generation: ``n`` programs from latents z ~ N(0, I), decoded with rejection.

    Latents are drawn on the CPU from a ``torch.Generator`` seeded with ``seed`` (so a seed gives the same
    latents on every device), in order; a refused draw is replaced by the next one, up to ``max_tries``
    draws per sample. A sample refused ``max_tries`` times is decoded from its last latent without
    rejection and marked ``tries = max_tries + 1``.

    Args:
        vae: the model (its decoder is used, in eval mode, on its device).
        n: programs to generate (1 to :data:`MAX_SAMPLES`).
        seed: the generator's seed (an integer).
        max_tries: draws per sample (1 to :data:`MAX_TRIES`; the reference's paper reports 10-20% refused draws).
        **options: :class:`DecodeOptions` fields.

    Returns:
        ``n`` :class:`Decoded` programs; the share with ``tries <= max_tries`` is the share valid within
        ``max_tries`` draws, and with ``tries == 1`` the share valid on the first draw.
    """
    n = _check_int("n", n, 1, MAX_SAMPLES)
    seed = _check_int("seed", seed, -(2 ** 63))
    if seed >= 2 ** 64:
        raise ValueError(f"seed must be below 2**64, got {seed}")
    max_tries = _check_int("max_tries", max_tries, 1, MAX_TRIES)
    opts = DecodeOptions(**options)
    dec = vae.decoder
    gen = torch.Generator().manual_seed(seed)
    out = []
    with _inference(dec):
        net = _Net(dec)
        for _ in range(n):
            for t in range(1, max_tries + 1):
                z = torch.randn(dec.hidden_dim, generator=gen)
                try:
                    d = _decode_with(net, z, True, opts)
                except InvalidSample:
                    continue
                d.tries = t
                break
            else:
                d = _decode_with(net, z, False, opts)
                d.tries = max_tries + 1
            out.append(d)
    return out


def encode(vae: VAE, program: Program | str, *, file: str = "<program>") -> torch.Tensor:
    """The mean code μ of a program (eval mode, no gradients).

    Args:
        vae: the model.
        program: a :class:`~shapeprog.lang.Program` or its text.
        file: the program's name in error messages.

    Returns:
        μ: (H,) float on the model's device.

    Raises:
        ParseError: at ``file:line:column``: a text that does not parse, or a program the model cannot
            encode (more than 10 Cuboid lines in a block, a cuboid beyond the vector's 11 slots).
    """
    if isinstance(program, str):
        program = parse(program, file)
    elif not isinstance(program, Program):
        raise TypeError(f"program must be a shapeprog Program or its text, got {type(program).__name__}")
    p = next(vae.parameters())
    tree = program_to_tree(program, file=file, dtype=p.dtype, device=p.device)
    with _inference(vae):
        mu, _ = vae.encoder(tree)
    return mu


def decode(vae: VAE, z: torch.Tensor, **options) -> Decoded:
    """Decode the latent ``z`` (H,) without rejection (invalid lines are skipped): :func:`decode_latent`."""
    return decode_latent(vae.decoder, z, **options)


def interpolate(vae: VAE, a, b, steps: int, **options) -> list[Decoded]:
    """Programs along the straight line between two codes.

    Args:
        vae: the model.
        a, b: programs (:class:`~shapeprog.lang.Program` or text, encoded to μ by :func:`encode`) or
            latents (H,).
        steps: results, both ends included (>= 2).
        **options: :class:`DecodeOptions` fields.

    Returns:
        ``steps`` :class:`Decoded` programs, non-rejecting, from ``(1 - t) a + t b`` for t = 0 .. 1.
    """
    steps = _check_int("steps", steps, 2)
    opts = DecodeOptions(**options)
    H = vae.decoder.hidden_dim
    za, zb = (_check_latent(x, H).detach() if isinstance(x, torch.Tensor) else encode(vae, x) for x in (a, b))
    zb = zb.to(za.device, za.dtype)
    with _inference(vae.decoder):
        net = _Net(vae.decoder)
        return [_decode_with(net, za + (zb - za) * (i / (steps - 1)), False, opts) for i in range(steps)]
