"""Decoding CSGNet / CSGNetStack: greedy, sampling and batched beam search (spec section (g)).

All decoders work on a batch of targets at once. For CSGNetStack the predicted prefix of every row
(every image × beam) is executed incrementally by one :class:`~csgnet.renderer.StackMachine`, and the
top-K stack maps it holds are the encoder's extra input at the next step, as in the paper: an invalid
prefix leaves that row's stack all zeros from then on; after ``$`` the row's stack is frozen.

Two behaviours (``mode``):

* ``"improved"`` (default): a row that emitted ``$`` is finished; it is no longer extended and keeps
  its score, so finished and unfinished hypotheses compete by log-probability.
* ``"reference"``: the published beam search: every row decodes ``max_len`` steps, ``$`` is fed back as
  input and the scores of the tokens after it keep accumulating; programs are cut at the first ``$``.

``constrained=True`` (off by default, so that decoding is the paper's unless asked) masks the tokens
that would make the program impossible to finish validly within ``max_len`` tokens (an operator with
fewer than two shapes on the stack, ``$`` unless exactly one shape is on it, a primitive when the
remaining steps cannot reduce the stack any more), so every decoded program is valid.

``precision`` (:data:`PRECISIONS`) is the arithmetic of the model's layers while decoding: ``"float32"`` (the
default of these functions, and the protocol of every table), ``"bfloat16"`` (the encoder and the output
layers under ``torch.autocast`` with bfloat16; the GRU state, the log-softmax and every score stay float32,
and the stack machine renders as before) or ``"auto"`` (:func:`resolve_precision`: bfloat16 on a CPU that
computes it natively, float32 elsewhere).

``views`` (:data:`VIEWS`, 3D only; 1, the paper's decoding, by default) decodes one program from several mirror
images of each target at once: the model reads the target flipped along some axes, its log-probabilities are
mapped back through the same flip of every primitive's centre, and each step takes the mean log-probability over
the views (a product of experts). Greedy and beam search then run on that mean exactly as on one model's, so
``beam=1`` with ``views=8`` is still one arg-max decode; the model's work grows with the views (the wall time less,
since each beam is rendered and scored once: Table 5 in docs/csgnet.md). A decoded program's ``logprob`` is then
that mean summed over its steps, not one model's log-probability.
"""
from __future__ import annotations

import contextlib
import numbers
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from .lang import Program, completable
from .renderer import StackMachine, primitive_cache, unpack
from .vocab import codes, vocabulary

__all__ = ["Decoded", "greedy", "beam_search", "decode", "sample", "Sampled", "MAX_BEAM", "check_beam",
           "PRECISIONS", "AUTO_BF16_DIMS", "native_bf16", "resolve_precision", "VIEWS", "check_views",
           "flip_view", "mirror"]

_MODES = ("improved", "reference")
MAX_BEAM = 256
"""Widest beam accepted: decoding costs grow with ``N × width`` rows (the paper uses at most 40)."""
PRECISIONS = ("auto", "float32", "bfloat16")
"""The ``precision`` choices of the decoders: ``"auto"`` (:func:`resolve_precision`), ``"float32"``,
``"bfloat16"`` (the model's layers under bfloat16 autocast; scores stay float32)."""
AUTO_BF16_DIMS = (2,)
"""The models ``"auto"`` decodes in bfloat16: the 2D ones (CSGNetStack about 1.9 times faster on a CPU with
AMX, the same accuracy); the 3D lite CSGNet gains nothing and stays float32 (docs/csgnet.md)."""
_NATIVE_BF16_CHECKS = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
_FLIPS = ((), (0,), (1,), (2,), (0, 1), (0, 2), (1, 2), (0, 1, 2))
VIEWS = {1: (((), False),), 2: (((), False), ((0,), False)), 4: tuple((a, False) for a in ((), (0,), (2,), (0, 2))),
         8: tuple((a, False) for a in _FLIPS), 16: tuple((a, s) for s in (False, True) for a in _FLIPS)}
"""The ``views`` choices: how many mirror images of a 3D target one decode reads, each ``(axes, swap)``: flipped
along ``axes`` (0, 1, 2 = a primitive's x, y, z), then with x and y exchanged if ``swap`` (every 3D primitive is
symmetric under both: the cylinders stand along z). The first is always the target itself."""


def native_bf16() -> bool:
    """True when this CPU computes bfloat16 natively (AVX512-BF16 or AMX tiles, as torch reports them);
    False when it does not, or when this torch has no such check."""
    for name in _NATIVE_BF16_CHECKS:
        check = getattr(torch.cpu, name, None)
        try:
            if check is not None and bool(check()):
                return True
        except (RuntimeError, OSError):  # a torch build that cannot answer: count it as no
            continue
    return False


def resolve_precision(precision: str, device="cpu", dim: int = 2) -> str:
    """``"float32"`` or ``"bfloat16"``: the arithmetic ``precision`` (:data:`PRECISIONS`) means on ``device``
    for a ``dim``-D model. ``"auto"`` is bfloat16 for the models of :data:`AUTO_BF16_DIMS` on a CPU with native
    bfloat16 (:func:`native_bf16`) and float32 elsewhere, GPUs included.

    Raises:
        ValueError: ``precision`` is not one of :data:`PRECISIONS` (the message names it and them).
    """
    if not isinstance(precision, str) or precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "auto":
        fast = dim in AUTO_BF16_DIMS and torch.device(device).type == "cpu" and native_bf16()
        return "bfloat16" if fast else "float32"
    return precision


@dataclass
class Decoded:
    """Decoded programs of ``N`` targets, ``k`` per target, best first.

    Attributes:
        tokens: ``(N, k, T)`` int64 token indices, ``$``-padded after each program.
        lengths: ``(N, k)`` number of program tokens (before the first ``$``).
        logprob: ``(N, k)`` the score the hypotheses were ranked by (sum of log-probabilities; ``-inf``
            for a beam slot that never held a hypothesis).
        valid: ``(N, k)`` bool, the program is valid (exactly one shape left, no underflow).
        dim: 2 or 3.
    """

    tokens: torch.Tensor
    lengths: torch.Tensor
    logprob: torch.Tensor
    valid: torch.Tensor
    dim: int

    @property
    def k(self) -> int:
        return self.tokens.shape[1]

    def text(self, i: int, j: int = 0) -> str:
        """Text of hypothesis ``j`` of target ``i`` (what the tokens say, valid or not)."""
        n = int(self.lengths[i, j])
        return vocabulary(self.dim).text(self.tokens[i, j, :n].tolist())

    def texts(self) -> list[list[str]]:
        return [[self.text(i, j) for j in range(self.k)] for i in range(self.tokens.shape[0])]

    def program(self, i: int, j: int = 0) -> Program:
        n = int(self.lengths[i, j])
        return vocabulary(self.dim).decode(self.tokens[i, j, :n].tolist())

    def flat_tokens(self) -> torch.Tensor:
        """``(N * k, T)`` tokens with everything from the first ``$`` on set to ``$``."""
        return self.tokens.reshape(-1, self.tokens.shape[-1])


def check_views(views, dim: int) -> int:
    """``views`` as a key of :data:`VIEWS`; more than one only in 3D. Otherwise a ``ValueError`` naming it."""
    if isinstance(views, bool) or not isinstance(views, numbers.Integral) or int(views) not in VIEWS:
        raise ValueError(f"views must be one of {sorted(VIEWS)}, got {views!r}")
    if views > 1 and dim != 3:
        raise ValueError(f"views > 1 is for 3D models (the 3D primitives are mirror-symmetric); this model is {dim}D")
    return int(views)


def flip_view(targets: torch.Tensor, axes: tuple[int, ...], swap: bool = False) -> torch.Tensor:
    """``(N, 64, 64, 64)`` targets mirrored along the volume ``axes`` (0, 1, 2 = a primitive's x, y, z) about the
    centre of the primitives' coordinate grid, then with x and y exchanged if ``swap``: voxel ``i`` holds the
    point ``i``, so centre ``c`` maps to ``64 - c`` and voxel ``i`` to ``64 - i``; plane 0 takes the (empty)
    point 64."""
    out = targets
    if axes:
        dims = [a + 1 for a in axes]
        out = torch.roll(torch.flip(targets, dims), [1] * len(dims), dims)
        for d in dims:
            out.select(d, 0).zero_()
    return out.transpose(1, 2).contiguous() if swap else out


_MIRRORS: dict[tuple[int, ...], tuple[torch.Tensor, torch.Tensor]] = {}


def mirror(axes: tuple[int, ...], swap: bool = False, dim: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    """``(index, missing)``, both ``(V,)``: ``index[t]`` is the token that draws token ``t``'s primitive as
    :func:`flip_view` maps the volume (operators and ``$`` map to themselves). A primitive whose image is not
    in the vocabulary (some cubes touching the grid's upper edge: the grid is not symmetric) has ``missing[t]``
    set and maps to itself."""
    key = (dim, swap, *axes)
    if key not in _MIRRORS:
        v = vocabulary(dim)
        where = {t: i for i, t in enumerate(v.tokens)}
        index, missing = list(range(len(v.tokens))), [False] * len(v.tokens)
        for i, text in enumerate(v.tokens[: v.num_primitives]):
            head, args = text[:-1].split("(")
            nums = [int(a) for a in args.split(",")]
            for a in axes:
                nums[a] = 64 - nums[a]
            if swap:
                nums[0], nums[1] = nums[1], nums[0]
            j = where.get(f"{head}({','.join(map(str, nums))})")
            if j is None:
                missing[i] = True
            else:
                index[i] = j
        _MIRRORS[key] = (torch.tensor(index), torch.tensor(missing))
    return _MIRRORS[key]


class _Views:
    """The mirror maps of ``views`` views, ``(G, V)`` each, and the combination of their log-probabilities.

    A view whose mirror image of a chosen primitive is missing from the vocabulary reads that primitive as
    itself, which draws something else in its frame; from that step on it no longer votes for that row
    (``dropped``, reordered with the rows' parents)."""

    def __init__(self, views: int, dim: int, device):
        self.views = VIEWS[views]
        maps = [mirror(a, s, dim) for a, s in self.views]
        self.index = torch.stack([m[0] for m in maps]).to(device)
        self.missing = torch.stack([m[1] for m in maps]).to(device)
        self.G = len(self.views)
        self.dropped: torch.Tensor | None = None  # (G, R): view g no longer votes for row r

    def targets(self, targets: torch.Tensor) -> torch.Tensor:
        """``(G·N, ...)``: every view of every target, view-major."""
        return targets if self.G == 1 else torch.cat([flip_view(targets, a, s) for a, s in self.views])

    def combine(self, logp: torch.Tensor) -> torch.Tensor:
        """``(G·R, V)`` per-view log-probabilities -> ``(R, V)`` their mean in the target's own frame, over the
        views that still vote for the row and have the token's mirror image."""
        if self.G == 1:
            return logp
        per = logp.view(self.G, -1, logp.shape[1])
        if self.dropped is None:
            self.dropped = torch.zeros((self.G, per.shape[1]), dtype=torch.bool, device=logp.device)
        canon = torch.stack([per[g].index_select(1, self.index[g]) for g in range(self.G)])
        canon = canon.masked_fill(self.missing[:, None, :] | self.dropped[:, :, None], float("nan"))
        return canon.nanmean(0)  # view 0 (the target itself) misses nothing and is never dropped

    def tokens(self, tok: torch.Tensor) -> torch.Tensor:
        """``(R,)`` tokens in the target's frame -> ``(G·R,)`` each view's own (a view without the token's image
        gets the token itself and stops voting for the row)."""
        if self.G == 1:
            return tok
        self.dropped = self.dropped | self.missing[:, tok]
        return torch.cat([self.index[g].index_select(0, tok) for g in range(self.G)])

    def rows(self, parent: torch.Tensor, R: int) -> torch.Tensor:
        """``(R,)`` parents of the target's rows -> ``(G·R,)`` of every view's rows."""
        if self.G == 1:
            return parent
        self.dropped = self.dropped.index_select(1, parent)
        return torch.cat([parent + g * R for g in range(self.G)])


def _token_classes(dim: int, device) -> tuple[torch.Tensor, torch.Tensor, int]:
    kinds = primitive_cache(dim, device).kinds
    c = codes()
    return c.is_draw(kinds), c.is_op(kinds), len(vocabulary(dim)) - 1


class _Rows:
    """Decoding state of ``B`` rows (targets repeated per beam): GRU state, previous token, stack."""

    def __init__(self, model, targets: torch.Tensor, repeat: int, max_len: int, skip_done: bool = False,
                 precision: str = "float32"):
        cfg = model.config
        self.bf16 = resolve_precision(precision, targets.device, cfg.dim) == "bfloat16"
        self.repeat, self.skip_done, self.steps = repeat, skip_done, 0
        self.unique_targets = targets
        self.model, self.dim, self.max_len = model, cfg.dim, max_len
        self.device = targets.device
        self.is_draw, self.is_op, self.stop = _token_classes(cfg.dim, self.device)
        self.kinds = primitive_cache(cfg.dim, self.device).kinds
        # only CSGNetStack reads every row's target again (at each step); CSGNet encodes each target once
        self.targets = targets.repeat_interleave(repeat, 0) if repeat > 1 and cfg.stack else targets
        B = targets.shape[0] * repeat
        self.B = B
        if cfg.stack:
            self.machine = StackMachine(B, cfg.dim, max(max_len, cfg.stack_k), self.device)
            self.projected = None
        else:
            # the features are fixed per target: their share of the GRU gates is computed once, and a
            # beam's parent always belongs to the same target, so reordering never touches it
            self.machine = None
            with self._layers():
                f = model.project_features(model.encode(targets))
            self.projected = f.repeat_interleave(repeat, 0) if repeat > 1 else f
            self.w_tok = model.token_input_weight()
        self.h = None
        self.prev = torch.full((B,), model.start, dtype=torch.long, device=self.device)
        self.depth = torch.zeros(B, dtype=torch.long, device=self.device)
        self.broken = torch.zeros(B, dtype=torch.bool, device=self.device)
        self.done = torch.zeros(B, dtype=torch.bool, device=self.device)
        self.length = torch.zeros(B, dtype=torch.long, device=self.device)
        self.history: list[torch.Tensor] = []
        self.parents: list[torch.Tensor | None] = []  # parents[t]: rows after step t -> rows before it
        self._parent: torch.Tensor | None = None

    def _layers(self):
        """The context of the model's layers: bfloat16 autocast with ``precision="bfloat16"``."""
        if not self.bf16:
            return contextlib.nullcontext()  # float32: whatever autocast the caller runs under stays in force
        return torch.autocast(self.device.type, dtype=torch.bfloat16)

    def scope(self):
        """The context of a whole decoding loop. With bfloat16, a disabled autocast around the steps' enabled
        ones: autocast keeps its bfloat16 copies of the weights until the outermost of its contexts ends, so
        they are cast once per decode instead of once per step; what runs between the steps (the stack
        machine, the beam bookkeeping) stays outside autocast."""
        if not self.bf16:
            return contextlib.nullcontext()
        return torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=False)

    def logits(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(logits (B, V), new GRU state (B, H))`` of the current rows, both float32."""
        with self._layers():
            if self.machine is not None:
                logits, h = self.model.step(self._stack_features(), self.prev, self.h)
            else:
                logits, h = self.model.step_projected(self.projected, self.prev, self.h, self.w_tok)
        return logits.float(), h.float()  # the state carried between steps stays float32 (a no-op in float32)

    def _stack_features(self) -> torch.Tensor:
        """CSGNetStack's encoder features of every row, computed only where they can differ: at the first
        step the rows of a target are equal (encoded once per target), and with ``skip_done`` a finished
        row, whose next token is forced to ``$``, gets zeros instead."""
        step, self.steps = self.steps, self.steps + 1
        k = self.model.config.stack_k
        if step == 0 and self.repeat > 1:
            first = self.machine.top(k)[:: self.repeat]
            f = self.model.encode(self.unique_targets, unpack(first, self.dim))
            return f.repeat_interleave(self.repeat, 0)
        if self.skip_done and bool(self.done.any()):
            live = torch.nonzero(~self.done).flatten()  # not empty: decoding stops when every row is done
            stack = unpack(self.machine.top(k).index_select(0, live), self.dim)
            f = self.model.encode(self.targets.index_select(0, live), stack)
            return f.new_zeros((self.B, f.shape[1])).index_copy(0, live, f)
        return self.model.encode(self.targets, unpack(self.machine.top(k), self.dim))

    def mask(self, logp: torch.Tensor, t: int, constrained: bool, finish: bool) -> torch.Tensor:
        """Apply the validity constraint and the finished-row rule to log-probabilities ``(B, V)``."""
        neg = torch.tensor(float("-inf"), dtype=logp.dtype, device=logp.device)
        if constrained:
            draw_ok, op_ok, stop_ok = completable(self.depth[:, None], self.max_len - t)
            ok = torch.where(self.is_draw[None], draw_ok, torch.where(self.is_op[None], op_ok, stop_ok))
            logp = torch.where(ok, logp, neg)
        if finish and bool(self.done.any()):
            rows = torch.nonzero(self.done).flatten()
            only_stop = torch.full((rows.numel(), logp.shape[1]), float("-inf"), dtype=logp.dtype, device=logp.device)
            only_stop[:, self.stop] = 0.0
            logp = logp.index_copy(0, rows, only_stop)
        return logp

    def reorder(self, parent: torch.Tensor) -> None:
        """Row ``i`` continues row ``parent[i]`` (always a row of the same target)."""
        self.h = self.h_new.index_select(0, parent)
        for name in ("prev", "depth", "broken", "done", "length"):
            setattr(self, name, getattr(self, name).index_select(0, parent))
        if self.machine is not None:
            self.machine.reorder(parent)
        self._parent = parent

    def advance(self, tokens: torch.Tensor) -> None:
        """Append one token per row (rows already finished ignore it)."""
        kinds = self.kinds[tokens]
        live = ~self.done
        stop = tokens == self.stop
        self.length += (live & ~stop).long()
        draw, op = self.is_draw[tokens] & live, self.is_op[tokens] & live
        self.broken |= op & (self.depth < 2)
        self.depth = self.depth + draw.long() - (op & ~self.broken).long()
        newly = live & stop
        if self.machine is not None:
            self.machine.step(torch.where(live, kinds, torch.full_like(kinds, codes().stop)), token_ids=tokens)
        self.done |= newly
        self.history.append(torch.where(live, tokens, torch.full_like(tokens, self.stop)))
        self.parents.append(self._parent)
        self._parent = None
        self.prev = tokens

    @property
    def valid(self) -> torch.Tensor:
        return ~self.broken & (self.depth == 1)

    def tokens(self) -> torch.Tensor:
        """``(B, T)`` the token sequence of every current row, followed back through the parents."""
        if not self.history:
            return torch.empty((self.B, 0), dtype=torch.long, device=self.device)
        out = []
        row = torch.arange(self.B, device=self.device)
        for t in range(len(self.history) - 1, -1, -1):
            out.append(self.history[t].index_select(0, row))
            if self.parents[t] is not None:
                row = self.parents[t].index_select(0, row)
        return torch.stack(out[::-1], dim=1)


def check_beam(width, name: str = "beam") -> int:
    """``width`` as an int in ``[1, MAX_BEAM]``; otherwise a ``ValueError`` naming ``name``."""
    if isinstance(width, bool) or not isinstance(width, numbers.Integral) or not 1 <= width <= MAX_BEAM:
        raise ValueError(f"{name} must be an integer from 1 to {MAX_BEAM}, got {width!r}")
    return int(width)


def _check(model, targets, max_len, mode, precision="float32"):
    if mode not in _MODES:
        raise ValueError(f"mode must be one of {_MODES}, got {mode!r}")
    resolve_precision(precision)  # a bad name is refused before any work
    targets = torch.as_tensor(targets)
    want = (64,) * model.config.dim
    if targets.dim() == model.config.dim:
        targets = targets[None]
    if tuple(targets.shape[1:]) != want:
        raise ValueError(f"targets must be (N, {', '.join(map(str, want))}), got {tuple(targets.shape)}")
    dev = next(model.parameters()).device
    return targets.to(dev).bool(), int(max_len or model.config.max_len)


@torch.no_grad()
def beam_search(model, targets, width: int = 10, max_len: int | None = None, mode: str = "improved",
                constrained: bool = False, precision: str = "float32", views: int = 1) -> Decoded:
    """Batched beam search: ``N`` targets × ``width`` beams decoded together.

    Hypotheses are ranked by the sum of token log-probabilities (the reference multiplies
    probabilities, the same order). Step 1 expands only the START row of each target. ``precision``:
    :data:`PRECISIONS` (the scores are float32 in every one); ``views``: :data:`VIEWS` (the log-probabilities
    are the views' mean).

    Returns:
        :class:`Decoded` with ``k = width`` hypotheses per target, most likely first.
    """
    targets, T = _check(model, targets, max_len, mode, precision)
    N, w = targets.shape[0], check_beam(width, "width")
    vw = _Views(check_views(views, model.config.dim), model.config.dim, targets.device)
    rows = _Rows(model, vw.targets(targets), w, T, skip_done=mode == "improved", precision=precision)
    V = model.config.vocab_size
    score = torch.full((N, w), float("-inf"), device=targets.device)
    score[:, 0] = 0.0
    offsets = (torch.arange(N, device=targets.device) * w)[:, None]
    finish = mode == "improved"
    with rows.scope():
        for t in range(T):
            logits, rows.h_new = rows.logits()
            logp = vw.combine(rows.mask(F.log_softmax(logits.float(), dim=-1), t, constrained, finish))
            cand = (score.reshape(-1, 1) + logp).view(N, w * V)
            score, idx = cand.topk(w, dim=1)
            parent = (idx // V + offsets).flatten()
            tok = (idx % V).flatten()
            rows.reorder(vw.rows(parent, N * w))
            rows.advance(vw.tokens(tok))
            if finish and bool(rows.done.all()):
                break
    R = N * w  # the target's own rows come first (view 0)
    tokens = rows.tokens()[:R].view(N, w, -1)
    return Decoded(tokens, rows.length[:R].view(N, w), score, rows.valid[:R].view(N, w) & torch.isfinite(score),
                   model.config.dim)


@torch.no_grad()
def greedy(model, targets, max_len: int | None = None, mode: str = "improved", constrained: bool = False,
           precision: str = "float32", views: int = 1) -> Decoded:
    """Arg-max decoding (what the reference validates with). ``k = 1``; ``precision``: :data:`PRECISIONS`;
    ``views``: :data:`VIEWS` (the arg-max of the views' mean log-probability)."""
    targets, T = _check(model, targets, max_len, mode, precision)
    N = targets.shape[0]
    vw = _Views(check_views(views, model.config.dim), model.config.dim, targets.device)
    rows = _Rows(model, vw.targets(targets), 1, T, skip_done=mode == "improved", precision=precision)
    score = torch.zeros(N, device=targets.device)
    finish = mode == "improved"
    with rows.scope():
        for t in range(T):
            logits, rows.h = rows.logits()
            logp = vw.combine(rows.mask(F.log_softmax(logits.float(), dim=-1), t, constrained, finish))
            lp, tok = logp.max(dim=1)
            score = score + lp
            rows.advance(vw.tokens(tok))
            if finish and bool(rows.done.all()):
                break
    return Decoded(rows.tokens()[:N, None], rows.length[:N, None], score[:, None], rows.valid[:N, None],
                   model.config.dim)


@dataclass
class Sampled:
    """Programs sampled for policy-gradient training.

    Attributes:
        tokens: ``(N, T)`` sampled tokens (``$`` after the end).
        lengths: ``(N,)`` program tokens before the first ``$``.
        log_probs: ``(N, T)`` log-probability of each sampled token, differentiable; zero after the
            counted steps.
        counted: ``(N, T)`` bool, the steps whose log-probabilities count in the REINFORCE loss: the
            program's tokens and its ``$`` (all ``T`` steps if no ``$`` was sampled).
        entropy: ``(N, T)`` policy entropy at each counted step (zero elsewhere).
        valid: ``(N,)`` bool.
        dim: 2 or 3.
    """

    tokens: torch.Tensor
    lengths: torch.Tensor
    log_probs: torch.Tensor
    counted: torch.Tensor
    entropy: torch.Tensor
    valid: torch.Tensor
    dim: int

    def texts(self) -> list[str]:
        vocab = vocabulary(self.dim)
        return [vocab.text(self.tokens[i, : int(n)].tolist()) for i, n in enumerate(self.lengths)]


def sample(model, targets, max_len: int | None = None, generator: torch.Generator | None = None,
           constrained: bool = False, temperature: float = 1.0) -> Sampled:
    """Sample one program per target from the model's softmax, keeping the graph for REINFORCE.

    Runs in whatever mode the model is in (the reference samples in train mode, dropout active) and
    with gradients if they are enabled. The stack of CSGNetStack comes from executing the sampled prefix.
    """
    targets, T = _check(model, targets, max_len, "improved")
    rows = _Rows(model, targets, 1, T)
    lps, ents, counted = [], [], []
    for t in range(T):
        logits, rows.h = rows.logits()
        logp = rows.mask(F.log_softmax(logits.float() / temperature, dim=-1), t, constrained, finish=False)
        probs = logp.exp()
        tok = torch.multinomial(probs.detach(), 1, generator=generator).squeeze(1)
        live = ~rows.done
        counted.append(live)
        lps.append(torch.where(live, logp.gather(1, tok[:, None]).squeeze(1), torch.zeros((), device=logp.device)))
        ent = -(probs * torch.where(probs > 0, logp, torch.zeros_like(logp))).sum(1)
        ents.append(torch.where(live, ent, torch.zeros_like(ent)))
        rows.advance(tok)
        if bool(rows.done.all()):
            break
    return Sampled(rows.tokens(), rows.length, torch.stack(lps, 1), torch.stack(counted, 1),
                   torch.stack(ents, 1), rows.valid, model.config.dim)


def decode(model, targets, beam: int = 1, **kwargs) -> Decoded:
    """Greedy for ``beam == 1``, else :func:`beam_search`; ``beam`` is 1 to :data:`MAX_BEAM`; the keywords
    (``max_len``, ``mode``, ``constrained``, ``precision``, ``views``) are theirs."""
    beam = check_beam(beam)
    return greedy(model, targets, **kwargs) if beam <= 1 else beam_search(model, targets, beam, **kwargs)

