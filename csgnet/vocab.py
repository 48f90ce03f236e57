"""Token <-> index tables of CSGNet, built exactly as ``../specs/csg.md`` (a) describes.

The vocabulary is every grammar primitive that fits in the canvas, as its (truncated, in 3D) token text,
sorted as plain Python strings, followed by ``+ * - $``. 2D: 400 tokens (circles 0-90, squares 91-259,
triangles 260-395, ``+`` 396, ``*`` 397, ``-`` 398, ``$`` 399). 3D: 6635 tokens (spheres 0-648, cubes
649-1989, cylinders 1990-6630, ``+`` 6631, ``*`` 6632, ``-`` 6633, ``$`` 6634). The decoder's input
one-hot has one more entry, START (index ``len(vocab)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from typing import Iterable

import numpy as np

from . import primitives as P
from .lang import OPERATORS, STOP, Draw, Op, Program, parse

__all__ = ["Vocabulary", "vocabulary", "KIND_CODES", "OP_CODES", "STOP_CODE"]

GRID = tuple(range(8, 57, 8))  # positions 8, 16, ..., 56
SIZES = tuple(range(8, 33, 4))  # radii and heights 8, 12, ..., 32

# Integer codes of token kinds, shared with the renderers.
KIND_CODES = {"c": 0, "s": 1, "t": 2, "p": 3, "u": 4, "y": 5}
OP_CODES = {"+": 6, "*": 7, "-": 8}
STOP_CODE = 9
PAD_CODE = 9  # padding is a stop


def write_codes(tokens, kinds: np.ndarray, params: np.ndarray) -> None:
    """Write the renderer codes of ``tokens`` (:class:`Draw`, :class:`Op`; anything else is left as it
    is) into ``kinds[i]`` and ``params[i, :n]`` (zero-padded rows of 5)."""
    for i, t in enumerate(tokens):
        if isinstance(t, Draw):
            kinds[i] = KIND_CODES[t.kind]
            params[i, : len(t.params)] = t.params
        elif isinstance(t, Op):
            kinds[i] = OP_CODES[t.op]


def _fits_2d(kind: str, x: int, y: int, r: int) -> bool:
    if kind == "c":
        return x - r >= 0 and y - r >= 0 and x + r <= 63 and y + r <= 63
    # the spec's square and triangle rules bound the rasteriser's own truncated extents
    if kind == "s":
        lo_row, hi_row, lo_col, hi_col = P.square_bounds(x, y, r)
    else:
        hi_row, lo_row, lo_col, hi_col = P.triangle_vertices(x, y, r)
    return lo_row >= 0 and lo_col >= 0 and hi_row <= 63 and hi_col <= 63


def _fits_3d(kind: str, x: int, y: int, z: int, r: int, h: int | None = None) -> bool:
    if kind == "p":
        return all(c - (r - 1) >= 0 and c + (r - 1) <= 63 for c in (x, y, z))
    if kind == "u":
        return all(c - r // 2 >= 0 and c + r // 2 <= 63 for c in (x, y, z))
    return (all(c - (r - 1) >= 0 and c + (r - 1) <= 63 for c in (x, y))
            and z - h // 2 >= 0 and z + h // 2 <= 63)


def _primitive_texts(dim: int) -> list[str]:
    out = []
    if dim == 2:
        for k in "cst":
            for x in GRID:
                for y in GRID:
                    for r in SIZES:
                        if _fits_2d(k, x, y, r):
                            out.append(f"{k}({x},{y},{r})")
    else:
        for k in "puy":
            for x in GRID:
                for y in GRID:
                    for z in GRID:
                        for r in SIZES:
                            if k == "y":
                                out += [f"y({x},{y},{z},{r},{h})" for h in SIZES if _fits_3d(k, x, y, z, r, h)]
                            elif _fits_3d(k, x, y, z, r):
                                out.append(f"{k}({x},{y},{z},{r})")
    return sorted(out)


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
        kinds = np.full(len(self.tokens), STOP_CODE, dtype=np.int64)
        params = np.zeros((len(self.tokens), 5), dtype=np.int64)
        write_codes(self._draws, kinds, params)
        return kinds, params


@lru_cache(maxsize=None)
def vocabulary(dim: int) -> Vocabulary:
    """The CSGNet vocabulary of ``dim`` (2 or 3); built once per process."""
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim}")
    return Vocabulary(dim, tuple(_primitive_texts(dim)) + tuple(OPERATORS) + (STOP,))
