"""Export CSG results: canvases to PNG, voxel volumes to OBJ meshes, programs to OpenSCAD source.

Entry points: :func:`save_png`, :func:`voxels_to_mesh` and :func:`save_obj`, :func:`to_scad` and
:func:`save_scad`. In every exported geometry pixel and voxel centres sit at integer coordinates; a 2D
OpenSCAD model is mirrored so that the CAD view looks like the PNG, and every model is intersected with
the canvas. Files are written atomically (a temporary file in the target directory, then ``os.replace``).

See docs/csgnet.md ("The renderer", "Export") for the coordinates and the OpenSCAD form of each primitive.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw
from skimage.measure import marching_cubes

from shapeio import atomic_write
from shapeio.image import write_png
from shapeio.mesh import write_mesh

from . import primitives as P
from .primitives import SIZE
from .lang import Draw, Program, parse

__all__ = ["save_png", "voxels_to_mesh", "save_obj", "to_scad", "save_scad", "depth_view", "contact_sheet", "save_sheet",
           "LABEL_BAND"]


def _to_numpy_bool(a, name: str, shape: tuple[int, ...]) -> np.ndarray:
    if type(a).__module__.startswith("torch"):
        a = a.detach().cpu().numpy()
    a = np.asarray(a)
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a.astype(bool)


# ---------------------------------------------------------------------------------------------
# PNG

def save_png(canvas, path, scale: int = 4) -> Path:
    """Save a canvas as a black-on-white PNG, upscaled by nearest neighbour.

    Args:
        canvas: (64, 64) bool (NumPy or torch); True pixels are drawn black.
        path: the output file.
        scale: the integer upscaling factor (each pixel becomes ``scale x scale``).

    Returns:
        The path written.
    """
    img = _to_numpy_bool(canvas, "canvas", (SIZE, SIZE))
    return write_png(path, ~img, scale=scale)  # False (background) is white


# ---------------------------------------------------------------------------------------------
# meshes

def voxels_to_mesh(vol) -> tuple[np.ndarray, np.ndarray]:
    """A closed triangle mesh of a voxel volume (marching cubes at level 0.5).

    The volume is zero-padded by one voxel on every side first, so shapes touching the border get
    closed surfaces. Vertex coordinates are in voxel units in the ``vol[x, y, z]`` frame (voxel centres
    at integer coordinates); faces are oriented outward.

    Args:
        vol: (64, 64, 64) bool (NumPy or torch).

    Returns:
        vertices (V, 3) float64 and faces (F, 3) int64. An empty volume gives empty arrays.
    """
    v = _to_numpy_bool(vol, "vol", (SIZE, SIZE, SIZE))
    if not v.any():
        return np.zeros((0, 3), np.float64), np.zeros((0, 3), np.int64)
    padded = np.pad(v.astype(np.float32), 1)
    verts, faces, _, _ = marching_cubes(padded, level=0.5)
    verts = verts.astype(np.float64) - 1.0
    faces = faces.astype(np.int64)
    # orient outward: the signed volume of a closed, outward-oriented mesh is positive
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    if np.einsum("ij,ij->i", a, np.cross(b, c)).sum() < 0:
        faces = faces[:, ::-1].copy()
    return verts, faces


def _check_transform(transform) -> np.ndarray:
    t = np.asarray(transform, dtype=np.float64)
    if t.shape != (4, 4) or not np.isfinite(t).all() or abs(np.linalg.det(t[:3, :3])) < 1e-300:
        raise ValueError(f"transform must be an invertible, finite 4x4 affine matrix, got shape {t.shape}")
    return t


def save_obj(vol, path, transform=None) -> Path:
    """Save the marching-cubes mesh of a (64, 64, 64) bool volume as a Wavefront OBJ file.

    ``transform``: a 4x4 affine from voxel coordinates to the frame to write in (e.g. the input mesh's
    units, :func:`csgnet.inference.load_shape_framed`); default: voxel units. The first line is a comment
    naming the frame; coordinates are written with 6 significant digits.
    """
    verts, faces = voxels_to_mesh(vol)
    frame = "vertices in voxel units, vol[x, y, z] frame, voxel centres at integers"
    if transform is not None:
        t = _check_transform(transform)
        verts = verts @ t[:3, :3].T + t[:3, 3]
        frame = "vertices in the input's units (the voxel frame mapped back by the input's transform)"
    return write_mesh(path, verts, faces, file_type="obj", digits=6, comment="csgnet voxel mesh: " + frame)


# ---------------------------------------------------------------------------------------------
# OpenSCAD

def _scad_draw(d: Draw, fn: int) -> str:
    return P.primitive(d.kind).scad(d.params, fn, d.text())


_SCAD_OPS = {"+": "union", "*": "intersection", "-": "difference"}


def _scad_tree(node, fn: int, indent: str) -> list[str]:
    if isinstance(node, Draw):
        return [indent + _scad_draw(node, fn)]
    inner = indent + "    "
    return ([f"{indent}{_SCAD_OPS[node.op]}() {{"] + _scad_tree(node.left, fn, inner)
            + _scad_tree(node.right, fn, inner) + [f"{indent}}}"])


def to_scad(program, dim: int | None = None, fn: int = 128, transform=None) -> str:
    """OpenSCAD source that reproduces a program (see the module docstring for the conventions).

    Args:
        program: a :class:`~csgnet.lang.Program` or program text (then ``dim`` says 2 or 3, default 2).
        dim: the dimension of a text program.
        fn: ``$fn`` for circles, spheres and cylinders.
        transform: 3D only: a 4x4 affine from voxel coordinates to the frame to model in (e.g. the input
            mesh's units); the model is wrapped in ``multmatrix``.

    Returns:
        The ``.scad`` text.

    Raises:
        ValueError: for an invalid program (stack underflow or shapes left over).
    """
    if isinstance(program, str):
        program = parse(program, dim or 2)
    if not isinstance(program, Program):
        raise TypeError(f"program must be a Program or program text, got {type(program).__name__}")
    tree = program.tree()
    head = [f"// CSG program: {program.text()}",
            "// Generated by csgnet.export.to_scad. Pixel/voxel centres are at integer coordinates;",
            "// the canvas spans [-0.5, 63.5] on every axis."]
    if program.dim == 2:
        head += ["// 2D: x = image column, y = image row. Image rows grow downward, so the model is",
                 "// mirrored in y to look like the PNG (triangle apex up)."]
        body = _scad_tree(tree, fn, "        ")
        lines = head + ["mirror([0, 1, 0]) {", "    intersection() {"] + body + [
            "        translate([-0.5, -0.5]) square([64, 64]);  // the canvas (the renderer clips)",
            "    }", "}"]
    else:
        head += ["// 3D: x, y, z = volume axes 0, 1, 2 (vol[x, y, z]); cylinders stand along z."]
        body = _scad_tree(tree, fn, "    ")
        lines = ["intersection() {"] + body + [
            "    translate([-0.5, -0.5, -0.5]) cube([64, 64, 64]);  // the canvas (the renderer clips)",
            "}"]
        if transform is not None:
            t = _check_transform(transform)
            rows = ", ".join("[" + ", ".join(f"{v:.9g}" for v in row) + "]" for row in t)
            head += ["// multmatrix: voxel coordinates to the input's units"]
            lines = [f"multmatrix([{rows}]) {{"] + ["    " + line for line in lines] + ["}"]
        lines = head + lines
    if program.dim == 2 and transform is not None:
        raise ValueError("transform applies to 3D programs only")
    return "\n".join(lines) + "\n"


def save_scad(program, path, dim: int | None = None, fn: int = 128, transform=None) -> Path:
    """Write :func:`to_scad` of ``program`` to ``path`` (atomically)."""
    return atomic_write(path, to_scad(program, dim, fn, transform).encode())


# ---------------------------------------------------------------------------------------------
# pictures: depth views of volumes and contact sheets

def depth_view(vol, axis: int) -> np.ndarray:
    """A grey picture ``(64, 64) uint8`` of a voxel volume seen along ``axis`` (from index 0 on): each
    pixel's first occupied voxel, near dark and far light; white where the ray meets nothing."""
    vol = np.asarray(vol, dtype=bool)
    hit = vol.any(axis=axis)
    depth = np.argmax(vol, axis=axis).astype(np.float64) / max(vol.shape[axis] - 1, 1)
    return np.where(hit, np.round(30 + 170 * depth), 255).astype(np.uint8)

def contact_sheet(images, cols: int = 6):
    """Images side by side in grey frames: bool images are drawn black on white, uint8 ones as grey levels."""
    h, w = images[0].shape
    rows = -(-len(images) // cols)
    sheet = np.full((rows * (h + 2), cols * (w + 2)), 128, np.uint8)  # grey frames
    for i, img in enumerate(images):
        r, c = divmod(i, cols)
        img = np.asarray(img)
        grey = img if img.dtype == np.uint8 else np.where(img, 0, 255)
        sheet[r * (h + 2) + 1: r * (h + 2) + 1 + h, c * (w + 2) + 1: c * (w + 2) + 1 + w] = grey
    return sheet

LABEL_BAND = 14
"""Height (top) of the band that :func:`save_sheet` writes column labels in, and the left band's width per
character of the longest row label is ``LABEL_BAND // 2``."""


def save_sheet(sheet, path, scale: int = 3, columns=(), rows=()) -> Path:
    """Write a :func:`contact_sheet` as a PNG, each pixel ``scale`` times (atomically), with ``columns``
    labels in a band above the columns and ``rows`` labels in a band left of the rows (black on white, the
    default bitmap font; no band without labels). The sheet itself starts at ``(LABEL_BAND, left band)``."""
    big = np.kron(np.asarray(sheet, dtype=np.uint8), np.ones((scale, scale), np.uint8))
    top = LABEL_BAND if columns else 0
    left = (LABEL_BAND // 2) * (max(map(len, rows)) + 1) if rows else 0
    canvas = Image.new("L", (big.shape[1] + left, big.shape[0] + top), 255)
    canvas.paste(Image.fromarray(big), (left, top))
    draw = ImageDraw.Draw(canvas)
    for i, text in enumerate(columns):
        width = big.shape[1] / max(len(columns), 1)
        draw.text((left + i * width + 4, 1), str(text), fill=0)
    for i, text in enumerate(rows):
        height = big.shape[0] / max(len(rows), 1)
        draw.text((2, top + i * height + height / 2 - 5), str(text), fill=0)
    return write_png(path, np.asarray(canvas), mkdir=True)
