"""The test conditions of point cloud -> program: each cloud has its condition's defining property, exactly where
the geometry allows it, and the same seed gives the same cloud."""
import math

import numpy as np
import pytest
import torch

from shapeprog import corpus
from shapeprog.geometry import CUBOID_TRIANGLES, cuboid_corners
from shapeprog.pointcloud.conditions import (CONDITIONS, NOISE_LEVELS, ROUND_RADIUS, UNEVEN_RATIO, canonical_shape,
                                             condition_cloud, outer_surface_keep, rounded_box, uneven_keep,
                                             visible_from)
from shapeprog.sampling import sample_surface

CHAIR = corpus.ids("chair", "val")[0]


def boxes(*bounds, axes=None):
    """Cuboid corners ``(L, 8, 3) float64`` of axis-aligned boxes given as ``(lo, hi)`` pairs."""
    lo = torch.tensor([b[0] for b in bounds], dtype=torch.float64)
    hi = torch.tensor([b[1] for b in bounds], dtype=torch.float64)
    rot = torch.eye(3, dtype=torch.float64).expand(len(bounds), 3, 3) if axes is None else axes
    return cuboid_corners((lo + hi) / 2, hi - lo, rot)


def local(points, corners):
    """Points in each cuboid's frame ``(N, L, 3)`` and the half extents ``(L, 3)``."""
    c = np.asarray(corners, dtype=np.float64)
    o = c[:, 7]
    edges = np.stack([c[:, 3] - o, c[:, 5] - o, c[:, 6] - o], axis=1)
    half = np.linalg.norm(edges, axis=-1) / 2
    axes = edges / (2 * half[..., None])
    rel = np.asarray(points, dtype=np.float64)[:, None] - c.mean(axis=1)[None]
    return np.einsum("nlc,lkc->nlk", rel, axes), half


def strictly_inside(points, corners, margin=1e-9):
    """``(N, L) bool``: the point lies inside the cuboid by more than ``margin`` along every axis."""
    x, half = local(points, corners)
    return (np.abs(x) < half[None] - margin).all(-1)


@pytest.fixture(scope="module")
def chair():
    return canonical_shape("chair", CHAIR)


def test_an_unknown_condition_is_refused_naming_it_and_the_allowed_ones(chair):
    with pytest.raises(ValueError, match=r"'noisy'.*clean, noise-0\.01, noise-0\.02, uneven, partial, rounded, merged"):
        condition_cloud(chair[1], "noisy")
    with pytest.raises(ValueError, match="n_points"):
        condition_cloud(chair[1], "clean", n_points=0)
    with pytest.raises(ValueError, match="no cuboid"):
        condition_cloud(np.zeros((0, 8, 3)), "clean")


@pytest.mark.parametrize("condition", CONDITIONS)
def test_each_condition_is_deterministic_given_its_seed(chair, condition):
    a = condition_cloud(chair[1], condition, n_points=1500, seed=4)
    assert a.dtype == np.float64 and a.ndim == 2 and a.shape[1] == 3 and 0 < len(a) <= 1500
    assert np.array_equal(a, condition_cloud(torch.from_numpy(chair[1]), condition, n_points=1500, seed=4))
    b = condition_cloud(chair[1], condition, n_points=1500, seed=5)
    assert len(a) != len(b) or not np.array_equal(a, b)
    dropping = condition in ("uneven", "partial", "merged")
    assert (len(a) < 1500) == dropping


def test_the_clean_cloud_lies_on_the_cuboids_and_canonical_shape_shares_the_frame(chair):
    clean, corners = chair
    assert np.linalg.norm(clean.max(0) - clean.min(0)) == pytest.approx(2.0, abs=1e-6)
    for pts, tol in ((clean, 1e-5), (condition_cloud(corners, "clean", n_points=2000), 1e-6)):  # float32 programs
        x, half = local(pts, corners)
        excess = np.abs(x) - half[None]  # (N, L, 3): <= 0 inside; on a face one axis is 0
        inside = (excess <= tol).all(-1)
        on_face = inside & (np.abs(excess) <= tol).any(-1)
        assert on_face.any(1).all()


@pytest.mark.parametrize("condition", list(NOISE_LEVELS))
def test_noise_has_the_named_fraction_of_the_diagonal_as_sigma(condition):
    cube = boxes(([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]))
    info = {}
    x = condition_cloud(cube, condition, n_points=40_000, seed=1, info=info)
    assert info["sigma"] == pytest.approx(NOISE_LEVELS[condition] * 2 * math.sqrt(3), rel=1e-12)
    # the signed distance to the cube is the noise along the face's normal, except within a few sigma of an edge
    off_edge = np.sort(np.abs(x), axis=1)[:, 1] < 1 - 4 * info["sigma"]
    signed = np.abs(x).max(1)[off_edge] - 1.0
    assert signed.std() == pytest.approx(info["sigma"], rel=0.05)
    assert abs(signed.mean()) < 0.05 * info["sigma"]


def test_uneven_density_falls_by_the_ratio_along_the_direction():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0.0, 1.0, size=(400_000, 3))
    cube = boxes(([0.0, 0.0, 0.0], [1.0, 1.0, 1.0])).numpy()
    keep = uneven_keep(pts, cube, [2.0, 0.0, 0.0], np.random.default_rng(1))
    first, last = pts[:, 0] < 0.1, pts[:, 0] > 0.9
    ratio = keep[first].mean() / keep[last].mean()
    assert ratio == pytest.approx(UNEVEN_RATIO ** 0.9, rel=0.06)  # the slabs' mean keep probabilities
    assert keep.mean() == pytest.approx((1 - 1 / UNEVEN_RATIO) / math.log(UNEVEN_RATIO), rel=0.02)
    with pytest.raises(ValueError, match="direction"):
        uneven_keep(pts, cube, [0.0, 0.0, 0.0], rng)


def test_the_uneven_condition_keeps_its_share_along_the_drawn_direction(chair):
    info = {}
    x = condition_cloud(chair[1], "uneven", n_points=4000, seed=2, info=info)
    d = info["direction"]
    along = chair[1].reshape(-1, 3) @ d
    t = (x @ d - along.min()) / (along.max() - along.min())
    assert np.linalg.norm(d) == pytest.approx(1.0) and 0 <= t.min() and t.max() <= 1 + 1e-12
    assert np.mean(t < 0.5) > 0.6  # most kept points lie on the dense half


def surface(corners, n, seed=0):
    pts, normals = sample_surface(corners, n, generator=torch.Generator().manual_seed(seed))
    return pts.numpy(), normals.numpy(), corners[:, CUBOID_TRIANGLES].reshape(-1, 3, 3).numpy()


def test_a_camera_sees_the_near_face_only_and_nothing_behind_it():
    corners = boxes(([-0.5, -0.5, 0.0], [0.5, 0.5, 1.0]), ([-0.25, -0.25, -3.0], [0.25, 0.25, -2.0]))
    pts, normals, tris = surface(corners, 6000)
    seen = visible_from(pts, normals, tris, camera=[0.0, 0.0, 10.0])
    top = np.abs(pts[:, 2] - 1.0) < 1e-12
    assert np.array_equal(seen, top)  # the side faces turn away, the far box and its own top face are hidden
    # the far box alone: its top face is seen once the near box is gone
    alone = pts[:, 2] <= -2.0
    seen_alone = visible_from(pts[alone], normals[alone], tris[12:], camera=[0.0, 0.0, 10.0])
    assert np.array_equal(seen_alone, np.abs(pts[alone][:, 2] + 2.0) < 1e-12)


def test_a_face_turned_away_from_the_camera_is_not_seen_even_with_nothing_in_front():
    square = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]], [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0],
                                                                              [0.0, 1.0, 0.0]]])
    pts = np.random.default_rng(0).uniform(0.0, 1.0, size=(50, 3)) * [1.0, 1.0, 0.0]
    up = np.tile([0.0, 0.0, 1.0], (50, 1))
    assert visible_from(pts, up, square, camera=[0.5, 0.5, 3.0]).all()
    assert not visible_from(pts, up, square, camera=[0.5, 0.5, -3.0]).any()
    assert not visible_from(pts, up, square[:0], camera=[0.5, 0.5, -3.0]).any()


def test_a_partial_cloud_of_a_convex_box_is_its_faces_that_face_the_camera():
    cube = boxes(([-1.0, -0.5, -0.25], [1.0, 0.5, 0.25]))
    info = {}
    x = condition_cloud(cube, "partial", n_points=20_000, seed=3, info=info)
    cam = info["camera"]
    half = np.array([1.0, 0.5, 0.25])
    axis = np.argmax(np.abs(x) / half, axis=1)  # the face each point lies on
    normal = np.zeros_like(x)
    normal[np.arange(len(x)), axis] = np.sign(x[np.arange(len(x)), axis])
    assert ((normal * (cam - x)).sum(1) > 0).all()
    area = {0: 2 * (1.0 * 0.5), 1: 2 * (2.0 * 0.5), 2: 2 * (2.0 * 1.0)}  # the area of each pair of faces
    facing = sum(area[k] / 2 for k in range(3) if abs(cam[k]) > half[k])
    assert len(x) / 20_000 == pytest.approx(facing / sum(area.values()), abs=0.02)


def test_every_point_of_a_partial_chair_is_in_plain_view(chair):
    corners = chair[1]
    info = {}
    x = condition_cloud(corners, "partial", n_points=1500, seed=0, info=info)
    assert 100 < len(x) < 1500 * 0.6
    steps = np.linspace(0.0, 1.0 - 1e-3, 400)
    for p in x:
        march = info["camera"] + steps[:, None] * (p - info["camera"])
        assert not strictly_inside(march, corners, margin=1e-6).any(), p


def test_rounded_parts_lie_in_their_cuboid_and_near_its_surface():
    angle = 0.7
    rot = torch.tensor([[math.cos(angle), 0.0, -math.sin(angle)], [0.0, 1.0, 0.0],
                        [math.sin(angle), 0.0, math.cos(angle)]], dtype=torch.float64)[None]
    box = boxes(([0.0, 0.0, 0.0], [1.0, 0.4, 0.6]), axes=rot)
    x = condition_cloud(box, "rounded", n_points=20_000, seed=0)
    loc, half = local(x, box.numpy())
    gap = (half[0] - np.abs(loc[:, 0]))  # (N, 3): distance to each pair of faces
    r = ROUND_RADIUS * half.min()
    assert (gap >= -1e-9).all()  # inside the cuboid
    assert gap.min(1).max() <= r * (1 - 1 / math.sqrt(3)) + 0.05 * r  # near its surface
    assert (gap.min(1) > 0.1 * r).mean() > 0.005  # and rounded: some points are off the cuboid's surface


def test_a_rounded_box_spans_its_box_and_winds_outward():
    import trimesh

    v, f = rounded_box([1.0, 2.0, 3.0], np.eye(3), [0.5, 0.2, 0.3], 0.1)
    assert np.allclose(v.min(0), [0.5, 1.8, 2.7]) and np.allclose(v.max(0), [1.5, 2.2, 3.3])
    assert trimesh.Trimesh(v, f, process=False).volume > 0
    with pytest.raises(ValueError, match="radius"):
        rounded_box([0.0, 0.0, 0.0], np.eye(3), [0.5, 0.2, 0.3], 0.25)


def test_merged_parts_keep_only_their_outer_surface():
    # A, B interpenetrating; C resting on A (touching face at y = 1 over x in [0, 1])
    corners = boxes(([0.0, 0.0, 0.0], [2.0, 1.0, 1.0]), ([1.0, 0.5, 0.25], [3.0, 1.5, 0.75]),
                    ([0.0, 1.0, 0.0], [1.0, 2.0, 1.0]))
    x = condition_cloud(corners, "merged", n_points=30_000, seed=0)
    assert not strictly_inside(x, corners.numpy()).any()
    contact = (np.abs(x[:, 1] - 1.0) < 1e-9) & (x[:, 0] > 1e-6) & (x[:, 0] < 1 - 1e-6)
    assert not contact.any()
    exposed_top = (np.abs(x[:, 1] - 1.0) < 1e-9) & (x[:, 0] > 1.0) & (x[:, 2] > 0.75)
    assert exposed_top.sum() > 100
    # the same rule on points given directly: an exterior point is kept, a covered one is not
    pts = np.array([[1.5, 1.0, 0.9], [0.5, 1.0, 0.5], [1.5, 1.0, 0.5]])
    up = np.array([[0.0, 1.0, 0.0]] * 3)
    assert outer_surface_keep(pts, up, corners.numpy()).tolist() == [True, False, False]
