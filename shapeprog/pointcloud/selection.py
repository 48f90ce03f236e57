"""How close candidate programs are to an input cloud (:func:`selection_scores`), and which up axis makes a cloud
look like a category's training shapes (:func:`orientation_scores`, :func:`warn_up_axis`): what the robust method of
:func:`shapeprog.pointcloud.infer.infer` chooses by."""
from __future__ import annotations

import math
import warnings

import numpy as np
import torch

from .normalize import normalize

__all__ = ["FSCORE_THRESHOLD", "SELECT_POINTS", "UP_CANDIDATES", "UP_SHORTLIST", "UP_RATIO", "UpAxisWarning",
           "selection_scores", "orientation_scores", "warn_up_axis"]

#: The F-score's distance threshold, canonical units (AABB diagonal 2): the papers' 0.03.
FSCORE_THRESHOLD = 0.03
#: Points of the input, and surface samples of each candidate, in the robust method's selection score.
SELECT_POINTS = 2048
#: Up axes :func:`orientation_scores` compares (``up="auto"`` chooses among them).
UP_CANDIDATES = ("y", "z", "x")
#: Training programs per orientation in :func:`orientation_scores`.
UP_SHORTLIST = 4
#: :func:`infer` warns when another orientation's chamfer distance to its nearest training shapes is below this
#: share of the kept program's chamfer distance to the cloud. On the first 8 test chairs the right orientation's
#: nearest training cloud was at most 0.61 times as far as either wrong one's (chamfer 58-124 x1000 against
#: 173-243); a z-up box chair read y-up: 0.32.
UP_RATIO = 0.7


class UpAxisWarning(UserWarning):
    """The cloud matches the category's shapes clearly better with another up axis than the one given."""


def selection_scores(clouds, target: torch.Tensor, threshold: float = FSCORE_THRESHOLD) -> list:
    """``[fscore, cd]`` of each candidate cloud ``(M_i, 3)`` (None: no shape, scored ``[0, inf]``) against
    ``target`` ``(N, 3)``: the F-score at ``threshold`` (0-100) and the chamfer distance (unsquared, both
    directions, as :func:`shapeprog.metrics.chamfer` with ``eps = 0``), by k-d trees in float64."""
    from scipy.spatial import cKDTree  # lazy: scipy.spatial costs import time

    tgt = np.asarray(torch.as_tensor(target, dtype=torch.float64))
    tree = cKDTree(tgt)
    out = []
    for c in clouds:
        if c is None or len(c) == 0:
            out.append([0.0, math.inf])
            continue
        p = np.asarray(torch.as_tensor(c, dtype=torch.float64))
        d_pt = tree.query(p, k=1)[0]
        d_tp = cKDTree(p).query(tgt, k=1)[0]
        prec, rec = 100.0 * float(np.mean(d_pt < threshold)), 100.0 * float(np.mean(d_tp < threshold))
        f = 2 * prec * rec / (prec + rec + 1e-8)
        out.append([f, float(d_pt.mean() + d_tp.mean())])
    return out


def warn_up_axis(x: np.ndarray, kept_chamfer: float, up: str, index, seed: int) -> dict:
    """Warn (:class:`UpAxisWarning`) when another orientation of :data:`UP_CANDIDATES` brings the cloud nearer to
    the training shapes than the kept program (chamfer ``kept_chamfer``) is with ``up``, by the factor :data:`UP_RATIO` in
    chamfer distance; the chamfer distances, ``up``'s being the kept program's."""
    others = tuple(u for u in UP_CANDIDATES if u != up)
    scores = orientation_scores(x, index, seed, others)
    scores[up] = kept_chamfer
    best = min(scores, key=lambda u: scores[u])
    if scores[best] < UP_RATIO * scores[up]:
        warnings.warn(f"the cloud matches the training shapes far better with up={best!r} than with up={up!r} "
                      f"(chamfer x1000 {1000 * scores[best]:.0f} against {1000 * scores[up]:.0f}): pass up={best!r} "
                      f"(command line: --up {best})", UpAxisWarning, stacklevel=3)
    return scores


def orientation_scores(points, index, seed: int = 0, ups=UP_CANDIDATES) -> dict:
    """How well a cloud matches a category's training shapes with each up axis of :data:`UP_CANDIDATES`:
    ``{up: chamfer}`` for each of ``ups``, the smallest :func:`selection_scores` chamfer distance of the
    :data:`UP_SHORTLIST` training clouds of
    ``index`` that its coarse stage puts nearest to the cloud normalised with that ``up`` (:data:`SELECT_POINTS`
    points drawn with ``seed``). A chair lying on its back matches no training chair well; standing, it matches
    some closely.

    Args:
        points: ``(N, 3)`` float, the cloud in its own frame.
        index: a :class:`~shapeprog.pointcloud.retrieval.RetrievalIndex`.
        seed: the draw of the points.
    """
    x = np.asarray(points, dtype=np.float64)
    pick = np.random.default_rng(int(seed)).permutation(len(x))[:SELECT_POINTS]
    out = {}
    for up in ups:
        unit, _ = normalize(x[pick], up=up)
        target = torch.from_numpy(unit)
        refs = [index.reference_cloud(m.id)[:SELECT_POINTS] for m in index.shortlist(target, UP_SHORTLIST)]
        out[up] = min(cd for _, cd in selection_scores(refs, target))
    return out
