"""Shared helpers for the ShapeAssembly (shapeprog) tests."""

from __future__ import annotations

import torch

from shapeprog.geometry import cuboid_corners


def boxes(centers, dims, axes=None, dtype=torch.float64):
    """Corners ``(L, 8, 3)`` of cuboids with the given centres and dims (identity axes unless given)."""
    c = torch.as_tensor(centers, dtype=dtype).reshape(-1, 3)
    d = torch.as_tensor(dims, dtype=dtype).reshape(-1, 3)
    a = torch.eye(3, dtype=dtype).expand(c.shape[0], 3, 3) if axes is None else torch.as_tensor(axes, dtype=dtype)
    return cuboid_corners(c, d, a)
