"""The point-cloud operations of PointNet++ in plain PyTorch: farthest-point sampling, ball query, grouping.

Every function takes batches, runs on the tensors' device (CPU or GPU) and needs no compiled extension.
Clouds are ``(B, N, 3)`` float and per-point features are channel-last too, ``(B, N, C)``; indices are
``int64``. (The reference keeps features channel-first, ``(B, C, N)``, for its 1x1 convolutions;
channel-last rows feed matrix products directly, which made a CPU training step about a quarter
cheaper, see :mod:`shapeprog.pointcloud.encoder`.)

* :func:`farthest_point_sample` ``(B, N, 3) -> (B, M)``: starts at point 0 of every cloud, as the
  reference CUDA kernel does, then repeatedly takes the point farthest from those already taken.
* :func:`ball_query` ``(B, N, 3), (B, M, 3) -> (B, M, K)``: the first K points, in index order,
  strictly inside a ball round each centre; short lists are padded by repeating their first point; a
  ball that holds no point gets the cloud's nearest point K times.
* :func:`gather_points` / :func:`group_points`: features of the chosen points, ``(B, M, C)`` /
  ``(B, M, K, C)``; differentiable with respect to the features.
* :func:`query_and_group`: ball query, then the neighbours' coordinates relative to their centre
  and their features, ``(B, M, K, 3 + C)``; :func:`group_all`: the whole cloud as one group
  ``(B, 1, N, 3 + C)``, coordinates relative to the origin.

Sampling and ball query are not differentiable (they return indices) and run without autograd.
Differences from the reference kernels, all deliberate: ties in farthest-point sampling go to the
lowest index (the kernel's answer depends on its thread layout); points near the origin are not
skipped (the kernel never picks a point with ``|p|^2 <= 1e-3`` after the first); an empty ball gets
its nearest point instead of point 0. How fast they are on CPU: ``docs/benchmarks.md``.

Example:
    >>> import torch
    >>> xyz = torch.tensor([[[0.0, 0, 0], [1, 0, 0], [0.1, 0, 0], [2, 0, 0]]])
    >>> farthest_point_sample(xyz, 2).tolist()
    [[0, 3]]
    >>> ball_query(0.5, 3, xyz, xyz[:, [0, 3]]).tolist()  # point 3's ball holds only itself
    [[[0, 2, 0], [3, 3, 3]]]
"""
from __future__ import annotations

import contextlib
from typing import Iterator, Optional

import torch

from shapeprog.errors import PointCloudError

__all__ = ["CHUNK_ELEMENTS", "CHUNK_ELEMENTS_GPU", "ball_query", "farthest_point_sample", "gather_points", "group_all",
           "group_points", "query_and_group"]

#: Centre-point pairs that :func:`ball_query` tests at once on the CPU (4 MiB of float32 distances): a
#: block that stays in cache was faster than larger ones on the 2-core benchmark machine.
CHUNK_ELEMENTS = 1 << 20
#: The same on a GPU (256 MiB of float32 distances): one block for the encoder's sizes.
CHUNK_ELEMENTS_GPU = 1 << 26


# --------------------------------------------------------------------------------------------------
# checks


def _check_cloud(x, name: str, min_points: int = 1) -> torch.Tensor:
    """``x`` is a finite float ``(B, N, 3)`` tensor with ``N >= min_points``."""
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"`{name}` must be a torch.Tensor of shape (B, N, 3), got {type(x).__name__}")
    if x.dim() != 3 or x.shape[2] != 3:
        raise PointCloudError(f"must have shape (B, N, 3), got {tuple(x.shape)}", name)
    if not x.is_floating_point():
        raise PointCloudError(f"must be a floating-point tensor, got {x.dtype}", name)
    if x.shape[1] < min_points:
        raise PointCloudError(f"has {x.shape[1]} points per cloud, fewer than the {min_points} needed", name)
    bad = ~torch.isfinite(x.detach()).flatten(1).all(1)
    if bad.any():
        raise PointCloudError("a coordinate is not finite (NaN or infinite)", name, int(bad.nonzero()[0]))
    return x


def _check_count(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"`{name}` must be a positive int, got {value!r}")
    return value


def _check_radius(radius) -> float:
    if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not radius >= 0 or radius == float("inf"):
        raise ValueError(f"`radius` must be a finite number >= 0, got {radius!r}")
    return float(radius)


def _check_batch(x: torch.Tensor, name: str, like: torch.Tensor, like_name: str) -> None:
    if x.shape[0] != like.shape[0]:
        raise PointCloudError(f"holds {x.shape[0]} clouds but `{like_name}` holds {like.shape[0]}", name)
    if x.device != like.device:
        raise PointCloudError(f"is on {x.device} but `{like_name}` is on {like.device}", name)


def _check_rows(features, name: str = "features") -> torch.Tensor:
    if not isinstance(features, torch.Tensor):
        raise TypeError(f"`{name}` must be a torch.Tensor of shape (B, N, C), got {type(features).__name__}")
    if features.dim() != 3:
        raise PointCloudError(f"must have shape (B, N, C), got {tuple(features.shape)}", name)
    return features


def _check_features(features, like: torch.Tensor, like_name: str) -> torch.Tensor:
    """``features`` is ``(B, N, C)`` for the B clouds of N points of ``like (B, N, 3)``."""
    _check_rows(features)
    if features.shape[1] != like.shape[1]:
        raise PointCloudError(f"must have shape (B, {like.shape[1]}, C) for the {like.shape[1]} points of "
                              f"`{like_name}`, got {tuple(features.shape)}", "features")
    _check_batch(features, "features", like, like_name)
    return features


def _check_index(idx, features: torch.Tensor, dims: int) -> torch.Tensor:
    shape = "(B, M)" if dims == 2 else "(B, M, K)"
    if not isinstance(idx, torch.Tensor):
        raise TypeError(f"`idx` must be a torch.Tensor of shape {shape}, got {type(idx).__name__}")
    if idx.dim() != dims or idx.dtype != torch.long:
        raise PointCloudError(f"must be an int64 tensor of shape {shape}, got {idx.dtype} {tuple(idx.shape)}", "idx")
    _check_batch(idx, "idx", features, "features")
    n = features.shape[1]
    if idx.numel() and (int(idx.min()) < 0 or int(idx.max()) >= n):
        raise PointCloudError(f"indices must lie in [0, {n}), got [{int(idx.min())}, {int(idx.max())}]", "idx")
    return idx


def _work_dtype(x: torch.Tensor) -> torch.Tensor:
    """Coordinates for distance arithmetic: float32 and float64 as they are, half precisions as float32."""
    return x if x.dtype in (torch.float32, torch.float64) else x.float()


# --------------------------------------------------------------------------------------------------
# sampling and ball query


@contextlib.contextmanager
def _one_cpu_thread(device: torch.device) -> Iterator[None]:
    """Run the block on one intra-op thread when on the CPU, then restore the calling thread's setting.

    Sampling and ball query are long chains of small operations. With two intra-op threads on the
    shared 2-core machine every one of them waited for a thread descheduled by other work:
    farthest-point sampling of 16 clouds of 2,048 points took 12 s instead of 0.07 s on one thread.
    """
    threads = torch.get_num_threads()
    if device.type != "cpu" or threads == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


@torch.no_grad()
def _farthest_point_sample(xyz: torch.Tensor, m: int) -> torch.Tensor:
    """:func:`farthest_point_sample` without the checks."""
    with _one_cpu_thread(xyz.device):
        return _fps_loop(xyz, m)


def _fps_loop(xyz: torch.Tensor, m: int) -> torch.Tensor:
    b, n, _ = xyz.shape
    p = _work_dtype(xyz.detach()).permute(2, 0, 1).contiguous()  # (3, B, N): one contiguous row per axis
    flat = p.view(3, b * n)
    offset = torch.arange(0, b * n, n, device=xyz.device)
    nearest = torch.full((b, n), float("inf"), dtype=p.dtype, device=p.device)  # squared distance to the chosen set
    diff, dist = torch.empty_like(p), torch.empty_like(nearest)
    far = torch.zeros(b, dtype=torch.long, device=xyz.device)
    chosen = [far]
    for _ in range(m - 1):
        centre = flat.index_select(1, far + offset).view(3, b, 1)
        torch.sub(p, centre, out=diff)
        diff.mul_(diff)
        torch.sum(diff, 0, out=dist)
        torch.minimum(nearest, dist, out=nearest)
        far = nearest.argmax(1)  # the first of equal maxima: ties go to the lowest index
        chosen.append(far)
    return torch.stack(chosen, 1)


def farthest_point_sample(xyz: torch.Tensor, m: int) -> torch.Tensor:
    """Indices of ``m`` points of each cloud spread out by farthest-point sampling.

    The first index is 0 (the reference CUDA kernel's start; permute a cloud for another start). Each
    next point is the one whose squared distance to the nearest already chosen point is largest; equal
    distances go to the lowest index, so the result depends only on the coordinates and their order.
    Once every distinct position is chosen the remaining picks repeat point 0's position (distance 0
    everywhere, lowest index first). Not differentiable; runs without autograd.

    Args:
        xyz: ``(B, N, 3)`` float, finite, with ``N >= m``.
        m: how many points to choose.

    Returns:
        ``(B, m) int64`` indices into the N points.

    Raises:
        PointCloudError: ``xyz`` has a wrong shape or dtype, a non-finite coordinate (naming the cloud),
            or fewer than ``m`` points.
    """
    _check_count(m, "m")
    _check_cloud(xyz, "xyz", min_points=m)
    return _farthest_point_sample(xyz, m)


@torch.no_grad()
def _ball_query(radius: float, nsample: int, xyz: torch.Tensor, centres: torch.Tensor,
                chunk_elements: Optional[int] = None) -> torch.Tensor:
    """:func:`ball_query` without the checks."""
    with _one_cpu_thread(xyz.device):
        return _ball_query_blocks(radius, nsample, xyz, centres, chunk_elements)


def _ball_query_blocks(radius: float, nsample: int, xyz: torch.Tensor, centres: torch.Tensor,
                       chunk_elements: Optional[int]) -> torch.Tensor:
    b, n, _ = xyz.shape
    m = centres.shape[1]
    k = nsample
    device = xyz.device
    p = _work_dtype(xyz.detach())
    c = _work_dtype(centres.detach()).to(p.dtype)
    px, py, pz = (p[..., i].unsqueeze(1) for i in range(3))  # (B, 1, N) each
    r2 = radius * radius
    if chunk_elements is None:
        chunk_elements = CHUNK_ELEMENTS if device.type == "cpu" else CHUNK_ELEMENTS_GPU
    rows_per_chunk = max(1, chunk_elements // max(1, b * n))
    out = torch.empty(b, m, k, dtype=torch.long, device=device)
    empty = torch.zeros(b, m, dtype=torch.bool, device=device)
    slots = torch.arange(k, device=device)
    for s in range(0, m, rows_per_chunk):
        e = min(m, s + rows_per_chunk)
        cc = c[:, s:e].unsqueeze(3)  # (B, m, 3, 1)
        d = torch.sub(cc[:, :, 0], px)  # (B, m, N): the squared distance, axis by axis
        d.mul_(d)
        t = torch.sub(cc[:, :, 1], py)
        d.addcmul_(t, t)
        torch.sub(cc[:, :, 2], pz, out=t)
        d.addcmul_(t, t)
        inside = (d < r2).view(-1, n)  # (B*m, N); one row per ball
        rows, cols = inside.nonzero(as_tuple=True)  # row-major: each ball's points in index order
        count = torch.bincount(rows, minlength=inside.shape[0])
        rank = torch.arange(rows.shape[0], device=device) - (count.cumsum(0) - count)[rows]
        keep = rank < k
        rows, cols, rank = rows[keep], cols[keep], rank[keep]
        first = torch.zeros(inside.shape[0], dtype=torch.long, device=device)
        lead = rank == 0
        first[rows[lead]] = cols[lead]
        block = torch.where(slots < count.unsqueeze(1), torch.zeros((), dtype=torch.long, device=device),
                            first.unsqueeze(1))  # pad with the first point found
        block[rows, rank] = cols
        out[:, s:e] = block.view(b, e - s, k)
        empty[:, s:e] = (count == 0).view(b, e - s)
    if empty.any():  # no point inside: the nearest point of the cloud, nsample times
        bi, mi = empty.nonzero(as_tuple=True)
        step = max(1, chunk_elements // max(1, n))
        for s in range(0, bi.shape[0], step):
            bb, mm = bi[s:s + step], mi[s:s + step]
            dist = (p[bb] - c[bb, mm].unsqueeze(1)).square().sum(-1)  # (E, N)
            out[bb, mm] = dist.argmin(1).unsqueeze(1).expand(-1, k)
    return out


def ball_query(radius: float, nsample: int, xyz: torch.Tensor, centres: torch.Tensor,
               chunk_elements: Optional[int] = None) -> torch.Tensor:
    """The first ``nsample`` points, in index order, strictly inside the ball round each centre.

    Point ``j`` is in the ball of centre ``c`` when ``(x_j - x_c)^2 + (y_j - y_c)^2 + (z_j - z_c)^2 <
    radius^2`` (computed in the coordinates' precision, half precisions in float32). A ball with fewer
    than ``nsample`` points repeats its first (lowest-index) point in the remaining slots, as the
    reference kernel pads. A ball with no point at all (a centre away from the cloud, or radius 0) gets
    the cloud's nearest point to the centre in every slot (the first of equally near points), so that
    every group has a point of its own neighbourhood; the reference kernel would give point 0.
    Not differentiable; runs without autograd. Centre-point distances are computed in blocks of about
    ``chunk_elements`` pairs, so memory stays bounded for large clouds.

    Args:
        radius: the ball's radius, ``>= 0``.
        nsample: slots per ball (K).
        xyz: ``(B, N, 3)`` float, finite.
        centres: ``(B, M, 3)`` float, finite (typically points of ``xyz`` chosen by
            :func:`farthest_point_sample`).
        chunk_elements: pairs per block (default :data:`CHUNK_ELEMENTS` on the CPU,
            :data:`CHUNK_ELEMENTS_GPU` elsewhere).

    Returns:
        ``(B, M, nsample) int64`` indices into the N points.

    Raises:
        PointCloudError: a wrong shape or dtype, a non-finite coordinate, clouds of different batch
            sizes or devices.
    """
    radius = _check_radius(radius)
    _check_count(nsample, "nsample")
    _check_cloud(xyz, "xyz")
    _check_cloud(centres, "centres", min_points=0)
    _check_batch(centres, "centres", xyz, "xyz")
    if chunk_elements is not None:
        _check_count(chunk_elements, "chunk_elements")
    return _ball_query(radius, nsample, xyz, centres, chunk_elements)


# --------------------------------------------------------------------------------------------------
# grouping


def _group(points: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Rows of ``points (B, N, C)`` at ``idx (B, *S)``: ``(B, *S, C)``, contiguous (one ``gather``)."""
    b, _, ch = points.shape
    flat = idx.reshape(b, -1, 1).expand(-1, -1, ch)
    return points.gather(1, flat).view(*idx.shape, ch)


def gather_points(features: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """The features of the points ``idx`` of each cloud: ``out[b, m] = features[b, idx[b, m]]``.

    Args:
        features: ``(B, N, C)``, any dtype (the coordinates themselves, ``C = 3``, give the chosen
            points); gradients flow back to it.
        idx: ``(B, M) int64`` in ``[0, N)``, e.g. from :func:`farthest_point_sample`.

    Returns:
        ``(B, M, C)``, the dtype and device of ``features``.

    Raises:
        PointCloudError: a wrong shape or dtype, different batch sizes or devices, an index out of range.
    """
    _check_index(idx, _check_rows(features), 2)
    return _group(features, idx)


def group_points(features: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """The features of each group's points: ``out[b, m, k] = features[b, idx[b, m, k]]``.

    Args:
        features: ``(B, N, C)``, any dtype; gradients flow back to it.
        idx: ``(B, M, K) int64`` in ``[0, N)``, e.g. from :func:`ball_query`.

    Returns:
        ``(B, M, K, C)``, the dtype and device of ``features``.

    Raises:
        PointCloudError: a wrong shape or dtype, different batch sizes or devices, an index out of range.
    """
    _check_index(idx, _check_rows(features), 3)
    return _group(features, idx)


def _query_and_group(xyz: torch.Tensor, centres: torch.Tensor, features: Optional[torch.Tensor], radius: float,
                     nsample: int, use_xyz: bool = True) -> torch.Tensor:
    """:func:`query_and_group` without the checks."""
    idx = _ball_query(radius, nsample, xyz, centres)
    if features is None:
        return _group(xyz, idx) - centres.unsqueeze(2)
    if not use_xyz:
        return _group(features, idx)
    grouped = _group(torch.cat([xyz.to(features.dtype), features], 2), idx)  # (B, M, K, 3 + C): one gather
    grouped[..., :3] -= centres.unsqueeze(2).to(features.dtype)  # relative to the centre
    return grouped


def query_and_group(xyz: torch.Tensor, centres: torch.Tensor, features: Optional[torch.Tensor], radius: float,
                    nsample: int, use_xyz: bool = True) -> torch.Tensor:
    """The neighbourhood of every centre: :func:`ball_query`, then :func:`group_points`.

    Channels are the neighbours' coordinates relative to their centre (``use_xyz``), then their
    features. Differentiable with respect to ``xyz``, ``centres`` and ``features`` (the choice of
    neighbours is not).

    Args:
        xyz: ``(B, N, 3)`` float, finite.
        centres: ``(B, M, 3)`` float, finite.
        features: ``(B, N, C)`` or None (coordinates only).
        radius, nsample: as in :func:`ball_query`.
        use_xyz: put the relative coordinates in front of the features (needed when ``features`` is None).

    Returns:
        ``(B, M, nsample, 3 + C)`` (``(B, M, nsample, C)`` without ``use_xyz``), the dtype of the
        features (of ``xyz`` without features).

    Raises:
        PointCloudError: a wrong shape or dtype, a non-finite coordinate, different batch sizes or devices.
        ValueError: ``use_xyz=False`` without features, or a bad radius or nsample.
    """
    radius = _check_radius(radius)
    _check_count(nsample, "nsample")
    _check_cloud(xyz, "xyz")
    _check_cloud(centres, "centres", min_points=0)
    _check_batch(centres, "centres", xyz, "xyz")
    if features is None and not use_xyz:
        raise ValueError("`use_xyz=False` needs features: without them a group would have no channel")
    if features is not None:
        _check_features(features, xyz, "xyz")
    return _query_and_group(xyz, centres, features, radius, nsample, use_xyz)


def _group_all(xyz: torch.Tensor, features: Optional[torch.Tensor], use_xyz: bool = True) -> torch.Tensor:
    """:func:`group_all` without the checks."""
    if features is None:
        return xyz.unsqueeze(1)
    parts = [xyz.to(features.dtype), features] if use_xyz else [features]
    return torch.cat(parts, 2).unsqueeze(1)


def group_all(xyz: torch.Tensor, features: Optional[torch.Tensor] = None, use_xyz: bool = True) -> torch.Tensor:
    """Every point of each cloud as one group: the last set abstraction of PointNet++ SSG.

    The coordinates are taken as they are, that is relative to the origin (the one group's centre).

    Args:
        xyz: ``(B, N, 3)`` float, finite.
        features: ``(B, N, C)`` or None.
        use_xyz: put the coordinates in front of the features (needed when ``features`` is None).

    Returns:
        ``(B, 1, N, 3 + C)`` (``(B, 1, N, C)`` without ``use_xyz``).

    Raises:
        PointCloudError: a wrong shape or dtype, a non-finite coordinate, different batch sizes or devices.
        ValueError: ``use_xyz=False`` without features.
    """
    _check_cloud(xyz, "xyz")
    if features is None and not use_xyz:
        raise ValueError("`use_xyz=False` needs features: without them the group would have no channel")
    if features is not None:
        _check_features(features, xyz, "xyz")
    return _group_all(xyz, features, use_xyz)
