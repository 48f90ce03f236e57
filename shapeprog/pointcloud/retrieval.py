"""Nearest-neighbour retrieval: the training program whose cloud is closest to a query cloud (a baseline).

A :class:`RetrievalIndex` holds the normalised clouds of a category's training shapes (the ``train`` and
``val`` parts of the cache's split, both carved from the corpus train split; never ``test``).
:meth:`RetrievalIndex.search` returns, for each (normalised) query cloud, the shape with the smallest
chamfer distance (:func:`shapeprog.metrics.chamfer` with ``eps = 0``: mean nearest-point distance,
both directions summed, in canonical units).

The search has two stages, as :func:`shapeprog.vae.genmetrics.nearest_chamfer`: a coarse estimate of the
query against every reference from distance fields on a ``grid^3`` lattice (the references' fields are
computed once, when the index is built; :func:`shapeprog.vae.genmetrics.coarse_fields`), then exact
chamfer distances (k-d trees, float64) to the ``candidates`` best estimates. With
``candidates=None`` every reference is measured exactly. How often the two agree and the timings:
``docs/pointcloud.md`` (Retrieval).

Example:
    >>> import torch
    >>> g = torch.Generator().manual_seed(0)
    >>> refs = torch.rand(5, 300, 3, generator=g) - 0.5
    >>> index = RetrievalIndex("chair", [10, 11, 12, 13, 14], refs, grid=8, candidates=2)
    >>> index.search(refs[3:4])[0].id
    13
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Optional, Sequence, Union

import numpy as np
import torch

from shapeio.cache import cached

from .. import corpus
from ..parallel import ordered_map
from ..vae.genmetrics import coarse_fields
from ..lang import Program, parse
from ..metrics import chamfer
from .data import cloud_transforms, corpus_splits, sample_clouds
from .dataset import load_cache, read_split
from .normalize import CANONICAL_DIAGONAL, Transform, scale_program
from ..corpus import data_digest

__all__ = ["INDEX_CANDIDATES", "INDEX_GRID", "INDEX_POINTS", "Match", "RetrievalIndex"]

PathLike = Union[str, os.PathLike]

#: Bumped when the sampling of :meth:`RetrievalIndex.from_corpus` changes: cached indexes of other versions are
#: not read.
INDEX_CACHE_VERSION = 2
#: Points kept per reference cloud (the first ones of the cached cloud: an i.i.d. subset).
INDEX_POINTS = 2048
#: Lattice vertices per axis of the coarse stage (16^3 fields and splat weights: 16 KB per reference, float16).
INDEX_GRID = 16
#: References measured exactly per query.
INDEX_CANDIDATES = 16
_QUERY_CHUNK = 256  # queries whose coarse fields are computed at once
_REF_CHUNK = 1024   # references per matrix product of the coarse stage


@dataclass(frozen=True)
class Match:
    """The retrieved shape of one query.

    Attributes:
        category: the category.
        id: the shape id (corpus program ``category/id``).
        distance: chamfer distance to the query, in canonical units (AABB diagonal 2), from
            :meth:`RetrievalIndex.search`; from :meth:`RetrievalIndex.shortlist` it is the coarse stage's
            estimate instead (an ordering, not a chamfer distance).
        center, scale: the reference cloud's :class:`~shapeprog.pointcloud.normalize.Transform`
            (program frame -> canonical frame); None when the index was built from bare clouds.
    """

    category: str
    id: int
    distance: float
    center: Optional[tuple] = None
    scale: Optional[float] = None

    @property
    def name(self) -> str:
        """The corpus name, ``"chair/173"``."""
        return f"{self.category}/{self.id}"

    def program(self) -> Program:
        """The corpus program, in its own frame."""
        return parse(corpus.read(self.category, self.id), file=f"{self.name}.txt")

    def canonical_program(self) -> tuple[Program, np.ndarray]:
        """The program scaled into the canonical frame and the ``offset (3,) float64`` to add to its
        executed points to get the reference's normalised cloud (``-center * scale``, usually below
        0.01: the corpus shapes sit almost centred in their root bbox)."""
        if self.scale is None:
            raise ValueError("this match has no transform (the index was built from bare clouds)")
        t = Transform(self.center, self.scale)
        return scale_program(self.program(), t.scale), -np.asarray(t.center) * t.scale


def _as_clouds(x, name: str) -> list[torch.Tensor]:
    """A ``(Q, N, 3)`` tensor/array or a sequence of ``(N_i, 3)`` clouds as float64 CPU tensors."""
    if isinstance(x, (torch.Tensor, np.ndarray)) and x.ndim == 2:
        raise ValueError(f"`{name}` must be (Q, N, 3) or a list of (N, 3) clouds, got one (N, 3) cloud; "
                         "use search(cloud[None]) or query(cloud)")
    out = []
    for k, c in enumerate(x):
        c = torch.as_tensor(np.asarray(c) if not isinstance(c, torch.Tensor) else c).detach().cpu().double()
        if c.dim() != 2 or c.shape[1] != 3 or c.shape[0] < 1:
            raise ValueError(f"`{name}`[{k}] must have shape (N, 3) with N >= 1, got {tuple(c.shape)}")
        if not torch.isfinite(c).all():
            raise ValueError(f"`{name}`[{k}] has a NaN or infinite coordinate")
        out.append(c)
    return out


def _exact_job(job) -> list[list[float]]:
    """Exact chamfer of every query against its candidate clouds: ``[(query (N, 3), cands (k, M, 3))]``."""
    return [[float(chamfer(q.double(), r.double(), eps=0.0, method="kdtree")) for r in cands] for q, cands in job]


class RetrievalIndex:
    """Training clouds of one category, searchable by chamfer distance.

    Args:
        category: the category (names the matches' programs).
        ids: ``(R,)`` shape ids of the references.
        clouds: ``(R, M, 3) float`` reference clouds in the canonical frame (kept as float32).
        grid: lattice vertices per axis of the coarse stage.
        candidates: references measured exactly per query (None: all of them, exhaustive).
        centers, scales: ``(R, 3)`` and ``(R,)`` each reference's Transform (for
            :meth:`Match.canonical_program`); optional.
        fields: ``(splat, field)``, each ``(R, grid^3)``: the references' coarse fields as :meth:`fields` returns
            them (e.g. read back from a cache); None computes them (about 5 ms per reference).
    """

    def __init__(self, category: str, ids: Sequence[int], clouds, grid: int = INDEX_GRID,
                 candidates: Optional[int] = INDEX_CANDIDATES, centers=None, scales=None, fields=None):
        clouds = torch.as_tensor(np.asarray(clouds) if not isinstance(clouds, torch.Tensor) else clouds).detach()
        ids = np.asarray(ids, dtype=np.int64)
        if clouds.dim() != 3 or clouds.shape[2] != 3 or clouds.shape[0] == 0 or clouds.shape[0] != len(ids):
            raise ValueError(f"`clouds` must be (R, M, 3) with R = len(ids) = {len(ids)} >= 1, got {tuple(clouds.shape)}")
        if not torch.isfinite(clouds).all():
            raise ValueError("`clouds` has a NaN or infinite coordinate")
        if isinstance(grid, bool) or not isinstance(grid, int) or grid < 2:
            raise ValueError(f"`grid` must be an int >= 2, got {grid!r}")
        self.category, self.ids, self.grid = category, ids, grid
        self.candidates = candidates
        self.clouds = clouds.to(torch.float32)
        self.centers = None if centers is None else np.asarray(centers, dtype=np.float64)
        self.scales = None if scales is None else np.asarray(scales, dtype=np.float64)
        if fields is not None:
            splat, field = (torch.as_tensor(np.asarray(f)).to(torch.float16) for f in fields)
            if tuple(splat.shape) != (len(ids), grid ** 3) or tuple(field.shape) != (len(ids), grid ** 3):
                raise ValueError(f"`fields` must be two (R, grid^3) = ({len(ids)}, {grid ** 3}) arrays, got "
                                 f"{tuple(splat.shape)} and {tuple(field.shape)}")
            self.splat, self.field = splat, field
        else:
            splat, field = [], []
            for s in range(0, len(ids), _QUERY_CHUNK):
                h, d = coarse_fields(self._unit(clouds[s:s + _QUERY_CHUNK].double()), grid)
                splat.append(h.to(torch.float16))
                field.append(d.to(torch.float16))
            self.splat, self.field = torch.cat(splat), torch.cat(field)  # (R, V) each
        self._dense = None  # float32 copies of splat and field, made by the first shortlist()
        self._rows = None  # shape id -> row, made by the first reference_cloud()

    @staticmethod
    def _unit(x: torch.Tensor) -> torch.Tensor:
        """Canonical frame (diagonal 2) -> the coarse stage's box [-0.5, 0.5]^3 (diagonal 1)."""
        return x / CANONICAL_DIAGONAL

    @classmethod
    def from_cache(cls, root: PathLike, category: str, points: int = INDEX_POINTS,
                   splits: Sequence[str] = ("train", "val"), **kwargs) -> "RetrievalIndex":
        """The index of a cloud cache (:func:`shapeprog.pointcloud.data.make_clouds`): the clouds of
        ``splits`` (default: train and val, i.e. the whole corpus train split), normalised with their
        stored transforms, ``points`` points each (the first ones). ``kwargs`` go to the constructor."""
        if "test" in splits:
            raise ValueError("the test split (the corpus val split) must not be retrieved from")
        cache = load_cache(root, category)
        split = read_split(root, category, cache)
        ids = sorted(i for s in splits for i in split[s])
        rows = cache.index(ids)
        m = min(int(points), cache.points.shape[1])
        x = cache.points[rows, :m].astype(np.float64)
        x = (x - cache.center[rows, None, :]) * cache.scale[rows, None, None]
        return cls(category, cache.ids[rows], torch.from_numpy(x), centers=cache.center[rows],
                   scales=cache.scale[rows], **kwargs)

    @classmethod
    def from_corpus(cls, category: str, points: int = INDEX_POINTS, seed: int = 0, executor=None,
                    progress=None, ids: Optional[Sequence[int]] = None, cache: bool = True,
                    **kwargs) -> "RetrievalIndex":
        """The index of the corpus train split of ``category`` without a cache: each program executed and
        ``points`` points sampled from its cuboids (:func:`~shapeprog.pointcloud.data.sample_clouds`, the
        cache's per-shape seeds), normalised. The same shapes as :meth:`from_cache` with the default splits
        (the training carve-out and its validation part); the clouds are other samples of the same
        surfaces. About 22 s for chairs on one core (``docs/pointcloud.md``); ``executor`` runs the
        per-shape jobs, ``progress(done, total)`` is called after each. Shapes that fail to execute are
        left out (none in the shipped corpus). ``ids`` restricts the index to some of those shapes (a ValueError
        names an id outside the corpus train split). ``kwargs`` go to the constructor.

        With ``cache`` the clouds (float32) and their coarse fields (float16, ``grid``) are kept in the on-disk cache
        (:mod:`shapeio.cache`), keyed by the category, ``points``, ``seed``, ``grid``, the ids, the corpus archive's
        digest and :data:`INDEX_CACHE_VERSION`: a later call with the same key reads them (about 0.3 s for chairs)
        instead of sampling the corpus and computing the fields again (about 40 s)."""
        split = corpus_splits(category)
        train = sorted(split["train"] + split["val"])
        if ids is None:
            ids = train
        else:
            known = set(train)
            bad = [int(i) for i in ids if int(i) not in known]
            if bad:
                raise ValueError(f"{category}/{bad[0]} is not in the corpus train split; the index holds training "
                                 "shapes only")
            ids = sorted(int(i) for i in ids)
        grid = int(kwargs.pop("grid", INDEX_GRID))

        def compute() -> dict:
            cs = sample_clouds(category, ids, n_points=points, seed=seed, executor=executor, progress=progress)
            centers, scales = cloud_transforms(cs.points)
            unit = (cs.points.astype(np.float64) - centers[:, None, :]) * scales[:, None, None]
            built = cls(category, cs.ids, torch.from_numpy(unit), grid=grid)
            return {"ids": np.asarray(cs.ids, dtype=np.int64), "unit": built.clouds.numpy(), "centers": centers,
                    "scales": scales, "splat": built.splat.numpy(), "field": built.field.numpy()}

        if cache:
            key = {"category": category, "points": int(points), "seed": int(seed), "grid": grid,
                   "ids": [int(i) for i in ids], "corpus": data_digest(), "version": INDEX_CACHE_VERSION}
            got = cached("retrieval-index", key, compute)
        else:
            got = compute()
        return cls(category, got["ids"], torch.from_numpy(got["unit"]), grid=grid, centers=got["centers"],
                   scales=got["scales"], fields=(got["splat"], got["field"]), **kwargs)

    def __len__(self) -> int:
        return len(self.ids)

    def reference_cloud(self, shape_id: int) -> torch.Tensor:
        """The reference cloud ``(M, 3) float32`` of shape ``shape_id``, in the canonical frame.

        Raises:
            KeyError: the shape is not in the index."""
        if self._rows is None:
            self._rows = {int(i): r for r, i in enumerate(self.ids)}
        try:
            return self.clouds[self._rows[int(shape_id)]]
        except KeyError:
            raise KeyError(f"{self.category}/{int(shape_id)} is not in the index") from None

    def _match(self, row: int, dist: float) -> Match:
        if self.scales is None:
            return Match(self.category, int(self.ids[row]), dist)
        return Match(self.category, int(self.ids[row]), dist, tuple(self.centers[row]), float(self.scales[row]))

    def _candidates(self, queries: list[torch.Tensor], k: int, values: bool = False, dense: bool = False):
        """``(Q, k)`` rows with the smallest coarse estimates, best first (and the estimates with ``values``);
        ``dense``: use (and keep) float32 copies of the references' fields instead of converting them per call."""
        if dense and self._dense is None:
            self._dense = (self.splat.float(), self.field.float())
        splat, field = self._dense if dense else (self.splat, self.field)
        out, vals = [], []
        for s in range(0, len(queries), _QUERY_CHUNK):
            chunk = queries[s:s + _QUERY_CHUNK]
            fields = [coarse_fields(self._unit(q)[None], self.grid) for q in chunk]
            hq = torch.cat([f[0] for f in fields])
            dq = torch.cat([f[1] for f in fields])
            est = torch.empty(len(chunk), len(self.ids))
            for r in range(0, len(self.ids), _REF_CHUNK):
                hr = splat[r:r + _REF_CHUNK].float()
                dr = field[r:r + _REF_CHUNK].float()
                est[:, r:r + _REF_CHUNK] = hq @ dr.T + dq @ hr.T
            top = est.topk(k, dim=1, largest=False)
            out.append(top.indices)
            vals.append(top.values)
        return (torch.cat(out), torch.cat(vals)) if values else torch.cat(out)

    def shortlist(self, cloud, k: int = INDEX_CANDIDATES) -> list[Match]:
        """The ``k`` references of smallest coarse estimate for one ``(N, 3)`` cloud in the canonical frame,
        best first, without the exact stage (about 12 ms for chairs; ``k`` above the index's size gives
        every reference): the candidates that
        :func:`~shapeprog.pointcloud.infer.infer` scores itself with ``retrieval=``. Each
        :class:`Match`'s ``distance`` is the coarse estimate. The first call keeps float32 copies of the
        references' fields (twice their float16 memory: about 110 MiB more for chairs) so that later calls do
        not convert them again (about 14 ms per call for chairs)."""
        if isinstance(k, bool) or not isinstance(k, int) or k < 1:
            raise ValueError(f"`k` must be an integer >= 1, got {k!r}")
        q = _as_clouds([cloud], "cloud")
        k = min(k, len(self.ids))
        rows, est = self._candidates(q, k, values=True, dense=True)
        return [self._match(int(r), float(e)) for r, e in zip(rows[0].tolist(), est[0].tolist())]

    def search(self, queries, executor=None, candidates: Union[int, None, str] = "default",
               chunk: int = 8) -> list[Match]:
        """The nearest reference of every query.

        Args:
            queries: ``(Q, N, 3)`` clouds or a list of ``(N_i, 3)`` clouds, in the canonical frame
                (:func:`shapeprog.pointcloud.normalize`).
            executor: a ``concurrent.futures.Executor`` for the exact stage (jobs of ``chunk``
                queries); None runs it here.
            candidates: references measured exactly per query; None: every reference (exhaustive);
                default: the index's ``candidates``.
            chunk: queries per exact-stage job.

        Returns:
            One :class:`Match` per query, in order.
        """
        qs = _as_clouds(queries, "queries")
        if not qs:
            return []
        cand = self.candidates if candidates == "default" else candidates
        n = len(self.ids)
        k = n if cand is None else max(1, min(int(cand), n))
        rows = torch.arange(n).expand(len(qs), -1) if k >= n else self._candidates(qs, k)
        jobs = ([(qs[i], self.clouds[rows[i]]) for i in range(s, min(s + chunk, len(qs)))]
                for s in range(0, len(qs), chunk))  # made one at a time: a job copies its candidates
        dist = torch.tensor([row for part in ordered_map(executor, _exact_job, jobs) for row in part], dtype=torch.float64)
        best = dist.argmin(dim=1)
        return [self._match(int(rows[i, b]), float(dist[i, b])) for i, b in enumerate(best.tolist())]

    def query(self, cloud, **kwargs) -> Match:
        """:meth:`search` of one ``(N, 3)`` cloud."""
        return self.search([cloud], **kwargs)[0]
