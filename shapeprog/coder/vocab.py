"""The recognition network's tokens (:mod:`shapeprog.coder.recnet`): scenes of primitives and target
expressions as token sequences, and back.

* **Values as ranks** (:func:`encode_scene`). The scene's distinct values (2 decimals) are sorted; each
  slot (primitive p, field j) is the *rank* of its value in that list. Up to P = 16 primitives × 9 fields
  = 144 conditioning tokens (2D: 12 × 4).
* **Vocabulary** (:class:`Vocab`): ``<start>``, ``<var>`` (a float that refers to a scene value), the
  library's shape functions (base and abstractions), the float operators, the constants 0, 1, 2, the axes
  and the counts ``INT#1#`` … ``INT#6#``.
* **Targets** (:func:`encode_target`): the expression in prefix order; a float literal within
  :data:`~shapeprog.coder.dream.LITERAL_TOL` of a scene value is ``<var>`` with that value's rank; else,
  for a ``SymTrans`` distance that is the difference of two scene values, ``Sub <var> <var>``; else
  ``<var>`` with the nearest value's rank (the positions of a sub-dream that got an extra Move).
  :func:`decode_tokens` inverts it.

Example:
    >>> from shapeprog.coder.lang import Library, parse
    >>> scene = ((0.1, 0.5, 0.1, -0.4, 0.0, 0.2, 0.0, 0.0, 0.0), (0.1, 0.5, 0.1, 0.4, 0.0, 0.2, 0.0, 0.0, 0.0))
    >>> vocab = Vocab.of(Library())
    >>> e = parse("SymRef(Move(Cuboid(0.1,0.5,0.1),-0.4,0.0,0.2),AX)")
    >>> toks, ranks = encode_target(e, scene, vocab)
    >>> [vocab.tokens[t] for t in toks[:3]], ranks[3:7]
    (['SymRef', 'Move', 'Cuboid'], [2, 5, 2, 0])
    >>> decode_tokens(toks, ranks, scene, vocab) == e
    True
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .dream import LITERAL_TOL, distance_literals
from .lang import (FLOAT_CONSTANTS, FLOAT_FN, AxisConst, Call, Expr, IntConst, Library, Num, ProgramError, Type,
                   walk)

__all__ = [
    "COUNT_TOKENS",
    "MAX_FLOAT_TERMS",
    "MAX_TOKENS",
    "Scene",
    "TargetError",
    "Vocab",
    "decode_tokens",
    "encode_scene",
    "encode_target",
]


#: Tokens of one expression at most, the start token included.
MAX_TOKENS = 32
#: Terms (leaves) of one float sub-expression at most.
MAX_FLOAT_TERMS = 3
#: The counts the network can write.
COUNT_TOKENS = (1, 2, 3, 4, 5, 6)


class TargetError(ProgramError):
    """A target the network cannot be trained on; ``reason`` names the kind (counted by
    :func:`~shapeprog.coder.train.tensorize`)."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason

    def __reduce__(self):  # picklable, so that it crosses a process pool with its reason
        return type(self), (str(self), self.reason)


START, VAR = "<start>", "<var>"


# ----------------------------------------------------------------------------- vocabulary and tokens


@dataclass(frozen=True)
class Vocab:
    """The output tokens of a library and their types.

    Attributes:
        tokens: the token texts; index 0 is ``<start>``, 1 is ``<var>``.
        returns: each token's type (None for ``<start>``).
        params: each token's argument types (``()`` for leaves).
    """

    tokens: tuple
    returns: tuple
    params: tuple

    @classmethod
    def of(cls, library: Library) -> "Vocab":
        lang = library.lang
        toks, rets, pars = [START, VAR], [None, Type.FLOAT], [(), ()]
        for sig in lang.functions:
            if sig.returns is Type.SHAPE:
                toks.append(sig.name), rets.append(Type.SHAPE), pars.append(sig.params)
        for ab in library.abstractions:
            toks.append(ab.name), rets.append(Type.SHAPE), pars.append(ab.signature.params)
        for sig in lang.functions:
            if sig.kind == FLOAT_FN:
                toks.append(sig.name), rets.append(Type.FLOAT), pars.append(sig.params)
        for c in FLOAT_CONSTANTS:
            toks.append(repr(c)), rets.append(Type.FLOAT), pars.append(())
        for a in lang.axes:
            toks.append(a), rets.append(Type.AXIS), pars.append(())
        for k in COUNT_TOKENS:
            toks.append(f"INT#{k}#"), rets.append(Type.INT), pars.append(())
        return cls(tuple(toks), tuple(rets), tuple(pars))

    def __len__(self) -> int:
        return len(self.tokens)

    def index(self, token: str) -> int:
        try:
            return self._index()[token]
        except KeyError:
            raise TargetError(f"token {token!r} is not in the vocabulary", "token not in the vocabulary") from None

    def _index(self) -> dict:
        d = self.__dict__.get("_idx")
        if d is None:
            d = {t: i for i, t in enumerate(self.tokens)}
            object.__setattr__(self, "_idx", d)
        return d


@dataclass(frozen=True)
class Scene:
    """A scene as the network reads it.

    Attributes:
        values: the sorted distinct values (the rank of a value is its index).
        ranks: (P·S,) int64, the rank of each slot, primitive by primitive.
        fields: (P·S,) int64, each slot's field index (0..S-1).
    """

    values: tuple
    ranks: np.ndarray
    fields: np.ndarray


def encode_scene(prims: Sequence[Sequence[float]]) -> Scene:
    """The :class:`Scene` of primitives (values rounded to 2 decimals)."""
    p = np.round(np.asarray(prims, dtype=np.float64), 2) + 0.0
    if p.ndim != 2 or len(p) == 0:
        raise ValueError(f"a scene is a non-empty (P, S) array of primitives, got shape {p.shape}")
    values = np.unique(p)
    ranks = np.searchsorted(values, p.ravel())
    fields = np.tile(np.arange(p.shape[1]), p.shape[0])
    return Scene(tuple(float(v) for v in values), ranks.astype(np.int64), fields.astype(np.int64))


def _nearest(values: tuple, v: float) -> int:
    a = np.asarray(values)
    return int(np.abs(a - v).argmin())


def encode_target(expr: Expr, scene_prims, vocab: Vocab, library: Library | None = None) -> tuple:
    """``(tokens, ranks)``: the expression's tokens in prefix order (no start token) and, per token, the
    referenced rank (``<var>`` tokens) or -1. ``library``: the abstractions of ``expr`` (for their
    ``SymTrans`` distance parameters).

    Raises:
        TargetError: a token outside the vocabulary, or more than :data:`MAX_TOKENS` - 1 tokens.
    """
    scene = scene_prims if isinstance(scene_prims, Scene) else encode_scene(scene_prims)
    vals = np.asarray(scene.values)
    dist = distance_literals(expr, library)
    toks, ranks = [], []
    for n in walk(expr):
        if isinstance(n, Call):
            toks.append(vocab.index(n.fn)), ranks.append(-1)
        elif isinstance(n, Num):
            r = _nearest(scene.values, n.value)
            if abs(vals[r] - n.value) > LITERAL_TOL + 1e-9 and id(n) in dist and "Sub" in vocab.tokens:
                d = np.abs(vals[:, None] - vals[None] - n.value)
                a, b = np.unravel_index(int(d.argmin()), d.shape)
                if d[a, b] <= LITERAL_TOL + 1e-9:
                    toks += [vocab.index("Sub"), 1, 1]
                    ranks += [-1, int(a), int(b)]
                    continue
            toks.append(1), ranks.append(r)
        elif isinstance(n, AxisConst):
            toks.append(vocab.index(n.name)), ranks.append(-1)
        elif isinstance(n, IntConst):
            toks.append(vocab.index(f"INT#{n.value}#")), ranks.append(-1)
        else:
            raise TargetError(f"a target has no variables; got {n!r}", "target not encodable")
    if len(toks) > MAX_TOKENS - 1:
        raise TargetError(f"the target has {len(toks)} tokens; at most {MAX_TOKENS - 1} (MAX_TOKENS)",
                          "target over MAX_TOKENS")
    return toks, ranks


def decode_tokens(tokens: Sequence[int], ranks: Sequence[int], scene_prims, vocab: Vocab) -> Expr:
    """The expression of prefix ``tokens`` (no start token); ``<var>`` tokens take the value of their
    rank in the scene.

    Raises:
        ProgramError: an incomplete or overlong token sequence, or a rank outside the scene.
    """
    scene = scene_prims if isinstance(scene_prims, Scene) else encode_scene(scene_prims)
    pos = [0]

    def go():
        if pos[0] >= len(tokens):
            raise ProgramError("the token sequence ends inside an expression")
        i = pos[0]
        pos[0] += 1
        t = int(tokens[i])
        name = vocab.tokens[t]
        if t == 1:
            r = int(ranks[i])
            if not 0 <= r < len(scene.values):
                raise ProgramError(f"rank {r} is outside the scene's {len(scene.values)} values")
            return Num(scene.values[r])
        if t == 0:
            raise ProgramError("<start> inside an expression")
        ret = vocab.returns[t]
        if ret is Type.AXIS:
            return AxisConst(name)
        if ret is Type.INT:
            return IntConst(int(name[4:-1]))
        if ret is Type.FLOAT and not vocab.params[t]:
            return Num(float(name))
        return Call(name, tuple(go() for _ in vocab.params[t]))

    e = go()
    if pos[0] != len(tokens):
        raise ProgramError(f"{len(tokens) - pos[0]} token(s) after the end of the expression")
    return e
