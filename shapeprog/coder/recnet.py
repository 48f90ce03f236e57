"""ShapeCoder's recognition network (mode ``nocontext``): a scene of primitives in, an expression of the
library out, its floats as references to the scene's values. Plain PyTorch; the training loop is
:mod:`shapeprog.coder.train`.

Scenes and targets as tokens: :mod:`shapeprog.coder.vocab`.

* **Model** (:class:`RecognitionNet`). Conditioning token i: [a learned 128-d vector of position i ‖
  Embedding(rank) + Embedding(field), 16-d]. Sequence token t: [Embedding(token), 128-d ‖ the rank
  embedding of the referenced value for ``<var>`` tokens, else 0] + a learned positional embedding
  (144-d). Two post-LayerNorm blocks (8-head attention + residual, LayerNorm; 144→144→144 feed-forward
  with leaky-ReLU 0.2 + residual, LayerNorm; dropout 0.5): the conditioning tokens attend to each other
  (padding masked), the sequence tokens to the conditioning tokens and causally to the sequence. Heads:
  a token MLP over the vocabulary and a variable MLP with one logit per rank (144).
* **Sampling** (:func:`sample`): batched, prefix order, with type masks (a slot of type Shape takes a
  shape function, Float a ``<var>``, an operator or a constant, ...); a float sub-expression has at most
  :data:`MAX_FLOAT_TERMS` terms and contains a ``<var>``; the whole expression fits in
  :data:`MAX_TOKENS`. Row 0 of a batch is the greedy (arg-max) expression when asked. Decoding is
  incremental (:meth:`RecognitionNet.step`): the keys and values of the conditioning tokens are computed
  once per scene and those of the sequence once per token.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from shapeio.weights import read_weights, write_weights

from .lang import Library, Type
from .vocab import MAX_FLOAT_TERMS, MAX_TOKENS, Vocab, decode_tokens, encode_scene

__all__ = [
    "FORMAT",
    "VERSION",
    "NetConfig",
    "RecognitionNet",
    "load_checkpoint",
    "sample",
    "save_checkpoint",
]

#: The weights-file family of a recognition network and its version.
FORMAT, VERSION = "shapeprog-coder-recnet", 1


# ----------------------------------------------------------------------------- the model


@dataclass(frozen=True)
class NetConfig:
    """Sizes of a :class:`RecognitionNet` (the paper's by default).

    Attributes:
        vocab: tokens of the vocabulary. fields: slots per primitive (9 / 4). max_prims: 16 / 12.
        token_dim: 128. value_dim: 16. heads: 8. layers: 2. dropout: 0.5. max_tokens: 32.
    """

    vocab: int
    fields: int = 9
    max_prims: int = 16
    token_dim: int = 128
    value_dim: int = 16
    heads: int = 8
    layers: int = 2
    dropout: float = 0.5
    max_tokens: int = MAX_TOKENS

    @property
    def width(self) -> int:
        return self.token_dim + self.value_dim

    @property
    def inputs(self) -> int:
        return self.fields * self.max_prims


class _Block(nn.Module):
    """Post-LayerNorm attention block; conditioning and sequence parts are computed apart so that the
    conditioning part can be computed once per scene when sampling."""

    def __init__(self, width: int, heads: int, dropout: float):
        super().__init__()
        if width % heads:
            raise ValueError(f"width {width} is not a multiple of heads {heads}")
        self.heads = heads
        self.qkv = nn.Linear(width, 3 * width)
        self.out = nn.Linear(width, width)
        self.ln1, self.ln2 = nn.LayerNorm(width), nn.LayerNorm(width)
        self.ff = nn.Sequential(nn.Linear(width, width), nn.LeakyReLU(0.2), nn.Linear(width, width))
        self.drop = nn.Dropout(dropout)

    def _split(self, x):
        b, n, w = x.shape
        return x.view(b, n, self.heads, w // self.heads).transpose(1, 2)

    def _attend(self, x, keys, mask):
        q = self._split(F.linear(x, self.qkv.weight[: x.shape[-1]], self.qkv.bias[: x.shape[-1]]))
        kv = F.linear(keys, self.qkv.weight[x.shape[-1]:], self.qkv.bias[x.shape[-1]:])
        k, v = kv.chunk(2, -1)
        k, v = self._split(k), self._split(v)
        y = F.scaled_dot_product_attention(q, k, v, attn_mask=mask[:, None])
        y = y.transpose(1, 2).reshape(x.shape)
        x = self.ln1(x + self.drop(self.out(y)))
        return self.ln2(x + self.drop(self.ff(x)))

    def kv(self, x):
        """The keys and values of states ``x`` (B, N, W), each (B, heads, N, W / heads)."""
        w = x.shape[-1]
        k, v = F.linear(x, self.qkv.weight[w:], self.qkv.bias[w:]).chunk(2, -1)
        return self._split(k), self._split(v)

    def step(self, s, keys, values, n):
        """One new sequence state ``s`` (B, 1, W) attending to the first ``n`` cached ``keys`` / ``values``
        (B, heads, capacity, ·: the conditioning tokens, then the earlier sequence tokens) and to itself,
        whose key and value are written at index ``n``. No padding: every cached key is attended (a sampling
        scene has no padded slots)."""
        w = s.shape[-1]
        q = self._split(F.linear(s, self.qkv.weight[:w], self.qkv.bias[:w]))
        k, v = self.kv(s)
        keys[:, :, n:n + 1], values[:, :, n:n + 1] = k, v
        y = F.scaled_dot_product_attention(q, keys[:, :, :n + 1], values[:, :, :n + 1])
        y = y.transpose(1, 2).reshape(s.shape)
        x = self.ln1(s + self.drop(self.out(y)))
        return self.ln2(x + self.drop(self.ff(x)))

    def cond(self, c, cmask):
        """c: (B, I, W); cmask: (B, I) bool, True for real slots."""
        return self._attend(c, c, cmask[:, None, :].expand(-1, c.shape[1], -1))

    def seq(self, s, c, cmask):
        """s: (B, T, W) attends to c (B, I, W) where cmask, and causally to s."""
        t = s.shape[1]
        causal = torch.ones(t, t, dtype=torch.bool, device=s.device).tril()
        mask = torch.cat([cmask[:, None, :].expand(-1, t, -1), causal[None].expand(s.shape[0], -1, -1)], -1)
        return self._attend(s, torch.cat([c, s], 1), mask)


def _mlp(width: int, out: int) -> nn.Module:
    return nn.Sequential(nn.Linear(width, width), nn.LeakyReLU(0.2), nn.Linear(width, out))


class RecognitionNet(nn.Module):
    """The recognition network (see the module docstring).

    Args:
        cfg: the :class:`NetConfig`.
    """

    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        w = cfg.width
        self.slot_const = nn.Parameter(torch.randn(cfg.inputs, cfg.token_dim) * 0.02)
        self.rank_emb = nn.Embedding(cfg.inputs, cfg.value_dim)
        self.field_emb = nn.Embedding(cfg.fields, cfg.value_dim)
        self.tok_emb = nn.Embedding(cfg.vocab, cfg.token_dim)
        self.pos_emb = nn.Parameter(torch.randn(cfg.max_tokens, w) * 0.02)
        self.blocks = nn.ModuleList(_Block(w, cfg.heads, cfg.dropout) for _ in range(cfg.layers))
        self.tok_head = _mlp(w, cfg.vocab)
        self.var_head = _mlp(w, cfg.inputs)

    def encode(self, ranks: torch.Tensor, fields: torch.Tensor, cmask: torch.Tensor) -> list:
        """The conditioning states at the input of every block and after the last.

        Args:
            ranks, fields: (B, I) int64 (padding: any value where ``cmask`` is False); cmask: (B, I) bool.

        Returns:
            list of ``layers + 1`` tensors (B, I, W).
        """
        b, i = ranks.shape
        if i > self.cfg.inputs:
            raise ValueError(f"{i} conditioning tokens; the network takes at most {self.cfg.inputs}")
        val = self.rank_emb(ranks.clamp(0, self.cfg.inputs - 1)) + self.field_emb(fields.clamp(0, self.cfg.fields - 1))
        c = torch.cat([self.slot_const[:i].expand(b, -1, -1), val], -1)
        out = [c]
        for blk in self.blocks:
            c = blk.cond(c, cmask)
            out.append(c)
        return out

    def decode(self, conds: list, cmask: torch.Tensor, tokens: torch.Tensor, tok_ranks: torch.Tensor) -> tuple:
        """Logits for the next token after each sequence position.

        Args:
            conds: from :meth:`encode`. tokens: (B, T) int64 starting with ``<start>``. tok_ranks: (B, T)
            int64, the rank of ``<var>`` tokens (else ignored).

        Returns:
            ``(token_logits (B, T, V), var_logits (B, T, I))``; the variable logits of ranks beyond a
            scene's values are not masked here (see :func:`var_mask`).
        """
        t = tokens.shape[1]
        if t > self.cfg.max_tokens:
            raise ValueError(f"{t} sequence tokens; the network takes at most {self.cfg.max_tokens}")
        val = self.rank_emb(tok_ranks.clamp(0, self.cfg.inputs - 1)) * (tokens == 1)[..., None]
        s = torch.cat([self.tok_emb(tokens), val], -1) + self.pos_emb[:t]
        for blk, c in zip(self.blocks, conds):
            s = blk.seq(s, c, cmask)
        return self.tok_head(s), self.var_head(s)

    def start(self, conds: list, n: int) -> list:
        """A decoding cache for ``n`` rows of one unpadded scene (``conds`` from :meth:`encode` with batch 1):
        per block, the keys and values of the conditioning tokens, computed once and shared by the rows."""
        cache = []
        for blk, c in zip(self.blocks, conds):
            k, v = blk.kv(c[:1])
            i = k.shape[2]
            keys = k.new_empty(n, k.shape[1], i + self.cfg.max_tokens, k.shape[3])
            values = torch.empty_like(keys)
            keys[:, :, :i], values[:, :, :i] = k, v
            cache.append((keys, values, i))
        return cache

    def step(self, cache: list, position: int, tokens: torch.Tensor, tok_ranks: torch.Tensor) -> tuple:
        """The logits after one more token per row, given the cache of :meth:`start` filled by the steps at
        the earlier positions (this one writes its keys and values there); the same values as the last
        position of :meth:`decode` on the whole sequence.

        Args:
            position: the token's index in the sequence (0 for ``<start>``). tokens, tok_ranks: (B,) int64.
        """
        if position >= self.cfg.max_tokens:
            raise ValueError(f"position {position}; the network takes at most {self.cfg.max_tokens} tokens")
        val = self.rank_emb(tok_ranks.clamp(0, self.cfg.inputs - 1)) * (tokens == 1)[..., None]
        s = (torch.cat([self.tok_emb(tokens), val], -1) + self.pos_emb[position])[:, None]
        for blk, (keys, values, i) in zip(self.blocks, cache):
            s = blk.step(s, keys, values, i + position)
        return self.tok_head(s[:, 0]), self.var_head(s[:, 0])

    def forward(self, ranks, fields, cmask, tokens, tok_ranks):
        """:meth:`encode` then :meth:`decode` (shapes as there)."""
        return self.decode(self.encode(ranks, fields, cmask), cmask, tokens, tok_ranks)


def var_mask(n_values: torch.Tensor, inputs: int) -> torch.Tensor:
    """(B, inputs) bool: rank r is allowed when r < the scene's number of values (``n_values`` (B,))."""
    return torch.arange(inputs, device=n_values.device)[None] < n_values[:, None]


def save_checkpoint(path, model: RecognitionNet, vocab: Vocab, extra: dict | None = None) -> None:
    """Write the model's ``state_dict``, its :class:`NetConfig` and the vocabulary atomically (a weights file
    of :mod:`shapeio.weights`, family :data:`FORMAT`, version :data:`VERSION`)."""
    write_weights(path, FORMAT, VERSION, {"config": asdict(model.cfg), "vocab": list(vocab.tokens),
                                          "state_dict": model.state_dict(), "extra": extra or {}})


def load_checkpoint(path, library: Library) -> tuple:
    """``(model, vocab, extra)`` from :func:`save_checkpoint`, on the CPU; the vocabulary must be the
    library's.

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file: not such a checkpoint, another version, or written for another library.
    """
    ck = read_weights(path, FORMAT, VERSION, what="recognition network checkpoint")
    vocab = Vocab.of(library)
    if tuple(ck["vocab"]) != vocab.tokens:
        raise ValueError(f"{path}: the checkpoint's vocabulary is not the library's")
    model = RecognitionNet(NetConfig(**ck["config"]))
    model.load_state_dict(ck["state_dict"])
    return model, vocab, ck.get("extra", {})


# ----------------------------------------------------------------------------- sampling


def _min_lengths(vocab: Vocab) -> dict:
    """Fewest tokens that complete a slot of each type."""
    inf = 10 ** 6
    best = {Type.FLOAT: 1, Type.AXIS: 1, Type.INT: 1, Type.SHAPE: inf}
    for _ in range(8):
        for t, ret in enumerate(vocab.returns):
            if ret is Type.SHAPE:
                best[Type.SHAPE] = min(best[Type.SHAPE], 1 + sum(best[p] for p in vocab.params[t]))
    return best


class _Grammar:
    """The type masks of one sample (prefix order)."""

    def __init__(self, vocab: Vocab, minlen: dict, max_len: int, masks: dict | None = None):
        self.vocab, self.minlen, self.max_len = vocab, minlen, max_len
        self.masks = {} if masks is None else masks  # mask per grammar state, shareable between samples
        self.stack = [(Type.SHAPE, None)]  # (type, float group) of the pending slots, top last
        self.length = 0
        self.prev_inv = False

    @property
    def done(self) -> bool:
        return not self.stack

    def allowed(self) -> np.ndarray:
        """The tokens allowed next (a read-only mask)."""
        if not self.stack:
            return np.zeros(len(self.vocab), dtype=bool)
        want, group = self.stack[-1]
        rest = sum(self.minlen[t] for t, _ in self.stack[:-1])
        room = self.max_len - 1 - self.length - rest  # tokens left for this slot
        key = (want, room, self.prev_inv, None if group is None else (group["used"], group["open"], group["var"]))
        out = self.masks.get(key)
        if out is None:
            out = self.masks[key] = self._allowed(want, group, room)
            out.flags.writeable = False
        return out

    def _allowed(self, want, group, room) -> np.ndarray:
        v = self.vocab
        out = np.zeros(len(v), dtype=bool)
        for t in range(1, len(v)):
            if v.returns[t] is not want:
                continue
            need = 1 + sum(self.minlen[p] for p in v.params[t])
            if need > room:
                continue
            if want is Type.FLOAT:
                g = group or {"used": 0, "open": 1, "var": False}
                nargs = len(v.params[t])
                if t == 1:
                    pass
                elif nargs == 0:  # a constant: not the last leaf of a group without a variable
                    if g["open"] == 1 and not g["var"]:
                        continue
                elif nargs == 2:
                    if g["used"] + g["open"] + 1 > MAX_FLOAT_TERMS:
                        continue
                elif self.prev_inv:  # no Inv(Inv(...))
                    continue
            out[t] = True
        return out

    def push(self, t: int) -> None:
        v = self.vocab
        want, group = self.stack.pop()
        self.length += 1
        self.prev_inv = False
        if want is Type.FLOAT:
            g = group or {"used": 0, "open": 1, "var": False}
            nargs = len(v.params[t])
            g["open"] += nargs - 1
            if nargs == 0:
                g["used"] += 1
                g["var"] = g["var"] or t == 1
            self.prev_inv = nargs == 1
            for p in reversed(v.params[t]):
                self.stack.append((p, g))
            return
        for p in reversed(v.params[t]):
            self.stack.append((p, None))


@torch.no_grad()
def sample(model: RecognitionNet, vocab: Vocab, prims, n: int = 64, generator: torch.Generator | None = None,
           greedy_first: bool = True, temperature: float = 1.0, incremental: bool = True) -> list:
    """``n`` expressions for a scene, sampled token by token under the type masks.

    Args:
        prims: the scene's primitives (at most ``model.cfg.max_prims``).
        greedy_first: row 0 takes the arg-max token and rank at every step.
        incremental: decode with the cache of :meth:`RecognitionNet.step` (False: run :meth:`RecognitionNet.decode`
            on the whole sequence at every step; the same samples, several times slower).

    Returns:
        list of ``n`` expressions (floats as the scene's values); a row that cannot complete within
        :data:`MAX_TOKENS` (never, with the masks) is left out.
    """
    cfg = model.cfg
    scene = encode_scene(prims)
    if len(prims) > cfg.max_prims or len(prims[0]) != cfg.fields:
        raise ValueError(f"the network takes at most {cfg.max_prims} primitives of {cfg.fields} fields, "
                         f"got {len(prims)} of {len(prims[0])}")
    dev = next(model.parameters()).device
    was_training = model.training
    model.eval()
    try:
        ranks = torch.as_tensor(scene.ranks, device=dev)[None]
        fields = torch.as_tensor(scene.fields, device=dev)[None]
        cmask = torch.ones_like(ranks, dtype=torch.bool)
        conds = model.encode(ranks, fields, cmask)
        if incremental:
            cache = model.start(conds, n)
        else:
            conds, cmask = [c.expand(n, -1, -1) for c in conds], cmask.expand(n, -1)
            seq_t, seq_r = [], []
        vmask = torch.arange(cfg.inputs, device=dev) < len(scene.values)
        minlen = _min_lengths(vocab)
        masks: dict = {}
        gram = [_Grammar(vocab, minlen, cfg.max_tokens, masks) for _ in range(n)]
        tk = torch.zeros(n, dtype=torch.long, device=dev)  # <start>
        rk = torch.zeros(n, dtype=torch.long, device=dev)
        out_t = [[] for _ in range(n)]
        out_r = [[] for _ in range(n)]
        for _step in range(cfg.max_tokens - 1):
            if all(g.done for g in gram):
                break
            if incremental:
                tl, vl = model.step(cache, _step, tk, rk)
            else:
                seq_t.append(tk)
                seq_r.append(rk)
                tl, vl = (x[:, -1] for x in model.decode(conds, cmask, torch.stack(seq_t, 1), torch.stack(seq_r, 1)))
            tl, vl = tl.float(), vl.float()
            allow = torch.as_tensor(np.stack([g.allowed() for g in gram]), device=dev)
            tl = tl.masked_fill(~allow, -math.inf)
            vl = vl.masked_fill(~vmask[None], -math.inf)
            dead = ~allow.any(1)
            tl[dead, 0] = 0.0  # finished rows: a dummy token
            if temperature != 1.0:
                tl, vl = tl / temperature, vl / temperature
            tk = torch.multinomial(tl.softmax(-1), 1, generator=generator)[:, 0]
            rk = torch.multinomial(vl.softmax(-1), 1, generator=generator)[:, 0]
            if greedy_first:
                tk[0], rk[0] = tl[0].argmax(), vl[0].argmax()
            tk_l, rk_l = tk.tolist(), rk.tolist()
            for i, g in enumerate(gram):
                if g.done:
                    continue
                g.push(tk_l[i])
                out_t[i].append(tk_l[i])
                out_r[i].append(rk_l[i] if tk_l[i] == 1 else -1)
    finally:
        model.train(was_training)
    exprs = []
    for i, g in enumerate(gram):
        if g.done:
            exprs.append(decode_tokens(out_t[i], out_r[i], scene, vocab))
    return exprs
