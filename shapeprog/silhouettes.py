"""Front and side silhouettes of the PartNet corpus: a real-shape set of 64x64 binary masks.

Every corpus program is executed in float64 and its leaf cuboids are projected orthographically
in the ShapeAssembly frame: ``front`` is seen from +z, ``side`` from +x; images are
``img[row, col]`` with rows growing downward. Each image is fitted to the canvas and rasterised
exactly (a pixel is on iff its centre lies in a projected cuboid; parts thinner than a pixel are
widened to one). Splits: the corpus's train and val lists, with test carved out of val.
``python -m shapeprog assembly silhouettes --out PATH`` builds the set shipped as
``csgnet/data/silhouettes.npz``; the file layout (a pickle-free ``.npz`` with packed-bit images, ids
and views per split), the views, fit, rasterisation and splits are in ``docs/csgnet.md``
("The PartNet silhouettes").

Example:
    >>> import torch
    >>> from shapeprog.geometry import cuboid_corners
    >>> box = cuboid_corners(torch.zeros(1, 3), torch.tensor([[2.0, 1.0, 1.0]]), torch.eye(3)[None])
    >>> img = silhouette(box, "front", size=16, margin=0)
    >>> int(img.sum()), bool(img[4:12].all())  # 16 x 8 pixels, rows 4..11
    (128, True)
"""
from __future__ import annotations

import warnings

import numpy as np
import torch
from tqdm import tqdm

from shapeio.silhouettes import SPLITS, write_silhouettes
from shapeio.silhouettes import SilhouetteSplit as Silhouettes

from . import corpus
from .execute import execute_batch
from .geometry import numpy_corners
from .lang import ParseError, parse

__all__ = ["MAX_SIZE", "VIEWS", "SPLITS", "Silhouettes", "silhouette", "silhouettes", "split_ids", "build", "write"]

VIEWS = ("front", "side")
SIZE = 64
MARGIN = 4
#: The largest image side (:func:`build` keeps every image: the corpus's 11,922 shapes x 2 views at 256 are 1.6 GB).
MAX_SIZE = 256
_EPS = 1e-9
MIN_WIDTH = 1.0
"""Projections narrower than this (pixels) across some direction are widened to it."""

# per view: (screen-right axis, sign), (screen-up axis, sign) in the ShapeAssembly frame
_VIEW_AXES = {"front": ((0, 1.0), (1, 1.0)), "side": ((2, -1.0), (1, 1.0))}


def _project(c: np.ndarray, view: str) -> np.ndarray:
    """(L, 8, 3) corners -> (L, 8, 2) screen coordinates (right, up)."""
    if view not in _VIEW_AXES:
        raise ValueError(f"unknown view {view!r}; expected one of {VIEWS}")
    (a, sa), (b, sb) = _VIEW_AXES[view]
    return np.stack([sa * c[..., a], sb * c[..., b]], axis=-1)


def _check_frame(size: int, margin: int) -> None:
    if isinstance(size, bool) or not isinstance(size, int) or not 1 <= size <= MAX_SIZE:
        raise ValueError(f"need an int size from 1 to {MAX_SIZE} (MAX_SIZE), got size={size!r}")
    if isinstance(margin, bool) or not isinstance(margin, int) or not 0 <= 2 * margin < size:
        raise ValueError(f"need an int margin with 0 <= margin < size / 2, got size={size}, margin={margin!r}")


def silhouette(corners, view: str, size: int = SIZE, margin: int = MARGIN) -> np.ndarray:
    """The binary silhouette of one shape's cuboids in one view.

    Args:
        corners: (L, 8, 3) float cuboid corners in the order of :mod:`shapeprog.geometry`
            (torch or NumPy), e.g. ``execute(program).corners``.
        view: ``"front"`` or ``"side"``.
        size: image side in pixels.
        margin: free pixels kept on each side along the longer extent.

    Returns:
        (size, size) bool.
    """
    _check_frame(size, margin)
    c = numpy_corners(corners)
    pts = _project(c, view)  # (L, 8, 2)
    lo, hi = pts.reshape(-1, 2).min(axis=0), pts.reshape(-1, 2).max(axis=0)
    extent = float((hi - lo).max())
    scale = (size - 2 * margin) / extent if extent > 0 else 1.0
    mid = (lo + hi) / 2.0
    half = (size - 1) / 2.0
    # screen (right, up) -> pixel (col, row)
    col = half + scale * (pts[..., 0] - mid[0])
    row = half - scale * (pts[..., 1] - mid[1])
    px = np.stack([col, row], axis=-1)  # (L, 8, 2)
    # centre and half-axis generators; corner 0 is (+,+,+), 4 flips x, 2 flips y, 1 flips z
    centre = px.mean(axis=1)  # (L, 2)
    gens = np.stack([(px[:, 0] - px[:, 4]) / 2, (px[:, 0] - px[:, 2]) / 2, (px[:, 0] - px[:, 1]) / 2], axis=1)
    # test directions: the perpendiculars of the generators (the edge normals) plus the generators
    # and the two axes, which bound degenerate (segment or point) projections
    perp = np.stack([-gens[..., 1], gens[..., 0]], axis=-1)
    axes = np.broadcast_to(np.eye(2), (len(c), 2, 2))
    normals = np.concatenate([perp, gens, axes], axis=1)  # (L, 8, 2)
    norm = np.linalg.norm(normals, axis=-1, keepdims=True)
    normals = np.where(norm > 1e-12, normals / np.where(norm > 0, norm, 1.0), 0.0)
    bound = np.abs(np.einsum("lkd,ljd->lkj", normals, gens)).sum(axis=-1)  # (L, 8)
    # thinner than a pixel across some direction: widen to one pixel, centred (stays visible)
    bound = np.maximum(bound, MIN_WIDTH / 2)
    # each cuboid is tested on the pixels of its own bounding box only
    reach = bound[:, 6:8]  # (L, 2) half extents along (col, row): the bounds of the axis normals
    first = np.clip(np.ceil(centre - reach - _EPS), 0, size).astype(int)
    last = np.clip(np.floor(centre + reach + _EPS), -1, size - 1).astype(int)
    out = np.zeros((size, size), bool)
    for part in range(len(c)):
        (c0, r0), (c1, r1) = first[part], last[part]
        if c1 < c0 or r1 < r0:
            continue  # entirely off the canvas
        cols, rows = np.meshgrid(np.arange(c0, c1 + 1, dtype=np.float64), np.arange(r0, r1 + 1, dtype=np.float64))
        d = np.stack([cols - centre[part, 0], rows - centre[part, 1]], axis=-1)  # (h, w, 2)
        inside = (np.abs(d @ normals[part].T) <= bound[part] + _EPS).all(axis=-1)
        out[r0:r1 + 1, c0:c1 + 1] |= inside
    return out


def silhouettes(corners, views=VIEWS, size: int = SIZE, margin: int = MARGIN) -> np.ndarray:
    """Silhouettes of one shape in several views: (V, size, size) bool (see :func:`silhouette`)."""
    return np.stack([silhouette(corners, v, size, margin) for v in views])


def split_ids(category: str) -> dict[str, list[int]]:
    """The shape ids of ``category`` per split: train, val and test (odd positions of val)."""
    val = corpus.ids(category, "val")
    return {"train": corpus.ids(category, "train"), "val": val[0::2], "test": val[1::2]}



def execute_items(items) -> tuple[list, list, list]:
    """Parse and execute corpus programs ``(split, category, id)`` in one batch: ``(kept, shapes, skipped)``,
    ``kept`` the ``(split, "category/id")`` of each executed shape, ``skipped`` a line per program that did not
    parse or is missing."""
    progs, kept, skipped = [], [], []
    for split, cat, i in items:
        name = f"{cat}/{i}"
        try:
            progs.append(parse(corpus.read(cat, i), file=f"{name}.txt"))
            kept.append((split, name))
        except (ParseError, KeyError) as e:
            skipped.append(f"{name}: {e}")
    with torch.no_grad():
        shapes = execute_batch(progs, dtype=torch.float64)
    return kept, shapes, skipped

def build(categories=("chair", "table", "storage"), size: int = SIZE, margin: int = MARGIN,
          limit: int | None = None, batch: int = 200, progress: bool = True) -> dict[str, Silhouettes]:
    """Execute the corpus programs and render their front and side silhouettes.

    Args:
        categories: corpus categories, in output order.
        size, margin: see :func:`silhouette`.
        limit: keep only the first ``limit`` shapes of each category and split (for quick checks).
        batch: programs per :func:`shapeprog.execute_batch` call.
        progress: show a progress bar (tqdm) on stderr.

    Returns:
        ``{"train": Silhouettes, "val": ..., "test": ...}``; within a split, shapes follow the
        category order and then the split file order, each shape's views in :data:`VIEWS` order.
        Programs that fail to parse or execute (none in the shipped corpus) are skipped with a
        warning naming them.

    Raises:
        ValueError: a ``size`` / ``margin`` that :func:`silhouette` rejects, before any program runs.
    """
    _check_frame(size, margin)
    jobs: list[tuple[str, str, int]] = []  # (split, category, id)
    for cat in categories:
        for split, ids in split_ids(cat).items():
            jobs += [(split, cat, i) for i in (ids if limit is None else ids[:limit])]
    out: dict[str, tuple[list, list, list]] = {s: ([], [], []) for s in SPLITS}
    skipped: list[str] = []
    bar = tqdm(total=len(jobs), desc="silhouettes", unit="shape", disable=not progress)
    for k in range(0, len(jobs), batch):
        chunk = jobs[k:k + batch]
        kept, shapes, failed = execute_items(chunk)
        skipped += failed
        for (split, name), shape in zip(kept, shapes):
            try:
                imgs = silhouettes(shape.corners, VIEWS, size, margin)
            except ValueError as e:
                skipped.append(f"{name}: {e}")
                continue
            images, names, views = out[split]
            images.extend(imgs)
            names.extend([name] * len(VIEWS))
            views.extend(VIEWS)
        bar.update(len(chunk))
    bar.close()
    if skipped:
        warnings.warn(f"{len(skipped)} shape(s) skipped: " + "; ".join(skipped), UserWarning, stacklevel=2)
    result = {}
    for split, (images, names, views) in out.items():
        arr = np.stack(images) if images else np.zeros((0, size, size), bool)
        result[split] = Silhouettes(arr, np.array(names, dtype="U32"), np.array(views, dtype="U8"))
    return result


def write(path, data: dict[str, Silhouettes], margin: int = MARGIN) -> None:
    """Write a built set (see :func:`build`) as a compressed ``.npz``, atomically
    (:func:`shapeio.silhouettes.write_silhouettes`; layout in :mod:`shapeio.silhouettes`)."""
    write_silhouettes(path, data, margin)
