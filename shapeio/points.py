"""Point clouds: binary PLY (``x y z`` and optional ``nx ny nz``) and OBJ ``v x y z`` lines.

Reading a PLY goes through trimesh, imported on first use (it takes most of a second to import).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable, Union

import numpy as np

from .arrays import as_numpy
from .files import atomic_write
from .mesh import _trimesh

__all__ = ["write_points", "read_points", "obj_vertices"]

PathLike = Union[str, os.PathLike]


def _points_array(x, name: str, path: PathLike) -> np.ndarray:
    arr = as_numpy(x)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{path}: `{name}` must have shape (N, 3), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{path}: `{name}` contains NaN or infinite values")
    return arr.astype(np.float32)


def write_points(path: PathLike, points, normals=None) -> Path:
    """Write a point cloud as a binary little-endian PLY (``x y z`` and optionally ``nx ny nz``, float32).

    Args:
        path: target file.
        points: ``(N, 3) float`` (NumPy or torch).
        normals: optional ``(N, 3) float``.

    Returns:
        The path written.
    """
    pts = _points_array(points, "points", path)
    names = ["x", "y", "z"]
    cols = [pts]
    if normals is not None:
        nrm = _points_array(normals, "normals", path)
        if nrm.shape != pts.shape:
            raise ValueError(f"{path}: `normals` must match `points` {pts.shape}, got {nrm.shape}")
        names += ["nx", "ny", "nz"]
        cols.append(nrm)
    body = np.ascontiguousarray(np.concatenate(cols, axis=1), dtype="<f4")
    header = "ply\nformat binary_little_endian 1.0\n"
    header += f"element vertex {pts.shape[0]}\n"
    header += "".join(f"property float {n}\n" for n in names)
    header += "end_header\n"

    def write(f):
        f.write(header.encode("ascii"))
        f.write(body.tobytes())

    return atomic_write(path, write)


def obj_vertices(lines: Iterable[str], where) -> np.ndarray:
    """The ``v x y z`` points of OBJ text ``lines`` as ``(N, 3) float32``; errors name ``where:line``."""
    pts = []
    for lineno, line in enumerate(lines, 1):
        parts = line.split()
        if not parts or parts[0] != "v":
            continue
        try:
            if len(parts) < 4:
                raise ValueError
            pts.append([float(parts[1]), float(parts[2]), float(parts[3])])
        except ValueError:
            raise ValueError(f"{where}:{lineno}: expected 'v x y z', got {line.strip()!r}") from None
    if not pts:
        raise ValueError(f"{where}: no 'v x y z' line found")
    return np.asarray(pts, dtype=np.float32)


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    try:
        loaded = _trimesh().load(str(path), file_type="ply", process=False)
    except Exception as err:
        raise ValueError(f"{path}: cannot read PLY: {err}") from err
    pts = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float32)
    raw = loaded.metadata.get("_ply_raw", {}).get("vertex", {}).get("data") if hasattr(loaded, "metadata") else None
    normals = None
    if raw is not None and raw.dtype.names and {"nx", "ny", "nz"} <= set(raw.dtype.names):
        normals = np.stack([raw["nx"], raw["ny"], raw["nz"]], axis=1).astype(np.float32)
    if pts.shape[0] == 0:
        raise ValueError(f"{path}: the PLY holds no vertex")
    return pts, normals


def read_points(path: PathLike, return_normals: bool = False):
    """Read a point cloud: an OBJ of ``v x y z`` lines, or a PLY (via trimesh).

    Args:
        path: ``.obj`` or ``.ply`` file.
        return_normals: also return the PLY's ``nx ny nz`` (None when absent or for OBJ).

    Returns:
        ``(N, 3) float32`` array, or ``(points, normals)`` with ``return_normals``.

    Raises:
        FileNotFoundError, ValueError: naming the file (and line for OBJ).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    suffix = path.suffix.lower()
    normals = None
    if suffix == ".obj":
        with open(path, "r", encoding="utf-8", errors="replace") as f:
            pts = obj_vertices(f, path)
    elif suffix == ".ply":
        pts, normals = _read_ply(path)
    else:
        raise ValueError(f"{path}: unsupported point-cloud format {suffix!r} (expected .obj or .ply)")
    if not np.isfinite(pts).all():
        raise ValueError(f"{path}: contains NaN or infinite coordinates")
    pts = np.ascontiguousarray(pts)
    if return_normals:
        return pts, None if normals is None else np.ascontiguousarray(normals)
    return pts
