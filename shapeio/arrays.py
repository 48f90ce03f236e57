"""NumPy views of array-likes (torch tensors included, without importing torch) and users' ``.npy`` grids."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence, Union

import numpy as np

from .files import InputError

__all__ = ["as_numpy", "int_entry", "read_grid", "MAX_GRID_CELLS"]

PathLike = Union[str, os.PathLike]

#: Largest ``.npy`` grid read (cells); a bigger file is an :class:`~shapeio.files.InputError` before
#: its data is read.
MAX_GRID_CELLS = 256 ** 3


def as_numpy(x) -> np.ndarray:
    """``x`` as a NumPy array; a torch tensor is detached and moved to the CPU first."""
    if type(x).__module__.startswith("torch"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def int_entry(value, path: PathLike, name: str, low: int | None = None, high: int | None = None) -> int:
    """A stored integer scalar (an ``.npz`` entry ``name`` of ``path``) within ``[low, high]`` (a bound of None is
    open), or an :class:`~shapeio.files.InputError` naming the file, the entry and what it holds."""
    arr = np.asarray(value)
    ok = arr.ndim == 0 and np.issubdtype(arr.dtype, np.integer)
    if ok and (low is None or int(arr) >= low) and (high is None or int(arr) <= high):
        return int(arr)
    bounds = (f" in [{low}, {high}]" if low is not None and high is not None else f" >= {low}" if low is not None
              else f" <= {high}" if high is not None else "")
    raise InputError(f"{path}: the entry {name!r} is not an integer{bounds}: dtype {arr.dtype}, shape {arr.shape}")


def read_grid(path: PathLike, ndims: Sequence[int] = (2, 3), max_cells: int = MAX_GRID_CELLS) -> np.ndarray:
    """A user's ``.npy`` file as a bool grid (non-zero = inside).

    The header is checked before the data is read: the number of axes must be one of ``ndims``, the
    size at most ``max_cells``, the values bool, integer or float (no complex, string or object
    arrays; pickles are refused). Float grids must be finite.

    Args:
        path: the ``.npy`` file.
        ndims: accepted numbers of axes.
        max_cells: the largest grid accepted.

    Returns:
        ``(H, W)`` or ``(X, Y, Z)`` bool, ``arr != 0``.

    Raises:
        FileNotFoundError: no such file.
        InputError: naming the file: unreadable, or a grid the rules above refuse.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    fmt = np.lib.format
    try:
        with open(path, "rb") as f:
            version = fmt.read_magic(f)
            read_header = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
            shape, _, dtype = read_header(f)
    except Exception as e:  # NumPy's header parser raises many types (ValueError, SyntaxError, TokenError, ...)
        raise InputError(f"{path}: not a readable .npy array ({type(e).__name__}: {e})") from None
    if len(shape) not in ndims:
        raise InputError(f"{path}: expected a grid with {' or '.join(map(str, ndims))} axes, got shape {shape}")
    cells = int(np.prod(shape, dtype=np.float64))
    if cells > max_cells:
        raise InputError(f"{path}: the grid has {cells} cells; at most MAX_GRID_CELLS = {max_cells} are read")
    if dtype.kind not in "biuf":
        raise InputError(f"{path}: the grid holds {dtype} values; expected bool, integer or float")
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as e:  # a truncated or inconsistent file: EOFError, ValueError, OSError, ...
        raise InputError(f"{path}: not a readable .npy array ({type(e).__name__}: {e})") from None
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise InputError(f"{path}: the grid holds NaN or infinite values")
    return arr != 0
