"""Shared helpers for the ShapeAssembly (shapeprog) tests."""

from __future__ import annotations

import math

import torch

from shapeprog.geometry import cuboid_corners


def boxes(centers, dims, axes=None, dtype=torch.float64):
    """Corners ``(L, 8, 3)`` of cuboids with the given centres and dims (identity axes unless given)."""
    c = torch.as_tensor(centers, dtype=dtype).reshape(-1, 3)
    d = torch.as_tensor(dims, dtype=dtype).reshape(-1, 3)
    a = torch.eye(3, dtype=dtype).expand(c.shape[0], 3, 3) if axes is None else torch.as_tensor(axes, dtype=dtype)
    return cuboid_corners(c, d, a)


def rot_y(angle, dtype=torch.float64):
    """The ``(3, 3)`` axes (rows) of a frame turned by ``angle`` radians about y."""
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, 0, -s], [0, 1, 0], [s, 0, c]], dtype=dtype)


def rotation(axis, angle, dtype=torch.float64):
    """Rotation matrix ``(3, 3)`` about ``axis`` by ``angle`` radians (Rodrigues), independent of the executor."""
    k = torch.as_tensor(axis, dtype=dtype)
    k = k / k.norm()
    K = torch.tensor([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]], dtype=dtype)
    return torch.eye(3, dtype=dtype) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
