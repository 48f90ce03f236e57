"""Synthetic CSG program datasets: the sampler, dataset files, a torch ``Dataset`` and the 2D jitter.

The paper's generator is not public; this module follows the supplementary's rules
(``../specs/csg.md`` section (c)) and writes down every choice the text leaves open.

Sampling (:func:`sample_programs`)
    A program of length ``L`` has ``n = (L + 1) // 2`` primitives and ``n - 1`` operators. A candidate
    is drawn as

    1. a binary CSG tree shape, uniform over the ``Catalan(n - 1)`` shapes, written in postfix;
    2. for every leaf, a primitive type drawn from ``type_weights`` (uniform by default), then a
       primitive of that type uniformly from the vocabulary, so every primitive lies inside the canvas
       (rule (a)); note that the vocabulary holds unequal numbers of each type, which is why the type
       is drawn first;
    3. for every operator, ``+ * -`` drawn with ``op_weights`` (default ``(1, 5, 3)`` in 2D and
       ``(1, 8, 6)`` in 3D: subtract and intersect boosted, rule (d), so that the accepted operators come
       out closer to uniform).

    Candidates are rendered in batches with the bit-packed renderer (:mod:`csgnet.renderer`), pixel
    counts come from a popcount of the packed words, and a candidate is kept only if it passes:

    * **rule (b), every operation changes the pixel count** (``change_rule="operands"``, the default).
      For an operation ``R = op(A, B)`` (``A`` the earlier operand) let
      ``tau = min_change * (ON(A) + ON(B))`` with ``min_change = 0.1``. The result must differ in ON
      pixels by at least ``tau`` from every operand it contains or is contained in, and must keep at
      least ``tau`` pixels itself:

      - union ``A + B``:        ``|A \\ B| >= tau`` and ``|B \\ A| >= tau``
        (``ON(R) - ON(B)`` and ``ON(R) - ON(A)``: neither operand (nearly) swallows the other);
      - intersection ``A * B``: ``|A \\ B| >= tau``, ``|B \\ A| >= tau`` and ``|A & B| >= tau``
        (``ON(A) - ON(R)``, ``ON(B) - ON(R)`` and ``ON(R)``: it cuts both and is not (nearly) empty);
      - subtraction ``A - B``:  ``|A & B| >= tau`` and ``|A \\ B| >= tau``
        (``ON(A) - ON(R)`` and ``ON(R)``: it removes something and leaves something).

      Why not the literal "ON(A) + ON(B) - ON(R)" (pixels on the stack before and after): under that
      reading a union of disjoint shapes is rejected while a union with a shape inside the other one
      passes, and intersections pass almost always, which contradicts the supplementary's remark that
      rule (b) favours unions. The literal reading is still available as ``change_rule="sum"``:
      ``ON(A) + ON(B) - ON(R) >= tau`` for ``+`` and ``*``, ``ON(A) - ON(R) >= tau`` for ``-``.
    * **rule (c), the final shape is large enough:** ``ON(result) >= min_pixels``; the paper gives no
      value, ours defaults to 100 pixels in 2D (2.4 % of the canvas, about the smallest vocabulary
      triangle) and 1000 voxels in 3D (0.4 %, between the smallest cube and the smallest sphere).
    * **no duplicates:** programs are compared as token sequences (textual identity; ``A+B`` and
      ``B+A`` are different programs), within a length and across its three splits.

    Rules (b) and (c) act after the draws, so the *accepted* type and operator frequencies are not the
    drawing weights; ``python bench/bench_csg_data.py`` prints them.

Files (:func:`generate_dataset`, :func:`load_dataset`)
    ``<out>/<dim>d/len_<LL>/{train,val,test}.txt``, one program per line in the dataset text format
    (2D ``c(32,32,28)s(32,32,20)+``, 3D long form ``sp(32,32,32,8)cu(16,16,16,12)+``), and
    ``<out>/<dim>d/meta.json`` (dim, seed, scale, lengths, counts, rules, versions). Split sizes are the
    paper's Table 2 times ``scale``, rounded, at least 1. Generation is deterministic for a seed:
    programs come in fixed chunks of ``chunk_size`` programs, chunk ``i`` of length ``L`` drawing from
    ``numpy.random.default_rng([seed, dim, L, i])``; chunks are merged in index order (dropping
    programs seen in an earlier chunk) and the merged list is cut into train, val and test. The files
    are therefore identical for any number of worker processes.

Training helpers
    :class:`ProgramDataset` (token indices padded with ``$`` and lengths) and :func:`jitter` (the 2D
    Keras-style random affine augmentation of section (c)).
"""

from __future__ import annotations

import json
import math
import platform
import warnings
from dataclasses import asdict, dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import torch

from shapeio import atomic_write

from .lang import Program, parse_lines
from .renderer import StackMachine, apply_op_, encode_tokens, popcount, primitive_cache
from . import primitives as P
from .vocab import codes, vocabulary

__all__ = [
    "TABLE2",
    "SPLITS",
    "Rules",
    "split_sizes",
    "sample_programs",
    "check_programs",
    "generate_dataset",
    "load_dataset",
    "ProgramDataset",
    "jitter",
]

FORMAT_VERSION = 1
SPLITS = ("train", "val", "test")

# Paper Table 2: (train, val, test) programs per length.
TABLE2 = {
    2: {3: (25_000, 5_000, 5_000), 5: (100_000, 10_000, 50_000), 7: (150_000, 20_000, 50_000),
        9: (250_000, 20_000, 50_000), 11: (350_000, 20_000, 100_000), 13: (350_000, 20_000, 100_000)},
    3: {3: (100_000, 10_000, 20_000), 5: (200_000, 20_000, 40_000), 7: (400_000, 40_000, 80_000)},
}

_OPS = "+*-"
_OP_WEIGHTS = {2: (1.0, 5.0, 3.0), 3: (1.0, 8.0, 6.0)}


@dataclass(frozen=True)
class Rules:
    """The sampling rules (see the module docstring). Every field is recorded in ``meta.json``.

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
            if len(w) != 3 and name == "op_weights" or min(w, default=-1) < 0 or sum(w) <= 0:
                many = "3" if name == "op_weights" else "per primitive type:"
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


def _lengths(dim: int, lengths: Iterable[int] | None) -> list[int]:
    _check_dim(dim)
    if lengths is None:
        return sorted(TABLE2[dim])
    out = sorted({int(L) for L in lengths})
    bad = [L for L in out if L not in TABLE2[dim]]
    if bad:
        raise ValueError(f"lengths {bad} are not {dim}D program lengths; expected some of {sorted(TABLE2[dim])}")
    return out


def split_sizes(dim: int, scale: float, lengths: Iterable[int] | None = None) -> dict[int, dict[str, int]]:
    """Programs per length and split: paper Table 2 times ``scale``, rounded half up, at least 1."""
    if not scale > 0:
        raise ValueError(f"scale must be > 0, got {scale}")
    return {L: {s: max(1, int(math.floor(n * scale + 0.5))) for s, n in zip(SPLITS, TABLE2[dim][L])}
            for L in _lengths(dim, lengths)}


# ---------------------------------------------------------------------------------------------
# sampling

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


def _chunk_job(args) -> np.ndarray:
    """One chunk of programs; runs in a worker process. Seeded by (seed, dim, length, chunk)."""
    dim, length, seed, chunk, rules = args
    rng = np.random.default_rng([seed, dim, length, chunk])
    return sample_programs(dim, length, rules.chunk_size, rng, rules).astype(np.int16)


def _worker_init() -> None:
    torch.set_num_threads(1)


# ---------------------------------------------------------------------------------------------
# files

def _split_path(root: Path, dim: int, length: int, split: str) -> Path:
    return root / f"{dim}d" / f"len_{length:02d}" / f"{split}.txt"


@lru_cache(maxsize=None)
def _token_texts(dim: int) -> tuple[str, ...]:
    vocab = vocabulary(dim)
    out = []
    for i, t in enumerate(vocab.tokens):
        if t in _OPS or t == "$":
            out.append(t)
        else:
            out.append(vocab.decode([i]).text(long=True))
    return tuple(out)


P.on_change(_token_texts.cache_clear)


def _lines(rows: np.ndarray, dim: int) -> str:
    texts = _token_texts(dim)
    return "".join("".join(texts[i] for i in row) + "\n" for row in rows.tolist())


def generate_dataset(out_dir, dim: int = 2, scale: float = 0.001, seed: int = 0, workers: int = 1,
                     lengths: Iterable[int] | None = None, progress: bool = True, **rules) -> dict:
    """Generate a synthetic dataset and write it under ``out_dir/<dim>d/``.

    Args:
        out_dir: dataset directory (created).
        dim: 2 or 3.
        scale: fraction of the paper's Table 2 sizes (``0.001``: 25/5/5 programs of length 3 in 2D).
        seed: the seed; the same seed gives identical files for any ``workers``.
        workers: processes (``1``: in this process).
        lengths: program lengths (default: all of the dimension, 3-13 in 2D, 3-7 in 3D).
        progress: show a tqdm progress bar.
        **rules: :class:`Rules` fields (``min_change``, ``change_rule``, ``min_pixels``, ``op_weights``,
            ``type_weights``, ``chunk_size``, ``batch_size``).

    Returns:
        ``{length: {"train": n, "val": n, "test": n}}``, the programs written.
    """
    _check_dim(dim)
    rules_ = Rules.from_kwargs(dim, **rules)
    lengths_ = _lengths(dim, lengths)
    sizes = split_sizes(dim, scale, lengths_)
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    workers = int(workers)
    root = Path(out_dir)
    totals = {L: sum(sizes[L].values()) for L in lengths_}
    plan = [(L, i) for L in lengths_ for i in range(-(-totals[L] // rules_.chunk_size))]

    from tqdm.auto import tqdm

    bar = tqdm(total=sum(totals.values()), desc=f"{dim}D programs", unit="prog", disable=not progress)
    pool = None
    if workers > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_init)
    futures: dict = {}
    nxt = 0

    def get(L: int, i: int) -> np.ndarray:
        nonlocal nxt
        job = (dim, L, seed, i, rules_)
        if pool is None:
            return _chunk_job(job)
        while nxt < len(plan) and len(futures) < 2 * workers:
            pL, pi = plan[nxt]
            futures[(pL, pi)] = pool.submit(_chunk_job, (dim, pL, seed, pi, rules_))
            nxt += 1
        fut = futures.pop((L, i), None) or pool.submit(_chunk_job, job)
        return fut.result()

    try:
        for L in lengths_:
            seen: set = set()
            rows: list[np.ndarray] = []
            i = 0
            while len(rows) < totals[L]:
                before = len(rows)
                for row in get(L, i).astype(np.int64):
                    key = row.tobytes()
                    if key not in seen:
                        seen.add(key)
                        rows.append(row)
                        if len(rows) == totals[L]:
                            break
                bar.update(len(rows) - before)
                i += 1
            start = 0
            for split in SPLITS:
                k = sizes[L][split]
                atomic_write(_split_path(root, dim, L, split), _lines(np.stack(rows[start:start + k]), dim), mkdir=True)
                start += k
    finally:
        bar.close()
        if pool is not None:
            for f in futures.values():
                f.cancel()
            pool.shutdown(wait=True, cancel_futures=True)

    meta = {
        "format": "one program per line, postfix, no '$' (2D c/s/t, 3D long form sp/cu/cy)",
        "format_version": FORMAT_VERSION,
        "dim": dim,
        "seed": seed,
        "scale": scale,
        "lengths": lengths_,
        "counts": {str(L): sizes[L] for L in lengths_},
        "rules": asdict(rules_),
        "versions": {"numpy": np.__version__, "torch": torch.__version__.split("+")[0],
                     "python": platform.python_version()},
    }
    atomic_write(root / f"{dim}d" / "meta.json", json.dumps(meta, indent=2) + "\n", mkdir=True)
    return {L: dict(sizes[L]) for L in lengths_}


def load_dataset(path, dim: int, split: str, lengths: Iterable[int] | None = None, *,
                 errors: str = "warn") -> dict[int, list[Program]]:
    """Read one split of a dataset written by :func:`generate_dataset`.

    Args:
        path: the dataset directory (the ``out_dir`` given to :func:`generate_dataset`).
        dim: 2 or 3.
        split: ``"train"``, ``"val"`` or ``"test"``.
        lengths: lengths to read (default: those in ``meta.json``, else every ``len_*`` folder).
        errors: a bad line (unparsable, or a program whose length is not the file's) is reported as
            ``file:line: reason``. ``"warn"`` (default) issues one ``UserWarning`` listing every bad line
            and keeps the good programs; ``"raise"`` raises one ``ValueError`` listing them all.

    Returns:
        ``{length: [Program, ...]}`` in file order.
    """
    _check_dim(dim)
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    if errors not in ("warn", "raise"):
        raise ValueError(f"errors must be 'warn' or 'raise', got {errors!r}")
    base = Path(path) / f"{dim}d"
    if lengths is None:
        meta = base / "meta.json"
        if meta.exists():
            lengths = json.loads(meta.read_text())["lengths"]
        else:
            lengths = sorted(int(p.name[4:]) for p in base.glob("len_*") if p.name[4:].isdigit())
        if not lengths:
            raise FileNotFoundError(f"no {dim}D dataset under {str(base)!r} (expected len_XX folders)")
    out: dict[int, list[Program]] = {}
    bad: list[str] = []
    for L in sorted(int(v) for v in lengths):
        f = _split_path(Path(path), dim, L, split)
        if not f.exists():
            raise FileNotFoundError(f"missing dataset file {str(f)!r}")
        with open(f, encoding="utf-8") as fh:
            lines = fh.read().splitlines()
        programs, errs = parse_lines(lines, dim, file=str(f), errors="collect")
        bad += [str(e) for e in errs]
        # parse_lines drops bad and blank lines; match programs back to line numbers for the length check
        err_lines = {e.line for e in errs}
        numbers = [i for i, s in enumerate(lines, 1) if s.strip() and i not in err_lines]
        keep = []
        for no, p in zip(numbers, programs):
            if len(p) != L:
                bad.append(f"{f}:{no}: program has {len(p)} tokens, expected {L} in {p.text()!r}")
            else:
                keep.append(p)
        out[L] = keep
    if bad:
        msg = f"{len(bad)} bad line(s) in the {dim}D {split} split:\n  " + "\n  ".join(bad)
        if errors == "raise":
            raise ValueError(msg)
        warnings.warn(msg + "\nthe other programs were loaded", UserWarning, stacklevel=2)
    return out


# ---------------------------------------------------------------------------------------------
# torch dataset and augmentation

class ProgramDataset(torch.utils.data.Dataset):
    """Programs as padded token indices, for supervised training.

    Item ``i`` is ``(tokens, length)``: ``tokens (max_len + 1,) int64`` holds the program's token
    indices followed by ``$`` (the stop index) up to the end, ``length`` the number of program tokens
    (without ``$``). The supervised targets are ``tokens[:length + 1]``.

    Args:
        programs: :class:`~csgnet.lang.Program` objects or texts of one dimension.
        dim: 2 or 3.
        max_len: pad to this many program tokens (default: the longest program).

    Raises:
        KeyError: a primitive outside the vocabulary.
        ValueError: a program longer than ``max_len``.
    """

    def __init__(self, programs: Sequence[Program | str], dim: int, max_len: int | None = None):
        _check_dim(dim)
        vocab = vocabulary(dim)
        encoded = [vocab.encode(p) for p in programs]
        longest = max((len(e) for e in encoded), default=0)
        self.max_len = longest if max_len is None else int(max_len)
        if longest > self.max_len:
            raise ValueError(f"a program has {longest} tokens, more than max_len={self.max_len}")
        self.dim = dim
        self.tokens = torch.full((len(encoded), self.max_len + 1), vocab.stop, dtype=torch.int64)
        for i, e in enumerate(encoded):
            self.tokens[i, : len(e)] = torch.tensor(e, dtype=torch.int64)
        self.lengths = torch.tensor([len(e) for e in encoded], dtype=torch.int64)

    def __len__(self) -> int:
        return self.tokens.shape[0]

    def __getitem__(self, i: int) -> tuple[torch.Tensor, torch.Tensor]:
        return self.tokens[i], self.lengths[i]


_CENTRE = 32.5  # Keras' centre h / 2 + 0.5


def jitter(images, generator, shift: float = 3.0, zoom: float = 2.0 / 64.0):
    """The 2D training augmentation: a Keras-style random affine per image, nearest-neighbour.

    Output pixel ``p = (row, col)`` samples the input at ``Z (p - c) + t + c`` with ``c = (32.5, 32.5)``,
    ``t = (t_row, t_col)`` each uniform in ``[-shift, shift]`` and ``Z = diag(z_row, z_col)`` each uniform
    in ``[1 - zoom, 1 + zoom]``; samples outside the canvas take the nearest edge value
    (``scipy.ndimage.affine_transform(order=0, mode='nearest')``). Per image the draws come in the order
    ``t_row, t_col, z_row, z_col`` (``../specs/csg.md`` section (c)).

    Args:
        images: (B, 64, 64) bool, NumPy array or torch tensor.
        generator: ``numpy.random.Generator`` or ``torch.Generator`` (consumed: 4 uniforms per image).
        shift: translation range in pixels (3 in the reference).
        zoom: zoom range (2/64 in the reference).

    Returns:
        (B, 64, 64) bool, the same type (and device) as ``images``.
    """
    from scipy.ndimage import affine_transform

    is_torch = isinstance(images, torch.Tensor)
    arr = images.detach().cpu().numpy() if is_torch else np.asarray(images)
    if arr.ndim != 3 or arr.shape[1:] != (64, 64):
        raise ValueError(f"images must be (B, 64, 64), got shape {tuple(arr.shape)}")
    B = arr.shape[0]
    if isinstance(generator, torch.Generator):
        u = torch.rand((B, 4), generator=generator, dtype=torch.float64).numpy()
    elif isinstance(generator, np.random.Generator):
        u = generator.random((B, 4))
    else:
        raise TypeError(f"generator must be a numpy.random.Generator or torch.Generator, got {type(generator).__name__}")
    t = -shift + 2.0 * shift * u[:, :2]
    z = (1.0 - zoom) + 2.0 * zoom * u[:, 2:]
    c = np.array([_CENTRE, _CENTRE])
    src = arr.astype(np.uint8)
    out = np.empty_like(src)
    for b in range(B):
        affine_transform(src[b], z[b], offset=t[b] + c - z[b] * c, output=out[b], order=0, mode="nearest")
    out = out.astype(bool)
    return torch.from_numpy(out).to(images.device) if is_torch else out
