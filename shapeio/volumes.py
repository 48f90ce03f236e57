"""The volume set's file: a NumPy ``.npz`` (no pickles) of 64³ occupancy volumes, one entry per split and field.

* ``{split}_volumes``: ``(N, size, size, ceil(size / 8)) uint8``, ``np.packbits`` of the bool volumes
  ``vol[x, y, z]`` along the last axis (NumPy's default big-endian bit order);
* ``{split}_ids``: ``(N,)`` str, ``"category/id"``;
* ``size``, ``margin``: ints; ``version``: :data:`FORMAT_VERSION`.

Written by :func:`write_volumes` (``python -m shapeprog assembly volumes``), read by :func:`read_volumes`
(``csgnet.shapes3d.load_volumes``); ``docs/csgnet.md`` ("The ShapeAssembly volumes") describes the set.
The volumes stay packed (32 KiB each at 64³) until :func:`unpack_volumes`, since a whole split unpacked
takes 256 KiB per shape.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Union

import numpy as np

from .files import atomic_write
from .silhouettes import SPLITS, check_split, read_set, set_header

__all__ = ["FORMAT_VERSION", "MAX_SIZE", "SPLITS", "VolumeSplit", "pack_volumes", "unpack_volumes", "write_volumes",
           "read_volumes"]

PathLike = Union[str, os.PathLike]

#: The layout version this module writes and reads.
FORMAT_VERSION = 1
MAX_SIZE = 256
"""The largest volume side a volume file may declare."""


@dataclass(frozen=True)
class VolumeSplit:
    """One split of a volume set, packed.

    Attributes:
        packed: ``(N, size, size, ceil(size / 8)) uint8``, :func:`pack_volumes` of the volumes.
        ids: ``(N,)`` str, the shape of each volume (``"chair/173"``).
        size: the volume side.
    """

    packed: np.ndarray
    ids: np.ndarray
    size: int

    def __len__(self) -> int:
        return len(self.packed)

    def volumes(self, limit: int | None = None) -> np.ndarray:
        """The first ``limit`` volumes (default: all) unpacked: ``(n, size, size, size) bool``."""
        return unpack_volumes(self.packed[:limit], self.size)


def pack_volumes(volumes: np.ndarray) -> np.ndarray:
    """``(..., D, H, W) bool`` -> ``(..., D, H, ceil(W / 8)) uint8`` (bits along the last axis)."""
    return np.packbits(np.asarray(volumes, dtype=bool), axis=-1)


def unpack_volumes(packed: np.ndarray, size: int) -> np.ndarray:
    """The inverse of :func:`pack_volumes` for volumes of side ``size``."""
    return np.unpackbits(packed, axis=-1, count=size).astype(bool)


def write_volumes(path: PathLike, data: Mapping[str, VolumeSplit], margin: int) -> Path:
    """Write ``{split: VolumeSplit}`` (all of one size) and the fitting ``margin`` they were drawn with as a
    compressed ``.npz``, atomically, as :func:`shapeio.silhouettes.write_silhouettes` writes images; returns the
    path. Raises ``ValueError`` naming ``path`` for no split, an unknown split or mismatched arrays."""
    size = next(iter(data.values())).size if data else None
    arrays = set_header(path, size, margin, FORMAT_VERSION, "volumes")
    want = (size, size, -(-size // 8))
    for split, s in data.items():
        check_split(split)
        packed = np.asarray(s.packed)
        if s.size != size or packed.dtype != np.uint8 or packed.ndim != 4 or packed.shape[1:] != want:
            raise ValueError(f"{path}: {split} volumes must be packed as (N, {', '.join(map(str, want))}) uint8, "
                             f"got {packed.shape} {packed.dtype} of side {s.size}")
        if len(s.ids) != len(packed):
            raise ValueError(f"{path}: {split} has {len(packed)} volumes but {len(s.ids)} ids")
        arrays[f"{split}_volumes"] = packed
        arrays[f"{split}_ids"] = np.asarray(s.ids, dtype=str)
    return atomic_write(path, lambda f: np.savez_compressed(f, **arrays))


def read_volumes(path: PathLike, split: str) -> VolumeSplit:
    """Read one split of a volume file (packed; :meth:`VolumeSplit.volumes` unpacks).

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file: an unknown split, not an ``.npz``, a missing entry, another
            version, or arrays of the wrong dtype or shape.
    """
    check_split(split)
    p, (packed, ids), size = read_set(path, "volume", (f"{split}_volumes", f"{split}_ids"), FORMAT_VERSION,
                                      f"a volume set with a {split} split")
    want = (size, size, -(-size // 8))
    if packed.dtype != np.uint8 or packed.ndim != 4 or packed.shape[1:] != want:
        raise ValueError(f"{p}: {split}_volumes has dtype {packed.dtype} and shape {packed.shape}; expected "
                         f"(N, {', '.join(map(str, want))}) uint8 (packed bits)")
    if len(ids) != len(packed):
        raise ValueError(f"{p}: {split} has {len(packed)} volumes but {len(ids)} ids")
    return VolumeSplit(packed, ids, size)
