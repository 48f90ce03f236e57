"""Point clouds to ShapeAssembly programs: PointNet++ in plain PyTorch.

:mod:`~shapeprog.pointcloud.ops` holds the batched point-cloud operations (farthest-point sampling,
ball query, grouping; CPU and GPU, no compiled extension) and :mod:`~shapeprog.pointcloud.encoder` the
set abstraction layer and the spec's PointNet++ SSG encoder, ``(B, N, 3) -> (B, 256)``. See
``docs/pointcloud.md``.
"""
from __future__ import annotations

from shapeprog.errors import PointCloudError

from .encoder import PointNet2SSG, SetAbstraction
from .ops import ball_query, farthest_point_sample, gather_points, group_all, group_points, query_and_group

__all__ = ["PointCloudError", "PointNet2SSG", "SetAbstraction", "ball_query", "farthest_point_sample",
           "gather_points", "group_all", "group_points", "query_and_group"]
