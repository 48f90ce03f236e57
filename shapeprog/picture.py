"""Pictures of cuboid shapes: shaded parts from a fixed three-quarter view, in NumPy and OpenCV.

:func:`render_png` draws ``corners: (L, 8, 3)`` (y-up world, spec corner order) with an
orthographic camera looking from the front-right-top, a small z-buffer rasteriser (2x supersampled
then area-downsampled), Lambert shading with a fixed light, one colour per part label, a white
background and thin dark edges wherever the visible face changes. No matplotlib, no GPU.
"""
from __future__ import annotations

import os
from typing import Optional, Union

import cv2
import numpy as np
import torch

from shapeio.image import write_png
from shapeprog.geometry import mesh_arrays
from shapeprog.geometry import check_corners

__all__ = ["MAX_GRID_PIXELS", "MAX_SIZE", "check_grid", "render_png", "render_grid", "part_colors", "camera", "PALETTE", "VIEW_DIRECTION", "LIGHT_DIRECTION"]

#: Part palette (RGB uint8): colours are assigned by label rank, cycling.
PALETTE = np.array(
    [
        [31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
        [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207],
        [174, 199, 232], [255, 187, 120], [152, 223, 138], [255, 152, 150], [197, 176, 213],
        [196, 156, 148], [247, 182, 210], [199, 199, 199], [219, 219, 141], [158, 218, 229],
    ],
    dtype=np.uint8,
)

#: Unit vector from the scene towards the camera (front = +z, right = +x, up = +y).
VIEW_DIRECTION = np.array([0.9, 0.75, 1.5]) / np.linalg.norm([0.9, 0.75, 1.5])
#: Unit vector towards the light.
LIGHT_DIRECTION = np.array([0.4, 1.0, 0.7]) / np.linalg.norm([0.4, 1.0, 0.7])

_AMBIENT = 0.38
_EDGE_RGB = np.array([45, 45, 45], dtype=np.float64)
_SUPERSAMPLE = 2
#: The largest picture side in pixels (a render holds about 40 bytes per supersampled pixel: 0.7 GB at 2048).
MAX_SIZE = 2048
#: The most pixels of a :func:`render_grid` sheet (3 bytes each: 200 MB).
MAX_GRID_PIXELS = 1 << 26


def check_size(size) -> int:
    """``size`` when it is an int from 8 to :data:`MAX_SIZE`; otherwise ValueError."""
    if isinstance(size, bool) or not isinstance(size, int) or not 8 <= size <= MAX_SIZE:
        raise ValueError(f"`size` must be an int from 8 to {MAX_SIZE} (MAX_SIZE), got {size!r}")
    return size


def check_grid(count: int, cols: int, size: int) -> None:
    """Refuse (ValueError) a :func:`render_grid` of ``count`` shapes, ``cols`` per row, ``size`` pixels per cell
    whose sheet would exceed :data:`MAX_GRID_PIXELS` (or a bad ``size`` or ``cols``); callers check before
    their work."""
    check_size(size)
    if isinstance(cols, bool) or not isinstance(cols, int) or cols < 1:
        raise ValueError(f"`cols` must be an int >= 1, got {cols!r}")
    cols = min(cols, max(count, 1))
    pixels = -(-count // cols) * cols * size * size
    if pixels > MAX_GRID_PIXELS:
        raise ValueError(f"a grid of {count} pictures of {size} pixels has {pixels} pixels; at most {MAX_GRID_PIXELS} "
                         "(MAX_GRID_PIXELS): use fewer shapes or a smaller size")


def part_colors(n: int, labels=None) -> np.ndarray:
    """RGB colours ``(n, 3) uint8`` of ``n`` parts: by ``labels`` (e.g. program line) or by index.

    Equal labels share a colour; distinct labels get palette entries in sorted label order.
    """
    if labels is None:
        keys = np.arange(n)
    else:
        keys = np.asarray(labels.detach().cpu() if isinstance(labels, torch.Tensor) else labels).reshape(-1)
        if keys.shape[0] != n:
            raise ValueError(f"`labels` must have one entry per part ({n}), got {keys.shape[0]}")
        _, keys = np.unique(keys, return_inverse=True)
    return PALETTE[np.asarray(keys).reshape(-1) % len(PALETTE)]


def camera() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The picture's view frame: unit ``(right, up, back)`` vectors, ``back`` = :data:`VIEW_DIRECTION`
    (screen x = right, screen y = up)."""
    back = VIEW_DIRECTION
    right = np.cross(np.array([0.0, 1.0, 0.0]), back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    return right, up, back


def _rasterize(tri_xy: np.ndarray, tri_z: np.ndarray, size: int):
    """Z-buffer: for each pixel the index of the nearest triangle (-1 for background).

    tri_xy: (T, 3, 2) pixel coordinates (x right, y down); tri_z: (T, 3) depth, larger = nearer.
    """
    zbuf = np.full((size, size), -np.inf)
    ids = np.full((size, size), -1, dtype=np.int64)
    for t in range(tri_xy.shape[0]):
        (x0, y0), (x1, y1), (x2, y2) = tri_xy[t]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        xmin = max(int(np.floor(min(x0, x1, x2))), 0)
        xmax = min(int(np.ceil(max(x0, x1, x2))), size - 1)
        ymin = max(int(np.floor(min(y0, y1, y2))), 0)
        ymax = min(int(np.ceil(max(y0, y1, y2))), size - 1)
        if xmin > xmax or ymin > ymax:
            continue
        px = np.arange(xmin, xmax + 1) + 0.5
        py = (np.arange(ymin, ymax + 1) + 0.5)[:, None]
        w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) / area
        w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) / area
        w2 = 1.0 - w0 - w1
        inside = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9)
        if not inside.any():
            continue
        z = w0 * tri_z[t, 0] + w1 * tri_z[t, 1] + w2 * tri_z[t, 2]
        zb = zbuf[ymin : ymax + 1, xmin : xmax + 1]
        win = inside & (z > zb)
        zb[win] = z[win]
        ids[ymin : ymax + 1, xmin : xmax + 1][win] = t
    return ids


def render_png(
    corners,
    path: Optional[Union[str, os.PathLike]] = None,
    labels=None,
    size: int = 512,
) -> np.ndarray:
    """Render cuboids as a shaded picture, optionally writing it as PNG.

    Args:
        corners: ``(L, 8, 3) float`` tensor or array, y-up, spec corner order.
        path: optional ``.png`` file to write (atomically).
        labels: optional ``(L,)`` per-part labels (e.g. the program line that created each leaf);
            parts with equal labels share a colour. Default: one colour per part.
        size: image width and height in pixels.

    Returns:
        ``(size, size, 3) uint8`` RGB image.
    """
    if isinstance(corners, torch.Tensor):
        corners = corners.detach().cpu().numpy()
    corners = check_corners(np.array(corners, dtype=np.float64), arrays=True)  # a copy: torch.from_numpy below
    check_size(size)

    n = corners.shape[0]
    colors = part_colors(n, labels).astype(np.float64)
    big = size * _SUPERSAMPLE
    image = np.full((big, big, 3), 255.0)
    if n > 0:
        right, up, back = camera()
        pts, faces = (t.numpy() for t in mesh_arrays(torch.from_numpy(corners)))  # (8 L, 3), (12 L, 3)
        sx, sy, depth = pts @ right, pts @ up, pts @ back
        extent = max(sx.max() - sx.min(), sy.max() - sy.min(), 1e-9)
        scale = big * 0.88 / extent
        cx, cy = (sx.max() + sx.min()) / 2, (sy.max() + sy.min()) / 2
        px = (sx - cx) * scale + big / 2
        py = big / 2 - (sy - cy) * scale
        tri_xy = np.stack([px[faces], py[faces]], axis=-1)
        tri_z = depth[faces]
        ids = _rasterize(tri_xy, tri_z, big)

        v = pts[faces]
        normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
        normal *= np.where(normal @ back < 0, -1.0, 1.0)[:, None]  # two-sided: face the camera
        shade = _AMBIENT + (1 - _AMBIENT) * np.clip(normal @ LIGHT_DIRECTION, 0.0, 1.0)
        tri_rgb = colors[np.arange(faces.shape[0]) // 12] * shade[:, None]

        hit = ids >= 0
        image[hit] = tri_rgb[ids[hit]]
        # edges: a pixel whose visible face (part, side) differs from a neighbour's
        face_id = np.where(hit, ids // 2, -1)
        edge = np.zeros_like(hit)
        edge[:, :-1] |= face_id[:, :-1] != face_id[:, 1:]
        edge[:-1, :] |= face_id[:-1, :] != face_id[1:, :]
        edge = cv2.dilate(edge.astype(np.uint8), np.ones((2, 2), np.uint8)).astype(bool)
        image[edge] = _EDGE_RGB
    image = cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)
    image = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    if path is not None:
        write_png(path, image)
    return image


def render_grid(
    shapes,
    path: Optional[Union[str, os.PathLike]] = None,
    cols: int = 4,
    size: int = 192,
) -> np.ndarray:
    """Render several shapes side by side, row by row, as one picture (a sample sheet).

    Args:
        shapes: a sequence of ``corners`` ``(L, 8, 3)`` or ``(corners, labels)`` pairs, as
            :func:`render_png` takes them; an empty shape leaves a white cell.
        path: optional ``.png`` file to write (atomically).
        cols: cells per row (the last row is padded with white).
        size: each cell's width and height in pixels.

    Returns:
        ``(rows * size, cols * size, 3) uint8`` RGB image.
    """
    shapes = list(shapes)
    if not shapes:
        raise ValueError("render_grid needs at least one shape")
    check_grid(len(shapes), cols, size)
    cols = min(cols, len(shapes))
    rows = -(-len(shapes) // cols)
    sheet = np.full((rows * size, cols * size, 3), 255, dtype=np.uint8)
    for i, shape in enumerate(shapes):
        corners, labels = shape if isinstance(shape, tuple) else (shape, None)
        r, c = divmod(i, cols)
        sheet[r * size:(r + 1) * size, c * size:(c + 1) * size] = render_png(corners, labels=labels, size=size)
    if path is not None:
        write_png(path, sheet)
    return sheet
