"""Reading a cloud cache written by :func:`shapeprog.pointcloud.data.make_clouds`: :func:`load_cache`
checks its headers, :func:`read_split` gives one split's arrays, and :class:`CloudDataset` is the torch
``Dataset`` over a split (normalised, subsampled and optionally noised at load time, seeded per item and
epoch); :func:`collate_clouds` batches its items.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence, Union

import numpy as np
import torch

from shapeio.arrays import int_entry
from shapeio.files import InputError, parse_json

from .. import corpus
from ..lang import Program, parse
from .normalize import Transform
from .data import (
    CACHE_VERSION, CloudCache, MAX_CACHE_TABLE_BYTES, MAX_CLOUD_POINTS, PathLike, SPLITS, TRAIN_POINTS,
    cache_paths,
)

__all__ = [
    "CloudDataset",
    "collate_clouds",
    "load_cache",
    "read_split",
]


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
        int_entry(d[k], path, k, None if k == "seed" else 0)
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
