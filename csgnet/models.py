"""CSGNet and CSGNetStack as plain PyTorch modules (the spec's section (d), ``docs/csgnet.md``).

One class, :class:`CSGNet`, covers both models: with ``config.stack`` the encoder sees the target
concatenated with the top-K maps of the execution stack at every step (CSGNetStack); without it the
target is encoded once (CSGNet). The modules know nothing about training loops, data or decoding
(:mod:`csgnet.decode`, :mod:`csgnet.train.supervised`).

Sizes are configuration (:class:`ModelConfig`); :func:`preset` gives the ``paper`` sizes (parameter
counts equal to the reference's: 31,037,840 for 2D CSGNet, 36,562,243 for 3D CSGNet) and a ``small``
size that trains usefully on a 2-core CPU.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import torch
from torch import nn
import torch.nn.functional as F

from .lang import Draw
from .vocab import vocabulary

__all__ = ["ModelConfig", "preset", "PRESETS", "CSGNet", "Encoder2D", "Encoder3D", "Encoder3DLite", "FactoredLinear",
           "token_attributes", "default_stack_k", "widen", "ENCODERS", "HEADS"]

ENCODERS = ("paper", "lite")
HEADS = ("full", "factored")


def default_stack_k(max_len: int) -> int:
    """The deepest stack a valid program of ``max_len`` tokens can reach: (max_len + 1) // 2."""
    return max(1, (int(max_len) + 1) // 2)


@dataclass(frozen=True)
class ModelConfig:
    """Sizes of a CSGNet / CSGNetStack.

    Attributes:
        dim: 2 or 3.
        stack: CSGNetStack (encoder input = target + top-K stack maps at every step) or CSGNet.
        stack_k: K, the number of stack maps (default: :func:`default_stack_k` of ``max_len``).
        max_len: longest program the model decodes (13 in 2D, 7 in 3D).
        hidden: GRU hidden size (paper: 2048 in 2D, 1500 in 3D).
        embed: previous-token embedding size (128).
        channels: encoder conv channels, one block each (2D paper: 8, 16, 32; 3D: 32, 64, 128, 256, 256).
        enc_dropout: dropout inside the encoder (2D: after the first blocks' ReLU; 3D: every block).
        dropout: dropout on the encoder feature, the GRU output and between the two head layers.
        input_pool: max-pool the 64-sided input (target and stack maps) by this factor before the encoder
            (1 = none, as the paper; 2 makes a CPU-sized CSGNetStack four times cheaper).
        encoder: ``"paper"`` (the paper's blocks: 2D conv 3 → ReLU → [Dropout] → pool; 3D conv 4 → ReLU →
            pool → Dropout → BatchNorm) or, in 3D only, ``"lite"`` (conv 3, pad 1 → ReLU → pool →
            BatchNorm: each block halves the side exactly, about 1.4 times the paper blocks' speed on a CPU
            at the same channels; :class:`Encoder3DLite`).
        head: ``"full"`` (the paper's last layer: a free output vector per token) or ``"factored"``
            (:class:`FactoredLinear`: each token's output vector is its free vector plus the sum of vectors
            shared by the tokens with the same primitive type, centre coordinate or parameter value, so that
            what is learnt of one token's position or size reaches every token that shares it). Decoding is
            the same for both.
    """

    dim: int = 2
    stack: bool = False
    stack_k: int | None = None
    max_len: int = 13
    hidden: int = 2048
    embed: int = 128
    channels: tuple[int, ...] = (8, 16, 32)
    enc_dropout: float = 0.2
    dropout: float = 0.5
    input_pool: int = 1
    encoder: str = "paper"
    head: str = "full"

    def __post_init__(self):
        if self.encoder not in ENCODERS:
            raise ValueError(f"encoder must be one of {ENCODERS}, got {self.encoder!r}")
        if self.encoder == "lite" and self.dim != 3:
            raise ValueError("the 'lite' encoder is 3D only (the 2D paper encoder already uses 3×3 convolutions)")
        if self.head not in HEADS:
            raise ValueError(f"head must be one of {HEADS}, got {self.head!r}")
        if self.dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {self.dim!r}")
        object.__setattr__(self, "channels", tuple(int(c) for c in self.channels))
        if not self.channels:
            raise ValueError("channels must name at least one encoder block")
        if self.stack_k is None:
            object.__setattr__(self, "stack_k", default_stack_k(self.max_len))
        if self.stack_k < 1 or self.max_len < 1 or self.hidden < 1 or self.input_pool < 1:
            raise ValueError(f"stack_k, max_len, hidden and input_pool must be positive: {self}")
        if self.feature_side < 1:
            raise ValueError(f"{len(self.channels)} encoder blocks leave no spatial extent of a 64-sided input")

    @property
    def in_channels(self) -> int:
        return 1 + (self.stack_k if self.stack else 0)

    @property
    def feature_side(self) -> int:
        """Spatial side of the encoder output: each 2D block halves it (conv pad 1 keeps it), each 3D
        block's conv (kernel 4, pad 2) adds one before the halving."""
        side = 64 // self.input_pool
        for _ in self.channels:
            side = (side + 1) // 2 if self.dim == 3 and self.encoder == "paper" else side // 2
        return side

    @property
    def feature_size(self) -> int:
        """Length of the flattened encoder output (2048 for both paper encoders)."""
        return self.channels[-1] * self.feature_side ** self.dim

    @property
    def vocab_size(self) -> int:
        return len(vocabulary(self.dim))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["channels"] = list(self.channels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown model config keys {sorted(unknown)}")
        return cls(**d)


PRESETS: dict[tuple[str, int], dict] = {
    # the reference's sizes and the dropout values in effect in its scripts (spec (d))
    ("paper", 2): dict(hidden=2048, channels=(8, 16, 32), enc_dropout=0.2, dropout=0.5, max_len=13),
    ("paper", 3): dict(hidden=1500, channels=(32, 64, 128, 256, 256), enc_dropout=0.2, dropout=0.2, max_len=7),
    # trains on a 2-core CPU in tens of minutes; the shipped weights use it
    ("small", 2): dict(hidden=256, channels=(8, 16, 16), enc_dropout=0.0, dropout=0.1, max_len=13),
    ("small", 3): dict(hidden=256, channels=(8, 16, 32, 32), enc_dropout=0.0, dropout=0.1, max_len=7, input_pool=2),
    # beyond the paper, for a CPU: the lite 3D encoder on the 32³ max-pooled input and the factored head
    ("lite", 3): dict(hidden=256, channels=(8, 16, 32, 64), enc_dropout=0.0, dropout=0.1, max_len=7, input_pool=2,
                      encoder="lite", head="factored"),
}


def preset(name: str, dim: int, stack: bool = False, **overrides) -> ModelConfig:
    """A named size (``"paper"`` or ``"small"``) for ``dim``, with any field overridden."""
    key = (name, int(dim))
    if key not in PRESETS:
        raise ValueError(f"unknown preset {name!r} for {dim}D; known: {sorted({k[0] for k in PRESETS})}")
    return ModelConfig(dim=int(dim), stack=bool(stack), **{**PRESETS[key], **overrides})


class _ConvEncoder(nn.Module):
    """Conv blocks (:meth:`block`) after an optional max-pool of the input, flattened channel-major."""

    pool = None  # the max-pool function of the input's dimension
    memory_format = torch.contiguous_format  # both encoders use channels-last (1.3 to 1.6 times faster on a CPU)

    def __init__(self, in_channels: int, channels: tuple[int, ...], dropout: float, input_pool: int = 1):
        super().__init__()
        self.input_pool = int(input_pool)
        layers: list[nn.Module] = []
        c_in = in_channels
        for i, c in enumerate(channels):
            layers += self.block(c_in, c, dropout, last=i == len(channels) - 1)
            c_in = c
        self.net = nn.Sequential(*layers)
        self.net.to(memory_format=self.memory_format)

    @staticmethod
    def block(c_in: int, c_out: int, dropout: float, last: bool) -> list[nn.Module]:
        raise NotImplementedError

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``(B, C, 64, 64)`` or ``(B, C, 64, 64, 64)`` float → ``(B, F)`` features, flattened channel-major."""
        if self.input_pool > 1:
            x = self.pool(x, self.input_pool)
        return self.net(x.contiguous(memory_format=self.memory_format)).flatten(1)


class Encoder2D(_ConvEncoder):
    """conv 3×3 (pad 1) → ReLU → [Dropout] → MaxPool 2, per block; no dropout in the last block. The
    ReLU is applied after the pooling (the same values, on a quarter of the elements: ReLU commutes with
    max-pooling and with dropout)."""

    pool = staticmethod(F.max_pool2d)
    memory_format = torch.channels_last

    @staticmethod
    def block(c_in: int, c_out: int, dropout: float, last: bool) -> list[nn.Module]:
        return [nn.Conv2d(c_in, c_out, 3, padding=1), *([] if last else [nn.Dropout(dropout)]), nn.MaxPool2d(2),
                nn.ReLU()]


class Encoder3D(_ConvEncoder):
    """conv3d 4 (stride 1, pad 2) → ReLU → MaxPool3d 2 → Dropout → BatchNorm3d, per block (the ReLU
    applied after the pooling: the same values)."""

    pool = staticmethod(F.max_pool3d)
    memory_format = torch.channels_last_3d

    @staticmethod
    def block(c_in: int, c_out: int, dropout: float, last: bool) -> list[nn.Module]:
        return [nn.Conv3d(c_in, c_out, 4, padding=2), nn.MaxPool3d(2), nn.ReLU(), nn.Dropout(dropout),
                nn.BatchNorm3d(c_out)]


class Encoder3DLite(_ConvEncoder):
    """conv3d 3 (pad 1) → MaxPool3d 2 → ReLU → BatchNorm3d, per block (``encoder: lite``)."""

    pool = staticmethod(F.max_pool3d)
    memory_format = torch.channels_last_3d

    @staticmethod
    def block(c_in: int, c_out: int, dropout: float, last: bool) -> list[nn.Module]:
        return [nn.Conv3d(c_in, c_out, 3, padding=1), nn.MaxPool3d(2), nn.ReLU(),
                *([nn.Dropout(dropout)] if dropout > 0 else []), nn.BatchNorm3d(c_out)]


def token_attributes(dim: int) -> tuple[torch.Tensor, int]:
    """The shared attributes of each output token, for :class:`FactoredLinear`.

    A primitive token has its type, each centre coordinate (shared by all types: the first ``dim``
    parameters are the centre) and each parameter value of its type; an operator or ``$`` has only
    itself.

    Returns:
        ``(index (V, G) int64, n)``: row ``t`` lists token ``t``'s attribute numbers, padded with ``n``
        (the number of attributes; :class:`FactoredLinear` reads it as a zero row).
    """
    vocab = vocabulary(dim)
    table: dict = {}
    rows = []
    for text, draw in zip(vocab.tokens, vocab._draws):
        if isinstance(draw, Draw):
            keys = [("type", draw.kind)]
            keys += [("centre", i, v) for i, v in enumerate(draw.params[:dim])]
            keys += [("param", draw.kind, i, v) for i, v in enumerate(draw.params)]
        else:
            keys = [("token", text)]
        rows.append([table.setdefault(k, len(table)) for k in keys])
    n = len(table)
    width = max(len(r) for r in rows)
    return torch.tensor([r + [n] * (width - len(r)) for r in rows], dtype=torch.int64), n


class FactoredLinear(nn.Module):
    """A linear layer onto the vocabulary whose weight rows and biases are a free part plus the sum of
    the token's shared attribute parts (:func:`token_attributes`); the attribute parts start at zero, so
    at initialisation it is ``nn.Linear``. Its output is exactly ``F.linear(x, *self.folded())``."""

    def __init__(self, in_features: int, dim: int):
        super().__init__()
        index, n = token_attributes(dim)
        incidence = torch.zeros(index.shape[0], n + 1)
        incidence.scatter_(1, index, 1.0)
        # (V, n) 0/1: token t has attribute a; a dense product is faster than a gather of (V, G, in) rows
        self.register_buffer("incidence", incidence[:, :n].contiguous(), persistent=False)
        plain = nn.Linear(in_features, index.shape[0])
        self.weight, self.bias = plain.weight, plain.bias
        self.attr_weight = nn.Parameter(torch.zeros(n, in_features))
        self.attr_bias = nn.Parameter(torch.zeros(n))
        self._cache = None

    def folded(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The ``(V, in)`` weight and ``(V,)`` bias the layer applies (cached while nothing changes and no
        gradient is recorded)."""
        key = (self.weight._version, self.bias._version, self.attr_weight._version, self.attr_bias._version,
               self.weight.device, self.weight.dtype)
        if not torch.is_grad_enabled() and self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        w = self.weight + self.incidence.to(self.attr_weight.dtype) @ self.attr_weight
        b = self.bias + self.incidence.to(self.attr_bias.dtype) @ self.attr_bias
        if not torch.is_grad_enabled():
            self._cache = (key, (w, b))
        return w, b

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.linear(x, *self.folded())


class CSGNet(nn.Module):
    """CNN encoder + previous-token embedding + one-layer GRU + two fully connected layers.

    Token convention (spec (a)): outputs are the ``V`` vocabulary entries (``$`` last); the input
    one-hot has ``V + 1`` entries, the extra one (index ``V``) being START. The input embedding is the
    spec's ``Linear(V + 1 → 128)`` applied to a one-hot vector, stored as an embedding table plus a bias
    (the same parameters, without materialising one-hot vectors).

    Shapes: targets are ``(B, 64, 64)`` or ``(B, 64, 64, 64)`` (bool or float); stack maps are
    ``(B, K, 64, 64[, 64])``.
    """

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = config
        V = config.vocab_size
        if config.dim == 2:
            self.encoder = Encoder2D(config.in_channels, config.channels, config.enc_dropout, config.input_pool)
        else:
            enc = Encoder3DLite if config.encoder == "lite" else Encoder3D
            self.encoder = enc(config.in_channels, config.channels, config.enc_dropout, config.input_pool)
        self.token_embed = nn.Embedding(V + 1, config.embed)
        self.token_bias = nn.Parameter(torch.empty(config.embed))
        bound = 1.0 / math.sqrt(V + 1)  # nn.Linear's default initialisation for fan_in V + 1
        nn.init.uniform_(self.token_embed.weight, -bound, bound)
        nn.init.uniform_(self.token_bias, -bound, bound)
        self.feature_drop = nn.Dropout(config.dropout)
        self.gru = nn.GRU(config.feature_size + config.embed, config.hidden, batch_first=True)
        self.head = nn.Sequential(
            nn.Dropout(config.dropout), nn.Linear(config.hidden, config.hidden), nn.ReLU(),
            nn.Dropout(config.dropout),
            FactoredLinear(config.hidden, config.dim) if config.head == "factored" else nn.Linear(config.hidden, V))

    # ------------------------------------------------------------------------------------------
    @property
    def start(self) -> int:
        """Index of the START input symbol (= vocabulary size)."""
        return self.config.vocab_size

    @property
    def stop(self) -> int:
        return self.config.vocab_size - 1

    def _check_target(self, target: torch.Tensor) -> None:
        want = (64,) * self.config.dim
        if target.dim() != self.config.dim + 1 or tuple(target.shape[1:]) != want:
            raise ValueError(f"targets must be (B, {', '.join(map(str, want))}), got {tuple(target.shape)}")

    def encode(self, target: torch.Tensor, stack: torch.Tensor | None = None) -> torch.Tensor:
        """Encoder features ``(B, F)`` of targets and, for CSGNetStack, the current stack maps ``(B, K, ...)``."""
        self._check_target(target)
        if not self.config.stack:
            return self.encoder(target[:, None].float())
        if stack is None:
            raise ValueError("CSGNetStack needs the stack maps")
        if stack.shape[1] != self.config.stack_k or stack.shape[2:] != target.shape[1:]:
            raise ValueError(f"stack must be (B, {self.config.stack_k}, {', '.join(map(str, target.shape[1:]))}),"
                             f" got {tuple(stack.shape)}")
        # target and stack maps written once into channels-last memory (what the encoder runs on), instead of
        # converting, concatenating and reordering them; under autocast in its dtype, which holds their 0/1
        # values exactly and which the first convolution would cast them to
        device = target.device.type
        dtype = torch.get_autocast_dtype(device) if torch.is_autocast_enabled(device) else self.token_bias.dtype
        x = torch.empty(tuple(target.shape) + (stack.shape[1] + 1,), dtype=dtype, device=target.device)
        x[..., 0] = target
        x[..., 1:] = stack.movedim(1, -1)
        return self.encoder(x.movedim(-1, 1))

    def embed(self, tokens: torch.Tensor) -> torch.Tensor:
        return F.relu(self.token_embed(tokens) + self.token_bias)

    def forward(self, target: torch.Tensor, tokens_in: torch.Tensor, stack: torch.Tensor | None = None
                ) -> torch.Tensor:
        """Teacher-forced logits.

        Args:
            target: ``(B, 64, 64[, 64])``.
            tokens_in: ``(B, T)`` input tokens, START first.
            stack: CSGNetStack only, ``(T, B, K, 64, 64[, 64])``: the stack after 0..T-1 tokens (the
                renderer's :func:`~csgnet.renderer.stack_trace`, slot 0 = top).

        Returns:
            ``(B, T, V)`` unnormalised scores (``log_softmax`` gives the spec's output).
        """
        self._check_target(target)
        B, T = tokens_in.shape
        if self.config.stack:
            if stack is None or stack.shape[:2] != (T, B):
                raise ValueError(f"CSGNetStack needs stack maps (T={T}, B={B}, K, ...), "
                                 f"got {None if stack is None else tuple(stack.shape)}")
            tgt = target[None].expand((T,) + tuple(target.shape))
            feats = self.encode(tgt.reshape((T * B,) + tuple(target.shape[1:])),
                                stack.reshape((T * B,) + tuple(stack.shape[2:])))
            feats = feats.view(T, B, -1).transpose(0, 1)
        else:
            feats = self.encode(target)[:, None].expand(B, T, -1)
        x = torch.cat([self.feature_drop(feats), self.embed(tokens_in)], dim=-1)
        out, _ = self.gru(x)
        return self.head(out)

    def step(self, features: torch.Tensor, tokens: torch.Tensor, hidden: torch.Tensor | None
             ) -> tuple[torch.Tensor, torch.Tensor]:
        """One decoding step: encoder ``features (B, F)``, previous ``tokens (B,)`` and GRU state
        ``hidden (B, H)`` (None at the start) → ``(logits (B, V), new hidden (B, H))``."""
        x = torch.cat([self.feature_drop(features), self.embed(tokens)], dim=-1)[:, None]
        out, h = self.gru(x, None if hidden is None else hidden[None].contiguous())
        return self.head(out[:, 0]), h[0]

    def project_features(self, features: torch.Tensor) -> torch.Tensor:
        """The encoder features' share of the GRU input gates, ``(B, 3H)``.

        CSGNet's features are the same at every step, so decoders compute this product once per target
        instead of once per step and beam (:meth:`step_projected`); the dropout on the features is applied
        here, so this is exact in eval mode and samples one dropout mask per sequence in train mode.
        """
        w = self.gru.weight_ih_l0[:, : self.config.feature_size]
        return F.linear(self.feature_drop(features), w)

    def step_projected(self, projected: torch.Tensor, tokens: torch.Tensor, hidden: torch.Tensor | None,
                       token_weight: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`step` with the features given as :meth:`project_features` (the same GRU equations:
        ``r = σ(x_r + h_r)``, ``z = σ(x_z + h_z)``, ``n = tanh(x_n + r·h_n)``, ``h' = (1 - z)·n + z·h``).

        ``token_weight``: :meth:`token_input_weight`, made contiguous once by the caller to avoid a copy
        per step (default: made here).
        """
        if token_weight is None:
            token_weight = self.token_input_weight()
        gi = projected + F.linear(self.embed(tokens), token_weight, self.gru.bias_ih_l0)
        if hidden is None:
            hidden = projected.new_zeros(projected.shape[0], self.config.hidden)
        gh = F.linear(hidden, self.gru.weight_hh_l0, self.gru.bias_hh_l0)
        ir, iz, inn = gi.chunk(3, 1)
        hr, hz, hn = gh.chunk(3, 1)
        r = torch.sigmoid(ir + hr)
        z = torch.sigmoid(iz + hz)
        n = torch.tanh(inn + r * hn)
        h = n + z * (hidden - n)
        return self.head(h), h

    def token_input_weight(self) -> torch.Tensor:
        """The token-embedding columns of the GRU input weights, ``(3H, E)``, contiguous."""
        return self.gru.weight_ih_l0[:, self.config.feature_size:].contiguous()

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


def build(config: ModelConfig | dict) -> CSGNet:
    """A model from a :class:`ModelConfig` or its dict form."""
    if isinstance(config, dict):
        config = ModelConfig.from_dict(config)
    return CSGNet(config)


def widen(start: CSGNet, config: ModelConfig | dict) -> CSGNet:
    """A model of ``config`` that computes what ``start`` computes (equal up to the rounding of longer sums),
    with more units.

    ``config`` may differ from ``start.config`` only in ``hidden`` and ``channels`` (as many blocks, none
    narrower). Every unit of ``start`` keeps its weights; each new unit (encoder channel, GRU unit, hidden
    layer unit) takes the fresh layer's random input weights and zero output weights, so the outputs are
    unchanged (in eval mode, and in train mode for the same dropout draws) while the gradients reach the
    new units' output weights from the first step. A warm start for a wider run (``init_widen`` of
    :class:`csgnet.train.supervised.CSGNetModule`) instead of training the wider model from scratch.

    Raises:
        ValueError: the configurations differ in anything else, or ``config`` is narrower somewhere.
    """
    big = build(config)
    a, b = start.config, big.config
    rest = {k: v for k, v in a.to_dict().items() if k not in ("hidden", "channels")}
    if rest != {k: v for k, v in b.to_dict().items() if k not in ("hidden", "channels")}:
        raise ValueError(f"widen changes only hidden and channels: {a.to_dict()} against {b.to_dict()}")
    if len(a.channels) != len(b.channels) or any(x > y for x, y in zip(a.channels, b.channels)) or a.hidden > b.hidden:
        raise ValueError(f"widen needs as many encoder blocks, none narrower, and no smaller hidden size: "
                         f"channels {a.channels} -> {b.channels}, hidden {a.hidden} -> {b.hidden}")
    H, Hb, F0, Fb = a.hidden, b.hidden, a.feature_size, b.feature_size

    def put(dst: torch.Tensor, src: torch.Tensor) -> None:
        """``src`` into the leading block of ``dst``; the columns beyond ``src``'s in its rows set to zero
        (the new units' outputs reach the old units with zero weight)."""
        if dst.dim() == 1:
            dst[: src.shape[0]] = src
            return
        dst[: src.shape[0], : src.shape[1]] = src
        dst[: src.shape[0], src.shape[1]:] = 0

    with torch.no_grad():
        for m, n in zip(start.encoder.net, big.encoder.net):
            if isinstance(m, (nn.Conv2d, nn.Conv3d)):
                put(n.weight, m.weight)
                put(n.bias, m.bias)
            elif isinstance(m, (nn.BatchNorm2d, nn.BatchNorm3d)):
                for name in ("weight", "bias", "running_mean", "running_var"):
                    put(getattr(n, name), getattr(m, name))
                n.num_batches_tracked.copy_(m.num_batches_tracked)
        big.token_embed.weight.copy_(start.token_embed.weight)
        big.token_bias.copy_(start.token_bias)
        g, gb = start.gru, big.gru
        for k in range(3):  # gates r, z, n: rows k*H .. (k+1)*H
            rows, rows_b = slice(k * H, (k + 1) * H), slice(k * Hb, k * Hb + H)
            wi = gb.weight_ih_l0[rows_b]
            wi[:, :F0] = g.weight_ih_l0[rows, :F0]  # the features the start's encoder makes
            wi[:, F0:Fb] = 0  # the new channels' features
            wi[:, Fb:] = g.weight_ih_l0[rows, F0:]  # the token embedding
            put(gb.weight_hh_l0[rows_b], g.weight_hh_l0[rows])
            for name in ("bias_ih_l0", "bias_hh_l0"):
                getattr(gb, name)[rows_b] = getattr(g, name)[rows]
        lin, lin_b = start.head[1], big.head[1]
        put(lin_b.weight, lin.weight)
        put(lin_b.bias, lin.bias)
        out, out_b = start.head[-1], big.head[-1]
        put(out_b.weight, out.weight)
        out_b.bias.copy_(out.bias)
        if isinstance(out, FactoredLinear):
            put(out_b.attr_weight, out.attr_weight)
            out_b.attr_bias.copy_(out.attr_bias)
    return big
