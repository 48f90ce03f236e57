"""CSGNet's evaluation metrics, computed exactly as the reference computes them (spec section (h)).

:func:`chamfer` is the 2D edge chamfer distance in pixels (the fixed value 16, :data:`CHAMFER_PENALTY`,
for pairs with an empty or full image or an empty edge map); :func:`iou` names its denominator
(``"union"`` or ``"union+1"``); :func:`iou_3d` is the 3D evaluation IoU (``"union+1"``, never NaN);
:func:`reward` is the RL reward ``clip(1 - CD / (64 sqrt 2), 0, 1) ** gamma``.

See docs/csgnet.md ("Metrics") for which evaluation uses which IoU and how :func:`chamfer` is fast and
still equals the reference's per-pair computation bit for bit.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import torch

from .primitives import SIZE

__all__ = [
    "CHAMFER_PENALTY",
    "IOU_DENOMINATORS",
    "chamfer",
    "edges",
    "iou",
    "iou_3d",
    "reward",
]

CHAMFER_PENALTY = 16.0
"""The reference's fixed chamfer distance for an empty/full image or an empty edge map."""

IOU_DENOMINATORS = ("union", "union+1")

_IMAGE_BLOCK = 256  # images per block of OpenCV calls in chamfer (scratch arrays stay small)


# ---------------------------------------------------------------------------------------------
# input handling

def _is_torch(a) -> bool:
    return type(a).__module__.startswith("torch")


def _as_bool_numpy(a) -> np.ndarray:
    if _is_torch(a):
        a = a.detach().cpu().numpy()
    a = np.asarray(a)
    if a.dtype != np.bool_:
        a = a.astype(bool)
    return a


def _shape_error(name: str, expected: str, actual) -> ValueError:
    return ValueError(f"{name} must have shape {expected}, got {tuple(actual)}")


def _check_2d(a: np.ndarray, name: str) -> None:
    if a.ndim not in (2, 3) or a.shape[-2:] != (SIZE, SIZE):
        raise _shape_error(name, f"({SIZE}, {SIZE}) or (N, {SIZE}, {SIZE})", a.shape)


# ---------------------------------------------------------------------------------------------
# Canny edges, batched and exact

def edges(images, chunk: int = 1024) -> np.ndarray:
    """Canny edges of binary images, identical to ``cv2.Canny(img * 255, 1, 3) > 0`` per image.

    Args:
        images: (N, 64, 64) or (64, 64) bool (NumPy or torch).
        chunk: images converted to uint8 at a time (bounds the temporary memory).

    Returns:
        (N, 64, 64) bool (or (64, 64)).
    """
    a = _as_bool_numpy(images)
    _check_2d(a, "images")
    single = a.ndim == 2
    if single:
        a = a[None]
    n = a.shape[0]
    out = np.empty((n, SIZE, SIZE), bool)
    for s in range(0, n, chunk):
        e = _canny(a[s:s + chunk], 1)
        np.not_equal(e, 0, out=out[s:s + len(e)])
    return out[0] if single else out


def _canny(images: np.ndarray, workers: int) -> np.ndarray:
    """(K, 64, 64) bool -> (K, 64, 64) uint8 0/255: ``cv2.Canny(img * 255, 1, 3)`` of each image."""
    img = np.ascontiguousarray(images).view(np.uint8) * np.uint8(255)
    out = np.empty_like(img)

    def run(lo: int, hi: int) -> None:
        for i in range(lo, hi):
            cv2.Canny(img[i], 1, 3, edges=out[i])

    _spread(run, len(img), workers)
    return out


def _spread(run, n: int, workers: int) -> None:
    """``run(lo, hi)`` over ``range(n)``, split into one block per worker thread."""
    if workers <= 1 or n < 64:
        run(0, n)
        return
    bounds = np.linspace(0, n, workers + 1).astype(int).tolist()
    list(_thread_pool(workers).map(run, bounds[:-1], bounds[1:]))


_THREAD_POOLS: dict = {}


def _thread_pool(workers: int) -> ThreadPoolExecutor:
    if workers not in _THREAD_POOLS:
        _THREAD_POOLS[workers] = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="csgnet-metrics")
    return _THREAD_POOLS[workers]


# ---------------------------------------------------------------------------------------------
# chamfer distance

_HASH_MULT = np.random.default_rng(0x5EED).integers(1, 2**63, size=SIZE * SIZE // 64, dtype=np.uint64) | np.uint64(1)


def _unique_images(*stacks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct images over ``stacks`` (each (M_i, 64, 64) bool), numbered in concatenation order.

    Returns:
        (index of one copy of each distinct image, inverse (sum M_i,), ON pixels of each distinct
        image).
    """
    packed = np.concatenate([np.packbits(s.reshape(len(s), -1), axis=1, bitorder="little") for s in stacks])
    words = packed.view(np.uint64)  # (M, 64)
    # group by a 64-bit hash, then check that every image equals its group's first image
    with np.errstate(over="ignore"):
        h = (words * _HASH_MULT).sum(axis=1, dtype=np.uint64)
    _, first, inverse = np.unique(h, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    if not (words[first[inverse]] == words).all():  # a hash collision: exact grouping instead
        keys = np.ascontiguousarray(packed).view(np.dtype((np.void, packed.shape[1]))).ravel()
        _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        inverse = inverse.ravel()
    counts = np.bitwise_count(words[first]).sum(axis=1, dtype=np.int64)
    return first, inverse, counts


def _take(stacks: tuple, rows: np.ndarray) -> np.ndarray:
    """Images ``rows`` (indices over the concatenation of ``stacks``)."""
    if len(stacks) == 1:
        return stacks[0][rows]
    n0 = len(stacks[0])
    out = np.empty((len(rows),) + stacks[0].shape[1:], stacks[0].dtype)
    lo = rows < n0
    out[lo] = stacks[0][rows[lo]]
    out[~lo] = stacks[1][rows[~lo] - n0]
    return out


def _distance_maps(inv: np.ndarray, out: np.ndarray, workers: int) -> None:
    """``cv2.distanceTransform(inv, DIST_L2, 3)`` of each map, written into ``out``.

    Args:
        inv: (U, 64, 64) uint8, ``255 - E`` of the Canny edges ``E`` (0 on edges, 255 elsewhere).
        out: (U, 4097) float32; columns 0..4095 receive the flattened distance maps.
        workers: threads (OpenCV releases the GIL).
    """
    u = inv.shape[0]
    maps = out[:, :SIZE * SIZE].reshape(u, SIZE, SIZE)  # a view: cv2 writes in place

    def run(lo: int, hi: int) -> None:
        for i in range(lo, hi):
            cv2.distanceTransform(inv[i], cv2.DIST_L2, 3, dst=maps[i])

    _spread(run, u, workers)


def chamfer(pred, target, workers: int | None = None, chunk: int = 2048):
    """The reference's 2D edge chamfer distance, in pixels.

    For each pair: both images as uint8 0/255; the pair gets 16 if either image is all-zero or all-on
    or either Canny edge map is empty; otherwise, with ``E = cv2.Canny(img, 1, 3)`` and
    ``D = cv2.distanceTransform(255 - E, cv2.DIST_L2, 3)`` (the 3x3 chamfer approximation: axial step
    0.955, diagonal 1.3693),
    ``CD = 0.5 * (sum(D1 * E2) / (sum(E2) + 1) + sum(D2 * E1) / (sum(E1) + 1))``.
    The values equal the per-pair reference computation bit for bit (float64).

    Args:
        pred: (N, 64, 64) or (64, 64) bool, NumPy or torch (moved to the CPU).
        target: the same shape as ``pred``, or (64, 64) to compare every prediction with one target.
        workers: threads for the per-image OpenCV calls (default: ``min(4, os.cpu_count())``).
        chunk: pairs per block of the vectorised combination (bounds the memory).

    Returns:
        A Python float for one pair of (64, 64) images, else (N,) float64.

    Raises:
        ValueError: if the shapes are not (64, 64) / (N, 64, 64) or do not match.
    """
    p = _as_bool_numpy(pred)
    t = _as_bool_numpy(target)
    _check_2d(p, "pred")
    _check_2d(t, "target")
    single = p.ndim == 2 and t.ndim == 2
    if p.ndim == 2:
        p = p[None]
    if t.ndim == 2:
        t = t[None]
    if t.shape[0] == 1 and p.shape[0] != 1:
        t_index = np.zeros(p.shape[0], np.int64)
    elif p.shape[0] == 1 and t.shape[0] != 1:
        raise _shape_error("target", f"(64, 64) or {tuple(p.shape)} (the shape of pred)", t.shape)
    elif p.shape[0] != t.shape[0]:
        raise ValueError(f"pred and target must hold the same number of images: pred has shape "
                         f"{tuple(p.shape)}, target {tuple(t.shape)}")
    else:
        t_index = np.arange(t.shape[0])
    n = p.shape[0]
    if workers is None:
        workers = min(4, os.cpu_count() or 1)

    # distinct images over predictions and targets
    first, inverse, counts = _unique_images(p, t)
    ip = inverse[:n]
    it = inverse[n:][t_index]

    # Only images in a pair that can still avoid the penalty need edges, and only images in a pair
    # whose both edge maps are non-empty need a distance map (the reference skips the rest too).
    u = len(first)
    bad = (counts == 0) | (counts == SIZE * SIZE)
    live = ~bad[ip] & ~bad[it]
    need = np.zeros(u, bool)
    need[ip[live]] = True
    need[it[live]] = True
    todo = np.flatnonzero(need)
    # Canny edges of those images, block by block, kept as lists of edge pixels (flat indices)
    ecount = np.zeros(u, np.int64)
    pix = []
    for s in range(0, len(todo), _IMAGE_BLOCK):
        blk = todo[s:s + _IMAGE_BLOCK]
        e = _canny(_take((p, t), first[blk]), workers)
        e >>= 7  # 0/255 -> 0/1, a valid bool array
        flat = np.flatnonzero(e.view(bool))
        pix.append(flat + (s << 12))  # flat index over todo's images: image * 4096 + pixel
        ecount[blk] = np.bincount(flat >> 12, minlength=len(blk))
    pix = np.concatenate(pix) if pix else np.zeros(0, np.int64)
    bad[todo] |= ecount[todo] == 0
    live = ~bad[ip] & ~bad[it]
    out = np.full(n, CHAMFER_PENALTY, np.float64)
    ok = np.flatnonzero(live)
    if len(ok) == 0:
        return float(out[0]) if single else out
    need[:] = False
    need[ip[ok]] = True
    need[it[ok]] = True
    keep = need[todo]  # among the images with edges, those that take part in a scored pair
    # edge pixel lists of the kept images, padded with index 4096 (a zero distance)
    k = int(keep.sum())
    pos = np.full(u, -1, np.int64)
    pos[todo[keep]] = np.arange(k)
    owner = pos[todo[pix >> 12]]
    pix, owner = pix[owner >= 0] & (SIZE * SIZE - 1), owner[owner >= 0]
    cnt = ecount[todo[keep]]
    starts = np.cumsum(cnt) - cnt
    idx = np.full((k, int(cnt.max())), SIZE * SIZE, np.int32)
    idx[owner, np.arange(len(owner)) - starts[owner]] = pix
    esum = cnt.astype(np.float64) * 255.0  # sum of the 0/255 edge array

    # Distance maps block by block; each block serves every pair whose first (second) image is in
    # it: sum(D1 * E2) = 255 * (sum of D1 over E2's edge pixels), float32 values summed in float64
    # (exact, hence equal to the reference's float64 sums).
    pa, pb = pos[ip[ok]], pos[it[ok]]
    by_a, by_b = np.argsort(pa, kind="stable"), np.argsort(pb, kind="stable")
    s_ab = np.empty(len(ok), np.float64)
    s_ba = np.empty(len(ok), np.float64)
    blk_n = min(_IMAGE_BLOCK, k)
    maps = np.empty((blk_n, SIZE * SIZE + 1), np.float32)  # column 4096 stays 0
    maps[:, -1] = 0
    inv = np.empty((blk_n, SIZE * SIZE), np.uint8)
    for s in range(0, k, blk_n):
        m = min(blk_n, k - s)
        e0 = starts[s]
        e1 = e0 + int(cnt[s:s + m].sum())
        inv[:m] = 255  # 255 - E: 0 on the edge pixels of image s + i
        inv[owner[e0:e1] - s, pix[e0:e1]] = 0
        _distance_maps(inv[:m].reshape(m, SIZE, SIZE), maps[:m], workers)
        for order, mine, other, dst in ((by_a, pa, pb, s_ab), (by_b, pb, pa, s_ba)):
            lo, hi = np.searchsorted(mine, [s, s + m], sorter=order)
            for c in range(lo, hi, chunk):
                sel = order[c:min(hi, c + chunk)]
                q = idx[other[sel], :int(cnt[other[sel]].max())]
                dst[sel] = maps[mine[sel, None] - s, q].sum(axis=1, dtype=np.float64) * 255.0
    out[ok] = (s_ab / (esum[pb] + 1) + s_ba / (esum[pa] + 1)) / 2.0
    return float(out[0]) if single else out


# ---------------------------------------------------------------------------------------------
# IoU

def iou(pred, target, denominator: str = "union"):
    """Intersection over union of bool images or volumes, with the reference's two denominators.

    * ``"union"``: ``|A and B| / |A or B|``; NaN when both are empty (2D synthetic validation and the
      2D CAD beam search of the reference).
    * ``"union+1"``: ``|A and B| / (|A or B| + 1)``; never NaN (the RL IoU reward, ``test_cad.py``'s
      "iou", and all 3D evaluation).

    Non-bool inputs are thresholded with ``!= 0`` (the reference's ``astype(bool)``).

    Args:
        pred: (64, 64), (N, 64, 64) or (N, 64, 64, 64); NumPy or torch (a tensor stays on its device).
        target: the same shape as ``pred`` (or one image/volume without the batch axis, broadcast).
        denominator: ``"union"`` or ``"union+1"``.

    Returns:
        A float for a single (64, 64) pair; otherwise (N,) float64 (NumPy) or a float64 tensor.
    """
    if denominator not in IOU_DENOMINATORS:
        raise ValueError(f"denominator must be one of {IOU_DENOMINATORS}, got {denominator!r}")
    torch_mode = _is_torch(pred) or _is_torch(target)
    if torch_mode:
        dev = pred.device if _is_torch(pred) else target.device
        a = torch.as_tensor(pred, device=dev) != 0
        b = torch.as_tensor(target, device=dev) != 0
    else:
        a = np.asarray(pred) != 0
        b = np.asarray(target) != 0
    shape_ok = {(SIZE, SIZE), (SIZE, SIZE, SIZE)}
    for name, x in (("pred", a), ("target", b)):
        if not (tuple(x.shape) == (SIZE, SIZE) or tuple(x.shape[1:]) in shape_ok):
            raise _shape_error(name, "(64, 64), (N, 64, 64) or (N, 64, 64, 64)", x.shape)
    single = a.ndim == 2 and b.ndim == 2
    if single:
        a, b = a[None], b[None]
    if a.ndim != b.ndim:
        if b.ndim == a.ndim - 1 and tuple(b.shape) == tuple(a.shape[1:]):
            b = b[None]
        else:
            raise ValueError(f"target shape {tuple(b.shape)} does not match pred shape {tuple(a.shape)}")
    if a.shape[1:] != b.shape[1:] or (a.shape[0] != b.shape[0] and b.shape[0] != 1):
        raise ValueError(f"target shape {tuple(b.shape)} does not match pred shape {tuple(a.shape)}")
    dims = tuple(range(1, a.ndim))
    if torch_mode:
        inter = (a & b).sum(dim=dims).to(torch.float64)
        union = (a | b).sum(dim=dims).to(torch.float64)
    else:
        inter = (a & b).sum(axis=dims).astype(np.float64)
        union = (a | b).sum(axis=dims).astype(np.float64)
    if denominator == "union+1":
        out = inter / (union + 1)
    elif torch_mode:
        out = inter / union  # 0/0 -> NaN in torch
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            out = inter / union
    if single:
        return float(out[0])
    return out


def iou_3d(pred, target):
    """The 3D evaluation IoU: ``|A and B| / (|A or B| + 1)`` per volume (never NaN).

    Args:
        pred: (N, 64, 64, 64) or (64, 64, 64) bool, NumPy or torch.
        target: the same shape as ``pred``, or one (64, 64, 64) volume.

    Returns:
        (N,) float64 (NumPy or tensor on ``pred``'s device); a float for a single volume pair.
    """
    single = tuple(np.shape(pred)) == (SIZE, SIZE, SIZE)
    p = pred[None] if single else pred
    t = target[None] if tuple(np.shape(target)) == (SIZE, SIZE, SIZE) else target
    if len(np.shape(p)) != 4 or tuple(np.shape(p)[1:]) != (SIZE, SIZE, SIZE):
        raise _shape_error("pred", "(N, 64, 64, 64) or (64, 64, 64)", np.shape(pred))
    if len(np.shape(t)) != 4 or tuple(np.shape(t)[1:]) != (SIZE, SIZE, SIZE):
        raise _shape_error("target", "(N, 64, 64, 64) or (64, 64, 64)", np.shape(target))
    out = iou(p, t, denominator="union+1")  # never NaN: the denominator is at least 1
    return float(out[0]) if single else out


# ---------------------------------------------------------------------------------------------
# reward

def _shaped_reward(cd, gamma: float):
    """``clip(1 - CD / (64 sqrt 2), 0, 1) ** gamma``."""
    return np.clip(1.0 - cd / (SIZE * math.sqrt(2.0)), 0.0, 1.0) ** gamma


def reward(pred, target, gamma: float = 20.0, invalid: str = "zero", valid=None, workers: int | None = None,
           return_chamfer: bool = False):
    """The RL reward ``clip(1 - CD / (64 sqrt 2), 0, 1) ** gamma`` from the chamfer distance.

    Args:
        pred: (N, 64, 64) or (64, 64) bool predictions (invalid programs render empty).
        target: the same shape, or one (64, 64) target.
        gamma: the shaping exponent (20 in the paper and the reference).
        invalid: ``"zero"`` (default, as the paper states): invalid programs and empty predictions get
            0. ``"reference"``: they get the reference's CD = 16, i.e. ``(1 - 16/(64 sqrt 2))**20``
            = 0.0204...
        valid: optional (N,) bool: programs marked False count as invalid whatever they render.
        return_chamfer: also return the chamfer distances the rewards come from (one pass for both).

    Returns:
        A float for one pair, else (N,) float64; with ``return_chamfer``, ``(reward, chamfer)``.
    """
    if invalid not in ("zero", "reference"):
        raise ValueError(f"invalid must be 'zero' or 'reference', got {invalid!r}")
    cd = chamfer(pred, target, workers=workers)
    single = np.ndim(cd) == 0
    cd = np.atleast_1d(np.asarray(cd, np.float64))
    r = _shaped_reward(cd, gamma)
    if invalid == "zero":
        p = _as_bool_numpy(pred)
        p = p[None] if p.ndim == 2 else p
        empty = ~p.reshape(p.shape[0], -1).any(axis=1)
        r = np.where(empty, 0.0, r)
    if valid is not None:
        v = _as_bool_numpy(valid).reshape(-1)
        if v.shape[0] != r.shape[0]:
            raise _shape_error("valid", f"({r.shape[0]},)", v.shape)
        penalty = 0.0 if invalid == "zero" else _shaped_reward(CHAMFER_PENALTY, gamma)
        r = np.where(v, r, penalty)
    if return_chamfer:
        return (float(r[0]), float(cd[0])) if single else (r, cd)
    return float(r[0]) if single else r
