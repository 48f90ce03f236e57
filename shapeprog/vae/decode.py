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
from .vectors import (ALIGNED, ATTACH, AXIS, COUNT, CUBE1, CUBE2, CUBE3, DIMS, DIST, FACE, LINE_DIM, NUM_SLOTS, UV,
                      program_to_tree)

__all__ = ["MAX_SAMPLES", "MAX_TRIES", "DecodeOptions", "Decoded", "InvalidSample", "decode", "decode_latent", "decode_programs", "encode", "interpolate",
           "sample"]


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


# ----------------------------------------------------------------------------- the network, one step


class _Head:
    """A 3-layer MLP whose input is ``[x (main), extra]``: the extra part's first-layer contribution is
    added by the caller (one-hot rows, or a term fixed for the whole node)."""

    def __init__(self, mlp, main: int, conv, lrelu):
        W1 = conv(mlp.l1.weight.detach())  # views, no copies: BLAS reads the strided blocks as they are
        self.W1 = W1[:, :main]
        self.X = W1[:, main:].T  # (extra, out): row i = column main + i
        self.b1 = conv(mlp.l1.bias.detach())
        self.W2, self.b2 = conv(mlp.l2.weight.detach()), conv(mlp.l2.bias.detach())
        self.W3, self.b3 = conv(mlp.l3.weight.detach()), conv(mlp.l3.bias.detach())
        self.lrelu = lrelu

    def const(self, extra=None, rows: slice | None = None):
        """The first-layer bias plus the contribution of an extra input fixed for a node (at ``rows``
        of the extra part)."""
        if extra is None:
            return self.b1
        return self.b1 + extra @ (self.X if rows is None else self.X[rows])

    def __call__(self, x, pre, rows: Sequence[int] = ()):
        y = self.W1 @ x + pre
        for r in rows:
            y = y + self.X[r]
        y = self.lrelu(y)
        y = self.lrelu(self.W2 @ y + self.b2)
        return self.W3 @ y + self.b3


class _Net:
    """The decoder run one step at a time for one sequence (NumPy on CPU, torch elsewhere).

    The same arithmetic as :meth:`Decoder.forward` (tested), without the batch and time dimensions, and
    with each head run only when the line needs it. The decoding loop talks to the network through
    these methods only (:class:`~shapeprog.vae.replay.Replay` is a stand-in with the same methods).
    """

    def __init__(self, decoder: Decoder, backend: str | None = None):
        p = next(decoder.parameters())
        self.device, self.dtype = p.device, p.dtype
        self.numpy = p.device.type == "cpu" if backend is None else backend == "numpy"
        conv = (lambda t: t.numpy()) if self.numpy else (lambda t: t)
        if self.numpy:
            lrelu = lambda x: np.maximum(x, 0.2 * x)  # noqa: E731
            self.sigmoid = lambda x: 0.5 * (1.0 + np.tanh(0.5 * x))
            self.tanh = np.tanh
            np_dtype = p.detach().numpy().dtype
            self.vec = lambda v: np.asarray(v, dtype=np_dtype)
        else:
            lrelu = lambda x: torch.maximum(x, 0.2 * x)  # noqa: E731
            self.sigmoid, self.tanh = torch.sigmoid, torch.tanh
            self.vec = lambda v: torch.tensor(v, dtype=self.dtype, device=self.device)
        H = self.H = decoder.hidden_dim
        self.decoder = decoder
        self.inp_net = _Head(decoder.inp_net, LINE_DIM, conv, lrelu)
        g = decoder.gru
        self.Wih, self.Whh = conv(g.weight_ih_l0.detach()), conv(g.weight_hh_l0.detach())
        self.bih, self.bhh = conv(g.bias_ih_l0.detach()), conv(g.bias_hh_l0.detach())
        heads = ("cmd_net", "cube_net", "dim_net", "align_net", "att_net", "sym_net", "squeeze_net", "next_net",
                 "leaf_net")
        for name in heads:
            setattr(self, name, _Head(getattr(decoder, name), H, conv, lrelu))

    def latent(self, z: torch.Tensor):
        """A latent (H,) tensor as the GRU's state in this backend."""
        z = z.detach().to(device=self.device, dtype=self.dtype)
        return z.cpu().numpy() if self.numpy else z

    def root_bbox(self, z: torch.Tensor) -> list[float]:
        """``bbdimNet(z)``: the root's bbox dims."""
        return self.decoder.bbox(z.detach().to(device=self.device, dtype=self.dtype)).tolist()

    def begin(self, h_start, bbox_dims: Sequence[float], depth: int) -> dict:
        """A node's context: the first-layer terms fixed by its bbox dims, depth and start latent."""
        hier = [0.0, 0.0, 0.0]
        hier[min(int(depth), 2)] = 1.0
        bb = self.vec(list(bbox_dims))
        return {
            "inp": self.inp_net.const(self.vec(list(bbox_dims) + hier)),
            "dim": self.dim_net.const(bb), "align": self.align_net.const(bb),
            "sym": self.sym_net.const(bb, slice(NUM_SLOTS, NUM_SLOTS + 3)),
            "next": self.next_net.const(h_start), "leaf": self.leaf_net.const(h_start),
        }

    def step(self, line: Sequence[float], h, ctx: dict):
        """One GRU step on the input ``line`` (63 floats); returns the new state (= the GRU output)."""
        H = self.H
        x = self.inp_net(self.vec(line), ctx["inp"])
        gi = self.Wih @ x + self.bih
        gh = self.Whh @ h + self.bhh
        r = self.sigmoid(gi[:H] + gh[:H])
        u = self.sigmoid(gi[H:2 * H] + gh[H:2 * H])
        n = self.tanh(gi[2 * H:] + r * gh[2 * H:])
        return n + u * (h - n)

    def command(self, h, ctx) -> list[float]:
        """The 7 command logits."""
        return self.cmd_net(h, self.cmd_net.b1).tolist()

    def cubes(self, h, ctx, cmd: int) -> list[float]:
        """The 33 cube logits given the command."""
        return self.cube_net(h, self.cube_net.b1, (cmd,)).tolist()

    def cuboid(self, h, ctx) -> tuple[list[float], float]:
        """A Cuboid line's dims (3) and aligned logit."""
        return self.dim_net(h, ctx["dim"]).tolist(), float(self.align_net(h, ctx["align"])[0])

    def attach(self, h, ctx, a: int, b: int) -> list[float]:
        """The 6 attach coordinates given the two slots."""
        return self.att_net(h, self.att_net.b1, (a, NUM_SLOTS + b)).tolist()

    def sym(self, h, ctx, a: int) -> list[float]:
        """The 3 axis logits, the count and the distance of a reflect/translate line given its slot."""
        return self.sym_net(h, ctx["sym"], (a,)).tolist()

    def squeeze(self, h, ctx, a: int, b: int, c: int) -> list[float]:
        """The 6 face logits and (u, v) of a squeeze line given its slots."""
        return self.squeeze_net(h, self.squeeze_net.b1, (a, NUM_SLOTS + b, 2 * NUM_SLOTS + c)).tolist()

    def leaf(self, h, ctx) -> float:
        """The leaf logit (< 0: the cuboid gets a sub-program)."""
        return float(self.leaf_net(h, ctx["leaf"])[0])

    def child(self, h, ctx):
        """The latent of the sub-program started at this step."""
        return self.next_net(h, ctx["next"])


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
