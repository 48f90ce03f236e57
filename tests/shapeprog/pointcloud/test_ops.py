"""Point-cloud ops against brute-force definitions: farthest-point sampling, ball query, grouping, errors."""
import numpy as np
import pytest
import torch

from shapeprog.errors import PointCloudError
from shapeprog.pointcloud import (ball_query, farthest_point_sample, gather_points, group_all, group_points,
                                  query_and_group)

DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no GPU"))]


def _cloud(b, n, seed, dtype=torch.float64):
    return torch.rand(b, n, 3, generator=torch.Generator().manual_seed(seed), dtype=dtype) - 0.5


def _grid_cloud(seed):
    """Integer points with repeats: every squared distance is an exact integer, so ties are real."""
    rng = np.random.default_rng(seed)
    pts = rng.integers(0, 3, size=(2, 40, 3)).astype(np.float64)
    return torch.from_numpy(pts)


# --------------------------------------------------------------------------------------------------
# brute-force definitions


def naive_fps(points: np.ndarray, m: int) -> list[int]:
    """Start at 0; each step recomputes every point's distance to the whole chosen set (O(N*M) per step)."""
    chosen = [0]
    while len(chosen) < m:
        d = ((points[:, None, :] - points[None, chosen, :]) ** 2).sum(-1).min(1)
        chosen.append(int(np.argmax(d)))  # the first of equal maxima
    return chosen


def naive_ball(points: np.ndarray, centres: np.ndarray, radius: float, k: int) -> np.ndarray:
    out = np.empty((len(centres), k), dtype=np.int64)
    for i, c in enumerate(centres):
        d = ((points - c) ** 2).sum(-1)
        inside = [j for j in range(len(points)) if d[j] < radius * radius][:k]
        if not inside:
            inside = [int(np.argmin(d))]
        out[i] = inside + [inside[0]] * (k - len(inside))
    return out


# --------------------------------------------------------------------------------------------------
# farthest-point sampling


@pytest.mark.parametrize("device", DEVICES)
def test_fps_equals_the_brute_force_definition(device):
    xyz = _cloud(3, 200, 0)
    got = farthest_point_sample(xyz.to(device), 60).cpu()
    assert got.dtype == torch.long and got.shape == (3, 60)
    for b in range(3):
        assert got[b].tolist() == naive_fps(xyz[b].numpy(), 60)


@pytest.mark.parametrize("device", DEVICES)
def test_fps_ties_go_to_the_lowest_index(device):
    xyz = _grid_cloud(1)
    n = xyz.shape[1]
    got = farthest_point_sample(xyz.to(device), n).cpu()  # beyond the distinct positions: repeats
    for b in range(2):
        want = naive_fps(xyz[b].numpy(), n)
        assert got[b].tolist() == want
        assert len(set(want)) == len(np.unique(xyz[b].numpy(), axis=0))  # every distinct position once, then 0s


def test_fps_float32_is_deterministic_and_batched_like_single_clouds():
    xyz = _cloud(4, 300, 2, torch.float32)
    a, b = farthest_point_sample(xyz, 32), farthest_point_sample(xyz, 32)
    assert torch.equal(a, b) and (a[:, 0] == 0).all()
    for i in range(4):
        assert torch.equal(farthest_point_sample(xyz[i:i + 1], 32)[0], a[i])
    assert len(set(a[0].tolist())) == 32  # distinct random points: no repeat
    half = xyz.to(torch.bfloat16)
    assert torch.equal(farthest_point_sample(half, 16), farthest_point_sample(half.float(), 16))


def test_fps_takes_all_points_and_leaves_autograd_alone():
    xyz = _cloud(1, 5, 3).requires_grad_()
    idx = farthest_point_sample(xyz, 5)
    assert sorted(idx[0].tolist()) == [0, 1, 2, 3, 4] and not idx.requires_grad


# --------------------------------------------------------------------------------------------------
# ball query


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("radius, k", [(0.15, 8), (0.3, 16), (0.0, 4), (2.0, 5)])
def test_ball_query_equals_the_brute_force_definition(device, radius, k):
    xyz = _cloud(2, 150, 4)
    centres = torch.cat([xyz[:, :20], _cloud(2, 10, 5) * 3], 1)  # points of the cloud and stray centres
    got = ball_query(radius, k, xyz.to(device), centres.to(device)).cpu()
    assert got.dtype == torch.long and got.shape == (2, 30, k)
    for b in range(2):
        np.testing.assert_array_equal(got[b].numpy(), naive_ball(xyz[b].numpy(), centres[b].numpy(), radius, k))


def test_ball_query_blocks_and_dtypes_agree():
    xyz = _cloud(3, 120, 6)
    centres = xyz[:, :40]
    whole = ball_query(0.25, 12, xyz, centres)
    assert torch.equal(ball_query(0.25, 12, xyz, centres, chunk_elements=7), whole)  # one centre per block
    assert torch.equal(ball_query(0.25, 12, xyz, centres, chunk_elements=1000), whole)  # blocks of 2 centres
    assert torch.equal(ball_query(0.25, 12, xyz.float(), centres.float()), whole)


def test_ball_query_pads_with_the_first_point_and_handles_empty_balls():
    xyz = torch.tensor([[[0.0, 0, 0], [5, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [4.8, 0, 0]]])
    centres = torch.tensor([[[0.0, 0, 0], [5.0, 0, 0], [10.0, 0, 0]]])
    got = ball_query(0.3, 4, xyz, centres)
    assert got.tolist() == [[[0, 2, 3, 0], [1, 4, 1, 1], [1, 1, 1, 1]]]  # the last ball is empty: nearest point
    assert ball_query(0.3, 2, xyz, centres)[0, 0].tolist() == [0, 2]  # the first K in index order
    # strictly inside: a point exactly on the sphere is out
    assert ball_query(0.5, 3, torch.tensor([[[0.0, 0, 0], [0.5, 0, 0]]]), torch.zeros(1, 1, 3)).tolist() == [[[0, 0, 0]]]


# --------------------------------------------------------------------------------------------------
# grouping


@pytest.mark.parametrize("device", DEVICES)
def test_grouping_equals_explicit_indexing(device):
    g = torch.Generator().manual_seed(7)
    feats = torch.randn(2, 30, 5, generator=g, dtype=torch.float64).to(device)
    idx2 = torch.randint(0, 30, (2, 6), generator=g).to(device)
    idx3 = torch.randint(0, 30, (2, 6, 4), generator=g).to(device)
    gp, gg = gather_points(feats, idx2), group_points(feats, idx3)
    assert gp.shape == (2, 6, 5) and gg.shape == (2, 6, 4, 5)
    for b in range(2):
        assert torch.equal(gp[b], feats[b][idx2[b]])
        assert torch.equal(gg[b], feats[b][idx3[b]])


@pytest.mark.parametrize("device", DEVICES)
def test_query_and_group_and_group_all(device):
    xyz = _cloud(2, 80, 8).to(device)
    feats = torch.randn(2, 80, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(9)).to(device)
    centres = gather_points(xyz, farthest_point_sample(xyz, 10))
    idx = ball_query(0.3, 6, xyz, centres)
    got = query_and_group(xyz, centres, feats, 0.3, 6)
    assert got.shape == (2, 10, 6, 7)
    assert torch.equal(got[..., :3], group_points(xyz, idx) - centres[:, :, None])
    assert torch.equal(got[..., 3:], group_points(feats, idx))
    assert torch.equal(query_and_group(xyz, centres, feats, 0.3, 6, use_xyz=False), group_points(feats, idx))
    assert torch.equal(query_and_group(xyz, centres, None, 0.3, 6), got[..., :3])
    everything = group_all(xyz, feats)
    assert everything.shape == (2, 1, 80, 7)
    assert torch.equal(everything[:, 0], torch.cat([xyz, feats], 2))
    assert torch.equal(group_all(xyz)[:, 0], xyz)


def test_grouping_gradients_reach_coordinates_centres_and_features():
    xyz = _cloud(1, 12, 10).requires_grad_()
    feats = torch.randn(1, 12, 2, dtype=torch.float64, requires_grad=True)
    centres = xyz[:, :3].detach().clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda x, c, f: query_and_group(x, c, f, 0.4, 4), (xyz, centres, feats))
    assert torch.autograd.gradcheck(lambda f: group_points(f, torch.tensor([[[0, 3], [5, 5]]])), (feats,))


# --------------------------------------------------------------------------------------------------
# bad input


def test_bad_clouds_raise_point_cloud_errors():
    ok = _cloud(2, 10, 11)
    with pytest.raises(PointCloudError, match=r"`xyz`: must have shape \(B, N, 3\), got \(10, 3\)"):
        farthest_point_sample(ok[0], 4)
    with pytest.raises(PointCloudError, match="fewer than the 11 needed"):
        farthest_point_sample(ok, 11)
    bad = ok.clone()
    bad[1, 4, 2] = float("nan")
    with pytest.raises(PointCloudError, match="cloud 1: a coordinate is not finite") as e:
        ball_query(0.2, 4, bad, ok[:, :3])
    assert e.value.index == 1 and e.value.name == "xyz"
    with pytest.raises(PointCloudError, match="floating-point"):
        farthest_point_sample(torch.zeros(1, 4, 3, dtype=torch.long), 2)
    with pytest.raises(PointCloudError, match="`centres`: holds 1 clouds but `xyz` holds 2"):
        ball_query(0.2, 4, ok, ok[:1, :3])
    with pytest.raises(TypeError, match="torch.Tensor"):
        farthest_point_sample(ok.numpy(), 2)
    with pytest.raises(ValueError, match="`m` must be a positive int"):
        farthest_point_sample(ok, 0)
    with pytest.raises(ValueError, match="`radius`"):
        ball_query(-1.0, 4, ok, ok)
    with pytest.raises(ValueError, match="`radius`"):
        ball_query(float("nan"), 4, ok, ok)


def test_bad_indices_and_features_raise_point_cloud_errors():
    feats = torch.zeros(2, 10, 4)
    with pytest.raises(PointCloudError, match=r"`idx`: indices must lie in \[0, 10\), got \[10, 10\]"):
        group_points(feats, torch.full((2, 3, 2), 10))
    with pytest.raises(PointCloudError, match="int64"):
        gather_points(feats, torch.zeros(2, 3, dtype=torch.int32))
    with pytest.raises(PointCloudError, match="`features`: must have shape"):
        gather_points(torch.zeros(2, 10), torch.zeros(2, 3, dtype=torch.long))
    with pytest.raises(PointCloudError, match=r"must have shape \(B, 12, C\)"):
        query_and_group(_cloud(2, 12, 12), _cloud(2, 3, 13), feats, 0.2, 4)
    with pytest.raises(ValueError, match="use_xyz=False"):
        group_all(_cloud(2, 12, 12), None, use_xyz=False)


def test_sampling_runs_on_one_cpu_thread_and_restores_the_setting():
    xyz = _cloud(2, 50, 14)
    want_fps, want_ball = farthest_point_sample(xyz, 8), ball_query(0.3, 4, xyz, xyz[:, :8])
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        assert torch.equal(farthest_point_sample(xyz, 8), want_fps)
        assert torch.equal(ball_query(0.3, 4, xyz, xyz[:, :8]), want_ball)
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
