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
* :mod:`~shapeprog.pointcloud.conditions`: test clouds of a shape under harder conditions (noise, uneven
  density, one depth camera's view, rounded and merged parts).

Cloud -> program (training in :mod:`~shapeprog.pointcloud.train`, the only module here importing Lightning):

* :func:`infer` (:mod:`shapeprog.pointcloud.infer`): a program for a cloud in any frame and scale, optionally
  polished by fitting, optionally searched (:mod:`~shapeprog.pointcloud.search`) or against the training
  programs nearest to it (``retrieval=``); :class:`CloudModel` and :func:`load_model` for trained weights files.
"""
from __future__ import annotations

from shapeio.points import read_cloud
from shapeprog.errors import PointCloudError

from .data import corpus_cloud, make_clouds, program_cloud
from .dataset import CloudDataset, collate_clouds, load_cache
from .encoder import PointNet2SSG, SetAbstraction
from .infer import CloudModel, Inference, infer, load_model
from .normalize import CANONICAL_DIAGONAL, Transform, normalize, scale_program
from .ops import ball_query, farthest_point_sample, gather_points, group_all, group_points, query_and_group
from .retrieval import Match, RetrievalIndex

__all__ = ["CANONICAL_DIAGONAL", "CloudDataset", "CloudModel", "Inference", "Match", "PointCloudError",
           "PointNet2SSG", "RetrievalIndex", "SetAbstraction", "Transform", "ball_query", "collate_clouds",
           "corpus_cloud", "farthest_point_sample", "gather_points", "group_all", "group_points", "infer",
           "load_cache", "load_model", "make_clouds", "normalize", "program_cloud", "query_and_group", "read_cloud",
           "scale_program"]
