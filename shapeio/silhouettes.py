"""The silhouette set's file: a NumPy ``.npz`` (no pickles) with one entry per split and field.

* ``{split}_images``: ``(N, size, ceil(size / 8)) uint8``, ``np.packbits`` of the bool masks along
  the column axis (NumPy's default big-endian bit order); ``(N, size, size) bool`` is read too;
* ``{split}_ids``: ``(N,)`` str, ``"category/id"``; ``{split}_views``: ``(N,)`` str, ``"front"`` / ``"side"``;
* ``size``, ``margin``: ints; ``version``: :data:`FORMAT_VERSION`.

Written by :func:`write_silhouettes` (``python -m shapeprog assembly silhouettes``), read by
:func:`read_silhouettes` (``csgnet.shapes2d.load_silhouettes``); ``docs/csgnet.md`` ("The PartNet silhouettes")
describes the set.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Union

import numpy as np

from .arrays import int_entry
from .files import atomic_write

__all__ = ["FORMAT_VERSION", "MAX_SIZE", "SPLITS", "SilhouetteSplit", "check_split", "split_keys", "write_silhouettes",
           "read_silhouettes"]

PathLike = Union[str, os.PathLike]

#: The layout version this module writes and reads.
FORMAT_VERSION = 1
SPLITS = ("train", "val", "test")
SIZE = 64  # the image side of files without a ``size`` entry
MAX_SIZE = 1024
"""The largest image side a silhouette file may declare."""


@dataclass(frozen=True)
class SilhouetteSplit:
    """One split of the silhouette set.

    Attributes:
        images: ``(N, size, size) bool``.
        ids: ``(N,)`` str, the corpus shape of each image (``"chair/173"``).
        views: ``(N,)`` str, ``"front"`` or ``"side"``.
    """

    images: np.ndarray
    ids: np.ndarray
    views: np.ndarray

    def __len__(self) -> int:
        return len(self.images)


def check_split(split: str) -> None:
    """Refuse a split name other than ``train``, ``val`` and ``test``."""
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")


def split_keys(split: str) -> tuple[str, str, str]:
    """The file's entries of one split: images, ids, views."""
    return f"{split}_images", f"{split}_ids", f"{split}_views"


def set_header(path, size: int | None, margin: int, version: int, what: str) -> dict:
    """The entries every set file starts with (``size``, ``margin``, ``version``); ``size`` None: no split.

    Raises:
        ValueError: naming ``path``: no split, or ``what`` (``"images"``, ``"volumes"``) of a side outside
            ``1..MAX_SIZE``.
    """
    if size is None:
        raise ValueError(f"{path}: no split to write")
    if not 1 <= size <= MAX_SIZE:
        raise ValueError(f"{path}: {what} of side {size}; at most MAX_SIZE = {MAX_SIZE} are written (and read)")
    return {"size": np.int64(size), "margin": np.int64(margin), "version": np.int64(version)}


def write_silhouettes(path: PathLike, data: Mapping[str, SilhouetteSplit], margin: int) -> Path:
    """Write a silhouette set as a compressed ``.npz``, atomically.

    Args:
        path: the output file.
        data: ``{split: SilhouetteSplit}`` (any of ``train``, ``val``, ``test``), images all of one size.
        margin: the fitting margin the images were drawn with (stored for readers).

    Returns:
        The path written.

    Raises:
        ValueError: naming ``path``: no split, an unknown split, or arrays of mismatched shapes.
    """
    size = next(iter(data.values())).images.shape[-1] if data else None
    arrays = set_header(path, size, margin, FORMAT_VERSION, "images")
    for split, s in data.items():
        check_split(split)
        images = np.asarray(s.images)
        if images.dtype != np.bool_ or images.ndim != 3 or images.shape[1:] != (size, size):
            raise ValueError(f"{path}: {split} images must be (N, {size}, {size}) bool, got {images.shape} {images.dtype}")
        if len(s.ids) != len(images) or len(s.views) != len(images):
            raise ValueError(f"{path}: {split} has {len(images)} images but {len(s.ids)} ids and {len(s.views)} views")
        key_images, key_ids, key_views = split_keys(split)
        arrays[key_images] = np.packbits(images, axis=-1)
        arrays[key_ids] = s.ids
        arrays[key_views] = s.views
    return atomic_write(path, lambda f: np.savez_compressed(f, **arrays))



def open_npz(path, what: str):
    """``(Path, NpzFile)`` of an ``.npz`` file of ``what`` (e.g. "a volume set"), read without pickles.

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file: not a readable ``.npz`` archive.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: no such file")
    try:
        z = np.load(p, allow_pickle=False)
    except Exception as e:  # numpy and zipfile raise many types for damaged files
        raise ValueError(f"{p}: not a readable .npz file ({type(e).__name__}: {e})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"{p}: not {what}: a single array, not an .npz archive")
    return p, z


def read_set(path, kind: str, need: tuple[str, ...], version: int, missing: str,
             default_size: int | None = None) -> tuple[Path, list[np.ndarray], int]:
    """The entries ``need`` of a ``kind`` set's ``.npz`` (``"silhouette"``, ``"volume"``), its format checked.

    ``version`` is the format version the caller reads; ``missing`` names the file in the error for absent
    entries. With ``default_size``, a file without ``version`` / ``size`` entries is read as ``version`` /
    ``default_size`` sided (the first silhouette files); without it both entries are required.

    Returns:
        ``(path, [the arrays of need], size)``.

    Raises:
        FileNotFoundError, ValueError: as :func:`open_npz`; a missing entry, another version, a size
            outside ``1..MAX_SIZE``, or a damaged member (each naming the file).
    """
    p, z = open_npz(path, f"a {kind} set")
    try:
        with z:
            keys = set(z.files)
            required = set(need) | (set() if default_size else {"size", "version"})
            if not required <= keys:
                raise ValueError(f"{p}: not {missing}: missing {', '.join(sorted(required - keys))} "
                                 f"(found {', '.join(sorted(keys)) or 'nothing'})")
            found = int_entry(z["version"], p, "version", 0, 2**31) if "version" in keys else version
            if found != version:
                raise ValueError(f"{p}: {kind} file version {found}; this reader reads version {version}")
            size = int_entry(z["size"], p, "size", 1, MAX_SIZE) if "size" in keys else default_size
            return p, [z[k] for k in need], size
    except ValueError as e:
        if str(e).startswith(f"{p}: "):
            raise
        raise ValueError(f"{p}: corrupt .npz file ({e})") from None
    except Exception as e:  # zipfile, zlib and numpy's readers raise many types for damaged members
        raise ValueError(f"{p}: corrupt .npz file ({type(e).__name__}: {e})") from None


def read_silhouettes(path: PathLike, split: str) -> SilhouetteSplit:
    """Read one split of a silhouette file.

    A file without a ``version`` entry is read as version 1; one without ``size`` as 64-sided.

    Args:
        path: an ``.npz`` written by :func:`write_silhouettes`.
        split: ``"train"``, ``"val"`` or ``"test"``.

    Returns:
        The split, images unpacked to ``(N, size, size) bool``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file: an unknown split, not an ``.npz``, a missing entry, another
            version, or arrays of the wrong dtype or shape.
    """
    check_split(split)
    key_images, key_ids, key_views = split_keys(split)
    p, (raw, ids, views), size = read_set(path, "silhouette", (key_images, key_ids, key_views), FORMAT_VERSION,
                                          "a silhouette set", default_size=SIZE)
    if raw.dtype == np.uint8 and raw.ndim == 3 and raw.shape[1:] == (size, -(-size // 8)):
        images = np.unpackbits(raw, axis=-1, count=size).astype(bool)
    elif raw.dtype == np.bool_ and raw.ndim == 3 and raw.shape[1:] == (size, size):
        images = raw
    else:
        raise ValueError(f"{p}: {key_images} has dtype {raw.dtype} and shape {raw.shape}; expected "
                         f"(N, {size}, {-(-size // 8)}) uint8 (packed bits) or (N, {size}, {size}) bool")
    if len(ids) != len(images) or len(views) != len(images):
        raise ValueError(f"{p}: {split} has {len(images)} images but {len(ids)} ids and {len(views)} views")
    return SilhouetteSplit(images, ids, views)
