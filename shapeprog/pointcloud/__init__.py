"""Point cloud -> ShapeAssembly program: the data side (clouds of corpus shapes, the canonical frame,
users' files, a nearest-neighbour baseline). See ``docs/pointcloud.md``.

* :mod:`~shapeprog.pointcloud.data`: clouds sampled from executed corpus programs, their cache and splits,
  :class:`CloudDataset`.
* :mod:`~shapeprog.pointcloud.normalize`: :func:`normalize` into the canonical frame and :class:`Transform`
  back; :func:`scale_program`.
* :mod:`~shapeprog.pointcloud.retrieval`: :class:`RetrievalIndex`, the nearest training program by chamfer.
* :func:`read_cloud` (from :mod:`shapeio.points`): users' clouds and meshes.
"""
from __future__ import annotations

from shapeio.points import read_cloud

from .data import CloudDataset, collate_clouds, corpus_cloud, load_cache, make_clouds, program_cloud
from .normalize import CANONICAL_DIAGONAL, Transform, normalize, scale_program
from .retrieval import Match, RetrievalIndex

__all__ = ["CANONICAL_DIAGONAL", "CloudDataset", "Match", "RetrievalIndex", "Transform", "collate_clouds",
           "corpus_cloud", "load_cache", "make_clouds", "normalize", "program_cloud", "read_cloud",
           "scale_program"]
