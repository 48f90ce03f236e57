"""Tests of csgnet.metrics: the reference chamfer distance (bit-exact batching), IoU, 3D IoU, reward."""

from __future__ import annotations

import math
import random

import cv2
import numpy as np
import pytest
import torch

import csgnet
from csg_testutil import random_program, reference_chamfer
from csgnet import metrics

N = 64


def square(r0, r1, c0, c1):
    img = np.zeros((N, N), bool)
    img[r0:r1 + 1, c0:c1 + 1] = True
    return img


@pytest.fixture(scope="module")
def shapes():
    rng = random.Random(7)
    # arbitrary integer parameters, many shapes touching or crossing the border
    imgs = csgnet.render([random_program(rng, 2, rng.randint(1, 7), lo=-6, hi=69, sizes=(1, 39))
                          for _ in range(600)], 2)
    # add shapes that fill whole border rows/columns and a few degenerate ones
    extra = [square(0, 63, 0, 20), square(0, 10, 0, 63), square(50, 63, 40, 63), square(0, 63, 0, 63),
             np.zeros((N, N), bool), square(5, 5, 5, 5), square(0, 0, 0, 63)]
    return np.concatenate([imgs, np.stack(extra)])


def test_identical_is_zero():
    img = csgnet.render("c(32,32,20)s(20,20,16)+")[0]
    assert metrics.chamfer(img, img) == 0.0


def test_penalties():
    img = csgnet.render("c(32,32,20)")[0]
    empty = np.zeros((N, N), bool)
    full = np.ones((N, N), bool)
    assert metrics.chamfer(empty, img) == 16.0
    assert metrics.chamfer(img, empty) == 16.0
    assert metrics.chamfer(full, img) == 16.0
    assert metrics.chamfer(img, full) == 16.0
    assert metrics.chamfer(empty, empty) == 16.0


def test_symmetric(shapes):
    a, b = shapes[:300], shapes[300:600]
    assert np.array_equal(metrics.chamfer(a, b), metrics.chamfer(b, a))


def test_concentric_squares():
    # Canny puts the edge outside on the top/left and inside on the bottom/right, so both squares' edge
    # rings lie k = 4 pixels apart on every side: most edge pixels are 4 axial steps (4 * 0.955) from
    # the other ring, pixels near the corners up to 4 diagonal steps (4 * 1.3693).
    outer = square(10, 53, 10, 53)
    inner = square(14, 49, 14, 49)
    cd = metrics.chamfer(outer, inner)
    assert 4 * 0.955 < cd < 4 * 1.3693
    assert cd == pytest.approx(4 * 0.955, abs=0.15)
    assert cd == reference_chamfer(outer, inner)


def test_diagonal_shift_is_one_axial_step():
    # Shifting a square by one pixel down and right moves every edge one pixel across: each edge pixel
    # is one axial step (0.955) from the other edge ring, except the two corners that only move along.
    a = square(10, 40, 10, 40)
    b = square(11, 41, 11, 41)
    cd = metrics.chamfer(a, b)
    assert cd == pytest.approx(0.955, abs=0.02) and cd == reference_chamfer(a, b)
    # a horizontal shift only moves the vertical sides: about half the edge pixels are 0.955 away
    c = square(10, 40, 11, 41)
    assert metrics.chamfer(a, c) == pytest.approx(0.955 / 2, abs=0.05)
    assert metrics.chamfer(a, c) == reference_chamfer(a, c)


def test_batched_equals_per_pair(shapes):
    rng = np.random.default_rng(3)
    i = rng.integers(len(shapes), size=500)
    j = rng.integers(len(shapes), size=500)
    pred, target = shapes[i], shapes[j]
    got = metrics.chamfer(pred, target)
    want = np.array([reference_chamfer(a, b) for a, b in zip(pred, target)])
    assert got.dtype == np.float64 and got.shape == (500,)
    assert np.array_equal(got, want)  # bit for bit
    assert (want != 16.0).sum() > 200  # the comparison exercised real distances
    # single pairs and a shared (64, 64) target give the same values
    assert metrics.chamfer(pred[0], target[0]) == want[0]
    shared = metrics.chamfer(pred[:50], target[0])
    assert np.array_equal(shared, [reference_chamfer(a, target[0]) for a in pred[:50]])
    # one thread and several give the same values; torch input too
    assert np.array_equal(metrics.chamfer(pred, target, workers=1), want)
    assert np.array_equal(metrics.chamfer(torch.from_numpy(pred), torch.from_numpy(target)), want)


def test_edges_equal_cv2_canny(shapes):
    want = np.stack([cv2.Canny(a.astype(np.uint8) * 255, 1, 3) > 0 for a in shapes])
    assert np.array_equal(metrics.edges(shapes), want)
    assert np.array_equal(metrics.edges(shapes, chunk=7), want)
    # border-touching shapes have edges on the outermost rows/columns
    assert want[:, 0, :].any() and want[:, -1, :].any() and want[:, :, 0].any() and want[:, :, -1].any()


def test_chamfer_shape_errors():
    img = np.zeros((N, N), bool)
    with pytest.raises(ValueError, match=r"pred must have shape \(64, 64\) or \(N, 64, 64\), got \(32, 32\)"):
        metrics.chamfer(np.zeros((32, 32), bool), img)
    with pytest.raises(ValueError, match=r"pred has shape \(3, 64, 64\), target \(2, 64, 64\)"):
        metrics.chamfer(np.zeros((3, N, N), bool), np.zeros((2, N, N), bool))


def test_iou_denominators():
    a = square(0, 9, 0, 9)  # 100 px
    b = square(0, 9, 5, 14)  # 100 px, 50 shared, union 150
    assert metrics.iou(a, b) == pytest.approx(50 / 150)
    assert metrics.iou(a, b, "union") == pytest.approx(50 / 150)
    assert metrics.iou(a, b, "union+1") == pytest.approx(50 / 151)
    empty = np.zeros((N, N), bool)
    assert math.isnan(metrics.iou(empty, empty, "union"))
    assert metrics.iou(empty, empty, "union+1") == 0.0
    batch = metrics.iou(np.stack([a, empty]), np.stack([b, empty]))
    assert batch.shape == (2,) and batch[0] == pytest.approx(1 / 3) and math.isnan(batch[1])
    with pytest.raises(ValueError, match="denominator"):
        metrics.iou(a, b, "union + 1")
    with pytest.raises(ValueError, match=r"got \(3, 3\)"):
        metrics.iou(np.zeros((3, 3)), np.zeros((3, 3)))


def test_iou_torch_stays_torch():
    a = torch.zeros(2, N, N, dtype=torch.bool)
    b = torch.zeros(2, N, N, dtype=torch.bool)
    a[0, :10, :10] = True
    b[0, :10, :5] = True
    out = metrics.iou(a, b, "union+1")
    assert isinstance(out, torch.Tensor) and out.dtype == torch.float64 and out.device == a.device
    assert out[0].item() == pytest.approx(50 / 101) and out[1].item() == 0.0


def test_iou_3d():
    vols = csgnet.render(["sp(32,32,32,16)", "cu(32,32,32,20)", "sp(8,8,8,8)cu(8,8,8,8)-"], 3)
    a, b = vols[:2], vols[1:]
    got = metrics.iou_3d(a, b)
    inter = (a & b).reshape(2, -1).sum(1)
    union = (a | b).reshape(2, -1).sum(1)
    assert np.allclose(got, inter / (union + 1))
    assert got[1] == 0.0  # disjoint: the cube at the centre, a shape in the corner
    # a cube inside a sphere: |A and B| = the cube's 31^3 voxels, |A or B| = the sphere's 124487
    sphere, cube = csgnet.render(["sp(32,32,32,32)", "cu(32,32,32,32)"], 3)
    assert metrics.iou_3d(cube, sphere) == 31 ** 3 / (124487 + 1)
    empty = np.zeros((N, N, N), bool)
    assert metrics.iou_3d(empty, empty) == 0.0
    assert metrics.iou_3d(vols[0], vols[0]) == pytest.approx(vols[0].sum() / (vols[0].sum() + 1))
    t = metrics.iou_3d(torch.from_numpy(a), torch.from_numpy(b))
    assert isinstance(t, torch.Tensor) and np.allclose(t.numpy(), got)
    with pytest.raises(ValueError, match=r"\(N, 64, 64, 64\)"):
        metrics.iou_3d(np.zeros((2, N, N), bool), np.zeros((2, N, N), bool))


def test_reward():
    img = csgnet.render("c(32,32,20)")[0]
    other = csgnet.render("c(30,32,20)")[0]
    empty = np.zeros((N, N), bool)
    assert metrics.reward(img, img) == 1.0
    cd = metrics.chamfer(other, img)
    assert metrics.reward(other, img) == pytest.approx((1 - cd / (64 * math.sqrt(2))) ** 20)
    assert metrics.reward(other, img, return_chamfer=True) == (metrics.reward(other, img), cd)
    rs, cds = metrics.reward(np.stack([other, empty]), img, return_chamfer=True)
    assert rs.tolist() == [metrics.reward(other, img), 0.0] and cds.tolist() == [cd, 16.0]
    assert metrics.reward(empty, img) == 0.0
    ref = metrics.reward(empty, img, invalid="reference")
    assert ref == pytest.approx((1 - 16 / (64 * math.sqrt(2))) ** 20) and ref == pytest.approx(0.0204, abs=1e-4)
    r = metrics.reward(np.stack([img, img]), img, valid=np.array([True, False]))
    assert r.tolist() == [1.0, 0.0]
    r = metrics.reward(np.stack([img, img]), img, valid=np.array([True, False]), invalid="reference")
    assert r[1] == pytest.approx(ref)


def test_batched_blocks_duplicates_and_hash_collisions(shapes, monkeypatch):
    """Many images over several blocks of OpenCV calls, targets shared by many pairs, the same image
    on both sides, and the exact grouping taken when image hashes collide."""
    rng = np.random.default_rng(11)
    i = rng.integers(len(shapes), size=300)
    j = rng.integers(40, size=300)  # 40 targets shared by about 7 pairs each
    pred, target = shapes[i], shapes[j]
    pred[:20] = target[:20]  # identical pairs: distance 0 (or 16 for penalty images)
    want = np.array([reference_chamfer(a, b) for a, b in zip(pred, target)])
    monkeypatch.setattr(metrics, "_IMAGE_BLOCK", 16)  # many blocks, pairs served across blocks
    assert np.array_equal(metrics.chamfer(pred, target, workers=1), want)
    assert np.array_equal(metrics.chamfer(pred, target, workers=3, chunk=7), want)
    monkeypatch.setattr(metrics, "_HASH_MULT", np.zeros_like(metrics._HASH_MULT))  # every hash equal
    first, inverse, counts = metrics._unique_images(pred, target)
    stack = np.concatenate([pred, target])
    assert np.array_equal(stack[first][inverse], stack)
    assert len(first) == len(np.unique(stack.reshape(len(stack), -1), axis=0))
    assert np.array_equal(counts, stack[first].reshape(len(first), -1).sum(axis=1))
    assert np.array_equal(metrics.chamfer(pred, target, workers=1), want)
