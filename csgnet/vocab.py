"""Token <-> index tables of CSGNet, and the renderers' integer codes of token kinds.

The vocabulary is every grammar primitive of the table (:mod:`csgnet.primitives`) that fits in the
canvas, as its (truncated, in 3D) token text, sorted as plain Python strings, followed by ``+ * - $``
(the spec's section (a)). 2D: 400 tokens (circles 0-90, squares 91-259, triangles 260-395, ``+`` 396,
``*`` 397, ``-`` 398, ``$`` 399). 3D: 6635 tokens (spheres 0-648, cubes 649-1989, cylinders 1990-6630,
``+`` 6631, ``*`` 6632, ``-`` 6633, ``$`` 6634). The decoder's input one-hot has one more entry, START
(index ``len(vocab)``).

Kind codes (:func:`codes`) number the primitives in table order, then the operators ``+ * -``, then
the stop code (which also pads); ``KIND_CODES``, ``OP_CODES``, ``STOP_CODE`` and ``PAD_CODE`` read
the current table.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Iterable

import numpy as np

from . import primitives as P
from .lang import OPERATORS, STOP, Draw, Op, Program, parse

__all__ = ["Vocabulary", "vocabulary", "Codes", "codes", "KIND_CODES", "OP_CODES", "STOP_CODE", "PAD_CODE"]


@dataclass(frozen=True)
class Codes:
    """The renderers' integer codes of token kinds, derived from the table of primitives.

    Attributes:
        kind: primitive letter -> code, ``0 .. n_draw - 1`` in table order.
        op: ``+ * -`` -> the codes after the primitives.
        stop: the code of ``$`` and of padding (after the operators).
    """

    kind: dict
    op: dict
    stop: int

    @property
    def n_draw(self) -> int:
        """The number of primitive codes: a code ``k`` draws iff ``k < n_draw``."""
        return len(self.kind)

    def is_draw(self, kinds):
        """Elementwise "draws" of codes (ints, NumPy arrays or torch tensors)."""
        return kinds < self.n_draw

    def is_op(self, kinds):
        """Elementwise "is an operator" of codes (ints, NumPy arrays or torch tensors)."""
        return (kinds >= self.n_draw) & (kinds < self.stop)


@lru_cache(maxsize=None)
def codes() -> Codes:
    """The kind codes of the current table (recomputed when the table changes)."""
    kind = {p.kind: i for i, p in enumerate(P.primitives())}
    op = {o: len(kind) + i for i, o in enumerate(OPERATORS)}
    return Codes(kind, op, len(kind) + len(op))


def __getattr__(name):  # the code tables as module constants, always those of the current table
    c = codes()
    values = {"KIND_CODES": c.kind, "OP_CODES": c.op, "STOP_CODE": c.stop, "PAD_CODE": c.stop}
    if name in values:
        return dict(values[name]) if isinstance(values[name], dict) else values[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def write_codes(tokens, kinds: np.ndarray, params: np.ndarray) -> None:
    """Write the renderer codes of ``tokens`` (:class:`Draw`, :class:`Op`; anything else is left as it
    is) into ``kinds[i]`` and ``params[i, :n]`` (zero-padded rows of 5)."""
    c = codes()
    for i, t in enumerate(tokens):
        if isinstance(t, Draw):
            kinds[i] = c.kind[t.kind]
            params[i, : len(t.params)] = t.params
        elif isinstance(t, Op):
            kinds[i] = c.op[t.op]


def _primitive_texts(dim: int) -> list[str]:
    return sorted(t for row in P.primitives(dim) for t in P.grammar_texts(row))


@dataclass(frozen=True)
class Vocabulary:
    """The token table of one dimension.

    Attributes:
        dim: 2 or 3.
        tokens: token texts in index order (3D primitives in the truncated ``p(...)`` form).
    """

    dim: int
    tokens: tuple[str, ...]
    _index: dict = field(repr=False, compare=False, hash=False, default=None)
    _draws: tuple = field(repr=False, compare=False, hash=False, default=None)

    def __post_init__(self):
        object.__setattr__(self, "_index", {t: i for i, t in enumerate(self.tokens)})
        draws = []
        for t in self.tokens:
            draws.append(Op(t) if t in OPERATORS else (None if t == STOP else parse(t, self.dim, strict=False).tokens[0]))
        object.__setattr__(self, "_draws", tuple(draws))

    def __len__(self) -> int:
        return len(self.tokens)

    @property
    def size(self) -> int:
        """Number of output classes (including ``$``)."""
        return len(self.tokens)

    @property
    def stop(self) -> int:
        """Index of ``$`` (the last class)."""
        return self._index[STOP]

    @property
    def start(self) -> int:
        """Index of START in the decoder's input one-hot (one past the last class)."""
        return len(self.tokens)

    @property
    def num_primitives(self) -> int:
        return len(self.tokens) - 4

    def op_index(self, op: str) -> int:
        return self._index[op]

    def index(self, token: "str | Draw | Op") -> int:
        """Index of a token given as text (``c(8,8,8)``, ``sp(...)``/``p(...)``, ``+``, ``$``) or object."""
        if isinstance(token, Draw):
            key = token.text(long=False)
        elif isinstance(token, Op):
            key = token.op
        else:
            key = token
            if key not in self._index and key not in OPERATORS and key != STOP:
                key = parse(key, self.dim, strict=False).tokens[0].text(long=False)
        try:
            return self._index[key]
        except KeyError:
            raise KeyError(f"{key!r} is not in the {self.dim}D vocabulary (only grammar primitives "
                           f"that fit in the canvas are)") from None

    def token(self, index: int) -> str:
        return self.tokens[index]

    def encode(self, program: "Program | str") -> list[int]:
        """Token indices of a program (no ``$``). Raises ``KeyError`` for an off-vocabulary primitive."""
        if isinstance(program, str):
            program = parse(program, self.dim, strict=False)
        return [self.index(t) for t in program.tokens]

    def decode(self, indices: Iterable[int]) -> Program:
        """The program of a token index sequence, cut at the first ``$`` (which may be absent)."""
        out = []
        for i in indices:
            i = int(i)
            if i == self.stop:
                break
            if not 0 <= i < len(self.tokens):
                raise ValueError(f"token index {i} out of range [0, {len(self.tokens)}) for the {self.dim}D vocabulary")
            out.append(self._draws[i])
        return Program(tuple(out), self.dim)

    def text(self, indices: Iterable[int]) -> str:
        """The program text of a token index sequence (cut at ``$``)."""
        return self.decode(indices).text()

    def table(self) -> tuple[np.ndarray, np.ndarray]:
        """Renderer table: ``kinds (V,) int64`` codes and ``params (V, 5) int64`` (zero-padded)."""
        kinds = np.full(len(self.tokens), codes().stop, dtype=np.int64)
        params = np.zeros((len(self.tokens), P.MAX_PARAMS), dtype=np.int64)
        write_codes(self._draws, kinds, params)
        return kinds, params


@lru_cache(maxsize=None)
def vocabulary(dim: int) -> Vocabulary:
    """The CSGNet vocabulary of ``dim`` (2 or 3); built once per process."""
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    return Vocabulary(dim, tuple(_primitive_texts(dim)) + tuple(OPERATORS) + (STOP,))


@P.on_change
def _table_changed() -> None:
    codes.cache_clear()
    vocabulary.cache_clear()
