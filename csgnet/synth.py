"""The synthetic CSG program sampler: the supplementary's rules, drawn bottom-up in batches.

:func:`sample_programs` draws distinct rule-abiding programs as token indices, :func:`check_programs`
checks programs against rules (b) and (c), :class:`Rules` holds every choice the spec leaves open, and
:func:`sample_chunk` is the seeded unit of work of :func:`csgnet.data.generate_dataset`. The primitive
types and their default weights are the rows of :mod:`csgnet.primitives`. The reading of each rule
is written down in docs/csgnet.md ("Synthetic data").
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import torch

from . import primitives as P
from .renderer import StackMachine, apply_op_, encode_tokens, popcount, primitive_cache
from .vocab import codes, vocabulary

__all__ = ["Rules", "sample_programs", "check_programs", "sample_chunk"]

_OPS = "+*-"
_OP_WEIGHTS = {2: (1.0, 5.0, 3.0), 3: (1.0, 8.0, 6.0)}


@dataclass(frozen=True)
class Rules:
    """The sampling rules (see docs/csgnet.md, "Synthetic data"). Every field is recorded in ``meta.json``.

    Attributes:
        min_change: rule (b) threshold as a fraction of ``ON(A) + ON(B)``.
        change_rule: ``"operands"`` (default) or ``"sum"`` (the literal stack-total reading).
        min_pixels: rule (c): least ON pixels (voxels) of the final shape; ``None`` = 100 (2D), 1000 (3D).
        op_weights: drawing weights of ``+``, ``*``, ``-``; ``None`` = ``(1, 5, 3)`` (2D), ``(1, 8, 6)``
            (3D): subtract and intersect boosted so that the accepted operators are closer to uniform.
        type_weights: drawing weights of the primitive types, in table order (2D c, s, t; 3D sphere,
            cube, cylinder); ``None`` = each row's ``synth_weight`` (all 1).
        retries: failed pairings after which an operand subtree is discarded (0: exact rejection
            sampling, see :func:`sample_programs`).
        chunk_size: accepted programs per chunk (the unit of parallel work and of seeding).
        batch_size: subtrees combined per batch; ``None`` = 256 (2D), 64 (3D).
    """

    min_change: float = 0.1
    change_rule: str = "operands"
    min_pixels: int | None = None
    op_weights: tuple[float, float, float] | None = None
    type_weights: tuple[float, ...] | None = None
    retries: int = 3
    chunk_size: int = 256
    batch_size: int | None = None

    def __post_init__(self):
        if self.change_rule not in ("operands", "sum"):
            raise ValueError(f"change_rule must be 'operands' or 'sum', got {self.change_rule!r}")
        if not 0 <= self.min_change < 1:
            raise ValueError(f"min_change must lie in [0, 1), got {self.min_change}")
        for name in ("op_weights", "type_weights"):
            if getattr(self, name) is None:
                continue
            w = tuple(float(v) for v in getattr(self, name))
            count_ok = len(w) == 3 if name == "op_weights" else len(w) > 0  # types: checked per dim in resolved()
            if not count_ok or min(w) < 0 or sum(w) <= 0:
                many = "3" if name == "op_weights" else "one or more"
                raise ValueError(f"{name} must be {many} non-negative weights with a positive sum, got {w}")
            object.__setattr__(self, name, w)
        if self.chunk_size < 1:
            raise ValueError(f"chunk_size must be >= 1, got {self.chunk_size}")

    def resolved(self, dim: int) -> "Rules":
        """These rules with the per-dimension defaults filled in."""
        types = P.primitives(dim)
        if self.type_weights is not None and len(self.type_weights) != len(types):
            raise ValueError(f"type_weights must have one weight per {dim}D primitive type "
                             f"({', '.join(p.name for p in types)}), got {self.type_weights}")
        return replace(self,
                       type_weights=self.type_weights if self.type_weights is not None else
                       tuple(float(p.synth_weight) for p in types),
                       op_weights=self.op_weights if self.op_weights is not None else _OP_WEIGHTS[dim],
                       min_pixels=self.min_pixels if self.min_pixels is not None else (100 if dim == 2 else 1000),
                       batch_size=self.batch_size if self.batch_size is not None else (256 if dim == 2 else 64))

    @classmethod
    def from_kwargs(cls, dim: int, **kwargs) -> "Rules":
        names = set(cls.__dataclass_fields__)
        unknown = sorted(set(kwargs) - names)
        if unknown:
            raise TypeError(f"unknown sampling rule(s) {unknown}; expected some of {sorted(names)}")
        return cls(**kwargs).resolved(dim)


def _check_dim(dim: int) -> None:
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")



@lru_cache(maxsize=None)
def _tree_patterns(n: int) -> np.ndarray:
    """(Catalan(n-1), 2n-1) bool: the postfix draw (True) / operator (False) patterns of all binary
    trees with ``n`` leaves."""
    @lru_cache(maxsize=None)
    def shapes(k: int) -> tuple[tuple[bool, ...], ...]:
        if k == 1:
            return ((True,),)
        return tuple(a + b + (False,) for i in range(1, k) for a in shapes(i) for b in shapes(k - i))

    return np.array(shapes(n), dtype=bool)


@lru_cache(maxsize=None)
def _type_tables(dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per primitive type: first vocabulary index and count; and the op token indices."""
    vocab = vocabulary(dim)
    kinds, _ = vocab.table()
    type_codes = [codes().kind[p.kind] for p in P.primitives(dim)]
    first = np.array([int(np.flatnonzero(kinds == c)[0]) for c in type_codes], dtype=np.int64)
    count = np.array([int((kinds == c).sum()) for c in type_codes], dtype=np.int64)
    for f, c, code in zip(first, count, type_codes):  # each type is one contiguous block (sorted by letter)
        assert (kinds[f:f + c] == code).all()
    ops = np.array([vocab.op_index(o) for o in _OPS], dtype=np.int64)
    return first, count, ops


P.on_change(_type_tables.cache_clear)


def _weights(w) -> np.ndarray:
    return np.asarray(w) / sum(w)


def _draw_primitives(dim: int, rules: Rules, shape, rng: np.random.Generator) -> np.ndarray:
    """Vocabulary indices of random primitives, ``shape`` of them: a type drawn with ``type_weights``,
    then a primitive of that type uniformly."""
    first, count, _ = _type_tables(dim)
    types = rng.choice(len(first), size=shape, p=_weights(rules.type_weights))
    u = rng.random(shape)
    return first[types] + np.minimum((u * count[types]).astype(np.int64), count[types] - 1)


def _draw_candidates(dim: int, length: int, rules: Rules, size: int, rng: np.random.Generator) -> np.ndarray:
    """(size, length) int64 token indices of random valid programs (not yet checked against the rules)."""
    n = (length + 1) // 2
    patterns = _tree_patterns(n)
    ops = _type_tables(dim)[2]
    mask = patterns[rng.integers(len(patterns), size=size)]
    prims = _draw_primitives(dim, rules, (size, n), rng)
    opers = ops[rng.choice(3, size=(size, n - 1), p=_weights(rules.op_weights))]
    tokens = np.empty((size, length), dtype=np.int64)
    tokens[mask] = prims.ravel()  # boolean assignment fills row-major: each row has n draws
    tokens[~mask] = opers.ravel()
    return tokens


def check_programs(tokens: np.ndarray | torch.Tensor, dim: int, rules: Rules | None = None) -> np.ndarray:
    """Which programs satisfy rules (b) and (c).

    Args:
        tokens: (B, T) int token indices of valid programs of one length ``T`` (no ``$``).
        dim: 2 or 3.
        rules: the rules (defaults if None).

    Returns:
        (B,) bool.
    """
    rules = (rules or Rules()).resolved(dim)
    tokens = torch.as_tensor(np.asarray(tokens), dtype=torch.int64)
    if tokens.dim() != 2:
        raise ValueError(f"tokens must be (B, T), got shape {tuple(tokens.shape)}")
    B, T = tokens.shape
    kinds, _ = encode_tokens(tokens, dim)
    machine = StackMachine(B, dim, T // 2 + 1)
    ok = np.ones(B, dtype=bool)
    kinds_np = kinds.numpy()
    for t in range(T):
        rows = np.flatnonzero(codes().is_op(kinds_np[:, t]) & ok)
        if rows.size:
            top = machine.top(2).index_select(0, torch.from_numpy(rows))
            a, b = popcount(top[:, 1]), popcount(top[:, 0])
            ab = popcount(top[:, 1] & top[:, 0])
            good = _op_passes(a, b, ab, kinds_np[rows, t], rules)
            ok[rows[~good]] = False
        machine.step(kinds[:, t], token_ids=tokens[:, t])
    ok &= popcount(machine.result()) >= rules.min_pixels
    return ok


def _result_count(a: np.ndarray, b: np.ndarray, ab: np.ndarray, op: np.ndarray) -> np.ndarray:
    """``ON(op(A, B))`` from ``ON(A)``, ``ON(B)``, ``ON(A & B)`` and the operator kind codes."""
    c = codes().op
    return np.where(op == c["+"], a + b - ab, np.where(op == c["*"], ab, a - ab))


def _op_passes(a: np.ndarray, b: np.ndarray, ab: np.ndarray, op: np.ndarray, rules: Rules) -> np.ndarray:
    """Rule (b) for operations ``op(A, B)`` given ``ON(A)``, ``ON(B)``, ``ON(A & B)`` and the operator
    kind codes, all ``(N,)``."""
    tau = rules.min_change * (a + b)
    union, inter = op == codes().op["+"], op == codes().op["*"]
    a_only, b_only = a - ab, b - ab
    if rules.change_rule == "operands":
        return np.where(union, (a_only >= tau) & (b_only >= tau),
                        np.where(inter, (a_only >= tau) & (b_only >= tau) & (ab >= tau),
                                 (ab >= tau) & (a_only >= tau)))
    result = _result_count(a, b, ab, op)
    return np.where(union | inter, a + b - result >= tau, a - result >= tau)


def _catalan(k: int) -> int:
    return math.comb(2 * k, k) // (k + 1)


class _Builder:
    """Bottom-up sampler of rule-abiding subtrees (see :func:`sample_programs`).

    ``pools[k]`` holds accepted subtrees with ``k`` leaves: token indices ``(m, 2k-1)``, packed canvases
    ``(m, *C)``, ON counts ``(m,)`` and the number of failed pairings ``(m,)``.
    """

    def __init__(self, dim: int, rules: Rules, rng: np.random.Generator):
        self.dim, self.rules, self.rng = dim, rules, rng
        self.ops = _type_tables(dim)[2]
        self.op_codes = np.array([codes().op[o] for o in _OPS], dtype=np.int64)
        self.ow = _weights(rules.op_weights)
        self.pools: dict[int, list] = {}

    def _primitives(self, m: int):
        idx = _draw_primitives(self.dim, self.rules, m, self.rng)
        canvas = primitive_cache(self.dim, "cpu").get(torch.from_numpy(idx))
        return [idx[:, None], canvas, popcount(canvas), np.zeros(m, dtype=np.int64)]

    def take(self, k: int, m: int):
        """``m`` subtrees with ``k`` leaves (removed from the pool)."""
        if k == 1:
            return self._primitives(m)
        idle = 0
        while k not in self.pools or len(self.pools[k][0]) < m:
            before = len(self.pools[k][0]) if k in self.pools else 0
            self._grow(k, max(m, self.rules.batch_size))
            idle = idle + 1 if (k not in self.pools or len(self.pools[k][0]) <= before) else 0
            if idle >= 100:
                raise RuntimeError(f"no {self.dim}D subtree with {k} leaves passed rule (b) in 100 batches; "
                                   f"the rules are too strict ({self.rules})")
        pool = self.pools[k]
        out = [a[:m] for a in pool]
        self.pools[k] = [a[m:] for a in pool]
        return out

    def _give_back(self, k: int, items) -> None:
        if k == 1 or len(items[0]) == 0:
            return  # primitives are drawn fresh
        if k in self.pools:
            self.pools[k] = [np.concatenate([p, q]) if isinstance(p, np.ndarray) else torch.cat([p, q])
                             for p, q in zip(self.pools[k], items)]
        else:
            self.pools[k] = items

    def _grow(self, k: int, size: int) -> None:
        """Try ``size`` combinations ``op(left, right)`` with ``k`` leaves in all; keep those passing rule (b)."""
        js = np.arange(1, k)
        w = np.array([_catalan(j - 1) * _catalan(k - j - 1) for j in js], dtype=np.float64)
        split = self.rng.choice(js, size=size, p=w / w.sum())
        for j in js:
            m = int((split == j).sum())
            if m == 0:
                continue
            left, right = self.take(j, m), self.take(k - j, m)
            choice = self.rng.choice(3, size=m, p=self.ow)
            op, code = self.ops[choice], self.op_codes[choice]
            la, ra = left[1], right[1]
            ab = popcount(la & ra)
            good = _op_passes(left[2], right[2], ab, code, self.rules)
            g = torch.from_numpy(good)
            res = _combine(la[g], ra[g], code[good])
            cnt = _result_count(left[2][good], right[2][good], ab[good], code[good])
            tokens = np.concatenate([left[0][good], right[0][good], op[good][:, None]], axis=1)
            self._give_back(k, [tokens, res, cnt, np.zeros(len(cnt), dtype=np.int64)])
            bad = ~good
            for jj, side in ((j, left), (k - j, right)):
                fails = side[3][bad] + 1
                keep = fails <= self.rules.retries
                kb = bad.copy()
                kb[bad] = keep
                self._give_back(jj, [side[0][kb], side[1][torch.from_numpy(kb)], side[2][kb], fails[keep]])


def _combine(a: torch.Tensor, b: torch.Tensor, code: np.ndarray) -> torch.Tensor:
    """Packed canvases ``op(a[i], b[i])`` for the operator kind codes ``code``; ``a``, ``b``: (N, *C)."""
    out = torch.empty_like(a)
    for op in codes().op.values():
        rows = torch.from_numpy(np.flatnonzero(code == op))
        if len(rows):
            out[rows] = apply_op_(op, a[rows], b[rows])  # the gathers are copies: a and b stay as they are
    return out


def sample_programs(dim: int, length: int, n: int, rng: np.random.Generator, rules: Rules | None = None,
                    exclude: set | None = None) -> np.ndarray:
    """Draw ``n`` distinct programs that satisfy the rules.

    The sampler works bottom-up and in batches: a program with ``n`` leaves is ``op(left, right)`` where
    the split of the leaves is drawn so that tree shapes are uniform, ``left`` and ``right`` are
    themselves rule-abiding subtrees drawn the same way, and the operator is drawn from ``op_weights``;
    rule (b) is checked at every node on the packed canvases (popcounts of ``A``, ``B`` and ``A & B``).
    When a combination fails, both operands go back to their pools to be paired with other partners,
    up to ``retries`` failures each (``retries=0`` discards them, which is exactly whole-program rejection
    sampling with a uniform tree shape, and much slower for long programs). Rule (c) and the
    duplicate check act on the whole program.

    Args:
        dim: 2 or 3.
        length: program length (odd; 3-13 in 2D, 3-7 in 3D).
        n: number of programs.
        rng: the random source (consumed).
        rules: :class:`Rules` (defaults if None).
        exclude: token rows (``bytes`` of int64 rows) to avoid; updated with the drawn programs.

    Returns:
        (n, length) int64 token indices, in the order they were accepted.
    """
    _check_dim(dim)
    if length < 3 or length % 2 == 0:
        raise ValueError(f"program length must be odd and >= 3, got {length}")
    rules = (rules or Rules()).resolved(dim)
    seen = set() if exclude is None else exclude
    builder = _Builder(dim, rules, rng)
    leaves = (length + 1) // 2
    out: list[np.ndarray] = []
    while len(out) < n:
        tokens, _, count, _ = builder.take(leaves, min(rules.batch_size, max(n - len(out), 1) * 2))
        for row, c in zip(tokens, count):
            if c < rules.min_pixels:
                continue
            key = row.tobytes()
            if key in seen:
                continue
            seen.add(key)
            out.append(row)
            if len(out) == n:
                break
    return np.stack(out) if out else np.zeros((0, length), dtype=np.int64)


def sample_chunk(args) -> np.ndarray:
    """Chunk ``i`` of the programs of one length: ``rules.chunk_size`` programs as ``(n, length)`` int16
    token indices, drawn from ``numpy.random.default_rng([seed, dim, length, i])``.

    Args:
        args: ``(dim, length, seed, i, rules)`` (one tuple, so that a process pool can map over chunks).
    """
    dim, length, seed, chunk, rules = args
    rng = np.random.default_rng([seed, dim, length, chunk])
    return sample_programs(dim, length, rules.chunk_size, rng, rules).astype(np.int16)


def worker_init() -> None:
    """Initialiser of sampling worker processes: one torch thread each."""
    torch.set_num_threads(1)
