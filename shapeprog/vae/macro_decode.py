"""Decoding latents into macro programs with validity, and the entry points of a :class:`MacroVAE`.

:func:`decode_macro_latent` writes a hierarchical macro program from a latent one line at a time (greedy
argmax), breadth first over the blocks, with the grammar's rules applied to the logits:

* a block's first line is its bbox (the root's dims from the bbox head, a child's the dims of the cuboid
  it fills in its parent's expansion);
* a function is allowed when the block has room for the cuboids it creates (``NUM_SLOTS``) and, when its
  first base line acts on the last declared cuboid (``needs_subject``), the block has declared one;
  ``stop`` once the block has created a cuboid;
* a cuboid argument is chosen among the slots declared so far;
* floats are clamped to their slots' ranges (:func:`float_ranges`: dims at least ``MIN_DIM``, attach and
  squeeze coordinates and translate distances in [0, 1], a macro's float parameter as the base slots it
  fills alone), and the base ``translate`` count is rounded to a whole number from 1 to the executor's limit;
* the chosen call is expanded with the block's lines so far (:meth:`shapeprog.macros.Library.expand`);
  an expansion that raises :class:`~shapeprog.macros.MacroError` (an attach to its own subject, a
  fractional count from a macro's expression, ...) refuses the call.

A refused call ends the sample (:class:`~shapeprog.vae.validity.InvalidSample`) when ``reject`` is set
(unconditional generation: :func:`sample_macro` draws a new latent); otherwise the next most likely allowed
command is tried, and a block with none ends. Every decoded program is compiled and executed
(:func:`shapeprog.macros.execute.compile_hierarchy`); one that does not execute is refused the same way.

Example:
    >>> from shapeprog.macros import Library
    >>> from shapeprog.vae.layout import LineLayout
    >>> from shapeprog.vae.macro_model import MacroVAE
    >>> vae = MacroVAE(LineLayout(Library()), hidden_dim=32)
    >>> out = sample_macro(vae, 2, seed=0)
    >>> [d.hierarchy.names[0] for d in out], all(d.shape.corners.shape[0] >= 1 for d in out)
    (['Program_0', 'Program_0'], True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .. import limits
from ..execute import ExecutedShape, ExecutionPlan
from ..lang import Program
from ..macros.execute import compile_hierarchy
from ..macros.grammar import CuboidLine
from ..macros.hierarchy import MacroHierarchy, to_text
from ..macros.lang import BOOL, CUBE, FLOAT, MacroError, MacroProgram
from .decode import MAX_SAMPLES, MAX_TRIES, _check_int
from .layout import GROUPS, MAX_BLOCK_LINES, NUM_SLOTS, LineLayout, MacroNode, macro_program_to_tree, tree_to_macro_program
from .macro_model import MacroVAE
from .model import one_hot_argmax
from .validity import InvalidSample

__all__ = ["MAX_DEPTH", "MAX_NODES", "MIN_DIM", "MacroDecoded", "decode_macro", "decode_macro_latent", "encode_macro",
           "float_ranges", "sample_macro"]

#: Block depth of a decoded program (root 0): a cuboid at depth MAX_DEPTH - 1 is a leaf.
MAX_DEPTH = 4
#: Blocks of a decoded program.
MAX_NODES = 32
#: The smallest base Cuboid dim a decoded line takes.
MIN_DIM = 0.01


@dataclass
class MacroDecoded:
    """A decoded macro program.

    Attributes:
        hierarchy: the hierarchical macro program (calling the model's library, no definitions of its own).
        text: its text (:func:`shapeprog.macros.hierarchy.to_text`).
        program: its expansion as a hierarchical ShapeAssembly program (what the metrics read).
        shape: the executed leaf cuboids.
        skipped: refused calls replaced by a less likely command (non-rejecting decoding).
        tries: latents drawn (:func:`sample_macro`); ``max_tries + 1`` marks a sample refused ``max_tries``
            times and then decoded without rejection from its last latent.
    """

    hierarchy: MacroHierarchy
    text: str
    program: Program
    shape: ExecutedShape
    skipped: int = 0
    tries: int = 1


#: The value range of each float slot of the base functions (translate's count is rounded apart).
_BASE_RANGES = {"Cuboid": ((MIN_DIM, math.inf),) * 3, "attach": ((0.0, 1.0),) * 6, "squeeze": ((0.0, 1.0),) * 2,
                "translate": ((1.0, float(limits.MAX_TRANSLATE_COPIES)), (0.0, 1.0))}


def float_ranges(library, func: str) -> tuple[tuple[float, float], ...]:
    """The range a decoded float argument of ``func`` is clamped to, per float parameter in order.

    A base function's slots have their own ranges (dims at least :data:`MIN_DIM`, attach and squeeze
    coordinates and translate distances in [0, 1]). A macro's float parameter takes the intersection of the
    ranges of the base slots it fills *alone* in the macro's expansion (``Cuboid(x0, bb_y, x1, b0)``: x0 and
    x1 are dims); a parameter only found in expressions (``0.65 * x0``, ``bb_y - x0``) is not clamped.
    """
    f = library[func]
    names = [p.name for p in f.params if p.type == FLOAT]
    if f.is_base:
        return _BASE_RANGES.get(func, ())[: len(names)]
    lo = {n: -math.inf for n in names}
    hi = {n: math.inf for n in names}
    for call in library.expand_macro(func).body:
        params = [p for p in library[call.func].params if p.type == FLOAT]
        ranges = _BASE_RANGES.get(call.func, ())
        floats = [a for a, p in zip(call.args, library[call.func].params) if p.type == FLOAT]
        for k, (a, _) in enumerate(zip(floats, params)):
            if k < len(ranges) and len(a.terms) == 1 and a.terms[0][0] == 1.0 and a.terms[0][1] in lo:
                v = a.terms[0][1]
                lo[v], hi[v] = max(lo[v], ranges[k][0]), min(hi[v], ranges[k][1])
    return tuple((lo[n], hi[n]) if lo[n] <= hi[n] else (-math.inf, math.inf) for n in names)


def _clean(func: str, row: list[float], lay: LineLayout, ranges) -> None:
    """Clamp a line vector's floats to their ranges (:func:`float_ranges`), in place; a base translate's
    count is rounded to a whole number."""
    fs = lay.slices[FLOAT].start
    for k, (lo, hi) in enumerate(ranges):
        row[fs + k] = min(max(row[fs + k], lo), hi)
    if func == "translate":
        row[fs] = float(round(row[fs]))


def _propose(dec, lay: LineLayout, out: torch.Tensor, c: int, declared: int, bbox_dims: torch.Tensor) -> list[float]:
    """The line vector of command ``c`` at GRU output ``out`` (H,), cuboid ids among ``declared`` slots."""
    func = lay.commands[c]
    row = [0.0] * lay.width
    row[c] = 1.0
    cmd_oh = torch.zeros(len(lay.commands), dtype=out.dtype, device=out.device)
    cmd_oh[c] = 1.0
    used = {t: lay.masks[t][c].tolist() for t in lay.masks}
    cube_oh = out.new_zeros(lay.counts[CUBE] * GROUPS[CUBE])
    if lay.counts[CUBE]:
        logits = dec.type_nets["cube_net"](torch.cat([out, cmd_oh])).reshape(lay.counts[CUBE], NUM_SLOTS)
        for k, u in enumerate(used[CUBE]):
            if u:
                j = int(logits[k, :declared].argmax())
                row[lay.slices[CUBE].start + k * NUM_SLOTS + j] = 1.0
                cube_oh[k * NUM_SLOTS + j] = 1.0
    for t in ("float", "face", "axis", "bool"):
        if not lay.counts[t] or not any(used[t]):
            continue
        extra = [out, cmd_oh] + ([cube_oh] if t != BOOL else []) + ([bbox_dims] if t == FLOAT else [])
        y = dec.type_nets[f"{t}_net"](torch.cat(extra))
        if t in ("face", "axis"):
            y = one_hot_argmax(y, lay.counts[t])
        elif t == BOOL:
            y = (y > 0).to(y.dtype)
        vals = y.tolist()
        s = lay.slices[t]
        w = GROUPS[t]
        for k, u in enumerate(used[t]):
            if u:
                row[s.start + k * w: s.start + (k + 1) * w] = vals[k * w: (k + 1) * w]
    _clean(func, row, lay, float_ranges(lay.library, func))
    return row


def _expands(lay: LineLayout, rows: list[list[float]], n_created: int) -> tuple[bool, object]:
    """Whether a block's rows expand; ``(ok, expansion or None)``."""
    node = MacroNode(torch.tensor(rows, dtype=torch.float64), (None,) * n_created, "Program_0", lay.slices[FLOAT].start)
    h = tree_to_macro_program(node, lay)
    try:
        return True, lay.library.expand(h.programs[0])
    except MacroError:
        return False, None


def _decode_node(vae: MacroVAE, latent: torch.Tensor, bbox: list[float], depth: int, reject: bool, budget: list):
    """One block: ``(rows, created child latents or None per slot, skipped)``."""
    dec, lay = vae.decoder, vae.layout
    fs = lay.slices[FLOAT].start
    bbox_dims = torch.tensor(bbox, dtype=latent.dtype, device=latent.device)
    first = [0.0] * lay.width
    first[lay.command_index("Cuboid")] = 1.0
    first[fs: fs + 3] = bbox
    if lay.counts[BOOL]:
        first[lay.slices[BOOL].start] = 1.0
    rows = [first]
    h = latent.reshape(1, 1, -1)
    _, h = dec.run(lay.command_vector("start", latent.dtype, latent.device)[None], h, bbox_dims, depth)
    inp = first
    kids: list = [None]  # per created slot: the child's latent, or None (bbox: never)
    skipped = 0
    while len(rows) < MAX_BLOCK_LINES:
        out, h = dec.run(torch.tensor(inp, dtype=latent.dtype, device=latent.device)[None], h, bbox_dims, depth)
        out = out[0]
        declared = len(kids)
        logits = dec.cmd_net(out).tolist()
        allowed = [LineLayout.STOP] if declared > 1 else []
        for c in range(2, len(lay.commands)):
            f = lay.library[lay.commands[c]]
            if declared + f.n_cuboids <= NUM_SLOTS and (declared > 1 or not f.info.needs_subject):
                allowed.append(c)
        order = sorted(allowed, key=lambda c: -logits[c])
        chosen = None
        for attempt, c in enumerate(order):
            if c == LineLayout.STOP:
                break
            row = _propose(dec, lay, out, c, declared, bbox_dims)
            ok, _ = _expands(lay, rows + [row], declared + lay.library[lay.commands[c]].n_cuboids)
            if ok:
                chosen, chosen_c = row, c
                break
            if reject:
                raise InvalidSample(f"{lay.commands[c]} does not expand", step=len(rows))
            skipped += 1
        if chosen is None:
            break
        rows.append(chosen)
        n = lay.library[lay.commands[chosen_c]].n_cuboids
        if n:
            pos = torch.arange(n, device=out.device)
            nxt, leaf = dec.child_heads(out[None].expand(n, -1), latent[None].expand(n, -1), pos)
            for k in range(n):
                grow = float(leaf[k]) < 0 and depth + 1 < MAX_DEPTH and budget[0] < MAX_NODES
                if grow:
                    budget[0] += 1
                kids.append(nxt[k] if grow else None)
        inp = chosen
    return rows, kids, skipped


def _execute(h: MacroHierarchy, lay: LineLayout) -> tuple[Program, ExecutedShape]:
    c = compile_hierarchy(h, lay.library)
    shape = ExecutionPlan([c.program]).run()[0]
    if shape.corners.shape[0] == 0:
        raise ValueError("no leaf cuboid")
    return c.program, shape


@torch.no_grad()
def decode_macro_latent(vae: MacroVAE, z: torch.Tensor, *, reject: bool = False, decimals: int = 3) -> MacroDecoded:
    """Decode latent ``z`` (H,) into a macro program (see the module docstring).

    Raises:
        InvalidSample: with ``reject``, a call that does not expand, or a program that does not execute.
    """
    H = vae.decoder.hidden_dim
    z = torch.as_tensor(z, dtype=next(vae.parameters()).dtype)
    if z.shape != (H,) or not bool(torch.isfinite(z).all()):
        raise ValueError(f"`z` must be a finite ({H},) tensor, got shape {tuple(z.shape)}")
    lay = vae.layout
    was = vae.training
    vae.eval()
    try:
        bbox = [max(float(v), MIN_DIM) for v in vae.decoder.bbox(z).tolist()]
        budget = [1]
        skipped = 0
        built: dict[int, tuple] = {}
        queue = [(0, z, bbox, 0)]
        order = []
        while queue:
            key, latent, bb, depth = queue.pop(0)
            rows, kids, s = _decode_node(vae, latent, bb, depth, reject, budget)
            skipped += s
            order.append(key)
            dims = None
            kid_keys = []
            for j, k in enumerate(kids):
                if k is None:
                    kid_keys.append(None)
                    continue
                if dims is None:
                    _, exp = _expands(lay, rows, len(kids))
                    dims = [(ln.l, ln.h, ln.w) for ln in exp.lines[1:] if isinstance(ln, CuboidLine)]
                ck = len(built) + len(queue) + 1
                kid_keys.append(ck)
                queue.append((ck, k, [max(float(v), MIN_DIM) for v in dims[j - 1]], depth + 1))
            built[key] = (rows, kid_keys)

        def node(key: int) -> MacroNode:
            rows, kid_keys = built[key]
            kids = tuple(None if k is None else node(k) for k in kid_keys)
            return MacroNode(torch.tensor(rows, dtype=torch.float64), kids, f"Program_{key}", lay.slices[FLOAT].start)

        h = tree_to_macro_program(node(0), lay, decimals=decimals)
        try:
            program, shape = _execute(h, lay)
        except (MacroError, ValueError) as e:
            if reject:
                raise InvalidSample(f"the decoded program does not execute: {e}") from None
            raise
        return MacroDecoded(h, to_text(h), program, shape, skipped)
    finally:
        vae.train(was)


def sample_macro(vae: MacroVAE, n: int, seed: int = 0, max_tries: int = 10, decimals: int = 3) -> list[MacroDecoded]:
    """``n`` programs from latents drawn from N(0, I) (seeded), with rejection: a refused sample draws a new
    latent, up to ``max_tries`` times, then its last latent is decoded without rejection."""
    n = _check_int("n", n, 0, MAX_SAMPLES)
    max_tries = _check_int("max_tries", max_tries, 1, MAX_TRIES)
    seed = _check_int("seed", seed, -(2 ** 63))
    if seed >= 2 ** 64:
        raise ValueError(f"seed must be below 2**64, got {seed}")
    gen = torch.Generator().manual_seed(seed)
    H = vae.decoder.hidden_dim
    out = []
    for _ in range(int(n)):
        for tries in range(1, int(max_tries) + 1):
            z = torch.randn(H, generator=gen)
            try:
                d = decode_macro_latent(vae, z, reject=True, decimals=decimals)
                d.tries = tries
                break
            except InvalidSample:
                d = None
        if d is None:
            d = decode_macro_latent(vae, z, reject=False, decimals=decimals)
            d.tries = int(max_tries) + 1
        out.append(d)
    return out


@torch.no_grad()
def encode_macro(vae: MacroVAE, h: MacroHierarchy, file: str = "<program>") -> torch.Tensor:
    """The latent (mu, (H,)) of a hierarchical macro program calling the model's library."""
    tree = macro_program_to_tree(h, vae.layout, file, dtype=next(vae.parameters()).dtype)
    was = vae.training
    vae.eval()
    try:
        return vae.encode(tree)[1]
    finally:
        vae.train(was)


def decode_macro(vae: MacroVAE, z: torch.Tensor, decimals: int = 3) -> MacroDecoded:
    """:func:`decode_macro_latent` without rejection (reconstruction, interpolation)."""
    return decode_macro_latent(vae, z, reject=False, decimals=decimals)

