"""CSGNet's evaluation metrics, computed exactly as the reference computes them (spec section (h)).

* :func:`chamfer`: the 2D edge chamfer distance in pixels (``train_utils.chamfer`` of the reference):
  Canny edges of the 0/255 images, the 3x3 chamfer distance transform of each edge map, and the
  symmetric mean edge-to-edge distance. Pairs with an empty or full image, or an empty edge map,
  get the fixed value 16 (:data:`CHAMFER_PENALTY`).
* :func:`iou` with ``denominator="union"`` (``|A and B| / |A or B|``, NaN when both are empty: the 2D
  synthetic validation and the 2D CAD beam search) or ``denominator="union+1"``
  (``|A and B| / (|A or B| + 1)``: the RL IoU reward, ``test_cad.py`` and all 3D evaluation).
* :func:`iou_3d`: the 3D evaluation IoU, ``"union+1"`` on ``(N, 64, 64, 64)`` volumes (never NaN).
* :func:`reward`: the RL reward ``clip(1 - CD / (64 sqrt 2), 0, 1) ** gamma``.

How :func:`chamfer` is fast and still exact
-------------------------------------------
The reference loops over pairs and calls ``cv2.Canny`` and ``cv2.distanceTransform`` twice per pair.
Here every distinct image is processed once (targets are usually shared by many beams or samples):

1. **Edges.** All distinct images are tiled into one mosaic, each tile framed by a one-pixel copy of
   its own border, and ``cv2.Canny(dx, dy, 1, 3)`` runs once on the mosaic's Sobel derivatives with
   the frame's derivatives set to zero (see :func:`edges`): bit-identical to one ``cv2.Canny`` call
   per image, without the per-call overhead.
2. **Distances.** ``cv2.distanceTransform(255 - edges, DIST_L2, 3)`` per distinct image (the 3x3
   chamfer mask cannot be tiled: distances would leak between tiles), optionally on several threads
   (OpenCV releases the GIL).
3. **Combination.** ``sum(D1 * E2)`` is ``255 * (D1 . [E2 > 0])`` with the float32 distances summed in
   float64. That sum is exact (values < 2^7 with 24-bit mantissas, 4096 terms fit in 53 bits), so the
   result does not depend on summation order and equals the reference's float64 sums bit for bit.

``tests/csgnet/test_metrics.py`` checks bit equality against the per-pair computation on random
rendered programs, border-touching shapes included; ``bench/bench_csg_chamfer.py`` measures the speed.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = [
    "CHAMFER_PENALTY",
    "IOU_DENOMINATORS",
    "chamfer",
    "edges",
    "iou",
    "iou_3d",
    "reward",
]

SIZE = 64
CHAMFER_PENALTY = 16.0
"""The reference's fixed chamfer distance for an empty/full image or an empty edge map."""

IOU_DENOMINATORS = ("union", "union+1")



# ---------------------------------------------------------------------------------------------
# input handling

def _is_torch(a) -> bool:
    return type(a).__module__.startswith("torch")


def _as_bool_numpy(a, name: str) -> np.ndarray:
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

    The images are tiled into one mosaic per ``chunk``, each tile framed by a one-pixel copy of its
    own border (the ``BORDER_REPLICATE`` that ``cv2.Canny`` uses for its Sobel filter). ``cv2.Sobel``
    of the mosaic then equals each image's own derivatives on every tile pixel; the frame pixels'
    derivatives are set to zero, which is the zero gradient magnitude a single-image call assumes
    outside the image, and ``cv2.Canny(dx, dy, 1, 3)`` runs once on the mosaic. On a 0/255 image
    every non-zero L1 magnitude is >= 255, above both thresholds, so hysteresis cannot link across a
    frame and each tile's edges equal the single-image result bit for bit.

    Args:
        images: (N, 64, 64) or (64, 64) bool (NumPy or torch).
        chunk: images per mosaic.

    Returns:
        (N, 64, 64) bool (or (64, 64)).
    """
    import cv2

    a = _as_bool_numpy(images, "images")
    _check_2d(a, "images")
    single = a.ndim == 2
    if single:
        a = a[None]
    n = a.shape[0]
    out = np.empty((n, SIZE, SIZE), bool)
    t = SIZE + 2
    for s in range(0, n, chunk):
        img = a[s:s + chunk].astype(np.uint8) * np.uint8(255)
        k = img.shape[0]
        cols = max(1, int(math.ceil(math.sqrt(k))))
        rows = -(-k // cols)
        tiles = np.zeros((rows * cols, t, t), np.uint8)
        tiles[:k] = np.pad(img, ((0, 0), (1, 1), (1, 1)), mode="edge")
        mosaic = np.ascontiguousarray(tiles.reshape(rows, cols, t, t).transpose(0, 2, 1, 3)
                                      .reshape(rows * t, cols * t))
        dx = cv2.Sobel(mosaic, cv2.CV_16S, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
        dy = cv2.Sobel(mosaic, cv2.CV_16S, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
        for d in (dx, dy):  # zero gradient on every frame pixel
            v = d.reshape(rows, t, cols, t)
            v[:, 0] = 0
            v[:, -1] = 0
            v[:, :, :, 0] = 0
            v[:, :, :, -1] = 0
        e = cv2.Canny(dx, dy, 1, 3)
        out[s:s + k] = e.reshape(rows, t, cols, t).transpose(0, 2, 1, 3).reshape(rows * cols, t, t)[:k, 1:-1, 1:-1] > 0
    return out[0] if single else out


# ---------------------------------------------------------------------------------------------
# chamfer distance

def _unique_images(stack: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct images of ``stack`` (M, 64, 64) bool: (indices of one copy each, inverse (M,))."""
    packed = np.packbits(stack.reshape(stack.shape[0], -1), axis=1)  # (M, 512) uint8
    keys = np.ascontiguousarray(packed).view(np.dtype((np.void, packed.shape[1]))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    return first, inverse.ravel()


def _distance_maps(edge_maps: np.ndarray, out: np.ndarray, workers: int) -> None:
    """``cv2.distanceTransform(255 - E, DIST_L2, 3)`` of each edge map, written into ``out``.

    Args:
        edge_maps: (U, 64, 64) bool.
        out: (U, 4097) float32; columns 0..4095 receive the flattened distance maps.
        workers: threads (OpenCV releases the GIL).
    """
    import cv2

    u = edge_maps.shape[0]
    inv = np.where(edge_maps, np.uint8(0), np.uint8(255))
    maps = out[:, :SIZE * SIZE].reshape(u, SIZE, SIZE)  # a view: cv2 writes in place

    def run(lo: int, hi: int) -> None:
        for i in range(lo, hi):
            cv2.distanceTransform(inv[i], cv2.DIST_L2, 3, dst=maps[i])

    if workers <= 1 or u < 64:
        run(0, u)
    else:
        bounds = np.linspace(0, u, workers + 1).astype(int)
        with ThreadPoolExecutor(max_workers=workers) as pool:
            list(pool.map(run, bounds[:-1], bounds[1:]))


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
        workers: threads for the distance transforms (default: ``min(4, os.cpu_count())``).
        chunk: pairs per block of the final vectorised combination (bounds the memory).

    Returns:
        A Python float for one pair of (64, 64) images, else (N,) float64.

    Raises:
        ValueError: if the shapes are not (64, 64) / (N, 64, 64) or do not match.
    """
    p = _as_bool_numpy(pred, "pred")
    t = _as_bool_numpy(target, "target")
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
    stack = np.concatenate([p, t], axis=0)
    first, inverse = _unique_images(stack)
    uniq = stack[first]
    ip = inverse[:n]
    it = inverse[n:][t_index]

    # Only images in a pair that can still avoid the penalty need edges, and only images in a pair
    # whose both edge maps are non-empty need a distance map (the reference skips the rest too).
    u = len(uniq)
    counts = uniq.reshape(u, -1).sum(axis=1)
    bad = (counts == 0) | (counts == SIZE * SIZE)
    live = ~bad[ip] & ~bad[it]
    need = np.zeros(u, bool)
    need[ip[live]] = True
    need[it[live]] = True
    todo = np.flatnonzero(need)
    e = edges(uniq[todo]) if len(todo) else np.zeros((0, SIZE, SIZE), bool)
    ecount = np.zeros(u, np.int64)
    ecount[todo] = e.reshape(len(todo), SIZE * SIZE).sum(axis=1)
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
    todo, e = todo[keep], e[keep]
    k = len(todo)
    pos = np.full(u, -1, np.int64)
    pos[todo] = np.arange(k)
    # distance maps, flattened, plus a zero column 4096 that padded edge-pixel lists point at
    flat_d = np.zeros((k, SIZE * SIZE + 1), np.float32)
    _distance_maps(e, flat_d, workers)
    # Each sum(D1 * E2) is 255 * (sum of D1 over E2's edge pixels). Edge pixels are listed per image
    # (padded with index 4096, whose distance is 0) so each pair gathers a few hundred values, not 4096.
    cnt = ecount[todo]
    rows, cols = np.nonzero(e.reshape(k, SIZE * SIZE))
    starts = np.cumsum(cnt) - cnt
    idx = np.full((k, int(cnt.max())), SIZE * SIZE, np.int32)
    idx[rows, np.arange(len(rows)) - starts[rows]] = cols
    esum = cnt.astype(np.float64) * 255.0  # sum of the 0/255 edge array
    for s in range(0, len(ok), chunk):
        sel = ok[s:s + chunk]
        a, b = pos[ip[sel]], pos[it[sel]]
        ka = int(cnt[a].max())
        kb = int(cnt[b].max())
        # float32 distances summed in float64: exact, hence equal to the reference's float64 sums
        s_ab = flat_d[a[:, None], idx[b, :kb]].sum(axis=1, dtype=np.float64) * 255.0  # sum(D1 * E2)
        s_ba = flat_d[b[:, None], idx[a, :ka]].sum(axis=1, dtype=np.float64) * 255.0  # sum(D2 * E1)
        out[sel] = (s_ab / (esum[b] + 1) + s_ba / (esum[a] + 1)) / 2.0
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
        import torch

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
        import torch

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

def reward(pred, target, gamma: float = 20.0, invalid: str = "zero", valid=None, workers: int | None = None):
    """The RL reward ``clip(1 - CD / (64 sqrt 2), 0, 1) ** gamma`` from the chamfer distance.

    Args:
        pred: (N, 64, 64) or (64, 64) bool predictions (invalid programs render empty).
        target: the same shape, or one (64, 64) target.
        gamma: the shaping exponent (20 in the paper and the reference).
        invalid: ``"zero"`` (default, as the paper states): invalid programs and empty predictions get
            0. ``"reference"``: they get the reference's CD = 16, i.e. ``(1 - 16/(64 sqrt 2))**20``
            = 0.0204...
        valid: optional (N,) bool: programs marked False count as invalid whatever they render.

    Returns:
        A float for one pair, else (N,) float64.
    """
    if invalid not in ("zero", "reference"):
        raise ValueError(f"invalid must be 'zero' or 'reference', got {invalid!r}")
    cd = chamfer(pred, target, workers=workers)
    single = np.ndim(cd) == 0
    cd = np.atleast_1d(np.asarray(cd, np.float64))
    r = np.clip(1.0 - cd / (SIZE * math.sqrt(2.0)), 0.0, 1.0) ** gamma
    if invalid == "zero":
        p = _as_bool_numpy(pred, "pred")
        p = p[None] if p.ndim == 2 else p
        empty = ~p.reshape(p.shape[0], -1).any(axis=1)
        r = np.where(empty, 0.0, r)
    if valid is not None:
        v = _as_bool_numpy(valid, "valid").reshape(-1)
        if v.shape[0] != r.shape[0]:
            raise _shape_error("valid", f"({r.shape[0]},)", v.shape)
        penalty = 0.0 if invalid == "zero" else (1.0 - CHAMFER_PENALTY / (SIZE * math.sqrt(2.0))) ** gamma
        r = np.where(v, r, penalty)
    return float(r[0]) if single else r
