"""Real 3D target shapes for CSGNet: the ShapeAssembly volumes.

:func:`load_volumes` reads the chairs and tables of the ShapeAssembly corpus voxelised to 64³ (``vol[x, y, z]``,
y up), a file built once with ``python -m shapeprog assembly volumes --out data/assembly_volumes.npz
--workers 2`` (layout: :mod:`shapeio.volumes`; ``docs/csgnet.md``, "The ShapeAssembly volumes"). Splits
``train``, ``val`` and ``test`` are disjoint sets of shapes, each in a fixed shuffled order, so the first ``n``
of a split are a uniform sample of it. The set is not shipped (2.6 MB, built in about a minute); nothing is
read at import.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from shapeio.silhouettes import check_split
from shapeio.volumes import read_volumes

from .primitives import SIZE

__all__ = ["DEFAULT_VOLUMES", "load_volumes"]

#: Where :func:`load_volumes` looks without a path (relative to the working directory).
DEFAULT_VOLUMES = Path("data") / "assembly_volumes.npz"


def load_volumes(split: str = "train", path: str | os.PathLike | None = None, limit: int | None = None) -> np.ndarray:
    """One split of the ShapeAssembly volume set.

    Args:
        split: ``"train"``, ``"val"`` or ``"test"``.
        path: the file (default: :data:`DEFAULT_VOLUMES`).
        limit: only the first ``limit`` volumes (the others are never unpacked).

    Returns:
        ``(N, 64, 64, 64)`` bool volumes.

    Raises:
        FileNotFoundError: no such file (the message names the command that builds it).
        ValueError: an unknown split, a file that is not a volume set of this version, or volumes that are
            not 64-sided.
    """
    check_split(split)
    p = Path(path) if path is not None else DEFAULT_VOLUMES
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no volume file; build one with "
                                f"'python -m shapeprog assembly volumes --out {p} --workers 2'")
    data = read_volumes(p, split)
    if data.size != SIZE:
        raise ValueError(f"{p}: volumes of side {data.size}; CSGNet's 3D targets are {SIZE}-sided "
                         f"(build the set with --size {SIZE})")
    return data.volumes(limit)
