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


def random_cuboids(g: torch.Generator, n: int, min_dim: float = 0.05) -> torch.Tensor:
    """``(n, 8, 3)`` float64 corners of ``n`` randomly placed, sized (``min_dim`` to ``min_dim + 0.6``) and
    rotated cuboids, drawn from ``g``."""
    centers = torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5
    dims = min_dim + torch.rand(n, 3, generator=g, dtype=torch.float64) * 0.6
    axes = torch.stack([rotation(torch.randn(3, generator=g).tolist(), float(torch.rand(1, generator=g)) * 3)
                        for _ in range(n)])
    return cuboid_corners(centers, dims, axes)


#: A one-block program with attach, reflect and translate lines.
FLAT = """bbox = Cuboid(1.0, 1.0, 1.0, True)
cube0 = Cuboid(0.2, 0.5, 0.2, True)
cube1 = Cuboid(1.0, 0.1, 1.0, True)
attach(cube0, bbox, 0.5, 0.0, 0.5, 0.1, 0.0, 0.1)
attach(cube1, cube0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)
reflect(cube0, X)
translate(cube0, Z, 2, 0.8)
"""
