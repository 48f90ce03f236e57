"""Triangle meshes: the one writer (OBJ as plain text, PLY and GLB through trimesh) and users' meshes.

* :func:`obj_text` / :func:`write_mesh`: vertices, faces and optional per-vertex or per-face colours.
* :func:`write_parts`: a GLB scene with one coloured node per part.
* :func:`load_mesh` / :func:`read_mesh`: a user's mesh file (OBJ, PLY, STL, OFF, glTF) read with trimesh.

trimesh is imported on first use (it takes most of a second to import).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence, Union

import numpy as np

from .arrays import as_numpy
from .files import InputError, atomic_write

__all__ = ["MESH_SUFFIXES", "WRITE_SUFFIXES", "MAX_MESH_FACES", "obj_text", "write_mesh", "write_parts", "load_mesh", "read_mesh"]

PathLike = Union[str, os.PathLike]

#: File types read as meshes (lower-case suffixes).
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".off", ".ply", ".stl")
#: Most triangles in a mesh read by :func:`load_mesh`.
MAX_MESH_FACES = 5_000_000
#: File types :func:`write_mesh` writes.
WRITE_SUFFIXES = (".obj", ".ply", ".glb")


def _trimesh():
    try:
        # trimesh takes most of a second to import: loaded on first use
        import trimesh
    except ImportError as err:  # pragma: no cover - trimesh is a core dependency
        raise ImportError("mesh files need trimesh: pip install trimesh") from err
    return trimesh


def _vertices_faces(vertices, faces, where) -> tuple[np.ndarray, np.ndarray]:
    """Checked ``(V, 3) float64`` vertices and ``(F, 3) int64`` faces; errors name ``where``."""
    v, f = as_numpy(vertices), as_numpy(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.issubdtype(v.dtype, np.number):
        raise ValueError(f"{where}: `vertices` must be (V, 3) numbers, got {v.shape} {v.dtype}")
    if not np.isfinite(v).all():
        raise ValueError(f"{where}: `vertices` contains NaN or infinite values")
    if f.size == 0:
        f = f.reshape(0, 3)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise ValueError(f"{where}: `faces` must be (F, 3) integers, got {f.shape} {f.dtype}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise ValueError(f"{where}: `faces` index vertices 0..{len(v) - 1}, got {int(f.min())}..{int(f.max())}")
    return v.astype(np.float64), f.astype(np.int64)


def _rgba(colors, n: int, what: str, where) -> np.ndarray | None:
    """``(n, 3|4)`` uint8 or ``[0, 1]`` float colours as ``(n, 4) uint8`` (alpha 255 when absent)."""
    if colors is None:
        return None
    c = as_numpy(colors)
    if c.ndim != 2 or c.shape != (n, c.shape[1]) or c.shape[1] not in (3, 4):
        raise ValueError(f"{where}: `{what}` must be ({n}, 3) or ({n}, 4), got {c.shape}")
    if np.issubdtype(c.dtype, np.floating):
        if not (np.isfinite(c).all() and c.min() >= 0.0 and c.max() <= 1.0):
            raise ValueError(f"{where}: float `{what}` must hold values in [0, 1]")
        c = np.rint(c * 255.0)
    elif c.dtype != np.uint8:
        raise ValueError(f"{where}: `{what}` must be uint8 or float, got dtype {c.dtype}")
    c = c.astype(np.uint8)
    return c if c.shape[1] == 4 else np.concatenate([c, np.full((n, 1), 255, np.uint8)], axis=1)


def obj_text(vertices, faces, vertex_colors=None, comment: str | None = None, digits: int | None = None,
             groups: Sequence[tuple[str, int]] | None = None) -> str:
    """Wavefront OBJ text: ``v x y z [r g b]`` lines, then ``f a b c`` lines (1-based), LF line ends.

    Args:
        vertices: ``(V, 3) float``.
        faces: ``(F, 3) int``, 0-based.
        vertex_colors: optional ``(V, 3|4)`` uint8 or ``[0, 1]`` float; written as RGB in ``[0, 1]``.
        comment: optional first line, written after ``# ``.
        digits: significant digits of the coordinates (``{x:.6g}`` for 6); None writes Python's
            shortest repr of each value as a double (exact).
        groups: optional ``(name, face count)`` runs covering the faces in order: a ``g name`` line is
            written before each run's faces, so that a viewer can select each part. Names are single words.

    Returns:
        The file's text.
    """
    v, f = _vertices_faces(vertices, faces, "<obj>")
    if groups is not None:
        groups = [(str(name), int(n)) for name, n in groups]
        if sum(n for _, n in groups) != len(f) or any(n < 0 for _, n in groups):
            raise ValueError(f"<obj>: the groups cover {sum(n for _, n in groups)} faces, the mesh has {len(f)}")
        bad = [name for name, _ in groups if not name or any(c.isspace() for c in name)]
        if bad:
            raise ValueError(f"<obj>: a group name must be one word without spaces, got {bad[0]!r}")
    rgba = _rgba(vertex_colors, len(v), "vertex_colors", "<obj>")

    def num(x) -> str:
        return str(float(x)) if digits is None else f"{x:.{digits}g}"

    lines = [] if comment is None else [f"# {comment}\n"]
    if rgba is None:
        lines += [f"v {num(x)} {num(y)} {num(z)}\n" for x, y, z in v]
    else:
        lines += [f"v {num(x)} {num(y)} {num(z)} {r / 255:.6g} {g / 255:.6g} {b / 255:.6g}\n"
                  for (x, y, z), (r, g, b, _) in zip(v, rgba.tolist())]
    faces_text = [f"f {a} {b} {c}\n" for a, b, c in (f + 1).tolist()]
    if groups is None:
        lines += faces_text
    else:
        k = 0
        for name, n in groups:
            lines.append(f"g {name}\n")
            lines += faces_text[k:k + n]
            k += n
    return "".join(lines)


def write_mesh(path: PathLike, vertices, faces, face_colors=None, vertex_colors=None, comment: str | None = None,
               digits: int | None = None, file_type: str | None = None,
               groups: Sequence[tuple[str, int]] | None = None) -> Path:
    """Write a triangle mesh, atomically; the format follows the suffix (or ``file_type``).

    * ``obj``: :func:`obj_text` (per-vertex colours only; ``comment`` and ``digits`` apply).
    * ``ply``: binary PLY through trimesh, vertices and faces in the given order (no merging).
    * ``glb``: binary glTF through trimesh; colours become the mesh's vertex colours.

    Args:
        path: the output file.
        vertices: ``(V, 3) float`` (NumPy or torch).
        faces: ``(F, 3) int``, 0-based.
        face_colors: optional ``(F, 3|4)`` uint8 or ``[0, 1]`` float (PLY, GLB).
        vertex_colors: optional ``(V, 3|4)`` uint8 or ``[0, 1]`` float.
        comment, digits, groups: OBJ only, see :func:`obj_text`.
        file_type: ``"obj"``, ``"ply"`` or ``"glb"`` (default: the suffix of ``path``).

    Returns:
        The path written.

    Raises:
        ValueError: naming ``path``: an unknown format, bad arrays, face colours for OBJ.
    """
    kind = (file_type or Path(path).suffix[1:]).lower()
    if f".{kind}" not in WRITE_SUFFIXES:
        raise ValueError(f"{path}: unknown mesh format {kind!r} (use {', '.join(WRITE_SUFFIXES)})")
    v, f = _vertices_faces(vertices, faces, path)
    fc = _rgba(face_colors, len(f), "face_colors", path)
    vc = _rgba(vertex_colors, len(v), "vertex_colors", path)
    if kind == "obj":
        if fc is not None:
            raise ValueError(f"{path}: OBJ files hold no per-face colours; write .ply or .glb")
        text = obj_text(v, f, vc, comment, digits, groups)
        return atomic_write(path, text.encode("ascii"))
    mesh = _trimesh().Trimesh(vertices=v, faces=f, face_colors=fc, vertex_colors=vc, process=False)
    data = mesh.export(file_type=kind)
    return atomic_write(path, data)


def write_parts(path: PathLike, parts: Sequence[tuple], names: Sequence[str] | None = None) -> Path:
    """Write a binary glTF (GLB) scene with one node per part, each with a flat material colour.

    Args:
        path: the output file.
        parts: ``(vertices (V, 3) float, faces (F, 3) int, rgb (3,) or rgba (4,) uint8)`` per part.
        names: node and geometry names (default ``part_0``, ``part_1``, ...).

    Returns:
        The path written.
    """
    trimesh = _trimesh()
    names = [f"part_{k}" for k in range(len(parts))] if names is None else list(names)
    if len(names) != len(parts):
        raise ValueError(f"{path}: {len(names)} names for {len(parts)} parts")
    scene = trimesh.Scene()
    for (vertices, faces, color), name in zip(parts, names):
        v, f = _vertices_faces(vertices, faces, f"{path} ({name})")
        rgba = _rgba(np.reshape(as_numpy(color), (1, -1)), 1, "color", f"{path} ({name})")[0]
        mesh = trimesh.Trimesh(vertices=v, faces=f, process=False)
        mesh.visual = trimesh.visual.TextureVisuals(
            material=trimesh.visual.material.PBRMaterial(baseColorFactor=rgba, metallicFactor=0.0, roughnessFactor=0.8)
        )
        scene.add_geometry(mesh, node_name=name, geom_name=name)
    data = scene.export(file_type="glb")
    return atomic_write(path, data)


def load_mesh(path: PathLike):
    """A user's mesh file as one ``trimesh.Trimesh`` (scenes are concatenated).

    Raises:
        FileNotFoundError: no such file.
        InputError: unreadable, no triangles, more than :data:`MAX_MESH_FACES` triangles, or a NaN or
            infinite vertex coordinate (the message names the file).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    trimesh = _trimesh()
    try:
        # unprocessed, so that faces on non-finite vertices are seen here instead of silently dropped
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for bad files
        raise InputError(f"{path}: cannot read the mesh ({type(e).__name__}: {e})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(f"{path}: the file holds no triangles")
    vshape = np.shape(mesh.vertices)
    if len(vshape) != 2 or vshape[1] != 3:  # e.g. OBJ 'v' lines with two numbers
        raise InputError(f"{path}: the vertices are not 3D points (array of shape {vshape})")
    if len(mesh.faces) > MAX_MESH_FACES:
        raise InputError(f"{path}: the mesh has {len(mesh.faces)} triangles; at most "
                         f"MAX_MESH_FACES = {MAX_MESH_FACES} are read")
    bad = ~np.isfinite(np.asarray(mesh.vertices)).all(axis=1)
    if bad.any():
        raise InputError(f"{path}: vertex {int(np.argmax(bad)) + 1} has a NaN or infinite coordinate")
    try:
        with np.errstate(invalid="ignore", over="ignore"):  # coordinates near the float64 limit: merging casts
            mesh.process()
    except Exception as e:
        raise InputError(f"{path}: cannot read the mesh ({type(e).__name__}: {e})") from None
    return mesh


def read_mesh(path: PathLike) -> tuple[np.ndarray, np.ndarray]:
    """A user's mesh file as arrays (:func:`load_mesh`).

    Returns:
        ``vertices: (V, 3) float64`` and ``faces: (F, 3) int64`` (0-based).
    """
    mesh = load_mesh(path)
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)
