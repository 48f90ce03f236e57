"""Export of cuboid shapes and voxel grids, and point clouds as tensors: thin wrappers over :mod:`shapeio`.

Writers take plain arrays or tensors (``corners: (L, 8, 3) float`` in the spec's corner order), check
them with errors naming the file, and write atomically through :mod:`shapeio`:

* :func:`write_obj` writes the reference ``writeObj`` layout plus one ``g`` group per part
  (:func:`shapeio.mesh.write_mesh`), named by the program line that made the part (:func:`part_names`).
* :func:`write_ply`, :func:`write_glb`: triangle meshes via trimesh; per-part colours from ``labels``.
* :func:`write_points` / :func:`read_points`: point clouds (PLY with normals; OBJ ``v x y z``),
  :mod:`shapeio.points`, read back as tensors.
* :func:`write_voxels`: a ``.npy`` occupancy grid.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Union

import numpy as np
import torch

from shapeio import atomic_write
from shapeio import points as _points
from shapeio.arrays import as_numpy
from shapeio.mesh import obj_text as _mesh_obj_text
from shapeio.mesh import write_mesh, write_parts
from shapeio.points import write_points
from shapeprog.geometry import CUBOID_TRIANGLES, mesh_arrays
from shapeprog.picture import part_colors
from shapeprog.geometry import check_corners

__all__ = [
    "part_names",
    "write_obj",
    "obj_text",
    "write_ply",
    "write_glb",
    "write_points",
    "read_points",
    "write_voxels",
]

PathLike = Union[str, os.PathLike]


def _corners_array(corners, path: PathLike) -> np.ndarray:
    """``(L, 8, 3)`` corners (tensor or array) as a validated NumPy array, errors naming ``path``."""
    return check_corners(as_numpy(corners), where=path, arrays=True)


def _mesh(arr: np.ndarray, dtype) -> tuple[np.ndarray, np.ndarray]:
    """Vertices ``(8 L, 3)`` in ``dtype`` and faces ``(12 L, 3) int64`` of validated corners."""
    verts, faces = mesh_arrays(torch.from_numpy(np.ascontiguousarray(arr, dtype=dtype)))
    return verts.numpy(), faces.numpy()


def part_names(n: int, lines=None) -> list[str]:
    """One OBJ group name per part: ``line_<n>`` with ``n`` the 1-based program line that made the part
    (``ExecutedShape.line`` holds the 0-based lines), ``line_<n>.<k>`` for the k-th further part of the same
    line (translate copies); ``part_<k>`` without ``lines``."""
    if lines is None:
        return [f"part_{k}" for k in range(n)]
    ls = [int(v) for v in as_numpy(lines).reshape(-1).tolist()]
    if len(ls) != n:
        raise ValueError(f"{len(ls)} part lines for {n} parts")
    seen: dict = {}
    out = []
    for v in ls:
        seen[v] = seen.get(v, 0) + 1
        out.append(f"line_{v + 1}" if seen[v] == 1 else f"line_{v + 1}.{seen[v]}")
    return out


def _groups(n: int, lines) -> list[tuple[str, int]]:
    return [(name, len(CUBOID_TRIANGLES)) for name in part_names(n, lines)]


def obj_text(corners, lines=None) -> str:
    """The OBJ text of a list of cuboids (see :func:`write_obj`)."""
    arr = _corners_array(corners, "<obj>")
    return _mesh_obj_text(*_mesh(arr, np.float32), groups=_groups(len(arr), lines))


def write_obj(path: PathLike, corners, lines=None) -> Path:
    """Write cuboids in the reference OBJ layout, with one group per part.

    Every vertex first, leaf after leaf with 8 corners each, as ``v {x} {y} {z}`` where each number
    is Python's ``str`` of the float32 value converted to a double (``0.4424920082092285``); then per
    leaf a ``g <name>`` line (:func:`part_names`) and its triangles as ``f a b c`` with 1-based indices
    (leaf ``k`` adds ``8 k``) in the spec's triangle order. No header or normals; LF line ends.

    Args:
        path: target file.
        corners: ``(L, 8, 3) float`` array or tensor (converted to float32).
        lines: optional ``(L,)`` 0-based program line of each leaf (``ExecutedShape.line``), naming the groups
            ``line_<n>``; without it they are ``part_<k>``.

    Returns:
        The path written.
    """
    arr = _corners_array(corners, path)
    return write_mesh(path, *_mesh(arr, np.float32), file_type="obj", groups=_groups(len(arr), lines))


def write_ply(path: PathLike, corners, labels=None) -> Path:
    """Write the cuboids as one binary PLY triangle mesh (trimesh) with per-face part colours.

    Vertices and faces are in the same order as :func:`write_obj` (no vertex merging).

    Args:
        path: target file.
        corners: ``(L, 8, 3) float``.
        labels: optional ``(L,)`` part labels (e.g. program line); equal labels share a colour.
    """
    arr = _corners_array(corners, path)
    rgb = np.repeat(part_colors(arr.shape[0], labels), 12, axis=0)  # 12 triangles per cuboid
    return write_mesh(path, *_mesh(arr, np.float64), face_colors=rgb, file_type="ply")


def write_glb(path: PathLike, corners, labels=None) -> Path:
    """Write the cuboids as a binary glTF scene (trimesh), one coloured mesh node per part (``part_k``).

    Args:
        path: target file.
        corners: ``(L, 8, 3) float``.
        labels: optional ``(L,)`` part labels; equal labels share a colour.
    """
    arr = _corners_array(corners, path).astype(np.float64)
    colors = part_colors(arr.shape[0], labels)
    tri = CUBOID_TRIANGLES.numpy()
    return write_parts(path, [(arr[k], tri, colors[k]) for k in range(arr.shape[0])])


def read_points(path: PathLike, return_normals: bool = False):
    """Read a point cloud (:func:`shapeio.points.read_points`) as tensors.

    Args:
        path: ``.obj`` (``v x y z`` lines) or ``.ply`` file.
        return_normals: also return the PLY's ``nx ny nz`` (None when absent or for OBJ).

    Returns:
        ``(N, 3) float32`` tensor, or ``(points, normals)`` with ``return_normals``.

    Raises:
        FileNotFoundError, ValueError: naming the file (and line for OBJ).
    """
    pts, normals = _points.read_points(path, return_normals=True)
    out = torch.from_numpy(pts)
    if return_normals:
        return out, None if normals is None else torch.from_numpy(normals)
    return out


def write_voxels(path: PathLike, grid) -> Path:
    """Write an occupancy grid ``(X, Y, Z) bool`` (any array or tensor) as ``.npy``."""
    arr = as_numpy(grid)
    if arr.ndim != 3:
        raise ValueError(f"{path}: `grid` must be 3-D (X, Y, Z), got shape {arr.shape}")
    return atomic_write(path, lambda f: np.save(f, arr, allow_pickle=False))
