"""Surface sampling and voxelisation of executed cuboid shapes.

Every function takes plain tensors: ``corners: (L, 8, 3) float`` in the corner order of the
specification (corner ``i`` uses signs ``4*[x negative] + 2*[y negative] + [z negative]``), so the
functions work on anything that produces cuboid corners, not only on the executor's output.

* :func:`sample_surface` draws area-weighted surface points with the reflection trick. Point
  positions and normals are differentiable with respect to ``corners``; the categorical face choice
  is not.
* :func:`voxelize` is an occupancy grid at any resolution (voxel centres tested against oriented
  boxes).
* :func:`lattice_voxelize` is the 20^3 point lattice with 8 shifted copies that the recon IoU of the
  ShapeAssembly paper uses (see :func:`shapeprog.metrics.voxel_iou`).
"""
from __future__ import annotations

from typing import Optional, Sequence, Tuple, Union

import torch

from shapeprog.geometry import CORNER_SIGNS, CUBOID_TRIANGLES, check_corners

__all__ = ["sample_surface", "triangle_areas", "voxelize", "lattice_voxelize", "inside_cuboids"]

#: Largest triangle area accepted by :func:`sample_surface` (the reference asserts the same bound).
MAX_TRIANGLE_AREA = 1e6


def _triangles(corners: torch.Tensor) -> torch.Tensor:
    """Triangle vertices ``(12 L, 3, 3)`` of cuboids ``(L, 8, 3)`` in the specification's face order."""
    tri = torch.as_tensor(CUBOID_TRIANGLES, dtype=torch.long, device=corners.device)
    return corners[:, tri].reshape(-1, 3, 3)


def _raw_areas(tris: torch.Tensor) -> torch.Tensor:
    """``|(v1 - v0) x (v2 - v1)|`` (twice the area) of triangles ``(T, 3, 3)``."""
    return torch.linalg.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 1], dim=-1).norm(dim=-1)


def triangle_areas(corners: torch.Tensor) -> torch.Tensor:
    """Areas ``(12 L,)`` of the cuboids' triangles, as the reference computes them for sampling.

    ``area = 0.5 * (|(v1 - v0) x (v2 - v1)| + 1e-8)``.
    """
    return 0.5 * (_raw_areas(_triangles(check_corners(corners))) + 1e-8)


def sample_surface(
    corners: torch.Tensor,
    n: int,
    generator: Optional[torch.Generator] = None,
) -> Tuple[torch.Tensor, torch.Tensor]:
    """Sample ``n`` points uniformly by area on the surface of a union of cuboids.

    Faces are drawn i.i.d. from a categorical distribution weighted by triangle area
    (``0.5 * (|(v1 - v0) x (v2 - v1)| + 1e-8)``). For each point two uniform numbers ``r1, r2`` are
    drawn; if ``r1 + r2 > 1`` both become ``|r - 1|`` (the reflection trick), and the point is
    ``v0 + r1 (v1 - v0) + r2 (v2 - v0)``. The normal is the unit face normal
    ``(v1 - v0) x (v2 - v0)``, which points outward for the specification's winding and a
    right-handed frame.

    Gradients flow from points and normals to ``corners``; the face choice is discrete.
    The overlapping parts of intersecting cuboids are sampled too (as in the reference).

    Args:
        corners: ``(L, 8, 3) float`` cuboid corners, ``L >= 1``.
        n: number of points, ``n >= 1``.
        generator: optional ``torch.Generator`` on ``corners.device``; the same generator state
            gives the same points.

    Returns:
        points: ``(n, 3)`` float, same dtype and device as ``corners``.
        normals: ``(n, 3)`` float, unit length.

    Raises:
        ValueError: on a bad shape, NaN/inf corners, ``n < 1``, zero total area, or a triangle with
            area above ``1e6``.
    """
    check_corners(corners)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"`n` must be a positive int, got {n!r}")
    if corners.shape[0] == 0:
        raise ValueError("`corners` holds no cuboid (L = 0): there is no surface to sample")
    tris = _triangles(corners)
    v0, v1, v2 = tris[:, 0], tris[:, 1], tris[:, 2]
    raw = _raw_areas(tris)
    areas = 0.5 * (raw + 1e-8)
    check = raw.detach()
    if not torch.isfinite(check).all():
        raise ValueError("triangle areas contain NaN or infinite values")
    if float(check.sum()) <= 0.0:
        raise ValueError(f"the {corners.shape[0]} cuboids have zero total surface area; nothing to sample")
    big = float(areas.detach().max())
    if big > MAX_TRIANGLE_AREA:
        raise ValueError(f"a triangle has area {big:.4g} > {MAX_TRIANGLE_AREA:g}; the shape is degenerate")

    face = torch.multinomial(areas.detach(), n, replacement=True, generator=generator)
    r = torch.rand((n, 2), generator=generator, device=corners.device, dtype=corners.dtype)
    flip = r.sum(dim=1, keepdim=True) > 1.0
    r = torch.where(flip, (r - 1.0).abs(), r)
    r1, r2 = r[:, :1], r[:, 1:]
    a, b, c = v0[face], v1[face], v2[face]
    points = a + r1 * (b - a) + r2 * (c - a)
    normal = torch.linalg.cross(v1 - v0, v2 - v0, dim=-1)
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    return points, normal[face]


def _edge_frame(corners: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
    """Origin corner ``(L, 3)`` (signs ``(-,-,-)``, index 7) and edges ``(L, 3, 3)`` along x, y, z."""
    o = corners[:, 7]
    # corner 3 = (+,-,-), 5 = (-,+,-), 6 = (-,-,+)
    edges = torch.stack([corners[:, 3] - o, corners[:, 5] - o, corners[:, 6] - o], dim=1)
    return o, edges


def inside_cuboids(points: torch.Tensor, corners: torch.Tensor, chunk: int = 1 << 20) -> torch.Tensor:
    """Which points lie inside (or on) at least one cuboid.

    A point ``p`` is inside a cuboid when ``0 <= (p - o) . e <= |e|^2`` for its three edges ``e``
    from the corner ``o`` with signs ``(-,-,-)``, the reference's inside test.

    Args:
        points: ``(N, 3) float``.
        corners: ``(L, 8, 3) float``.
        chunk: bound on ``N * L`` handled at once (memory).

    Returns:
        ``(N,) bool``.
    """
    check_corners(corners)
    if points.dim() != 2 or points.shape[1] != 3:
        raise ValueError(f"`points` must have shape (N, 3), got {tuple(points.shape)}")
    points = points.to(corners.dtype)
    out = torch.zeros(points.shape[0], dtype=torch.bool, device=points.device)
    if corners.shape[0] == 0 or points.shape[0] == 0:
        return out
    o, edges = _edge_frame(corners.detach())
    sq = (edges * edges).sum(-1)  # (L, 3)
    step = max(1, chunk // corners.shape[0])
    for s in range(0, points.shape[0], step):
        p = points[s : s + step]
        proj = torch.einsum("nlc,lkc->nlk", p[:, None, :] - o[None], edges)  # (n, L, 3)
        ok = ((proj >= 0) & (proj <= sq[None])).all(-1).any(-1)
        out[s : s + step] = ok
    return out


def _resolution(resolution: Union[int, Sequence[int]]) -> Tuple[int, int, int]:
    if isinstance(resolution, int) and not isinstance(resolution, bool):
        res = (resolution,) * 3
    else:
        res = tuple(int(r) for r in resolution)
    if len(res) != 3 or min(res) < 1:
        raise ValueError(f"`resolution` must be a positive int or 3 positive ints, got {resolution!r}")
    return res  # type: ignore[return-value]


def voxelize(
    corners: torch.Tensor,
    resolution: Union[int, Sequence[int]],
    bounds: Optional[torch.Tensor] = None,
) -> torch.Tensor:
    """Occupancy grid of a union of cuboids, tested at voxel centres.

    Voxel ``(i, j, k)`` covers ``bounds[0] + ([i, j, k] + [0, 0, 0] .. [1, 1, 1]) * size`` with
    ``size = (bounds[1] - bounds[0]) / resolution``; it is occupied when its centre lies inside or
    on a cuboid (:func:`inside_cuboids`). The first grid index runs along world x, the second along
    y (up) and the third along z.

    Args:
        corners: ``(L, 8, 3) float``.
        resolution: voxels per axis, an int or ``(Rx, Ry, Rz)``.
        bounds: ``(2, 3) float`` min and max corner of the grid. Default: the axis-aligned bounding
            box of ``corners``.

    Returns:
        ``(Rx, Ry, Rz) bool`` on ``corners.device``.
    """
    check_corners(corners)
    res = _resolution(resolution)
    if bounds is None:
        if corners.shape[0] == 0:
            raise ValueError("`bounds` is required when `corners` holds no cuboid")
        flat = corners.detach().reshape(-1, 3)
        bounds = torch.stack([flat.min(0).values, flat.max(0).values])
    bounds = torch.as_tensor(bounds, dtype=corners.dtype, device=corners.device)
    if bounds.shape != (2, 3):
        raise ValueError(f"`bounds` must be (2, 3) float, got {tuple(bounds.shape)}")
    if not (bounds[1] >= bounds[0]).all():
        raise ValueError(f"`bounds` min must not exceed max, got {bounds.tolist()}")
    axes = [
        bounds[0, a] + (torch.arange(res[a], device=corners.device, dtype=corners.dtype) + 0.5)
        * (bounds[1, a] - bounds[0, a]) / res[a]
        for a in range(3)
    ]
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    return inside_cuboids(grid, corners).reshape(res)


def lattice_voxelize(corners: torch.Tensor, root_dims: torch.Tensor, n: int = 20) -> torch.Tensor:
    """The ShapeAssembly recon-IoU lattice: ``n^3`` points in the root bbox, 8 shifted copies each.

    The lattice points sit at local coordinates ``i / (n - 1)`` (bounds included) of the root
    bbox, which is centred at the origin with identity axes, so point ``i`` along axis ``a`` is
    ``(i / (n - 1) - 0.5) * root_dims[a]``. With ``offset = root_dims / (2 n)``, a lattice point is
    occupied when any of its 8 copies shifted by ``(+-offset_x, +-offset_y, +-offset_z)`` lies inside
    (or on) any cuboid.

    Args:
        corners: ``(L, 8, 3) float`` leaf cuboids.
        root_dims: ``(3,) float`` root bbox dims (x, y, z extents).
        n: lattice points per axis (20 in the reference).

    Returns:
        ``(n, n, n) bool``, indexed ``[x, y, z]``.
    """
    check_corners(corners)
    root_dims = torch.as_tensor(root_dims, dtype=corners.dtype, device=corners.device).detach()
    if root_dims.shape != (3,):
        raise ValueError(f"`root_dims` must have shape (3,), got {tuple(root_dims.shape)}")
    if isinstance(n, bool) or not isinstance(n, int) or n < 2:
        raise ValueError(f"`n` must be an int >= 2, got {n!r}")
    t = torch.arange(n, device=corners.device, dtype=corners.dtype) / (n - 1) - 0.5
    axes = [t * root_dims[a] for a in range(3)]
    lattice = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)
    offset = root_dims / (2 * n)
    signs = CORNER_SIGNS.to(corners)
    shifted = (lattice[:, None, :] + signs[None] * offset).reshape(-1, 3)  # (n^3 * 8, 3)
    occ = inside_cuboids(shifted, corners).reshape(-1, 8).any(1)
    return occ.reshape(n, n, n)
