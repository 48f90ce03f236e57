"""Test conditions for point cloud -> program: the cloud a shape gives under harder, more realistic inputs.

The clouds of the tables are sampled from the ground-truth program's own cuboids, the decoder's output space.
:func:`condition_cloud` turns a shape, its cuboids ``corners: (L, 8, 3)`` in the canonical frame (bounding-box
diagonal 2, y up), into a test cloud under a named condition (:data:`CONDITIONS`), deterministic given a seed:

* ``clean``: ``n_points`` points uniform by area on the cuboids' surfaces (overlapping parts sampled too, as
  the training clouds are);
* ``noise-0.01``, ``noise-0.02``: the clean cloud plus Gaussian noise whose sigma is that fraction of the
  shape's bounding-box diagonal (:data:`NOISE_LEVELS`);
* ``uneven``: the clean cloud thinned along a random direction ``d``: a point at relative position ``t`` in
  [0, 1] along ``d`` across the shape is kept with probability ``UNEVEN_RATIO ** -t``, so the density falls by
  the factor :data:`UNEVEN_RATIO` from one side of the shape to the other (:func:`uneven_keep`);
* ``partial``: what one depth camera sees: a camera :data:`CAMERA_DISTANCE` bounding-box diagonals from the
  shape's centre, at a random azimuth and an elevation in :data:`ELEVATION_RANGE` degrees, looking at the
  centre; a surface point is kept when it faces the camera (back faces removed) and the segment from the
  camera to it crosses no triangle of the shape before it (hidden surfaces removed; :func:`visible_from`).
  Parts inside other parts are hidden by them;
* ``rounded``: every cuboid replaced by a rounded box of the same extent and orientation (the convex hull of
  spheres of radius ``ROUND_RADIUS`` x the cuboid's smallest half extent at the corners of the shrunken box;
  :func:`rounded_box`), the union of these meshes sampled by area;
* ``merged``: the outer surface of the union of the parts: the clean samples that lie inside another part or
  on a face where two parts touch are dropped (a point is kept when the point :data:`MERGE_PROBE` outside it
  along its face's outward normal lies in no part; :func:`outer_surface_keep`).

The conditions that drop points (``uneven``, ``partial``, ``merged``) return the kept subset of ``n_points``
samples, so they have fewer points. Meshes are sampled by :func:`shapeio.points.sample_mesh`, the sampler of
mesh files. ``bench/pointcloud_robust.py --conditions ...`` measures point cloud -> program under each.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np
import torch

from shapeio.points import sample_mesh

from .. import corpus
from ..execute import execute
from ..geometry import CORNER_SIGNS, CUBOID_TRIANGLES, check_corners
from ..lang import parse
from ..sampling import inside_cuboids
from .data import CLOUD_POINTS, corpus_cloud
from .normalize import normalize

__all__ = ["CAMERA_DISTANCE", "CONDITIONS", "CONDITION_POINTS", "ELEVATION_RANGE", "MERGE_PROBE", "NOISE_LEVELS",
           "ROUND_RADIUS", "ROUND_SUBDIVISIONS", "UNEVEN_RATIO", "VISIBILITY_TOLERANCE", "canonical_shape",
           "check_condition", "condition_cloud", "outer_surface_keep", "rounded_box", "uneven_keep", "visible_from"]

#: Gaussian noise of the ``noise-*`` conditions: sigma as a fraction of the bounding-box diagonal.
NOISE_LEVELS = {"noise-0.01": 0.01, "noise-0.02": 0.02}
#: The condition names, in the tables' order.
CONDITIONS = ("clean", *NOISE_LEVELS, "uneven", "partial", "rounded", "merged")
#: Surface samples drawn per cloud (the conditions that drop points keep a subset of them).
CONDITION_POINTS = 5_000
#: ``uneven``: the density at one end of the random direction over that at the other end.
UNEVEN_RATIO = 10.0
#: ``partial``: the camera's distance from the shape's centre, in bounding-box diagonals.
CAMERA_DISTANCE = 2.0
#: ``partial``: the camera's elevation above the horizontal plane, degrees (drawn uniformly in between).
ELEVATION_RANGE = (10.0, 50.0)
#: ``partial``: a triangle hides a point when the segment from the camera crosses it more than this distance
#: (canonical units) before the point; faces flush with the point's own face do not hide it.
VISIBILITY_TOLERANCE = 1e-7
#: ``rounded``: the corner spheres' radius, as a fraction of each cuboid's smallest half extent.
ROUND_RADIUS = 0.5
#: ``rounded``: subdivisions of the icosphere whose vertices make each corner sphere (2: 162 vertices).
ROUND_SUBDIVISIONS = 2
#: ``merged``: the outward step (canonical units) of the probe that decides whether a point is on the outer surface.
MERGE_PROBE = 1e-4
#: Largest number of ray-triangle pairs :func:`visible_from` tests at once (memory).
_RAY_CHUNK = 1 << 19


def check_condition(name: str) -> str:
    """``name`` if it is one of :data:`CONDITIONS`; a ValueError naming it and the allowed names otherwise."""
    if name not in CONDITIONS:
        raise ValueError(f"unknown test condition {name!r}; the conditions are {', '.join(CONDITIONS)}")
    return name


def _trimesh():
    import trimesh  # imported on first use: it takes most of a second

    return trimesh


def _corners(corners) -> np.ndarray:
    check_corners(corners, arrays=True)
    if len(corners) == 0:
        raise ValueError("`corners` holds no cuboid (L = 0): there is no surface to sample")
    if isinstance(corners, torch.Tensor):
        return corners.detach().cpu().double().numpy()
    return np.asarray(corners, dtype=np.float64)


def _frames(corners: np.ndarray):
    """Centres ``(L, 3)``, unit axes ``(L, 3, 3)`` (rows) and half extents ``(L, 3)`` of cuboids ``(L, 8, 3)``."""
    o = corners[:, 7]  # signs (-, -, -); corners 3, 5, 6 are one step along x, y, z
    edges = np.stack([corners[:, 3] - o, corners[:, 5] - o, corners[:, 6] - o], axis=1)
    length = np.linalg.norm(edges, axis=-1)
    axes = edges / np.maximum(length, 1e-300)[..., None]
    return corners.mean(axis=1), axes, length / 2


def _cuboid_mesh(corners: np.ndarray):
    """Vertices ``(8 L, 3)`` and faces ``(12 L, 3)`` of cuboids, each face wound outward."""
    faces = CUBOID_TRIANGLES.numpy()[None] + 8 * np.arange(len(corners))[:, None, None]
    tri = corners[:, CUBOID_TRIANGLES.numpy()]  # (L, 12, 3, 3)
    normal = np.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :])
    inward = (normal * (tri.mean(axis=2) - corners.mean(axis=1)[:, None])).sum(-1) < 0  # a mirrored cuboid
    faces = np.where(inward[..., None], faces[..., ::-1], faces)
    return corners.reshape(-1, 3), faces.reshape(-1, 3)


def _mesh(vertices: np.ndarray, faces: np.ndarray):
    return _trimesh().Trimesh(vertices=vertices, faces=faces, process=False)


def _normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-300)


def rounded_box(center, axes, half, radius: float, subdivisions: int = ROUND_SUBDIVISIONS):
    """A rounded box: the convex hull of spheres of ``radius`` centred on the corners of the box shrunk by
    ``radius`` on every side, so that it spans exactly the box ``center +- half`` along ``axes``.

    Args:
        center: ``(3,)`` float, the box's centre.
        axes: ``(3, 3)`` float, its unit axes as rows.
        half: ``(3,)`` float, its half extents along them.
        radius: the rounding, ``0 < radius <= min(half)``.
        subdivisions: of the icosphere approximating each sphere (its vertices lie on the sphere).

    Returns:
        ``vertices: (V, 3) float64`` and ``faces: (F, 3) int64``, wound outward; every vertex lies in the box.
    """
    half = np.asarray(half, dtype=np.float64)
    if not 0 < radius <= half.min():
        raise ValueError(f"`radius` must be in (0, {half.min():.6g}] (the smallest half extent), got {radius!r}")
    sphere = _trimesh().creation.icosphere(subdivisions=int(subdivisions)).vertices
    inner = CORNER_SIGNS.numpy() * (half - radius)
    local = (inner[:, None] + radius * sphere[None]).reshape(-1, 3)
    hull = _trimesh().convex.convex_hull(local)
    vertices = np.asarray(center, dtype=np.float64) + np.asarray(hull.vertices) @ np.asarray(axes, dtype=np.float64)
    faces = np.asarray(hull.faces, dtype=np.int64)
    if np.linalg.det(np.asarray(axes, dtype=np.float64)) < 0:  # a mirrored frame turns the winding inward
        faces = faces[:, ::-1]
    return vertices, faces


def _rounded_mesh(corners: np.ndarray):
    """Every cuboid as :func:`rounded_box` (a flat cuboid, with no thickness to round, stays as it is)."""
    centers, axes, half = _frames(corners)
    verts, faces, base = [], [], 0
    for i in range(len(corners)):
        r = ROUND_RADIUS * half[i].min()
        if r > 1e-9:
            v, f = rounded_box(centers[i], axes[i], half[i], r)
        else:
            v, f = _cuboid_mesh(corners[i : i + 1])
        verts.append(v)
        faces.append(f + base)
        base += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def visible_from(points, normals, triangles, camera, tolerance: float = VISIBILITY_TOLERANCE) -> np.ndarray:
    """Which surface points a camera sees: the point faces it (``normal . (camera - point) > 0``) and the
    segment from the camera to it crosses no triangle more than ``tolerance`` before the point
    (Moeller-Trumbore, edges included).

    Args:
        points: ``(N, 3) float``, points on the surface.
        normals: ``(N, 3) float``, their outward normals.
        triangles: ``(T, 3, 3) float``, the surface's triangles (the occluders).
        camera: ``(3,) float``, the camera's position.
        tolerance: distance before the point within which a crossing does not hide it.

    Returns:
        ``(N,) bool``.
    """
    p = np.asarray(points, dtype=np.float64)
    cam = np.asarray(camera, dtype=np.float64).reshape(3)
    tri = np.asarray(triangles, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or np.shape(normals) != p.shape or tri.ndim != 3 or tri.shape[1:] != (3, 3):
        raise ValueError(f"expected points (N, 3), normals (N, 3), triangles (T, 3, 3); got {p.shape}, "
                         f"{np.shape(normals)}, {tri.shape}")
    d = p - cam  # the segment camera -> point is cam + s d, s in [0, 1]
    facing = (np.asarray(normals, dtype=np.float64) * -d).sum(-1) > 0
    length = np.linalg.norm(d, axis=-1)
    v0, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    tvec = cam - v0  # (T, 3)
    qvec = np.cross(tvec, e1)  # (T, 3)
    hidden = np.zeros(len(p), dtype=bool)
    todo = np.flatnonzero(facing)
    step = max(1, _RAY_CHUNK // max(1, len(tri)))
    for s in range(0, len(todo), step):
        idx = todo[s : s + step]
        dd = d[idx][:, None]  # (n, 1, 3)
        pvec = np.cross(dd, e2[None])  # (n, T, 3)
        det = (pvec * e1[None]).sum(-1)
        ok = np.abs(det) > 1e-300
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        u = (pvec * tvec[None]).sum(-1) * inv
        v = (dd * qvec[None]).sum(-1) * inv
        t = (qvec * e2).sum(-1)[None] * inv  # the crossing's parameter along the segment
        before = t * length[idx][:, None] < length[idx][:, None] - tolerance
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & before
        hidden[idx] = hit.any(axis=1)
    return facing & ~hidden


def uneven_keep(points, corners, direction, rng: np.random.Generator, ratio: float = UNEVEN_RATIO) -> np.ndarray:
    """Which points the ``uneven`` condition keeps: with ``t`` in [0, 1] the position along ``direction``
    between the shape's lowest and highest corner, a point is kept with probability ``ratio ** -t``.

    Args:
        points: ``(N, 3) float``.
        corners: ``(L, 8, 3) float``, the shape (its extent along ``direction``).
        direction: ``(3,) float``, non-zero.
        rng: the draws.
        ratio: the density at ``t = 0`` over that at ``t = 1``.

    Returns:
        ``(N,) bool``.
    """
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    if not np.linalg.norm(d) > 0:
        raise ValueError(f"`direction` must be non-zero, got {d.tolist()}")
    d = d / np.linalg.norm(d)
    along = np.asarray(corners, dtype=np.float64).reshape(-1, 3) @ d
    lo, hi = along.min(), along.max()
    t = np.clip((np.asarray(points, dtype=np.float64) @ d - lo) / max(hi - lo, 1e-300), 0.0, 1.0)
    return rng.random(len(t)) < float(ratio) ** -t


def outer_surface_keep(points, normals, corners, probe: float = MERGE_PROBE) -> np.ndarray:
    """Which cuboid-surface points lie on the outer surface of the cuboids' union: those whose probe
    ``point + probe * normal`` (one step outward) is inside no cuboid.

    Args:
        points: ``(N, 3) float``, points on the cuboids' faces.
        normals: ``(N, 3) float``, their faces' outward normals.
        corners: ``(L, 8, 3) float``, the cuboids.
        probe: the outward step.

    Returns:
        ``(N,) bool``.
    """
    q = np.asarray(points, dtype=np.float64) + probe * np.asarray(normals, dtype=np.float64)
    return ~inside_cuboids(torch.from_numpy(q), torch.as_tensor(np.asarray(corners, dtype=np.float64))).numpy()


def _camera(corners: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A camera at a random azimuth and an elevation in :data:`ELEVATION_RANGE`, :data:`CAMERA_DISTANCE`
    bounding-box diagonals from the shape's centre (y up)."""
    flat = corners.reshape(-1, 3)
    lo, hi = flat.min(0), flat.max(0)
    azimuth = rng.uniform(0.0, 2 * math.pi)
    elevation = math.radians(rng.uniform(*ELEVATION_RANGE))
    direction = np.array([math.cos(elevation) * math.sin(azimuth), math.sin(elevation),
                          math.cos(elevation) * math.cos(azimuth)])
    return (lo + hi) / 2 + CAMERA_DISTANCE * float(np.linalg.norm(hi - lo)) * direction


def condition_cloud(corners, condition: str, n_points: int = CONDITION_POINTS, seed: int = 0,
                    info: Optional[dict] = None) -> np.ndarray:
    """The test cloud of a shape under ``condition`` (see the module docstring).

    Args:
        corners: ``(L, 8, 3) float``, the shape's cuboids (torch or NumPy), in the canonical frame (y up).
        condition: one of :data:`CONDITIONS`.
        n_points: surface samples drawn (``uneven``, ``partial`` and ``merged`` keep a subset).
        seed: every random draw of the condition; the same shape, condition, count and seed give the same cloud.
        info: a dict that receives what was drawn: ``camera`` (``partial``), ``direction`` (``uneven``),
            ``sigma`` (noise), ``drawn`` (samples before dropping).

    Returns:
        ``(M, 3) float64``, ``M <= n_points``.

    Raises:
        ValueError: an unknown condition (naming it and the allowed ones), bad corners or ``n_points < 1``.
    """
    check_condition(condition)
    if isinstance(n_points, bool) or not isinstance(n_points, (int, np.integer)) or n_points < 1:
        raise ValueError(f"`n_points` must be a positive int, got {n_points!r}")
    c = _corners(corners)
    info = {} if info is None else info
    rng = np.random.default_rng([int(seed), CONDITIONS.index(condition)])
    sample_seed = int(rng.integers(2**63))
    vertices, faces = _rounded_mesh(c) if condition == "rounded" else _cuboid_mesh(c)
    points, face = sample_mesh(_mesh(vertices, faces), int(n_points), sample_seed, where=f"{condition} mesh")
    info["drawn"] = len(points)
    if condition in NOISE_LEVELS:
        flat = c.reshape(-1, 3)
        sigma = NOISE_LEVELS[condition] * float(np.linalg.norm(flat.max(0) - flat.min(0)))
        info["sigma"] = sigma
        return points + rng.normal(0.0, sigma, size=points.shape)
    if condition == "uneven":
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        info["direction"] = direction
        return points[uneven_keep(points, c, direction, rng)]
    if condition == "partial":
        camera = _camera(c, rng)
        info["camera"] = camera
        return points[visible_from(points, _normals(vertices, faces)[face], vertices[faces], camera)]
    if condition == "merged":
        return points[outer_surface_keep(points, _normals(vertices, faces)[face], c)]
    return points  # clean, rounded


def canonical_shape(category: str, shape_id: int, n_points: int = CLOUD_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """A corpus shape in the canonical frame of its clean cloud (the frame the tables score in).

    Returns:
        ``clean: (n_points, 3) float64``, the :func:`~shapeprog.pointcloud.data.corpus_cloud` normalised, and
        ``corners: (L, 8, 3) float64``, the executed program's cuboids in the same frame.
    """
    cloud, t = normalize(corpus_cloud(category, shape_id, n_points).astype(np.float64))
    with torch.no_grad():
        shape = execute(parse(corpus.read(category, shape_id), file=f"{category}/{int(shape_id)}.txt"))
    return cloud, t.apply(shape.corners.double().numpy())
