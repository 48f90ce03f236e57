"""Tests for shapeprog.metrics: chamfer, F-score, recon IoU, parameter distance."""
import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from sa_testutil import boxes, rot_y
from shapeprog import corpus, execute, metrics, physics
from shapeprog.execute import program_parameters
from shapeprog.lang import parse
from shapeprog.metrics import (
    adaptive_threshold,
    chamfer,
    fscore,
    nearest_neighbors,
    param_distance,
    voxel_iou,
)


def test_documented_physical_metrics_are_importable_from_metrics():
    for name in ("contact_graph", "rooted_parts", "rootedness", "stability"):
        assert getattr(metrics, name) is getattr(physics, name)


# ---------------------------------------------------------------- chamfer / nearest neighbours

def brute_nn(a, b):
    """The definition: squared distances of every pair in float64, first minimum."""
    full = ((a.double()[:, None] - b.double()[None]) ** 2).sum(-1)
    return full.min(1).values.sqrt(), full.argmin(1)


def brute_chamfer(a, b, threshold=0.0, eps=1e-8):
    d_ab, i_ab = brute_nn(a, b)
    d_ba, i_ba = brute_nn(b, a)
    s_ab = ((a.double() - b.double()[i_ab]) ** 2).sum(-1).add(eps).sqrt()
    s_ba = ((b.double() - a.double()[i_ba]) ** 2).sum(-1).add(eps).sqrt()
    return float((s_ab - threshold).clamp_min(0).mean() + (s_ba - threshold).clamp_min(0).mean())


@pytest.mark.parametrize("method", ["kdtree", "brute"])
def test_nearest_neighbors_match_brute_force_and_chunking(method):
    g = torch.Generator().manual_seed(0)
    a, b = torch.rand(700, 3, generator=g), torch.rand(500, 3, generator=g)
    d, i = nearest_neighbors(a, b, method=method)
    want_d, want_i = brute_nn(a, b)
    assert torch.equal(i, want_i)
    torch.testing.assert_close(d, want_d.float())
    d2, i2 = nearest_neighbors(a, b, chunk_elements=1000, method=method)  # brute: two rows per block
    assert torch.equal(i2, i) and torch.equal(d2, d)
    _, j = nearest_neighbors(a, a, exclude_self=True, method=method)
    full = ((a.double()[:, None] - a.double()[None]) ** 2).sum(-1)
    full.fill_diagonal_(float("inf"))
    assert torch.equal(j, full.argmin(1))


def test_nearest_neighbors_ties_and_duplicates():
    # every query has two equidistant neighbours: both methods return one of them
    ref = torch.tensor([[-1.0, 0, 0], [1.0, 0, 0], [0, 5.0, 0]])
    q = torch.zeros(4, 3)
    for method in ("kdtree", "brute"):
        d, i = nearest_neighbors(q, ref, method=method)
        assert torch.all(d == 1.0) and set(i.tolist()) <= {0, 1}
    # exclude_self with a duplicated point: its nearest other point is its twin, at distance 0
    pts = torch.tensor([[0.0, 0, 0], [0.0, 0, 0], [3.0, 0, 0]])
    for method in ("kdtree", "brute"):
        d, i = nearest_neighbors(pts, pts, exclude_self=True, method=method)
        assert i.tolist()[:2] == [1, 0] and i.tolist()[2] in (0, 1) and d.tolist() == [0.0, 0.0, 3.0]
    with pytest.raises(ValueError, match="method"):
        nearest_neighbors(q, ref, method="faiss")


@pytest.mark.parametrize("method", ["kdtree", "brute"])
def test_chamfer_matches_brute_force_definition(method):
    g = torch.Generator().manual_seed(3)
    a = torch.rand(2048, 3, generator=g) * torch.tensor([1.8, 0.8, 0.7])
    b = torch.rand(1500, 3, generator=g) * torch.tensor([1.9, 0.8, 0.7]) + 0.02
    for thr in (0.0, 0.02):
        assert chamfer(a, b, threshold=thr, method=method).item() == pytest.approx(brute_chamfer(a, b, thr), rel=1e-5)
    # float64 inputs agree to float64 rounding
    a64, b64 = a.double(), b.double()
    assert chamfer(a64, b64, method=method).item() == pytest.approx(brute_chamfer(a64, b64), rel=1e-12)
    # gradient: the nearest pairs only, equal to autograd through the definition
    x = a64[:300].clone().requires_grad_(True)
    y = b64[:200].clone().requires_grad_(True)
    chamfer(x, y, threshold=0.01, method=method).backward()
    x2, y2 = x.detach().clone().requires_grad_(True), y.detach().clone().requires_grad_(True)
    _, i_xy = brute_nn(x2, y2)
    _, i_yx = brute_nn(y2, x2)
    ref = (((x2 - y2[i_xy]) ** 2).sum(-1).add(1e-8).sqrt() - 0.01).relu().mean() + (
        ((y2 - x2[i_yx]) ** 2).sum(-1).add(1e-8).sqrt() - 0.01).relu().mean()
    ref.backward()
    torch.testing.assert_close(x.grad, x2.grad, rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(y.grad, y2.grad, rtol=1e-12, atol=1e-14)


def test_chamfer_hand_computed():
    a = torch.tensor([[0.0, 0.0, 0.0]])
    b = torch.tensor([[1.0, 0.0, 0.0], [0.0, 3.0, 0.0]])
    # a->b: 1 ; b->a: (1 + 3) / 2 = 2  (unsquared distances, each direction averaged)
    assert chamfer(a, b, eps=0.0).item() == pytest.approx(3.0)
    assert chamfer(b, a, eps=0.0).item() == pytest.approx(3.0)
    # threshold: relu(d - t)
    assert chamfer(a, b, threshold=1.5, eps=0.0).item() == pytest.approx(0.0 + (0 + 1.5) / 2)
    # the reference's sqrt(. + 1e-8)
    assert chamfer(a, b).item() == pytest.approx(math.sqrt(1 + 1e-8) + (math.sqrt(1 + 1e-8) + math.sqrt(9 + 1e-8)) / 2)


def test_chamfer_identical_symmetric_and_grad():
    g = torch.Generator().manual_seed(1)
    a, b = torch.rand(40, 3, generator=g, dtype=torch.float64), torch.rand(30, 3, generator=g, dtype=torch.float64)
    assert chamfer(a, a.clone(), eps=0.0).item() == 0.0
    assert chamfer(a, a.clone()).item() == pytest.approx(2e-4)
    assert chamfer(a, b).item() == pytest.approx(chamfer(b, a).item(), rel=1e-12)
    a.requires_grad_(True)
    b.requires_grad_(True)
    for method in ("kdtree", "brute"):
        assert torch.autograd.gradcheck(lambda x, y: chamfer(x, y, method=method), (a, b), eps=1e-7, atol=1e-6)
        # with a threshold that some pairs fall below (their gradient is zero)
        assert torch.autograd.gradcheck(lambda x, y: chamfer(x, y, threshold=0.1, method=method), (a, b),
                                        eps=1e-7, atol=1e-6)
    # only one cloud needs a gradient
    assert torch.autograd.gradcheck(lambda x: chamfer(x, b.detach()), (a,), eps=1e-7, atol=1e-6)


def test_chamfer_large_clouds_bounded_memory(monkeypatch):
    import shapeprog.metrics as M

    g = torch.Generator().manual_seed(2)
    a, b = torch.rand(10000, 3, generator=g), torch.rand(10000, 3, generator=g)
    c = chamfer(a, b)
    # random uniform clouds in the unit cube: mean NN distance ~ 0.554 * n^(-1/3) ~ 0.026
    assert 0.04 < c.item() < 0.065
    # the brute-force search never holds the 10^4 x 10^4 distance matrix: blocks of at most CHUNK_ELEMENTS
    blocks, cdist = [], torch.cdist

    def spy(x, y, **kw):
        blocks.append(x.shape[-2] * y.shape[-2])
        return cdist(x, y, **kw)

    monkeypatch.setattr(M.torch, "cdist", spy)
    assert chamfer(a, b, method="brute").item() == pytest.approx(c.item(), rel=1e-5)
    assert len(blocks) > 2 and max(blocks) <= M.CHUNK_ELEMENTS < 10000 * 10000


def test_chamfer_errors():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        chamfer(torch.zeros(5, 2), torch.zeros(5, 3))
    with pytest.raises(ValueError, match="NaN"):
        chamfer(torch.full((5, 3), float("nan")), torch.zeros(5, 3))
    with pytest.raises(ValueError, match="no point"):
        chamfer(torch.zeros(0, 3), torch.zeros(5, 3))


# ---------------------------------------------------------------- F-score

def grid_points(n, h):
    r = torch.arange(n, dtype=torch.float64) * h
    return torch.stack(torch.meshgrid(r, r, r, indexing="ij"), -1).reshape(-1, 3)


def test_adaptive_threshold_on_a_regular_grid():
    # every point's nearest other point is at the grid spacing
    assert adaptive_threshold(grid_points(6, 0.1)).item() == pytest.approx(0.1)
    # 90th percentile, linear interpolation: distances 1 (x9) and 2 (x1) -> quantile 0.9 of squares
    pts = torch.tensor([[float(i), 0, 0] for i in range(10)] + [[100.0, 0, 0], [102.0, 0, 0]])
    sq = np.array([1.0] * 10 + [4.0, 4.0])
    assert adaptive_threshold(pts).item() == pytest.approx(math.sqrt(np.percentile(sq, 90)))


def test_fscore_identical_far_and_hand_computed():
    t = grid_points(5, 0.1)
    assert fscore(t, t.clone()) == pytest.approx(100.0, abs=1e-6)
    assert fscore(t + 10.0, t) == 0.0
    # explicit threshold: half of pred is close, all of target is covered -> P=50, R=100
    pred = torch.tensor([[0.0, 0, 0], [5.0, 0, 0]])
    target = torch.tensor([[0.01, 0, 0]])
    assert fscore(pred, target, threshold=0.05) == pytest.approx(2 * 50 * 100 / (150 + 1e-8))
    # strict comparison at the threshold
    assert fscore(pred, target, threshold=0.01) == pytest.approx(0.0)


# ---------------------------------------------------------------- recon IoU

def test_voxel_iou():
    root = torch.tensor([2.0, 1.0, 1.0], dtype=torch.float64)
    full = boxes([0, 0, 0], root)
    assert voxel_iou(full, full.clone(), root) == 100.0
    left, right = boxes([-0.5, 0, 0], [1.0, 1.0, 1.0]), boxes([0.5, 0, 0], [1.0, 1.0, 1.0])
    # lattice x_i = (i/19 - .5) * 2, shift +-0.05: left covers x <= 0.05 (10 columns), right x >= -0.05 (10)
    assert voxel_iou(left, right, root) == 0.0
    assert voxel_iou(left, full, root) == pytest.approx(100.0 * 10 / 20)
    assert voxel_iou(torch.cat([left, right]), full, root) == 100.0
    # invariant to the order and the split of the parts
    assert voxel_iou(torch.cat([right, left]), torch.cat([left, right]), root) == 100.0


# ---------------------------------------------------------------- param distance

def leaves(centers, dims, node, axes=None, root=(2.0, 1.0, 1.0)):
    c = torch.tensor(centers, dtype=torch.float64).reshape(-1, 3)
    a = torch.eye(3, dtype=torch.float64).repeat(c.shape[0], 1, 1) if axes is None else torch.as_tensor(axes)
    return SimpleNamespace(centers=c, dims=torch.tensor(dims, dtype=torch.float64).reshape(-1, 3), axes=a,
                           node=torch.tensor(node), root_dims=torch.tensor(root, dtype=torch.float64))


def test_param_distance_hand_computed():
    gt = leaves([[0, 0, 0], [1, 0, 0]], [[1.0, 1.0, 1.0], [1.0, 2.0, 1.0]], [0, 0])
    assert param_distance(gt, gt).item() == 0.0
    # leaf 0 moved by 0.5 along x (0.5 / max root dim 2 = 0.25) and 10% wider (0.1); volumes 1 and 2
    pred = leaves([[0.5, 0, 0], [1, 0, 0]], [[1.1, 1.0, 1.0], [1.0, 2.0, 1.0]], [0, 0])
    assert param_distance(pred, gt).item() == pytest.approx((0.25 + 0.1) * 1 / 3)
    # leaf 1 turned 90 degrees about y: right.right' = 0, up.up' = 1, front.front' = 0 -> 1/2 + 0 + 1/2
    rot = torch.stack([torch.eye(3, dtype=torch.float64), rot_y(math.pi / 2)])
    pred = leaves([[0, 0, 0], [1, 0, 0]], [[1.0, 1.0, 1.0], [1.0, 2.0, 1.0]], [0, 0], axes=rot)
    assert param_distance(pred, gt).item() == pytest.approx(1.0 * 2 / 3)
    # a missing leaf is compared with a zero cuboid: |c| / 2 + 3 + 3/2, weight 2/3
    pred = leaves([[0, 0, 0]], [[1.0, 1.0, 1.0]], [0])
    assert param_distance(pred, gt).item() == pytest.approx((0.5 + 3 + 1.5) * 2 / 3)
    # an extra predicted leaf costs nothing
    pred = leaves([[0, 0, 0], [1, 0, 0], [5, 5, 5]], [[1.0, 1.0, 1.0], [1.0, 2.0, 1.0], [1, 1, 1]], [0, 0, 0])
    assert param_distance(pred, gt).item() == 0.0


def test_param_distance_pairs_by_node_group_and_index():
    gt = leaves([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[1.0, 1.0, 1.0]] * 3, [0, 1, 1])
    # same leaves, listed in another node order: the pairing follows (node, rank in node)
    pred = leaves([[1, 0, 0], [2, 0, 0], [0, 0, 0]], [[1.0, 1.0, 1.0]] * 3, [1, 1, 0])
    assert param_distance(pred, gt).item() == 0.0
    # node 0 loses its leaf: only that leaf is compared with a zero cuboid
    pred = leaves([[1, 0, 0], [2, 0, 0]], [[1.0, 1.0, 1.0]] * 2, [1, 1])
    assert param_distance(pred, gt).item() == pytest.approx((0 + 3 + 1.5) / 3)


def test_param_distance_on_executed_programs_and_gradient():
    p = parse(corpus.read("table", 33075))
    gt = execute(p, dtype=torch.float64)
    assert param_distance(execute(p, dtype=torch.float64), gt).item() == 0.0
    x = program_parameters(p, torch.float64)
    x[1] += 0.05  # root bbox height
    assert param_distance(execute(p, dtype=torch.float64, params=x), gt).item() > 0.0
    x = (x + 0.01).requires_grad_(True)
    f = lambda t: param_distance(execute(p, dtype=torch.float64, params=t), gt)  # noqa: E731
    assert torch.autograd.gradcheck(f, (x,), eps=1e-7, atol=1e-5)
    with pytest.raises(TypeError, match="centers"):
        param_distance(gt.corners, gt)
