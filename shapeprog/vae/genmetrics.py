"""Generation metrics of ShapeAssembly models: parts, realism, Fréchet distance, chamfer coverage, novelty.

The metrics of the ShapeAssembly paper's generation tables (Table 2: % rooted, % stable, % fool, FD;
Table 4: generalization, coverage, variety; Table 5: leaf parts) and the share of novel programs. They take
executed shapes (leaf ``corners (L, 8, 3)``), point clouds or programs, never a model, so any generator can
be measured. :func:`shapeprog.vae.gentable.generation_table` puts them into one markdown table. Every definition
and the choices taken where the paper is vague: ``docs/generation_metrics.md``.

* :func:`leaf_parts`: leaf cuboids of an executed program.
* :func:`frechet_distance` between Gaussian fits of two feature sets (:func:`classifier_features`: the
  global feature of this project's PointNet classifier); :func:`feature_variance` (the reference's
  "variance").
* :func:`percent_fool`: how often a freshly trained binary PointNet mistakes held-out shapes.
* :func:`nearest_chamfer` and its means :func:`generalization`, :func:`coverage`, :func:`variety` on
  scale-normalised clouds (:func:`chamfer_clouds`).
* :func:`novelty`: the share of programs whose text is not a training program's.

Example:
    >>> import numpy as np
    >>> a = np.random.default_rng(0).normal(size=(200, 4))
    >>> round(frechet_distance(a, a), 6), frechet_distance(a, a + 1.0) > 3.9
    (0.0, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Optional, Sequence

import numpy as np
import torch

from ..parallel import ordered_map
from ..errors import ExecutionError, ParseError
from ..execute import ExecutedShape, execute, execute_batch
from ..lang import Program, to_text
from ..sampling import sample_surface
from .pointnet import global_features, load_classifier, fit_classifier, predict
from .structure import _program

__all__ = ["CLASSIFIER_POINTS", "CHAMFER_POINTS", "FoolResult", "chamfer_clouds", "classifier_clouds",
           "classifier_features", "coarse_fields", "coverage", "execute_samples", "feature_variance", "frechet_distance",
           "gaussian_fit", "generalization", "leaf_parts", "nearest_chamfer", "novelty", "percent_fool",
           "program_key", "variety"]

#: Surface samples per shape for the PointNet metrics (the reference's 2,500).
CLASSIFIER_POINTS = 2500
#: Surface samples per shape for the chamfer metrics of Table 4.
CHAMFER_POINTS = 1024


# --------------------------------------------------------------------------------------------------
# programs -> executed shapes -> clouds


def execute_samples(samples: Iterable, batch: int = 200) -> tuple[list[Optional[torch.Tensor]], list[str]]:
    """Parse (texts) and execute programs; the leaf corners of each, or None where it fails.

    Args:
        samples: ``Program`` objects or program texts (corpus or flat format).
        batch: programs per :func:`shapeprog.execute_batch` call (a failing batch is retried one by one).

    Returns:
        ``(corners, errors)``: per sample ``(L, 8, 3) float32`` leaf corners (no grad) or None when the
        program does not parse, does not execute, or has no leaf cuboid; and one line per failure
        (``sample 12: ...``).
    """
    programs: list[Optional[Program]] = []
    errors: list[str] = []
    for i, item in enumerate(samples):
        try:
            programs.append(_program(item, f"sample {i}"))
        except ParseError as e:
            programs.append(None)
            errors.append(str(e))
    out: list[Optional[torch.Tensor]] = [None] * len(programs)
    ok = [i for i, p in enumerate(programs) if p is not None]
    with torch.no_grad():
        for s in range(0, len(ok), batch):
            rows = ok[s:s + batch]
            try:
                shapes = execute_batch([programs[i] for i in rows])
            except (ExecutionError, ValueError):
                shapes = []
                for i in rows:
                    try:
                        shapes.append(execute(programs[i]))
                    except (ExecutionError, ValueError) as e:
                        shapes.append(None)
                        errors.append(f"sample {i}: {e}")
            for i, shape in zip(rows, shapes):
                if shape is None:
                    continue
                if len(shape) == 0:
                    errors.append(f"sample {i}: no leaf cuboid")
                elif not torch.isfinite(shape.corners).all():
                    errors.append(f"sample {i}: non-finite corners")
                else:
                    out[i] = shape.corners.detach().float()
    return out, errors


def leaf_parts(item) -> int:
    """Leaf cuboids of an executed program (bbox cuboids excluded).

    ``item`` is a ``Program``, program text, an :class:`~shapeprog.execute.ExecutedShape` or corners
    ``(L, 8, 3)``. This equals the reference's ``gen_metrics`` part count, vertices / 8 of the exported
    mesh (8 vertices per leaf cuboid).
    """
    if isinstance(item, ExecutedShape):
        return len(item)
    if isinstance(item, (Program, str)):
        with torch.no_grad():
            return len(execute(_program(item, "<program>")))
    shape = tuple(getattr(item, "shape", ()))
    if len(shape) != 3 or shape[1:] != (8, 3):
        raise TypeError(f"expected a Program, text, ExecutedShape or (L, 8, 3) corners, got {type(item).__name__} "
                        f"{shape or ''}")
    return shape[0]


def _generator(seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(int(seed))


def classifier_clouds(corners: Sequence[torch.Tensor], n: int = CLASSIFIER_POINTS, seed: int = 0) -> torch.Tensor:
    """Clouds for the PointNet metrics, ``(S, n, 3) float32``: each shape is moved so that the per-axis
    mean of its corners (its mesh's vertices) is the origin, then ``n`` surface points are sampled
    (area-weighted, :func:`shapeprog.sampling.sample_surface`). No scaling (the corpus shapes are
    already normalised, PartNet's unit). One generator seeded with ``seed`` draws every shape in order."""
    g = _generator(seed)
    out = torch.empty(len(corners), n, 3)
    for i, c in enumerate(corners):
        c = torch.as_tensor(c).detach().float()
        out[i] = sample_surface(c - c.reshape(-1, 3).mean(0), n, generator=g)[0]
    return out


def chamfer_clouds(corners: Sequence[torch.Tensor], n: int = CHAMFER_POINTS, seed: int = 0) -> torch.Tensor:
    """Scale-normalised clouds for the chamfer metrics, ``(S, n, 3) float32``: each shape is moved so that
    the centre of its axis-aligned bounding box (over the leaf corners) is the origin and scaled so that
    the box's diagonal is 1, then ``n`` surface points are sampled. Every point lies in ``[-0.5, 0.5]^3``."""
    g = _generator(seed)
    out = torch.empty(len(corners), n, 3)
    for i, c in enumerate(corners):
        c = torch.as_tensor(c).detach().double().reshape(-1, 3)
        lo, hi = c.min(0).values, c.max(0).values
        diag = float((hi - lo).norm())
        if not diag > 0:
            raise ValueError(f"shape {i}: its bounding box has zero diagonal")
        unit = ((c - (lo + hi) / 2) / diag).reshape(-1, 8, 3)
        out[i] = sample_surface(unit, n, generator=g)[0].float()
    return out


# --------------------------------------------------------------------------------------------------
# classifier features: Fréchet distance and variance


def classifier_features(shapes, model=None, batch_size: int = 32, seed: int = 0) -> np.ndarray:
    """Global PointNet features ``(S, D) float64`` of shapes.

    Args:
        shapes: clouds ``(S, N, 3)`` prepared as :func:`classifier_clouds` does, or a sequence of leaf
            corners ``(L, 8, 3)`` (sampled here with 2,500 points and ``seed``).
        model: a :class:`~shapeprog.vae.pointnet.PointNetCls`; default the shipped classifier
            (:func:`shapeprog.vae.pointnet.load_classifier`).
    """
    if model is None:
        model = load_classifier()[0]
    clouds = shapes if isinstance(shapes, torch.Tensor) else classifier_clouds(shapes, seed=seed)
    return global_features(model, clouds, batch_size).double().numpy()


def gaussian_fit(features) -> tuple[np.ndarray, np.ndarray]:
    """Mean ``(D,)`` and covariance ``(D, D)`` (unbiased, ``N - 1``) of features ``(S, D)``, float64.

    The linear algebra here and in :func:`frechet_distance` runs in torch (float64), so it follows
    torch's thread setting (``torch.set_num_threads``) instead of NumPy's BLAS threads."""
    f = torch.as_tensor(np.asarray(features, dtype=np.float64))
    if f.dim() != 2 or f.shape[0] < 2:
        raise ValueError(f"features must have shape (S, D) with S >= 2, got {tuple(f.shape)}")
    if not torch.isfinite(f).all():
        raise ValueError("features contain NaN or infinite values")
    x = f - f.mean(0)
    return f.mean(0).numpy(), (x.T @ x / (f.shape[0] - 1)).numpy()


def _fit(x) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(x, tuple) and len(x) == 2:
        mu, cov = (np.asarray(v, dtype=np.float64) for v in x)
        if mu.ndim != 1 or cov.shape != (mu.shape[0], mu.shape[0]):
            raise ValueError(f"a Gaussian fit must be (mu (D,), cov (D, D)), got {mu.shape} and {cov.shape}")
        return mu, cov
    return gaussian_fit(x.numpy() if isinstance(x, torch.Tensor) else x)


def _psd_sqrt(s: torch.Tensor) -> torch.Tensor:
    w, v = torch.linalg.eigh((s + s.T) / 2)
    return (v * w.clamp_min(0.0).sqrt()) @ v.T


def frechet_distance(a, b, method: str = "eigh") -> float:
    """Fréchet distance between Gaussian fits of two feature sets (Heusel et al., the FID formula).

    ``|mu_a - mu_b|^2 + tr(S_a) + tr(S_b) - 2 tr((S_a S_b)^(1/2))``, in float64. Symmetric, 0 for a set
    and itself; tiny negative round-off is returned as 0. Its value depends on the feature extractor:
    distances are comparable only when computed with the same classifier.

    Args:
        a, b: features ``(S, D)`` (arrays or tensors, ``S >= 2``) or precomputed fits ``(mu, cov)``
            (:func:`gaussian_fit`).
        method: how ``tr((S_a S_b)^(1/2))`` is computed:

            * ``"eigh"`` (default): ``sum_i sqrt(l_i)`` over the eigenvalues of the symmetric PSD matrix
              ``S_a^(1/2) S_b S_a^(1/2)``, which has the same eigenvalues as ``S_a S_b``. Real and stable
              also when the covariances are singular (fewer shapes than feature dimensions).
            * ``"sqrtm"``: ``scipy.linalg.sqrtm(S_a S_b)`` as pytorch-fid does it: when the root is not
              finite both covariances get ``1e-6`` on the diagonal; the real part is kept if the
              imaginary part of its diagonal is below ``1e-3``, otherwise ``ValueError``.

    Returns:
        The distance (float, in squared feature units).
    """
    mu1, s1 = _fit(a)
    mu2, s2 = _fit(b)
    if mu1.shape != mu2.shape:
        raise ValueError(f"feature sizes differ: {mu1.shape[0]} and {mu2.shape[0]}")
    if method == "eigh":
        r = _psd_sqrt(torch.from_numpy(s1))
        m = r @ torch.from_numpy(s2) @ r
        tr_covmean = float(torch.linalg.eigvalsh((m + m.T) / 2).clamp_min(0.0).sqrt().sum())
    elif method == "sqrtm":
        from scipy import linalg  # lazy: scipy.linalg costs import time

        covmean = linalg.sqrtm(s1 @ s2)
        if not np.isfinite(covmean).all():
            offset = np.eye(s1.shape[0]) * 1e-6
            covmean = linalg.sqrtm((s1 + offset) @ (s2 + offset))
        if np.iscomplexobj(covmean):
            if not np.allclose(np.diagonal(covmean).imag, 0, atol=1e-3):
                raise ValueError(f"sqrtm gave an imaginary component of {np.abs(covmean.imag).max():.3g}; "
                                 "use method='eigh'")
            covmean = covmean.real
        tr_covmean = float(np.trace(covmean))
    else:
        raise ValueError(f"`method` must be 'eigh' or 'sqrtm', got {method!r}")
    d = float(((mu1 - mu2) ** 2).sum() + np.trace(s1) + np.trace(s2) - 2.0 * tr_covmean)
    return max(d, 0.0)


def feature_variance(features) -> float:
    """The reference's "variance": the mean over feature dimensions of the variance across shapes
    (population variance, ``ddof = 0``) of features ``(S, D)``."""
    f = np.asarray(features, dtype=np.float64)
    if f.ndim != 2 or f.shape[0] < 1:
        raise ValueError(f"features must have shape (S, D) with S >= 1, got {f.shape}")
    return float(f.var(axis=0).mean())


# --------------------------------------------------------------------------------------------------
# % fool


@dataclass
class FoolResult:
    """The outcome of :func:`percent_fool` (all rates are percentages of held-out shapes).

    Attributes:
        percent: held-out shapes (generated and real, equal numbers) misclassified, averaged over the
            last epochs: the "% fool" of the tables (50 when the classifier cannot tell them apart).
        generated_as_real: held-out generated shapes classified as real, same average.
        real_as_generated: held-out real shapes classified as generated, same average.
        per_epoch: ``percent`` of each averaged epoch.
        train: shapes of each kind the classifier was trained on.
        held_out: held-out shapes of each kind.
    """

    percent: float
    generated_as_real: float
    real_as_generated: float
    per_epoch: list = field(default_factory=list)
    train: int = 0
    held_out: int = 0


def percent_fool(
    generated: torch.Tensor,
    real: torch.Tensor,
    epochs: int = 12,
    average_last: int = 4,
    holdout: float = 0.2,
    points: Optional[int] = None,
    batch_size: int = 32,
    lr: float = 1e-3,
    seed: int = 0,
    log=None,
    **model_kwargs,
) -> FoolResult:
    """Realism: how often a binary PointNet, trained to tell generated from real shapes, gets held-out
    shapes wrong.

    ``n = min(len(generated), len(real))`` clouds of each kind are drawn at random (seeded); a fraction
    ``holdout`` of each kind is held out, and a fresh :class:`~shapeprog.vae.pointnet.PointNetCls` (k = 2) is
    trained on the rest for ``epochs`` epochs (:func:`shapeprog.vae.pointnet.fit_classifier`). After each of
    the last ``average_last`` epochs the held-out shapes are classified; the result is the percentage
    misclassified, averaged over those epochs.

    Args:
        generated: clouds ``(G, N, 3)`` of generated shapes (:func:`classifier_clouds`).
        real: clouds ``(R, N, 3)`` of training-set shapes, prepared the same way.
        epochs, average_last: the budget (the paper: 300 epochs, the last 50 averaged).
        holdout: fraction of each kind held out (at least one shape each).
        points: points per cloud and training visit (a random subset; all when None); held-out clouds
            are classified with their first ``points`` points (the samples are i.i.d.).
        batch_size, lr, seed, log, **model_kwargs: see :func:`shapeprog.vae.pointnet.fit_classifier`.

    Returns:
        A :class:`FoolResult`.
    """
    if not 1 <= average_last <= epochs:
        raise ValueError(f"`average_last` must lie in [1, epochs={epochs}], got {average_last}")
    if not 0.0 < holdout < 1.0:
        raise ValueError(f"`holdout` must lie in (0, 1), got {holdout}")
    n = min(len(generated), len(real))
    h = max(1, int(round(holdout * n)))
    if n - h < 2:
        raise ValueError(f"% fool needs at least 3 shapes of each kind, got {len(generated)} generated and {len(real)} real")
    g = _generator(seed)
    gen = generated[torch.randperm(len(generated), generator=g)[:n]]
    rel = real[torch.randperm(len(real), generator=g)[:n]]
    train = torch.cat([rel[h:], gen[h:]])
    labels = torch.cat([torch.zeros(n - h, dtype=torch.long), torch.ones(n - h, dtype=torch.long)])
    test = torch.cat([rel[:h], gen[:h]])
    if points is not None:
        test = test[:, :points]
    truth = torch.cat([torch.zeros(h, dtype=torch.long), torch.ones(h, dtype=torch.long)])
    rates = []

    def on_epoch(epoch: int, model, loss: float) -> None:
        if epoch >= epochs - average_last:
            pred = predict(model, test, batch_size)
            wrong = (pred != truth).double()
            rates.append((100 * float(wrong.mean()), 100 * float(wrong[h:].mean()), 100 * float(wrong[:h].mean())))

    fit_classifier(train, labels, k=2, epochs=epochs, batch_size=batch_size, lr=lr, points=points, seed=seed,
                   on_epoch=on_epoch, log=log, **model_kwargs)
    mean = np.asarray(rates).mean(axis=0)
    return FoolResult(float(mean[0]), float(mean[1]), float(mean[2]), [r[0] for r in rates], n - h, h)


# --------------------------------------------------------------------------------------------------
# chamfer to the nearest shape: generalization, coverage, variety

#: Grid vertices per axis of the coarse stage of :func:`nearest_chamfer`.
COARSE_GRID = 24
_REF_CHUNK = 256


def _grid_vertices(res: int) -> np.ndarray:
    t = np.linspace(-0.5, 0.5, res)
    return np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)


def coarse_fields(clouds: torch.Tensor, res: int = COARSE_GRID) -> tuple[torch.Tensor, torch.Tensor]:
    """The coarse stage of :func:`nearest_chamfer` for clouds ``(S, N, 3) float`` in ``[-0.5, 0.5]^3``.

    Returns:
        ``splat (S, V) float32``: trilinear weights of each cloud's points on the ``res^3`` lattice over
        ``[-0.5, 0.5]^3`` (each row sums to 1; points outside are clamped to the box), and
        ``field (S, V) float32``: the distance from every lattice vertex to the nearest cloud point,
        ``V = res^3``. ``splat_q @ field_r + splat_r @ field_q`` estimates the chamfer distance of two
        clouds (one side of each direction replaced by the interpolated field).
    """
    s, n, _ = clouds.shape
    verts = _grid_vertices(res)
    df = np.empty((s, res ** 3), dtype=np.float32)
    for i in range(s):
        df[i] = _tree(clouds[i].double().numpy()).query(verts, k=1)[0]
    u = ((clouds.double() + 0.5) * (res - 1)).clamp(0, res - 1)
    i0 = u.floor().long().clamp(max=res - 2)
    f = u - i0
    splat = torch.zeros(s, res ** 3, dtype=torch.float64)
    for corner in range(8):
        bits = [(corner >> (2 - a)) & 1 for a in range(3)]
        w = torch.ones(s, n, dtype=torch.float64)
        idx = torch.zeros(s, n, dtype=torch.long)
        for a, bit in enumerate(bits):
            w = w * (f[..., a] if bit else 1 - f[..., a])
            idx = idx * res + i0[..., a] + bit
        splat.scatter_add_(1, idx, w / n)
    return splat.float(), torch.from_numpy(df)


def _coarse_job(job) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`coarse_fields` of ``(clouds, res)``: one job of the coarse stage."""
    return coarse_fields(*job)


def _tree(points: np.ndarray):
    from scipy.spatial import cKDTree  # lazy: scipy.spatial costs import time

    return cKDTree(points, leafsize=16, balanced_tree=False, compact_nodes=False)


def _fine_job(job) -> list[list[float]]:
    """Exact chamfer (float64) of every query ``(c, N, 3)`` against its candidates: ``clouds (u, M, 3)``
    (each distinct candidate once) and ``local (c, k)`` indices into them."""
    queries, clouds, local = job
    trees = [None] * len(clouds)
    arrays = [x.double().numpy() for x in clouds]
    out = []
    for q, row_ids in zip(queries, local.tolist()):
        qn = q.double().numpy()
        tq = _tree(qn)
        row = []
        for j in row_ids:
            if trees[j] is None:
                trees[j] = _tree(arrays[j])
            row.append(float(trees[j].query(qn, k=1)[0].mean() + tq.query(arrays[j], k=1)[0].mean()))
        out.append(row)
    return out


def _fine_jobs(queries: torch.Tensor, refs: torch.Tensor, cand: torch.Tensor, chunk: int):
    """Jobs of :func:`_fine_job`, made one at a time: at most about 4M candidate points each."""
    rows = max(1, min(chunk, (1 << 22) // max(1, cand.shape[1] * refs.shape[1])))
    for s in range(0, len(queries), rows):
        ids, local = torch.unique(cand[s:s + rows], return_inverse=True)
        yield queries[s:s + rows], refs[ids], local


def _check_unit_clouds(x, name: str) -> torch.Tensor:
    if not isinstance(x, torch.Tensor) or x.dim() != 3 or x.shape[2] != 3 or x.shape[0] == 0 or x.shape[1] == 0:
        raise ValueError(f"`{name}` must be a (S, N, 3) float tensor with S, N >= 1, got "
                         f"{tuple(getattr(x, 'shape', ())) or type(x).__name__}")
    if x.abs().max() > 0.5 + 1e-5:
        raise ValueError(f"`{name}` must lie in [-0.5, 0.5]^3 (clouds from chamfer_clouds)")
    return x.detach().float()


def nearest_chamfer(
    queries: torch.Tensor,
    refs: Optional[torch.Tensor] = None,
    candidates: Optional[int] = 16,
    grid: int = COARSE_GRID,
    executor=None,
    chunk: int = 32,
) -> tuple[np.ndarray, np.ndarray]:
    """Chamfer distance from every query cloud to its nearest reference cloud.

    The distance is :func:`shapeprog.metrics.chamfer` with ``eps = 0``: the mean distance from each point
    to the nearest point of the other cloud, summed over both directions, on clouds that
    :func:`chamfer_clouds` normalised to unit bounding-box diagonal.

    The search runs in two stages. A coarse estimate of every pair replaces one side of each direction
    by a grid: the distance from each vertex of a ``grid^3`` lattice over ``[-0.5, 0.5]^3`` to the
    nearest cloud point, trilinearly interpolated at the other cloud's points. All pairs then cost one
    matrix product of splat weights and distance fields. The ``candidates`` references with the smallest
    estimates are then measured exactly, and the smallest exact distance is kept. With
    ``candidates=None`` (or at least as many as there are references) every pair is measured exactly.
    ``bench/bench_genmetrics.py --check-recall`` compares the two.

    Args:
        queries: ``(Q, N, 3) float`` clouds in ``[-0.5, 0.5]^3``.
        refs: ``(R, M, 3) float`` clouds; None compares the queries with each other, excluding each
            query itself (variety).
        candidates: references measured exactly per query.
        grid: lattice vertices per axis of the coarse stage.
        executor: a ``concurrent.futures.Executor`` for the per-shape work (grid distance fields in
            chunks of shapes, exact chamfers in chunks of ``chunk`` queries); None runs it here.
        chunk: queries per exact-stage job.

    Returns:
        ``(dist (Q,) float64, idx (Q,) int64)``: the distance to and the index of the nearest reference.
    """
    queries = _check_unit_clouds(queries, "queries")
    self_match = refs is None
    refs = queries if self_match else _check_unit_clouds(refs, "refs")
    if self_match and len(queries) < 2:
        raise ValueError("comparing clouds with each other needs at least 2 clouds")
    n_ref = len(refs) - (1 if self_match else 0)
    k = n_ref if candidates is None else max(1, min(int(candidates), n_ref))
    if k >= n_ref:
        cand = torch.arange(len(refs)).expand(len(queries), -1)
        if self_match:
            keep = ~torch.eye(len(queries), dtype=torch.bool)
            cand = cand[keep].reshape(len(queries), -1)
    else:
        cand = _coarse_candidates(queries, refs, self_match, k, int(grid), executor)
    parts = ordered_map(executor, _fine_job, _fine_jobs(queries, refs, cand, chunk))
    exact = torch.tensor([row for part in parts for row in part], dtype=torch.float64)
    best = exact.argmin(dim=1)
    dist = exact.gather(1, best[:, None])[:, 0]
    return dist.numpy(), cand.gather(1, best[:, None])[:, 0].numpy()


def _coarse_candidates(queries, refs, self_match: bool, k: int, res: int, executor) -> torch.Tensor:
    """Indices ``(Q, k)`` of the references with the smallest coarse chamfer estimates."""
    chunks = lambda x: ((x[s:s + _REF_CHUNK], res) for s in range(0, len(x), _REF_CHUNK))  # noqa: E731
    parts = list(ordered_map(executor, _coarse_job, chunks(queries)))
    hq, dq = torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])
    best_val = torch.full((len(queries), 0), math.inf)
    best_idx = torch.zeros((len(queries), 0), dtype=torch.long)
    ref_parts = [(hq, dq)] if self_match else None
    start = 0
    for hr, dr in (ref_parts or ordered_map(executor, _coarse_job, chunks(refs))):
        est = hq @ dr.T + dq @ hr.T  # (Q, chunk): queries to refs + refs to queries
        cols = torch.arange(start, start + est.shape[1])
        if self_match:
            est[torch.arange(len(queries))[:, None] == cols[None]] = math.inf
        val = torch.cat([best_val, est], 1)
        idx = torch.cat([best_idx, cols.expand(len(queries), -1)], 1)
        top = val.topk(min(k, val.shape[1]), dim=1, largest=False)
        best_val, best_idx = top.values, idx.gather(1, top.indices)
        start += est.shape[1]
    return best_idx


def generalization(generated: torch.Tensor, train: torch.Tensor, **kwargs) -> float:
    """Mean over generated clouds of the chamfer distance to the nearest training cloud (higher: less
    copying). ``kwargs`` go to :func:`nearest_chamfer`."""
    return float(nearest_chamfer(generated, train, **kwargs)[0].mean())


def coverage(reference: torch.Tensor, generated: torch.Tensor, **kwargs) -> float:
    """Mean over reference (validation) clouds of the chamfer distance to the nearest generated cloud
    (lower: the generated set covers the references better)."""
    return float(nearest_chamfer(reference, generated, **kwargs)[0].mean())


def variety(generated: torch.Tensor, **kwargs) -> float:
    """Mean over generated clouds of the chamfer distance to the nearest *other* generated cloud
    (higher: more varied)."""
    return float(nearest_chamfer(generated, None, **kwargs)[0].mean())


# --------------------------------------------------------------------------------------------------
# novelty


def program_key(item, decimals: int = 3) -> str:
    """The text a program is compared by: :func:`shapeprog.to_text` of the parsed program with every
    number rounded to ``decimals`` (the corpus writes 3), so spacing, number spelling (``1`` / ``1.0``)
    and float noise below the corpus precision do not count as differences."""
    return to_text(_program(item, "<program>"), decimals=decimals)


def novelty(samples: Iterable, training: Iterable, decimals: int = 3) -> float:
    """Percentage of ``samples`` (programs or texts) whose :func:`program_key` is no training program's.

    Raises:
        ParseError: a text that does not parse (pass only valid programs).
    """
    known = {program_key(p, decimals) for p in training}
    keys = [program_key(p, decimals) for p in samples]
    if not keys:
        raise ValueError("no sample to measure")
    return 100.0 * sum(k not in known for k in keys) / len(keys)
