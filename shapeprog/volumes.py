"""Voxelised shapes of the ShapeAssembly corpus: a real-shape set of 64³ occupancy volumes for 3D CSGNet.

Every corpus program is executed in float64 and its leaf cuboids are voxelised in the ShapeAssembly frame
(``vol[x, y, z]``, y up): the shape is scaled so that its longest side spans ``size - 2 * margin`` voxels
(56 of 64, the fit ``csgnet.inference.load_shape`` gives a mesh) and centred; a voxel is on iff its centre
lies in a cuboid, and parts thinner than a voxel are widened to one so that they stay. Splits are those of
the silhouette set (:func:`shapeprog.silhouettes.split_ids`: the corpus's train list; val and test the even
and odd positions of its val list), each in a fixed shuffled order (:data:`ORDER_SEED`), so the first ``n``
volumes of a split are a uniform sample of it. ``python -m shapeprog assembly volumes --out PATH`` builds the
set (file layout: :mod:`shapeio.volumes`); ``docs/csgnet.md`` ("The ShapeAssembly volumes") describes it.

Example:
    >>> import torch
    >>> from shapeprog.geometry import cuboid_corners
    >>> box = cuboid_corners(torch.zeros(1, 3), torch.tensor([[2.0, 1.0, 1.0]]), torch.eye(3)[None])
    >>> vol = volume(box, size=16, margin=0)
    >>> int(vol.sum()), bool(vol[:, 4:12, 4:12].all())  # 16 x 8 x 8 voxels
    (1024, True)
"""
from __future__ import annotations

import warnings

import numpy as np
from tqdm import tqdm

from shapeio.volumes import SPLITS, VolumeSplit, pack_volumes, write_volumes

from . import corpus
from .geometry import numpy_corners
from .parallel import ordered_map
from .silhouettes import execute_items, split_ids

__all__ = ["CATEGORIES", "MAX_SIZE", "ORDER_SEED", "VolumeSplit", "volume", "build", "write"]

SIZE = 64
MARGIN = 4
#: The largest volume side (a 256³ volume is 2 MiB packed).
MAX_SIZE = 256
#: The categories of the default set: chairs and tables (storage furniture is mostly one box).
CATEGORIES = ("chair", "table")
#: Seed of the fixed order of the shapes within a split.
ORDER_SEED = 0
#: Cuboids thinner than this (voxels) across some axis are widened to it.
MIN_WIDTH = 1.0
#: Shapes per job of the process pool.
CHUNK = 50
_EPS = 1e-9


def _check_frame(size: int, margin: int) -> None:
    if isinstance(size, bool) or not isinstance(size, int) or not 1 <= size <= MAX_SIZE:
        raise ValueError(f"need an int size from 1 to {MAX_SIZE} (MAX_SIZE), got size={size!r}")
    if isinstance(margin, bool) or not isinstance(margin, int) or not 0 <= 2 * margin < size:
        raise ValueError(f"need an int margin with 0 <= margin < size / 2, got size={size}, margin={margin!r}")


def volume(corners, size: int = SIZE, margin: int = MARGIN) -> np.ndarray:
    """The occupancy volume of one shape's cuboids, fitted to the grid.

    Args:
        corners: ``(L, 8, 3)`` float cuboid corners in the order of :mod:`shapeprog.geometry` (torch or
            NumPy), e.g. ``execute(program).corners``.
        size: volume side in voxels.
        margin: free voxels kept on each side along the longest extent.

    Returns:
        ``(size, size, size) bool``, indexed ``[x, y, z]``.
    """
    _check_frame(size, margin)
    c = numpy_corners(corners)
    lo, hi = c.reshape(-1, 3).min(axis=0), c.reshape(-1, 3).max(axis=0)
    extent = float((hi - lo).max())
    scale = (size - 2 * margin) / extent if extent > 0 else 1.0
    v = (size - 1) / 2.0 + scale * (c - (lo + hi) / 2.0)  # voxel coordinates, voxel centres at integers
    centre = v.mean(axis=1)  # (L, 3)
    # half-axis generators; corner 0 is (+,+,+), 4 flips x, 2 flips y, 1 flips z
    gens = np.stack([(v[:, 0] - v[:, 4]) / 2, (v[:, 0] - v[:, 2]) / 2, (v[:, 0] - v[:, 1]) / 2], axis=1)
    norm = np.linalg.norm(gens, axis=-1, keepdims=True)  # (L, 3, 1)
    unit = np.where(norm > 1e-12, gens / np.maximum(norm, 1e-12), np.eye(3)[None])
    gens = unit * np.maximum(norm, MIN_WIDTH / 2)
    sq = (gens * gens).sum(-1)  # (L, 3)
    reach = np.abs(gens).sum(axis=1)  # (L, 3) half extents of each cuboid's bounding box
    first = np.clip(np.ceil(centre - reach - _EPS), 0, size).astype(int)
    last = np.clip(np.floor(centre + reach + _EPS), -1, size - 1).astype(int)
    out = np.zeros((size,) * 3, bool)
    for part in range(len(c)):
        a, b = first[part], last[part]
        if (b < a).any():
            continue  # entirely off the grid
        axes = [np.arange(a[k], b[k] + 1, dtype=np.float64) - centre[part, k] for k in range(3)]
        d = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)  # (nx, ny, nz, 3)
        inside = (np.abs(d @ gens[part].T) <= sq[part] * (1 + _EPS) + _EPS).all(axis=-1)
        out[a[0]:b[0] + 1, a[1]:b[1] + 1, a[2]:b[2] + 1] |= inside
    return out


def _voxelise_chunk(job) -> tuple[list, list, list[str]]:
    """One pool job: ``(items [(split, category, id)], size, margin)`` -> ``(kept [(split, name)], packed
    volumes, skipped messages)``."""
    items, size, margin = job
    kept, shapes, skipped = execute_items(items)
    done, packed = [], []
    for (split, name), shape in zip(kept, shapes):
        try:
            packed.append(pack_volumes(volume(shape.corners, size, margin)))
            done.append((split, name))
        except ValueError as e:
            skipped.append(f"{name}: {e}")
    return done, packed, skipped


def build(categories=CATEGORIES, size: int = SIZE, margin: int = MARGIN, limit: int | None = None,
          executor=None, progress: bool = True) -> dict[str, VolumeSplit]:
    """Execute the corpus programs of ``categories`` and voxelise them.

    Args:
        categories: corpus categories.
        size, margin: see :func:`volume`.
        limit: keep only the first ``limit`` shapes of each category and split (for quick checks).
        executor: a ``concurrent.futures.Executor`` that runs the jobs of :data:`CHUNK` shapes (None: here).
        progress: show a progress bar (tqdm) on stderr.

    Returns:
        ``{"train": VolumeSplit, "val": ..., "test": ...}``, each split in its fixed shuffled order
        (:data:`ORDER_SEED`). Programs that fail to parse or execute (none in the shipped corpus) are
        skipped with a warning naming them.

    Raises:
        ValueError: an unknown category, or a ``size`` / ``margin`` that :func:`volume` rejects, before any
            program runs.
    """
    _check_frame(size, margin)
    unknown = [c for c in categories if c not in corpus.CATEGORIES]
    if unknown or not categories:
        raise ValueError(f"categories must be some of {', '.join(corpus.CATEGORIES)}, got {list(categories)}")
    items = [(split, cat, i) for cat in categories for split, ids in split_ids(cat).items()
             for i in (ids if limit is None else ids[:limit])]
    jobs = [(items[k:k + CHUNK], size, margin) for k in range(0, len(items), CHUNK)]
    out: dict[str, tuple[list, list]] = {s: ([], []) for s in SPLITS}
    skipped: list[str] = []
    with tqdm(total=len(items), desc="volumes", unit="shape", disable=not progress) as bar:
        for (done, packed, bad), job in zip(ordered_map(executor, _voxelise_chunk, jobs), jobs):
            for (split, name), p in zip(done, packed):
                out[split][0].append(p)
                out[split][1].append(name)
            skipped += bad
            bar.update(len(job[0]))
    if skipped:
        warnings.warn(f"{len(skipped)} shape(s) skipped: " + "; ".join(skipped), UserWarning, stacklevel=2)
    result = {}
    for split, (packed, names) in out.items():
        order = np.random.default_rng(ORDER_SEED).permutation(len(packed))
        arr = np.stack(packed)[order] if packed else np.zeros((0, size, size, -(-size // 8)), np.uint8)
        result[split] = VolumeSplit(arr, np.array(names, dtype="U32")[order], size)
    return result


def write(path, data: dict[str, VolumeSplit], margin: int = MARGIN) -> None:
    """Write a built set (see :func:`build`) as a compressed ``.npz``, atomically
    (:func:`shapeio.volumes.write_volumes`)."""
    write_volumes(path, data, margin)
