"""Export and import of cuboid shapes, point clouds and voxel grids.

Writers take plain arrays or tensors (``corners: (L, 8, 3) float`` in the spec's corner order) and
are atomic: they write a temporary file in the target's directory and move it into place with
``os.replace``, so a reader never sees a half-written file. Mesh formats other than the reference
OBJ layout go through trimesh.

* :func:`write_obj` writes the reference ``writeObj`` layout byte for byte.
* :func:`write_ply`, :func:`write_glb`: triangle meshes via trimesh; per-part colours from ``labels``.
* :func:`write_points` / :func:`read_points`: point clouds (PLY with normals; OBJ ``v x y z``).
* :func:`write_voxels`: a ``.npy`` occupancy grid.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Union

import numpy as np
import torch

from shapeio import atomic_write
from shapeprog.geometry import CUBOID_TRIANGLES, mesh_arrays
from shapeprog.picture import part_colors
from shapeprog.geometry import check_corners

__all__ = [
    "write_obj",
    "obj_text",
    "write_ply",
    "write_glb",
    "write_points",
    "read_points",
    "write_voxels",
    "write_png",
]

PathLike = Union[str, os.PathLike]


def _corners_array(corners, path: PathLike) -> np.ndarray:
    """``(L, 8, 3)`` corners (tensor or array) as a validated NumPy array, errors naming ``path``."""
    if isinstance(corners, torch.Tensor):
        corners = corners.detach().cpu().numpy()
    return check_corners(np.asarray(corners), where=path, arrays=True)


def _obj_text(arr: np.ndarray) -> str:
    """:func:`obj_text` of an already validated corner array."""
    verts, faces = (t.numpy() for t in mesh_arrays(torch.from_numpy(arr.astype(np.float32))))
    lines = [f"v {float(x)} {float(y)} {float(z)}\n" for x, y, z in verts]
    lines += [f"f {a} {b} {c}\n" for a, b, c in (faces + 1).tolist()]
    return "".join(lines)


def obj_text(corners) -> str:
    """The reference OBJ text of a list of cuboids (see :func:`write_obj`)."""
    return _obj_text(_corners_array(corners, "<obj>"))


def write_obj(path: PathLike, corners) -> Path:
    """Write cuboids in the reference OBJ layout.

    Every vertex first, leaf after leaf with 8 corners each, as ``v {x} {y} {z}`` where each number
    is Python's ``str`` of the float32 value converted to a double (``0.4424920082092285``); then
    every triangle as ``f a b c`` with 1-based indices (leaf ``k`` adds ``8 k``) in the spec's
    triangle order. No header, normals or groups; LF line ends.

    Args:
        path: target file.
        corners: ``(L, 8, 3) float`` array or tensor (converted to float32).

    Returns:
        The path written.
    """
    text = _obj_text(_corners_array(corners, path))
    return atomic_write(path, lambda f: f.write(text.encode("ascii")))


def _trimesh():
    try:
        import trimesh
    except ImportError as err:  # pragma: no cover - trimesh is a core dependency
        raise ImportError("mesh export needs trimesh: pip install trimesh") from err
    return trimesh


def _mesh(arr: np.ndarray, labels):
    trimesh = _trimesh()
    verts, faces = (t.numpy() for t in mesh_arrays(torch.from_numpy(arr.astype(np.float64))))
    rgb = np.repeat(part_colors(arr.shape[0], labels), 12, axis=0)
    rgba = np.concatenate([rgb, np.full((rgb.shape[0], 1), 255, np.uint8)], axis=1)
    return trimesh.Trimesh(vertices=verts, faces=faces, face_colors=rgba, process=False)


def write_ply(path: PathLike, corners, labels=None) -> Path:
    """Write the cuboids as one binary PLY triangle mesh (trimesh) with per-face part colours.

    Vertices and faces are in the same order as :func:`write_obj` (no vertex merging).

    Args:
        path: target file.
        corners: ``(L, 8, 3) float``.
        labels: optional ``(L,)`` part labels (e.g. program line); equal labels share a colour.
    """
    mesh = _mesh(_corners_array(corners, path), labels)
    data = mesh.export(file_type="ply")
    return atomic_write(path, lambda f: f.write(data))


def write_glb(path: PathLike, corners, labels=None) -> Path:
    """Write the cuboids as a binary glTF scene (trimesh), one coloured mesh node per part.

    Args:
        path: target file.
        corners: ``(L, 8, 3) float``.
        labels: optional ``(L,)`` part labels; equal labels share a colour.
    """
    trimesh = _trimesh()
    arr = _corners_array(corners, path).astype(np.float64)
    colors = part_colors(arr.shape[0], labels)
    scene = trimesh.Scene()
    tri = CUBOID_TRIANGLES.numpy()
    for k in range(arr.shape[0]):
        rgba = np.append(colors[k], 255).astype(np.uint8)
        mesh = trimesh.Trimesh(vertices=arr[k], faces=tri, process=False)
        mesh.visual = trimesh.visual.TextureVisuals(
            material=trimesh.visual.material.PBRMaterial(baseColorFactor=rgba, metallicFactor=0.0, roughnessFactor=0.8)
        )
        scene.add_geometry(mesh, node_name=f"part_{k}", geom_name=f"part_{k}")
    data = scene.export(file_type="glb")
    return atomic_write(path, lambda f: f.write(data))


def _points_array(x, name: str, path: PathLike) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    arr = np.asarray(x)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{path}: `{name}` must have shape (N, 3), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{path}: `{name}` contains NaN or infinite values")
    return arr.astype(np.float32)


def write_points(path: PathLike, points, normals=None) -> Path:
    """Write a point cloud as a binary little-endian PLY (``x y z`` and optionally ``nx ny nz``, float32).

    Args:
        path: target file.
        points: ``(N, 3) float``.
        normals: optional ``(N, 3) float``.
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


def _obj_vertices(lines, where) -> np.ndarray:
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


def _read_obj_points(path: Path) -> np.ndarray:
    with open(path, "r", encoding="utf-8", errors="replace") as f:
        return _obj_vertices(f, path)


def read_points(path: PathLike, return_normals: bool = False):
    """Read a point cloud: an OBJ of ``v x y z`` lines, or a PLY (via trimesh).

    Args:
        path: ``.obj`` or ``.ply`` file.
        return_normals: also return the PLY's ``nx ny nz`` (None when absent or for OBJ).

    Returns:
        ``(N, 3) float32`` tensor, or ``(points, normals)`` with ``return_normals``.

    Raises:
        FileNotFoundError, ValueError: naming the file (and line for OBJ).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    suffix = path.suffix.lower()
    normals = None
    if suffix == ".obj":
        pts = _read_obj_points(path)
    elif suffix == ".ply":
        trimesh = _trimesh()
        try:
            loaded = trimesh.load(str(path), file_type="ply", process=False)
        except Exception as err:
            raise ValueError(f"{path}: cannot read PLY: {err}") from err
        pts = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float32)
        raw = loaded.metadata.get("_ply_raw", {}).get("vertex", {}).get("data") if hasattr(loaded, "metadata") else None
        if raw is not None and raw.dtype.names and {"nx", "ny", "nz"} <= set(raw.dtype.names):
            normals = np.stack([raw["nx"], raw["ny"], raw["nz"]], axis=1).astype(np.float32)
        if pts.shape[0] == 0:
            raise ValueError(f"{path}: the PLY holds no vertex")
    else:
        raise ValueError(f"{path}: unsupported point-cloud format {suffix!r} (expected .obj or .ply)")
    if not np.isfinite(pts).all():
        raise ValueError(f"{path}: contains NaN or infinite coordinates")
    out = torch.from_numpy(np.ascontiguousarray(pts))
    if return_normals:
        return out, None if normals is None else torch.from_numpy(np.ascontiguousarray(normals))
    return out


def write_voxels(path: PathLike, grid) -> Path:
    """Write an occupancy grid ``(X, Y, Z) bool`` (any array or tensor) as ``.npy``."""
    if isinstance(grid, torch.Tensor):
        grid = grid.detach().cpu().numpy()
    arr = np.asarray(grid)
    if arr.ndim != 3:
        raise ValueError(f"{path}: `grid` must be 3-D (X, Y, Z), got shape {arr.shape}")
    return atomic_write(path, lambda f: np.save(f, arr, allow_pickle=False))


def write_png(path: PathLike, image) -> Path:
    """Write an ``(H, W, 3) uint8`` RGB image (or ``(H, W)`` grey) as PNG (OpenCV)."""
    import cv2

    arr = np.asarray(image)
    if arr.dtype != np.uint8 or arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != 3):
        raise ValueError(f"{path}: `image` must be (H, W, 3) or (H, W) uint8, got {arr.shape} {arr.dtype}")
    bgr = arr[..., ::-1] if arr.ndim == 3 else arr
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr))
    if not ok:  # pragma: no cover - OpenCV failure
        raise ValueError(f"{path}: PNG encoding failed")
    data = buf.tobytes()
    return atomic_write(path, lambda f: f.write(data))
