"""Real 2D target shapes for CSGNet: the shipped PartNet silhouettes and the paper's ``cad.h5``.

* :func:`load_silhouettes`: front and side silhouettes (64x64) of the PartNet chairs, tables and
  storage furniture of the ShapeAssembly corpus, shipped as ``csgnet/data/silhouettes.npz``
  (built by ``python -m shapeprog assembly silhouettes``; see ``docs/csgnet.md``, "The PartNet silhouettes").
  Splits ``train``, ``val`` and ``test``; this set stands in for the paper's CAD set and is not the same data.
* :func:`load_cad_h5`: the paper's ``cad.h5`` (datasets ``train_images``, ``val_images``,
  ``test_images``, each N x 64 x 64), for users who have that file. Needs ``h5py``, the ``cad``
  extra (``pip install -e '.[cad]'`` in the checkout).

Both return ``(N, 64, 64)`` bool arrays with rows as stored (``img[row, col]``, no transposition, as
the reference feeds the CAD images to the network). Nothing is read at import.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

import numpy as np

from shapeio.silhouettes import SPLITS, SilhouetteSplit, check_split, read_silhouettes

from .primitives import SIZE

__all__ = ["SPLITS", "SilhouetteSplit", "load_cad_h5", "load_silhouettes", "silhouettes_path"]


def silhouettes_path() -> Path:
    """The shipped silhouette file, ``csgnet/data/silhouettes.npz`` inside the installed package."""
    return Path(str(resources.files("csgnet").joinpath("data", "silhouettes.npz")))


def load_silhouettes(split: str = "train", path: str | os.PathLike | None = None,
                     with_ids: bool = False) -> np.ndarray | SilhouetteSplit:
    """Load one split of the PartNet silhouette set (file layout: :mod:`shapeio.silhouettes`).

    Args:
        split: ``"train"``, ``"val"`` or ``"test"``.
        path: a file written by ``python -m shapeprog assembly silhouettes --out PATH`` (default: the
            shipped ``csgnet/data/silhouettes.npz``).
        with_ids: also return the shape id and view of each image.

    Returns:
        ``(N, 64, 64)`` bool images, or a :class:`SilhouetteSplit` with ``with_ids=True``.

    Raises:
        FileNotFoundError: no such file (the message names the command that builds it).
        ValueError: an unknown split, or a file that is not a silhouette set of this version.
    """
    check_split(split)
    p = Path(path) if path is not None else silhouettes_path()
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no silhouette file; build one with "
                                f"'python -m shapeprog assembly silhouettes --out {p}'")
    data = read_silhouettes(p, split)
    return data if with_ids else data.images


def _h5py():
    try:
        import h5py  # optional: the 'cad' extra
    except ImportError as e:
        raise ImportError("reading cad.h5 needs h5py, which is not installed; install the 'cad' extra: "
                          "pip install -e '.[cad]' in the checkout (or pip install h5py)") from e
    return h5py


def load_cad_h5(path: str | os.PathLike, split: str = "test") -> np.ndarray:
    """Read one split of the paper's CAD image file (``data/cad/cad.h5`` of the reference code).

    Args:
        path: the ``.h5`` file.
        split: ``"train"``, ``"val"`` or ``"test"`` (datasets ``train_images``, ``val_images``,
            ``test_images``).

    Returns:
        ``(N, 64, 64)`` bool (non-zero = on, the reference's ``astype(bool)``), rows as stored.

    Raises:
        ImportError: h5py is missing (names the ``cad`` extra).
        FileNotFoundError: no such file.
        ValueError: not an HDF5 file, no such dataset, or a dataset that is not ``(N, 64, 64)``.
    """
    check_split(split)
    h5py = _h5py()
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such file")
    name = f"{split}_images"
    try:
        f = h5py.File(p, "r")
    except OSError as e:
        raise ValueError(f"{p}: not a readable HDF5 file ({e})") from None
    with f:
        if name not in f:
            found = ", ".join(sorted(f.keys())) or "nothing"
            raise ValueError(f"{p}: no dataset {name!r} (found: {found}); a CAD file holds "
                             f"train_images, val_images and test_images")
        ds = f[name]
        if not isinstance(ds, h5py.Dataset):
            raise ValueError(f"{p}: {name!r} is a group, not a dataset")
        if ds.ndim != 3 or ds.shape[1:] != (SIZE, SIZE):
            raise ValueError(f"{p}: dataset {name!r} has shape {ds.shape}; expected (N, {SIZE}, {SIZE})")
        data = ds[()]
    return np.asarray(data) != 0
