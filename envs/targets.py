"""Target sources of the CSG environments: where each episode's target shape comes from.

A target source is any object with a ``dim`` attribute (2 or 3) and a method
``sample(rng: numpy.random.Generator) -> Target``; the environment calls it once per episode with its
own ``np_random`` (or, in the vector environment, the sub-environment's generator), so targets follow
the environment's seeding. Three sources ship with the package:

* :class:`SyntheticTargets`: programs drawn with :func:`csgnet.synth.sample_programs` (the synthetic data
  rules), rendered by the batched renderer.
* :class:`ArrayTargets`: a list or array of bool images ``(N, 64, 64)`` or volumes ``(N, 64, 64, 64)``;
  a silhouette set stored as an ``(N, 64, 64)`` bool array plugs in here unchanged.
* :class:`ImageFolderTargets`: a folder of 64x64 PNG files.

:func:`as_target_source` turns the ``targets`` argument of the environments into a source.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Protocol, Sequence, runtime_checkable

import numpy as np
import torch

from csgnet.data import TABLE2
from csgnet.synth import sample_programs
from csgnet.primitives import SIZE
from csgnet.renderer import encode_tokens, execute
from csgnet.vocab import vocabulary
from shapeio.image import list_images, read_masks

from ._checks import check_dim, check_int

__all__ = [
    "Target",
    "TargetSource",
    "SyntheticTargets",
    "ArrayTargets",
    "ImageFolderTargets",
    "as_target_source",
]


@dataclass(frozen=True)
class Target:
    """One episode's target.

    Attributes:
        shape: ``(64, 64)`` bool image (2D) or ``(64, 64, 64)`` bool volume (3D).
        index: the target's index in its source.
        program: the program text that renders to ``shape``, when the source knows one.
    """

    shape: np.ndarray
    index: int
    program: str | None = None


@runtime_checkable
class TargetSource(Protocol):
    """What the CSG environments need from a source of target shapes."""

    dim: int

    def sample(self, rng: np.random.Generator) -> Target:
        """Draw one target with ``rng`` (the environment's random generator)."""
        ...


@lru_cache(maxsize=64)
def _synthetic_pool(dim: int, length: int, size: int, seed: int, rules) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Token indices ``(size, length) int64``, their renderings packed as ``(size, ...) uint8`` (bit ``k`` of
    byte ``j`` is pixel ``8 j + k`` of the flattened canvas) and their program texts; drawn once per
    argument set (a pure function of the arguments)."""
    rng = np.random.default_rng([seed, dim, length])
    pool = sample_programs(dim, length, size, rng, rules)
    pool.setflags(write=False)
    chunks = []
    for i in range(0, size, 256):
        ids = torch.from_numpy(pool[i:i + 256].copy())
        chunks.append(execute(*encode_tokens(ids, dim), dim, token_ids=ids).canvas)  # packed words
    words = torch.cat(chunks)
    packed = words.numpy().view(np.uint8).reshape(size, -1)
    packed.setflags(write=False)
    texts = tuple(vocabulary(dim).text(row) for row in pool)
    return pool, packed, texts


class SyntheticTargets:
    """Targets rendered from synthetic programs (:func:`csgnet.synth.sample_programs`).

    Drawing a rule-abiding program costs as much as a whole episode of the vector environment or more
    (``python bench/bench_envs.py --threads 1`` prints the cost per length), so the source draws a fixed
    pool of ``size`` distinct programs per length once (deterministically from ``seed``, on the first
    episode, and shared by every source with the same arguments in the process); each episode then
    picks a length uniformly and a program of that length uniformly with the environment's generator.

    Args:
        dim: 2 or 3.
        lengths: program lengths to draw (odd; default every synthetic length of ``dim``: 3-13 in 2D,
            3-7 in 3D).
        size: programs per length in the pool (default 512 in 2D, 64 in 3D).
        seed: the pool's seed (the pool is the same for every environment seed).
        rules: :class:`csgnet.synth.Rules` of the sampler (default rules if None).
    """

    def __init__(self, dim: int = 2, lengths: Sequence[int] | None = None, size: int | None = None,
                 seed: int = 0, rules=None):
        self.dim = check_dim(dim)
        if lengths is None:
            lengths = sorted(TABLE2[self.dim])
        self.lengths = tuple(int(L) for L in lengths)
        if not self.lengths:
            raise ValueError("lengths must name at least one program length")
        bad = [L for L in self.lengths if L < 3 or L % 2 == 0]
        if bad:
            raise ValueError(f"program lengths must be odd and >= 3, got {bad}")
        self.size = check_int("size", (512 if self.dim == 2 else 64) if size is None else size)
        self.seed = int(seed)
        self.rules = rules

    def __len__(self) -> int:
        return self.size * len(self.lengths)

    def _pool(self, li: int) -> tuple[np.ndarray, np.ndarray, tuple]:
        """The pool of ``self.lengths[li]`` (:func:`_synthetic_pool`)."""
        return _synthetic_pool(self.dim, self.lengths[li], self.size, self.seed, self.rules)

    def prepare(self) -> "SyntheticTargets":
        """Draw every length's pool now (otherwise each is drawn on its first use); returns self."""
        for li in range(len(self.lengths)):
            self._pool(li)
        return self

    def tokens(self, index: int) -> np.ndarray:
        """Token indices ``(L,) int64`` of pool entry ``index`` (lengths in order, ``size`` each)."""
        if not 0 <= index < len(self):
            raise IndexError(f"target index {index} out of range [0, {len(self)})")
        li, i = divmod(int(index), self.size)
        return self._pool(li)[0][i]

    def sample(self, rng: np.random.Generator) -> Target:
        li = int(rng.integers(len(self.lengths)))
        i = int(rng.integers(self.size))
        _, packed, texts = self._pool(li)
        # one row: np.unpackbits directly (csgnet.renderer.unpack's per-call set-up costs more than the row)
        shape = np.unpackbits(packed[i], bitorder="little").view(bool).reshape((SIZE,) * self.dim)
        return Target(shape, li * self.size + i, texts[i])

    def __repr__(self) -> str:
        return f"SyntheticTargets(dim={self.dim}, lengths={self.lengths}, size={self.size}, seed={self.seed})"


def _as_shapes(shapes, what: str) -> np.ndarray:
    """Stack images/volumes into one (N, 64, 64[, 64]) bool array, refusing values other than 0/1."""
    try:
        arr = np.asarray(shapes)
    except ValueError as e:  # ragged list
        raise ValueError(f"{what}: every target must have shape (64, 64) or (64, 64, 64): {e}") from None
    if arr.ndim not in (3, 4) or arr.shape[1:] not in ((SIZE, SIZE), (SIZE, SIZE, SIZE)):
        raise ValueError(f"{what} must have shape (N, 64, 64) or (N, 64, 64, 64), got {arr.shape}")
    if arr.shape[0] == 0:
        raise ValueError(f"{what} holds no target (N = 0)")
    if arr.dtype != np.bool_:
        if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
            raise TypeError(f"{what} must be bool (or 0/1 numbers), got dtype {arr.dtype}")
        bad = np.flatnonzero(((arr != 0) & (arr != 1)).reshape(arr.shape[0], -1).any(axis=1))
        if bad.size:
            raise ValueError(f"{what} must be binary: target(s) {bad[:10].tolist()} hold values other than 0 and 1")
        arr = arr != 0
    return arr


class ArrayTargets:
    """Targets from an array (or list) of bool shapes; each episode picks one uniformly.

    Args:
        shapes: ``(N, 64, 64)`` images or ``(N, 64, 64, 64)`` volumes, bool or 0/1 numbers (a list of
            ``(64, 64)`` arrays works too). The array is copied.
        programs: optional program text of each shape (reported in the reset info).
    """

    def __init__(self, shapes, programs: Sequence[str] | None = None):
        self.shapes = _as_shapes(shapes, "targets").copy()
        self.shapes.setflags(write=False)
        self.dim = self.shapes.ndim - 1
        if programs is not None:
            programs = list(programs)
            if len(programs) != len(self.shapes):
                raise ValueError(f"programs has {len(programs)} entries for {len(self.shapes)} targets")
        self.programs = programs

    def __len__(self) -> int:
        return self.shapes.shape[0]

    def sample(self, rng: np.random.Generator) -> Target:
        i = int(rng.integers(len(self)))
        return Target(self.shapes[i].copy(), i, None if self.programs is None else self.programs[i])

    def __repr__(self) -> str:
        return f"ArrayTargets({len(self)} x {self.shapes.shape[1:]})"


class ImageFolderTargets:
    """2D targets from the ``*.png`` files of a folder (sorted by name), read on the first episode.

    Each file must be a 64x64 image (grayscale, RGB or RGBA, converted to gray); a pixel is ON when
    its gray value exceeds ``threshold`` (bright shape on a dark background, the way
    :func:`csgnet.render` output saves as 0/255), or, with ``invert=True``, when it does not. This is
    the fixed-threshold rule of :func:`shapeio.image.read_masks` without fitting (``docs/shapeio.md``).

    Args:
        folder: the directory.
        threshold: gray level (0-255) above which a pixel is ON.
        invert: dark shapes on a bright background.

    Raises:
        FileNotFoundError: the folder does not exist or holds no PNG file.
        ValueError: a file is unreadable or not 64x64 (the message names it).
    """

    dim = 2

    def __init__(self, folder: str | os.PathLike, threshold: int = 127, invert: bool = False):
        self.folder = Path(folder)
        self.threshold = int(threshold)
        self.invert = bool(invert)
        self._shapes: np.ndarray | None = None
        self.files: list[Path] = list_images(self.folder, suffixes=(".png",))

    @property
    def shapes(self) -> np.ndarray:
        """``(N, 64, 64)`` bool, loaded on first access."""
        if self._shapes is None:
            out = read_masks(self.files, SIZE, threshold=self.threshold, invert=self.invert, fit=False)
            out.setflags(write=False)
            self._shapes = out
        return self._shapes

    def __len__(self) -> int:
        return len(self.files)

    def sample(self, rng: np.random.Generator) -> Target:
        i = int(rng.integers(len(self)))
        return Target(self.shapes[i].copy(), i)

    def __repr__(self) -> str:
        return f"ImageFolderTargets({str(self.folder)!r}, {len(self)} files)"


def as_target_source(targets, dim: int, max_length: int | None = None) -> TargetSource:
    """The target source described by an environment's ``targets`` argument.

    Args:
        targets: ``None`` or ``"synthetic"`` (:class:`SyntheticTargets` with every synthetic length up to
            ``max_length``), a folder path (:class:`ImageFolderTargets`), an array or list of shapes
            (:class:`ArrayTargets`), or any object with ``dim`` and ``sample(rng)``.
        dim: the environment's dimension; the source must match it.
        max_length: the environment's longest program.
    """
    dim = check_dim(dim)
    if targets is None or (isinstance(targets, str) and targets == "synthetic"):
        lengths = [L for L in sorted(TABLE2[dim]) if max_length is None or L <= max_length]
        if not lengths:
            raise ValueError(f"no synthetic program length fits max_length={max_length} "
                             f"(lengths: {sorted(TABLE2[dim])})")
        source = SyntheticTargets(dim, lengths)
    elif isinstance(targets, (str, os.PathLike)):
        source = ImageFolderTargets(targets)
    elif isinstance(targets, TargetSource):
        source = targets
    elif isinstance(targets, (np.ndarray, list, tuple)):
        source = ArrayTargets(targets)
    else:
        raise TypeError(f"targets must be None, 'synthetic', a folder, an array of shapes or a target source, "
                        f"got {type(targets).__name__}")
    if source.dim != dim:
        raise ValueError(f"the target source {source!r} holds {source.dim}D shapes, the environment is {dim}D")
    return source
