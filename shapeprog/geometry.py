"""Cuboid frames, corners and triangle meshes (pure torch, differentiable).

A cuboid is given by its centre ``(3,)``, its extents ``dims (3,)`` along its own
right/up/front axes, and ``axes (3, 3)`` whose **rows** are the unit right, up and
front vectors (a proper rotation). Batches carry a leading ``L`` (leaves).

Corner order (ShapeAssembly, spec section (c)): with half extents ``h`` and signs
``s = (sx, sy, sz)``, corner ``i`` has ``i = 4*[sx<0] + 2*[sy<0] + [sz<0]`` and lies
at ``centre + sum_k s_k * h_k * axes[k]``.

Example:
    >>> import torch
    >>> c = cuboid_corners(torch.zeros(1, 3), torch.ones(1, 3), torch.eye(3)[None])
    >>> c[0, 0].tolist(), c[0, 7].tolist()
    ([0.5, 0.5, 0.5], [-0.5, -0.5, -0.5])
"""
from __future__ import annotations

import torch

__all__ = ["CORNER_SIGNS", "CUBOID_TRIANGLES", "cuboid_corners", "mesh_arrays"]

#: (8, 3) signs of the corners along right/up/front, in the spec's order.
CORNER_SIGNS = torch.tensor(
    [[sx, sy, sz] for sx in (1.0, -1.0) for sy in (1.0, -1.0) for sz in (1.0, -1.0)]
)

#: (12, 3) int64 corner indices of the triangles, CCW seen from outside:
#: +x x2, +z x2, -z x2, -x x2, +y x2, -y x2.
CUBOID_TRIANGLES = torch.tensor(
    [
        [0, 2, 1], [1, 2, 3],
        [0, 4, 6], [0, 6, 2],
        [1, 3, 5], [3, 7, 5],
        [4, 5, 7], [4, 7, 6],
        [1, 5, 4], [0, 1, 4],
        [2, 6, 7], [2, 7, 3],
    ],
    dtype=torch.int64,
)


def _check(name: str, t: torch.Tensor, shape: tuple) -> None:
    if t.dim() != len(shape) or any(s is not None and s != d for s, d in zip(shape, t.shape)):
        want = "(" + ", ".join("L" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"`{name}` must have shape {want}, got {tuple(t.shape)}")


def cuboid_corners(centers: torch.Tensor, dims: torch.Tensor, axes: torch.Tensor) -> torch.Tensor:
    """Corners of a batch of oriented cuboids.

    Args:
        centers: (L, 3) float, cuboid centres.
        dims: (L, 3) float, full extents along the cuboid's right/up/front axes.
        axes: (L, 3, 3) float, rows are the unit right, up and front vectors.

    Returns:
        (L, 8, 3) float corners in the spec's order (see module docstring).
    """
    _check("centers", centers, (None, 3))
    _check("dims", dims, (centers.shape[0], 3))
    _check("axes", axes, (centers.shape[0], 3, 3))
    return corners_unchecked(centers, dims, axes)


def corners_unchecked(centers: torch.Tensor, dims: torch.Tensor, axes: torch.Tensor) -> torch.Tensor:
    """:func:`cuboid_corners` without the argument checks, for callers that built the tensors."""
    signs = CORNER_SIGNS.to(device=dims.device, dtype=dims.dtype)
    # (L, 8, 3) local offsets, then rotate: offset @ axes (rows are axis vectors).
    local = signs[None] * (0.5 * dims)[:, None, :]
    return centers[:, None, :] + local @ axes


def mesh_arrays(corners: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Triangle mesh of a batch of cuboids.

    Args:
        corners: (L, 8, 3) float corners from :func:`cuboid_corners`.

    Returns:
        vertices: (8L, 3) float, the corners leaf after leaf.
        faces: (12L, 3) int64, 0-based vertex indices (leaf k adds 8k).
    """
    _check("corners", corners, (None, 8, 3))
    n = corners.shape[0]
    offs = 8 * torch.arange(n, device=corners.device, dtype=torch.int64)
    faces = CUBOID_TRIANGLES.to(corners.device)[None] + offs[:, None, None]
    return corners.reshape(-1, 3), faces.reshape(-1, 3)
