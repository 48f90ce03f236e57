"""Cuboid frames, corners and triangle meshes (pure torch, differentiable), and the corner validator.

A cuboid is given by its centre ``(3,)``, its extents ``dims (3,)`` along its own
right/up/front axes, and ``axes (3, 3)`` whose **rows** are the unit right, up and
front vectors (a proper rotation). Batches carry a leading ``L`` (leaves).

Corner order (ShapeAssembly, spec section (c)): with half extents ``h`` and signs
``s = (sx, sy, sz)``, corner ``i`` has ``i = 4*[sx<0] + 2*[sy<0] + [sz<0]`` and lies
at ``centre + sum_k s_k * h_k * axes[k]``.

:func:`check_corners` validates ``corners: (L, 8, 3) float`` for every module that takes them;
:func:`numpy_corners` also converts them to a float64 NumPy array.

Example:
    >>> import torch
    >>> c = cuboid_corners(torch.zeros(1, 3), torch.ones(1, 3), torch.eye(3)[None])
    >>> c[0, 0].tolist(), c[0, 7].tolist()
    ([0.5, 0.5, 0.5], [-0.5, -0.5, -0.5])
"""
from __future__ import annotations

import numpy as np
import torch

__all__ = ["CORNER_SIGNS", "CUBOID_TRIANGLES", "check_corners", "cuboid_corners", "mesh_arrays",
           "numpy_corners"]

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


def check_corners(corners, name: str = "corners", where=None, arrays: bool = False):
    """Validate ``corners: (L, 8, 3) float`` and return it unchanged (the one corner validator).

    Args:
        corners: a ``torch.Tensor`` (or, with ``arrays=True``, a NumPy array).
        name: the argument name used in messages.
        where: optional prefix of the messages (e.g. the file being written).
        arrays: accept NumPy arrays as well as tensors.

    Raises:
        TypeError: if it is not a tensor (or array) or not floating point.
        ValueError: if the shape is not ``(L, 8, 3)`` or a value is NaN or infinite.
    """
    pre = "" if where is None else f"{where}: "
    if isinstance(corners, torch.Tensor):
        floating, isfinite = corners.is_floating_point(), torch.isfinite
    elif arrays and isinstance(corners, np.ndarray):
        floating, isfinite = np.issubdtype(corners.dtype, np.floating), np.isfinite
    else:
        raise TypeError(f"{pre}`{name}` must be a torch.Tensor of shape (L, 8, 3), got {type(corners).__name__}")
    if corners.ndim != 3 or tuple(corners.shape[1:]) != (8, 3):
        raise ValueError(f"{pre}`{name}` must have shape (L, 8, 3), got {tuple(corners.shape)}")
    if not floating:
        raise TypeError(f"{pre}`{name}` must be floating point, got {corners.dtype}")
    finite = isfinite(corners)
    if not finite.all():
        bad = [i for i, row in enumerate((~finite).reshape(corners.shape[0], -1).any(1).tolist()) if row]
        raise ValueError(f"{pre}`{name}` contains NaN or infinite values (cuboids {bad[:10]})")
    return corners


def numpy_corners(corners) -> np.ndarray:
    """Validated ``(L, 8, 3)`` float64 NumPy corners of at least one cuboid, from a floating-point
    tensor or any array-like (cast to float64); errors as :func:`check_corners`, and for ``L = 0``."""
    if isinstance(corners, torch.Tensor):
        corners = check_corners(corners).detach().cpu().numpy()
    corners = check_corners(np.asarray(corners, dtype=np.float64), arrays=True)
    if corners.shape[0] == 0:
        raise ValueError("`corners` holds no cuboid (L = 0)")
    return corners
