"""Point clouds of the corpus shapes: sampling, the on-disk cache, the splits and a torch ``Dataset``.

The papers sampled dense PartNet meshes, which this project does not have; our clouds are sampled from
the leaf cuboids of each executed corpus program (:func:`program_cloud`, area-weighted through
:func:`shapeprog.sampling.sample_surface`). Each cloud depends only on ``(category, shape id, seed)``
(:func:`cloud_seed`), so it is the same whatever the order, the worker or the executor.

* :func:`make_clouds` samples a category into ``<category>_clouds.npz`` and writes the splits to
  ``<category>_split.json`` beside it (``python -m shapeprog make-clouds``); a program that fails is
  reported by id and reason and the rest are kept.
* Splits (:func:`corpus_splits`): ``train`` and ``val`` are a seeded carve-out of the corpus's train
  split (:data:`VAL_FRACTION`); ``test`` is the corpus's ``val`` split (the papers' test shapes).
* :class:`CloudDataset` reads one split of a cache: ``points (n, 3) float32`` (normalised into the
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

from shapeio.files import InputError, atomic_write, parse_json

from .. import corpus
from ..errors import ExecutionError, ParseError
from ..execute import execute
from ..lang import Program, parse
from ..sampling import sample_surface
from .normalize import Transform, normalize

__all__ = ["CACHE_DTYPES", "CACHE_VERSION", "CLOUD_POINTS", "MAX_CLOUD_POINTS", "SPLITS", "TRAIN_POINTS",
           "VAL_FRACTION", "CloudCache", "CloudDataset", "CloudSet", "MakeCloudsReport", "cache_paths", "carve_validation",
           "cloud_seed", "cloud_transforms", "collate_clouds", "corpus_cloud", "corpus_splits", "load_cache", "make_clouds",
           "program_cloud", "read_split", "sample_clouds"]

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


def _check_cache_headers(z, path: Path, category: str) -> None:
    """Refuse a cache whose arrays, by their ``.npy`` headers, would decompress to more than a cache of
    ``category`` holds: ``points`` at most (corpus shapes of the category, :data:`MAX_CLOUD_POINTS`, 3), every
    other array at most :data:`MAX_CACHE_TABLE_BYTES`."""
    shapes = len(corpus.ids(category, "all"))
    for name in z.files:
        with z.zip.open(name + ".npy") as f:
            try:
                version = np.lib.format.read_magic(f)
                read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                shape, _, dtype = read(f)
            except ValueError as e:
                raise InputError(f"{path}: not a cloud cache (array {name!r}: {e})") from None
        nbytes = int(np.prod(shape, dtype=object)) * dtype.itemsize
        if name == "points":
            if len(shape) != 3 or shape[0] > shapes or shape[1] > MAX_CLOUD_POINTS or shape[2] != 3:
                raise InputError(f"{path}: 'points' of shape {shape}; a {category} cache holds at most ({shapes}, "
                                 f"{MAX_CLOUD_POINTS}, 3) (MAX_CLOUD_POINTS)")
        elif nbytes > MAX_CACHE_TABLE_BYTES:
            raise InputError(f"{path}: array {name!r} would take {nbytes} bytes; at most {MAX_CACHE_TABLE_BYTES} "
                             "(MAX_CACHE_TABLE_BYTES)")


def load_cache(root: PathLike, category: str) -> CloudCache:
    """Read ``root/<category>_clouds.npz`` (:func:`make_clouds`).

    Raises:
        FileNotFoundError: no cache (the message names the command that makes it).
        InputError: a file that is not such a cache, of another version or category.
    """
    path = cache_paths(root, category)[0]
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such cache; make it with "
                                f"`python -m shapeprog make-clouds --category {category} --out {root}`")
    try:
        with np.load(path, allow_pickle=False) as z:
            _check_cache_headers(z, path, category)  # before anything is decompressed
            d = {k: z[k] for k in z.files}
    except InputError:
        raise
    except Exception as e:
        raise InputError(f"{path}: cannot read the cloud cache ({type(e).__name__}: {e})") from None
    need = ("version", "category", "ids", "points", "center", "scale", "n_points", "seed", "failed_ids",
            "failed_reasons")
    missing = [k for k in need if k not in d]
    if missing:
        raise InputError(f"{path}: not a cloud cache (missing {', '.join(missing)})")
    for k in ("version", "n_points", "seed"):  # any integer seed; counts and versions are >= 0
        v = d[k]
        if np.ndim(v) != 0 or not np.issubdtype(v.dtype, np.integer) or (k != "seed" and int(v) < 0):
            raise InputError(f"{path}: not a cloud cache ('{k}' is not a{'n' if k == 'seed' else ' non-negative'} "
                             f"integer: dtype {v.dtype}, shape {np.shape(v)})")
    if int(d["version"]) != CACHE_VERSION:
        raise InputError(f"{path}: cache version {int(d['version'])}, this code reads version {CACHE_VERSION}; "
                         "make it again with `python -m shapeprog make-clouds --out NEW_FOLDER`")
    if np.ndim(d["category"]) != 0:
        raise InputError(f"{path}: not a cloud cache ('category' is not one name)")
    if str(d["category"]) != category:
        raise InputError(f"{path}: holds {str(d['category'])!r} clouds, not {category!r}")
    s = len(d["ids"])
    if d["points"].ndim != 3 or d["points"].shape[0] != s or d["points"].shape[2] != 3 or \
            d["center"].shape != (s, 3) or d["scale"].shape != (s,):
        raise InputError(f"{path}: inconsistent shapes: ids {d['ids'].shape}, points {d['points'].shape}, "
                         f"center {d['center'].shape}, scale {d['scale'].shape}")
    for k in ("ids", "failed_ids"):
        if d[k].ndim != 1 or not np.issubdtype(d[k].dtype, np.integer):
            raise InputError(f"{path}: not a cloud cache ('{k}' is not a list of shape ids)")
    for k in ("points", "center", "scale"):
        if not np.issubdtype(d[k].dtype, np.floating) or not np.isfinite(d[k]).all():
            raise InputError(f"{path}: not a cloud cache ('{k}' holds a non-finite or non-float value)")
    if (d["scale"] <= 0).any():
        raise InputError(f"{path}: not a cloud cache (a scale <= 0)")
    if d["failed_reasons"].shape != d["failed_ids"].shape:
        raise InputError(f"{path}: not a cloud cache ({len(d['failed_ids'])} failed ids but "
                         f"{len(d['failed_reasons'])} reasons)")
    return CloudCache(category, d["ids"].astype(np.int64), d["points"], d["center"].astype(np.float64),
                      d["scale"].astype(np.float64), int(d["n_points"]), int(d["seed"]),
                      dict(zip(d["failed_ids"].tolist(), d["failed_reasons"].tolist())), path)


def read_split(root: PathLike, category: str, cache: "CloudCache | None" = None) -> dict[str, list[int]]:
    """The ``train`` / ``val`` / ``test`` ids of ``root/<category>_split.json``.

    ``cache``: the :func:`load_cache` of the same folder, checked against the split file (the points per
    cloud and the sampling seed it records, and every id among the cached ones): the two files are written
    one after the other, and a split left by another run is refused.

    Raises:
        FileNotFoundError: no split file.
        InputError: not a split file, or not the split of ``cache``.
    """
    path = cache_paths(root, category)[1]
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such split file; make the cache and its split again with "
                                f"`python -m shapeprog make-clouds --category {category} --out NEW_FOLDER` (it never "
                                "writes beside an existing cache)")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: not a split file ({type(e).__name__}: {e})") from None
    record = parse_json(text, str(path))
    if not isinstance(record, dict):
        raise InputError(f"{path}: not a split file (a JSON object is expected)")
    for k in SPLITS:
        ids = record.get(k)
        if not isinstance(ids, list) or not all(type(i) is int and i >= 0 for i in ids):
            raise InputError(f"{path}: not a split file ('{k}' is not a list of shape ids)")
    if cache is not None:
        made = {"n_points": cache.n_points, "sampling_seed": cache.seed}
        other = [k for k, v in made.items() if record.get(k, v) != v]
        cached = set(cache.ids.tolist())
        missing = [i for k in SPLITS for i in record[k] if i not in cached]
        if other or missing:
            why = (f"{other[0]} {record[other[0]]!r} against the cache's {made[other[0]]!r}" if other
                   else f"shape {missing[0]} is not in the cache")
            raise InputError(f"{path}: not the split of {cache.path.name} ({why}); make both again with "
                             f"`python -m shapeprog make-clouds --category {category} --out NEW_FOLDER`")
    return {k: list(record[k]) for k in SPLITS}


# --------------------------------------------------------------------------------------------------
# torch Dataset


class CloudDataset(torch.utils.data.Dataset):
    """One split of a cloud cache as ``{"points", "id", "program", "scale", "center"}`` items.

    ``points`` are ``(n, 3) float32``: the stored cloud, mapped into the canonical frame with its stored
    :class:`Transform` (``normalize=True``), then a random subset of ``n`` points and Gaussian noise of
    standard deviation ``noise`` (in the frame's units). The draws of item ``i`` depend only on
    ``(seed, epoch, i)`` (:meth:`set_epoch`), so the same item is the same in every DataLoader worker.
    The noise is added after the normalisation: the target program's scale (``scale``) is that of the
    clean shape.

    Args:
        root: the cache folder (:func:`make_clouds`).
        category: the category.
        split: ``"train"``, ``"val"`` or ``"test"`` (the corpus's val split).
        points: points per item: an int, a ``(low, high)`` range (a count drawn per item, both ends
            included; batch them with :func:`collate_clouds`), or None for every stored point.
        noise: standard deviation of the Gaussian noise (0: none).
        normalize: map into the canonical frame (False: the program's own frame).
        seed: seed of the subsets and the noise.

    Item:
        ``points (n, 3) float32``, ``id`` (int), ``program`` (the corpus name ``"chair/173"``),
        ``scale`` (float) and ``center ((3,) float64)``: the clean cloud's Transform (the canonical
        program is ``scale_program(program, scale)``).
    """

    def __init__(self, root: PathLike, category: str, split: str = "train",
                 points: Union[int, tuple[int, int], None] = TRAIN_POINTS, noise: float = 0.0,
                 normalize: bool = True, seed: int = 0):
        if split not in SPLITS:
            raise ValueError(f"`split` must be one of {', '.join(SPLITS)}, got {split!r}")
        if not (noise >= 0 and np.isfinite(noise)):
            raise ValueError(f"`noise` must be a finite number >= 0, got {noise!r}")
        cache = load_cache(root, category)
        ids = read_split(root, category, cache)[split]
        rows = cache.index(ids)
        stored = cache.points.shape[1]
        if points is None:
            lo = hi = stored
        elif isinstance(points, (tuple, list)):
            lo, hi = (int(v) for v in points)
        else:
            lo = hi = int(points)
        if not 1 <= lo <= hi <= stored:
            raise ValueError(f"`points` must lie in [1, {stored}] (the cached count), low <= high; got {points!r}")
        self.category, self.split, self.noise, self.normalize, self.seed = category, split, float(noise), normalize, seed
        self.low, self.high, self.epoch = lo, hi, 0
        self.ids = cache.ids[rows]
        self.clouds = cache.points[rows]
        self.center = cache.center[rows]
        self.scale = cache.scale[rows]

    def __len__(self) -> int:
        return len(self.ids)

    def set_epoch(self, epoch: int) -> None:
        """Draw other subsets and noise (call once per epoch, as with a ``DistributedSampler``)."""
        self.epoch = int(epoch)

    def program_name(self, i: int) -> str:
        """The corpus name of item ``i``'s program (``"chair/173"``)."""
        return f"{self.category}/{int(self.ids[i])}"

    def program(self, i: int) -> Program:
        """Item ``i``'s program, parsed from the corpus (its own frame; scale it with
        ``scale_program(program, item["scale"])`` for the canonical frame)."""
        return parse(corpus.read(self.category, int(self.ids[i])), file=f"{self.program_name(i)}.txt")

    def transform(self, i: int) -> Transform:
        """Item ``i``'s :class:`Transform` into the canonical frame."""
        return Transform(tuple(self.center[i]), float(self.scale[i]))

    def __getitem__(self, i: int) -> dict:
        if not -len(self) <= i < len(self):
            raise IndexError(f"item {i} of a {len(self)}-item dataset")
        i = i % len(self)
        rng = np.random.default_rng([int(self.seed), self.epoch, i])
        n = self.low if self.low == self.high else int(rng.integers(self.low, self.high + 1))
        x = self.clouds[i]
        if n < len(x):
            x = x[np.sort(rng.choice(len(x), size=n, replace=False))]
        x = x.astype(np.float64)
        if self.normalize:
            x = (x - self.center[i]) * self.scale[i]
        if self.noise > 0:
            x = x + rng.normal(0.0, self.noise, size=x.shape)
        return {"points": torch.from_numpy(x.astype(np.float32)), "id": int(self.ids[i]),
                "program": self.program_name(i), "scale": float(self.scale[i]),
                "center": torch.from_numpy(self.center[i].copy())}


def collate_clouds(items: Sequence[dict]) -> dict:
    """Batch :class:`CloudDataset` items: ``points (B, n, 3)`` with ``n`` the smallest count in the batch
    (items with more points keep their first ``n``, a random subset already), ``id (B,) int64``,
    ``program`` (list of names), ``scale (B,) float64``, ``center (B, 3) float64``."""
    if not items:
        raise ValueError("cannot collate an empty batch")
    n = min(int(it["points"].shape[0]) for it in items)
    return {"points": torch.stack([it["points"][:n] for it in items]),
            "id": torch.tensor([it["id"] for it in items], dtype=torch.int64),
            "program": [it["program"] for it in items],
            "scale": torch.tensor([it["scale"] for it in items], dtype=torch.float64),
            "center": torch.stack([it["center"] for it in items])}
