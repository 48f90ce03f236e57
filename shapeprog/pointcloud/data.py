"""Point clouds of the corpus shapes: sampling, the on-disk cache and the splits.

The papers sampled dense PartNet meshes, which this project does not have; our clouds are sampled from
the leaf cuboids of each executed corpus program (:func:`program_cloud`, area-weighted through
:func:`shapeprog.sampling.sample_surface`). Each cloud depends only on ``(category, shape id, seed)``
(:func:`cloud_seed`), so it is the same whatever the order, the worker or the executor.

* :func:`make_clouds` samples a category into ``<category>_clouds.npz`` and writes the splits to
  ``<category>_split.json`` beside it (``python -m shapeprog make-clouds``); a program that fails is
  reported by id and reason and the rest are kept.
* Splits (:func:`corpus_splits`): ``train`` and ``val`` are a seeded carve-out of the corpus's train
  split (:data:`VAL_FRACTION`); ``test`` is the corpus's ``val`` split (the papers' test shapes).
* :class:`~shapeprog.pointcloud.dataset.CloudDataset` reads one split of a cache: ``points (n, 3) float32`` (normalised into the
  canonical frame of :mod:`shapeprog.pointcloud.normalize` by default, subsampled and optionally
  noised at load time, seeded per item and epoch), the shape id and the program's corpus name.

Layout of the files and the decisions: ``docs/pointcloud.md`` (Data).

Example:
    >>> pts = corpus_cloud("chair", 173, n_points=100)
    >>> pts.shape, pts.dtype.name, bool((pts == corpus_cloud("chair", 173, n_points=100)).all())
    ((100, 3), 'float32', True)
"""
from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import time
from concurrent.futures import Executor, ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Optional, Sequence, Union

import numpy as np
import torch

from shapeio.files import atomic_write

from .. import corpus
from ..errors import ExecutionError, ParseError
from ..execute import execute
from ..lang import Program, parse
from ..sampling import sample_surface
from .normalize import Transform, normalize

__all__ = [
    "CACHE_DTYPES",
    "CACHE_VERSION",
    "CLOUD_POINTS",
    "MAX_CLOUD_POINTS",
    "SPLITS",
    "TRAIN_POINTS",
    "VAL_FRACTION",
    "CloudCache",
    "CloudSet",
    "MakeCloudsReport",
    "cache_paths",
    "carve_validation",
    "cloud_seed",
    "cloud_transforms",
    "corpus_cloud",
    "corpus_splits",
    "make_clouds",
    "program_cloud",
    "sample_clouds",
]

PathLike = Union[str, os.PathLike]

#: Points sampled per shape for the cache (the papers' 10,000).
CLOUD_POINTS = 10_000
#: Points per cloud given to the network by default (a random subset at load time).
TRAIN_POINTS = 2_048
#: Most points per shape :func:`make_clouds` samples (a bound on the cache's size).
MAX_CLOUD_POINTS = 100_000
#: Bytes of each array of a cloud cache other than ``points`` (ids, transforms, failures), as its header
#: declares them before anything is decompressed.
MAX_CACHE_TABLE_BYTES = 64 << 20
#: Share of the corpus's train split carved out for validation.
VAL_FRACTION = 0.05
#: Storage types of the cached points.
CACHE_DTYPES = ("float16", "float32")
#: Version of the cache layout (the ``version`` entry of the ``.npz`` and the split file).
CACHE_VERSION = 1
#: The split names of the split file: train and val carved from the corpus train split, test = corpus val.
SPLITS = ("train", "val", "test")


# --------------------------------------------------------------------------------------------------
# one cloud


def cloud_seed(category: str, shape_id: int, seed: int = 0) -> int:
    """The sampling seed of one shape: a hash of ``(category, shape_id, seed)``, the same in every process
    and Python version (not Python's salted ``hash``)."""
    key = f"{category}/{int(shape_id)}/{int(seed)}".encode("ascii")
    return int.from_bytes(hashlib.blake2b(key, digest_size=8).digest(), "little") & ((1 << 63) - 1)


def _check_count(n_points) -> int:
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or not 1 <= n_points <= MAX_CLOUD_POINTS:
        raise ValueError(f"`n_points` must be an int in [1, {MAX_CLOUD_POINTS}] (MAX_CLOUD_POINTS), got {n_points!r}")
    return int(n_points)


def program_cloud(program: Union[Program, str], n_points: int = CLOUD_POINTS, seed: int = 0,
                  file: str = "<string>") -> np.ndarray:
    """Surface points of an executed program, uniform by area over its leaf cuboids.

    Args:
        program: a parsed program or its text.
        n_points: points to sample.
        seed: the ``torch.Generator`` seed of the sampling.
        file: the name parse and execution errors carry.

    Returns:
        ``(n_points, 3) float32``, in the program's frame (y up).

    Raises:
        ParseError, ExecutionError: the program does not parse or execute (naming ``file``).
        ValueError: the executed shape has no cuboid or no surface.
    """
    n = _check_count(n_points)
    if isinstance(program, str):
        program = parse(program, file=file)
    with torch.no_grad():
        try:
            shape = execute(program)
        except ExecutionError as e:
            raise ExecutionError(e.reason, e.line, file=file) from None
        if len(shape) == 0:
            raise ValueError(f"{file}: the program executes to no leaf cuboid; there is no surface to sample")
        pts, _ = sample_surface(shape.corners, n, generator=torch.Generator().manual_seed(int(seed)))
    return pts.numpy().astype(np.float32, copy=False)


def corpus_cloud(category: str, shape_id: int, n_points: int = CLOUD_POINTS, seed: int = 0) -> np.ndarray:
    """The cloud of corpus program ``category/shape_id``: :func:`program_cloud` with :func:`cloud_seed`."""
    name = f"{category}/{int(shape_id)}.txt"
    return program_cloud(corpus.read(category, shape_id), n_points, cloud_seed(category, shape_id, seed), name)


# --------------------------------------------------------------------------------------------------
# many clouds


@dataclass
class CloudSet:
    """Clouds of several shapes of one category.

    Attributes:
        category: the corpus category.
        ids: ``(S,) int64`` shape ids, in the order asked for (failed ones left out).
        points: ``(S, N, 3) float32``.
        failures: ``[(id, reason), ...]`` for the shapes that could not be sampled.
    """

    category: str
    ids: np.ndarray
    points: np.ndarray
    failures: list = field(default_factory=list)


def _cloud_job(job) -> tuple[int, Optional[np.ndarray], str]:
    """One shape: ``(category, id, text or None, n_points, seed)`` -> ``(id, points or None, reason)``."""
    category, shape_id, text, n_points, seed = job
    name = f"{category}/{shape_id}.txt"
    try:
        if text is None:
            text = corpus.read(category, shape_id)
        pts = program_cloud(text, n_points, cloud_seed(category, shape_id, seed), name)
        return shape_id, pts, ""
    except (ParseError, ExecutionError, KeyError, ValueError) as e:
        reason = str(e)
        if isinstance(e, KeyError):
            reason = str(e.args[0]) if e.args else "no such program"
        return shape_id, None, reason if reason.startswith(name) else f"{name}: {reason}"


def _init_worker() -> None:
    torch.set_num_threads(1)  # one process per core: no nested thread pools


def _pool(workers: Optional[int]) -> Optional[ProcessPoolExecutor]:
    workers = (os.cpu_count() or 1) if workers is None else int(workers)
    if workers <= 1:
        return None
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                               initializer=_init_worker)


def cloud_transforms(points, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """``(center (S, 3), scale (S,))`` float64: each cloud's canonical-frame :class:`Transform`
    (:func:`~shapeprog.pointcloud.normalize.normalize`, y up) of ``points`` ``(S, N, 3)``, each cloud converted to
    ``dtype`` first; the normalised clouds are ``(points - center[:, None]) * scale[:, None, None]``."""
    center = np.zeros((len(points), 3))
    scale = np.zeros(len(points))
    for k, pts in enumerate(points):
        t = normalize(pts.astype(dtype))[1]
        center[k], scale[k] = t.center, t.scale
    return center, scale


def sample_clouds(category: str, ids: Sequence[int], n_points: int = CLOUD_POINTS, seed: int = 0,
                  executor: Optional[Executor] = None, texts: Optional[Mapping[int, str]] = None,
                  progress: Optional[Callable[[int, int], None]] = None) -> CloudSet:
    """Sample the clouds of ``ids`` of ``category``, one job per shape.

    Args:
        category: the corpus category (part of every shape's seed).
        ids: shape ids.
        n_points: points per cloud.
        seed: the cache seed (with category and id it makes :func:`cloud_seed`).
        executor: a ``concurrent.futures.Executor`` running the per-shape jobs; None runs them here.
        texts: program texts replacing the corpus's for some ids (e.g. edited programs).
        progress: called with ``(done, total)`` after each shape.

    Returns:
        A :class:`CloudSet`; shapes that do not parse, execute or sample are in ``failures`` with the
        reason, the rest are kept.
    """
    corpus._check_category(category)
    n = _check_count(n_points)
    texts = texts or {}
    jobs = [(category, int(i), texts.get(int(i)), n, int(seed)) for i in ids]
    results = map(_cloud_job, jobs) if executor is None else executor.map(_cloud_job, jobs, chunksize=16)
    points = np.empty((len(jobs), n, 3), np.float32)  # filled in place: no second copy of the clouds
    ok = np.zeros(len(jobs), dtype=bool)
    failures = []
    for k, (shape_id, pts, reason) in enumerate(results):
        if pts is None:
            failures.append((shape_id, reason))
        else:
            points[k], ok[k] = pts, True
        if progress is not None:
            progress(k + 1, len(jobs))
    ids = np.asarray([j[1] for j in jobs], dtype=np.int64)
    return CloudSet(category, ids[ok], points if ok.all() else points[ok], failures)


# --------------------------------------------------------------------------------------------------
# splits


def carve_validation(ids: Sequence[int], fraction: float = VAL_FRACTION, seed: int = 0) -> tuple[list[int], list[int]]:
    """Split ``ids`` into ``(train, val)``: ``round(fraction * len(ids))`` ids drawn with ``seed`` go to val.

    The ids are sorted first, so the result does not depend on their order; both lists come back sorted.
    """
    if not 0.0 <= fraction < 1.0:
        raise ValueError(f"`fraction` must lie in [0, 1), got {fraction!r}")
    pool = np.unique(np.asarray(list(ids), dtype=np.int64))
    n_val = int(round(fraction * len(pool)))
    perm = np.random.default_rng(int(seed)).permutation(len(pool))
    val = np.sort(pool[perm[:n_val]])
    train = np.sort(pool[perm[n_val:]])
    return train.tolist(), val.tolist()


def corpus_splits(category: str, fraction: float = VAL_FRACTION, seed: int = 0) -> dict[str, list[int]]:
    """``{"train", "val", "test"}`` ids: train/val carved from the corpus's train split, test = corpus val."""
    train, val = carve_validation(corpus.ids(category, "train"), fraction, seed)
    return {"train": train, "val": val, "test": sorted(corpus.ids(category, "val"))}


# --------------------------------------------------------------------------------------------------
# the cache


def cache_paths(root: PathLike, category: str) -> tuple[Path, Path]:
    """``(root/<category>_clouds.npz, root/<category>_split.json)``."""
    root = Path(root)
    return root / f"{category}_clouds.npz", root / f"{category}_split.json"


@dataclass
class CloudCache:
    """A cache file in memory (:func:`load_cache`).

    Attributes:
        category: the corpus category.
        ids: ``(S,) int64`` shape ids (sorted).
        points: ``(S, N, 3)`` float16 or float32, in the programs' frame.
        center: ``(S, 3) float64`` and scale: ``(S,) float64``: each cloud's :class:`Transform` into the
            canonical frame (:func:`shapeprog.pointcloud.normalize` of the stored points).
        n_points: points sampled per shape, seed: the sampling seed.
        failed: ``{id: reason}`` of the shapes left out.
        path: the file read.
    """

    category: str
    ids: np.ndarray
    points: np.ndarray
    center: np.ndarray
    scale: np.ndarray
    n_points: int
    seed: int
    failed: dict
    path: Optional[Path] = None

    def __len__(self) -> int:
        return len(self.ids)

    def index(self, ids: Sequence[int]) -> np.ndarray:
        """Rows of ``ids`` (KeyError naming the first id that is not cached)."""
        rows = np.searchsorted(self.ids, np.asarray(ids, dtype=np.int64))
        for i, r in zip(ids, rows):
            if r >= len(self.ids) or self.ids[r] != i:
                raise KeyError(f"{self.path or 'cache'}: shape {self.category}/{int(i)} is not cached")
        return rows

    def transform(self, row: int) -> Transform:
        """The canonical-frame :class:`Transform` of row ``row``."""
        return Transform(tuple(self.center[row]), float(self.scale[row]))

    def normalized(self, rows=None) -> np.ndarray:
        """``(S', N, 3) float32`` clouds of ``rows`` (default: all) in the canonical frame."""
        rows = np.arange(len(self.ids)) if rows is None else np.asarray(rows)
        x = self.points[rows].astype(np.float64)
        return ((x - self.center[rows, None, :]) * self.scale[rows, None, None]).astype(np.float32)


@dataclass
class MakeCloudsReport:
    """What :func:`make_clouds` wrote: the two files, counts, failures, seconds and the cache's size."""

    cache: Path
    split: Path
    count: int
    failures: list
    seconds: float
    bytes: int


def make_clouds(category: str, out: PathLike, n_points: int = CLOUD_POINTS, seed: int = 0,
                executor: Optional[Executor] = None, workers: Optional[int] = None,
                val_fraction: float = VAL_FRACTION, split_seed: int = 0, dtype: str = "float16",
                ids: Optional[Sequence[int]] = None, texts: Optional[Mapping[int, str]] = None,
                progress: Optional[Callable[[int, int], None]] = None) -> MakeCloudsReport:
    """Sample a category's clouds into ``out/<category>_clouds.npz`` and write ``out/<category>_split.json``.

    Both files are written atomically (the folder is created). The ``.npz`` (compressed) holds
    ``version``, ``category``, ``ids (S,) int64`` (sorted), ``points (S, N, 3)`` of ``dtype``,
    ``center (S, 3)`` and ``scale (S,)`` float64 (each stored cloud's normalisation), ``n_points``,
    ``seed``, and ``failed_ids`` / ``failed_reasons``. The split file lists the cached ids of each split
    (:func:`corpus_splits`, computed from the whole corpus so that it does not depend on ``ids``).

    Args:
        category: ``chair``, ``table`` or ``storage``.
        out: the folder.
        n_points: points per shape (at most :data:`MAX_CLOUD_POINTS`).
        seed: sampling seed (see :func:`cloud_seed`).
        executor: runs the per-shape jobs; None makes a process pool of ``workers`` processes (none
            when ``workers`` is 1), shut down at the end.
        workers: processes of that pool (default: the CPU count).
        val_fraction, split_seed: the carve-out of :func:`carve_validation`.
        dtype: ``"float16"`` (half the size; coordinates within 5e-4 of the float32 samples) or
            ``"float32"``.
        ids: the shapes to sample (default: every id of the category, train and val).
        texts: program texts replacing the corpus's for some ids.
        progress: called with ``(done, total)`` after each shape.

    Returns:
        A :class:`MakeCloudsReport`.
    """
    corpus._check_category(category)
    if dtype not in CACHE_DTYPES:
        raise ValueError(f"`dtype` must be one of {', '.join(CACHE_DTYPES)}, got {dtype!r}")
    n = _check_count(n_points)
    splits = corpus_splits(category, val_fraction, split_seed)
    ids = sorted({int(i) for i in (corpus.ids(category, "all") if ids is None else ids)})
    cache_path, split_path = cache_paths(out, category)
    Path(out).mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    pool = _pool(workers) if executor is None else None
    try:
        clouds = sample_clouds(category, ids, n, seed, executor or pool, texts, progress)
    finally:
        if pool is not None:
            pool.shutdown()
    stored = clouds.points.astype(dtype)
    center, scale = cloud_transforms(stored, np.float32)
    failed_ids = np.asarray([i for i, _ in clouds.failures], dtype=np.int64)
    arrays = dict(version=np.int64(CACHE_VERSION), category=np.str_(category), ids=clouds.ids, points=stored,
                  center=center, scale=scale, n_points=np.int64(n), seed=np.int64(seed), failed_ids=failed_ids,
                  failed_reasons=np.asarray([r for _, r in clouds.failures], dtype=np.str_))
    atomic_write(cache_path, lambda f: np.savez_compressed(f, **arrays))
    cached = set(clouds.ids.tolist())
    record = {"version": CACHE_VERSION, "category": category, "cache": cache_path.name,
              "val_fraction": val_fraction, "split_seed": split_seed, "sampling_seed": seed, "n_points": n,
              "note": "train and val are carved from the corpus train split; test is the corpus val split",
              **{k: [i for i in v if i in cached] for k, v in splits.items()},
              "failed": {str(i): r for i, r in clouds.failures}}
    atomic_write(split_path, json.dumps(record, indent=1) + "\n")
    return MakeCloudsReport(cache_path, split_path, len(clouds.ids), clouds.failures, time.perf_counter() - t0,
                            cache_path.stat().st_size)
