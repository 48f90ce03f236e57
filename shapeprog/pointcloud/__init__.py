"""Point clouds to ShapeAssembly programs. See ``docs/pointcloud.md``.

Encoder (PointNet++ in plain PyTorch, CPU and GPU, no compiled extension):

* :mod:`~shapeprog.pointcloud.ops`: batched farthest-point sampling, ball query and grouping.
* :mod:`~shapeprog.pointcloud.encoder`: the set abstraction layer and the spec's PointNet++ SSG encoder,
  ``(B, N, 3) -> (B, 256)``.

Data (clouds of corpus shapes, the canonical frame, users' files, a nearest-neighbour baseline):

* :mod:`~shapeprog.pointcloud.data`: clouds sampled from executed corpus programs, their cache and splits,
  :class:`CloudDataset`.
* :mod:`~shapeprog.pointcloud.normalize`: :func:`normalize` into the canonical frame and :class:`Transform`
  back; :func:`scale_program`.
* :mod:`~shapeprog.pointcloud.retrieval`: :class:`RetrievalIndex`, the nearest training program by chamfer.
* :func:`read_cloud` (from :mod:`shapeio.points`): users' clouds and meshes.
"""
from __future__ import annotations

from shapeio.points import read_cloud
from shapeprog.errors import PointCloudError

from .data import CloudDataset, collate_clouds, corpus_cloud, load_cache, make_clouds, program_cloud
from .encoder import PointNet2SSG, SetAbstraction
from .normalize import CANONICAL_DIAGONAL, Transform, normalize, scale_program
from .ops import ball_query, farthest_point_sample, gather_points, group_all, group_points, query_and_group
from .retrieval import Match, RetrievalIndex

__all__ = ["CANONICAL_DIAGONAL", "CloudDataset", "Match", "PointCloudError", "PointNet2SSG", "RetrievalIndex",
           "SetAbstraction", "Transform", "ball_query", "collate_clouds", "corpus_cloud", "farthest_point_sample",
           "gather_points", "group_all", "group_points", "load_cache", "make_clouds", "normalize",
           "program_cloud", "query_and_group", "read_cloud", "scale_program"]
