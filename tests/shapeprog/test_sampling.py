"""Tests for shapeprog.sampling: surface sampling and voxelisation."""
import math

import pytest
import torch

from sa_testutil import boxes, rotation
from shapeprog.geometry import cuboid_corners
from shapeprog.sampling import inside_cuboids, lattice_voxelize, sample_surface, triangle_areas, voxelize


def box_surface_distance(points, center, dims, axes):
    """Distance of each point to the surface of one oriented box (axes rows are unit axes)."""
    local = (points - center) @ axes.T
    h = dims / 2
    outside = (local.abs() - h).clamp_min(0).norm(dim=-1)
    inside = (h - local.abs()).min(dim=-1).values.clamp_min(0)
    return torch.where(outside > 0, outside, inside)


def test_points_lie_on_surface_of_rotated_box():
    R = rotation([1, 2, 3], 0.7)
    center, dims = torch.tensor([0.3, -0.2, 0.5], dtype=torch.float64), torch.tensor([1.0, 0.4, 0.2], dtype=torch.float64)
    corners = cuboid_corners(center[None], dims[None], R[None])
    g = torch.Generator().manual_seed(0)
    pts, nrm = sample_surface(corners, 5000, generator=g)
    assert pts.shape == (5000, 3) and nrm.shape == (5000, 3)
    assert box_surface_distance(pts, center, dims, R).max() < 1e-12
    torch.testing.assert_close(nrm.norm(dim=-1), torch.ones(5000, dtype=torch.float64))
    # normals point outward: moving along the normal leaves the box
    local_out = ((pts + 1e-3 * nrm) - center) @ R.T
    assert ((local_out.abs() - dims / 2).max(dim=-1).values > 0).all()
    # the normal is one of +-axes
    assert (torch.abs(nrm @ R.T).max(dim=-1).values > 1 - 1e-9).all()


def test_points_cover_all_faces_uniformly():
    corners = boxes([0, 0, 0], [1, 1, 1])
    pts, nrm = sample_surface(corners, 60000, generator=torch.Generator().manual_seed(1))
    # six faces of equal area: each gets 1/6; binomial std = sqrt(n p (1-p)) ~ 91; allow 5 sigma
    face = (nrm.abs().argmax(1) * 2 + (nrm.sum(1) < 0).long())
    counts = torch.bincount(face, minlength=6).double()
    assert (counts - 10000).abs().max() < 5 * math.sqrt(60000 * (1 / 6) * (5 / 6))
    # uniform within a face: the four quadrants of the +y face get equal shares
    top = pts[nrm[:, 1] > 0.5]
    quad = (top[:, 0] > 0).long() * 2 + (top[:, 2] > 0).long()
    q = torch.bincount(quad, minlength=4).double()
    m = top.shape[0]
    assert (q - m / 4).abs().max() < 5 * math.sqrt(m * 0.25 * 0.75)


def test_area_weighting_twice_the_area_gets_twice_the_points():
    # box B has exactly twice the surface area of box A (all dims scaled by sqrt 2)
    s = math.sqrt(2.0)
    corners = boxes([[-3, 0, 0], [3, 0, 0]], [[1, 0.5, 0.25], [s, 0.5 * s, 0.25 * s]])
    n = 30000
    pts, _ = sample_surface(corners, n, generator=torch.Generator().manual_seed(2))
    k = int((pts[:, 0] > 0).sum())
    # expected share 2/3; binomial sd = sqrt(n * 2/3 * 1/3) ~ 82; 5 sigma bound
    assert abs(k - n * 2 / 3) < 5 * math.sqrt(n * 2 / 9)


def test_triangle_areas_match_box_faces():
    corners = boxes([0, 0, 0], [1, 2, 3])
    areas = triangle_areas(corners)
    # +x x2, +z x2, -z x2, -x x2, +y x2, -y x2 ; each triangle is half a face
    expect = torch.tensor([6, 6, 2, 2, 2, 2, 6, 6, 3, 3, 3, 3], dtype=torch.float64) / 2 + 0.5e-8
    torch.testing.assert_close(areas, expect)


def test_generator_determinism_and_dtype_device():
    corners = boxes([[0, 0, 0], [1, 1, 1]], [[1, 1, 1], [0.5, 0.2, 0.1]]).float()
    a = sample_surface(corners, 100, generator=torch.Generator().manual_seed(5))
    b = sample_surface(corners, 100, generator=torch.Generator().manual_seed(5))
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    assert a[0].dtype == torch.float32


def test_gradient_matches_finite_differences():
    R = rotation([0.2, 1, 0.3], 0.4)
    corners = boxes([[0.1, 0.2, 0.3], [0.5, -0.4, 0.0]], [[1.0, 0.5, 0.3], [0.2, 0.6, 0.4]],
                    axes=torch.stack([R, torch.eye(3, dtype=torch.float64)]))
    corners.requires_grad_(True)
    w = torch.randn(64, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(3))

    def f(c):
        # same generator state -> same faces and barycentric numbers; the face choice depends
        # on the areas, so perturbations stay small enough not to change the draw
        p, nrm = sample_surface(c, 64, generator=torch.Generator().manual_seed(9))
        return (p * w).sum() + (nrm * w).sum()

    assert torch.autograd.gradcheck(f, (corners,), eps=1e-7, atol=1e-6)


def test_errors_are_clear():
    corners = boxes([0, 0, 0], [1, 1, 1])
    with pytest.raises(ValueError, match=r"\(L, 8, 3\)"):
        sample_surface(corners[:, :4], 10)
    bad = corners.clone()
    bad[0, 3, 1] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        sample_surface(bad, 10)
    with pytest.raises(ValueError, match="zero total surface area"):
        sample_surface(torch.zeros(2, 8, 3), 10)
    with pytest.raises(ValueError, match="area"):
        sample_surface(boxes([0, 0, 0], [1e4, 1e4, 1]), 10)
    with pytest.raises(ValueError, match="positive int"):
        sample_surface(corners, 0)
    with pytest.raises(TypeError, match="`corners` must be floating point, got torch.int64"):
        sample_surface(corners.long(), 10)


def test_voxelize_axis_aligned_box_exact_count():
    # grid [0, 1]^3 at resolution 10: voxel centres at 0.05, 0.15, ..., 0.95
    # box x in [0.2, 0.6] -> centres 0.25..0.55 (4), y in [0.0, 1.0] (10), z in [0.31, 0.52] -> 0.35, 0.45 (2)
    corners = boxes([0.4, 0.5, 0.415], [0.4, 1.0, 0.21])
    bounds = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], dtype=torch.float64)
    grid = voxelize(corners, 10, bounds)
    assert grid.shape == (10, 10, 10) and grid.dtype == torch.bool
    assert int(grid.sum()) == 4 * 10 * 2
    assert grid[2:6, :, 3:5].all()
    # any resolution, anisotropic
    g2 = voxelize(corners, (5, 7, 3), bounds)
    assert g2.shape == (5, 7, 3)
    # x centres .1 .3 .5 .7 .9 -> .3,.5 ; z centres 1/6, .5, 5/6 -> .5 ; y all 7
    assert int(g2.sum()) == 2 * 7 * 1


def test_voxelize_default_bounds_fill_a_single_box():
    corners = boxes([1, 2, 3], [0.3, 0.6, 0.9])
    assert bool(voxelize(corners, 17).all())


def test_voxelize_rotated_box_volume():
    R = rotation([1, 1, 0], 0.6)
    corners = boxes([0, 0, 0], [1.0, 0.6, 0.3], axes=R[None])
    bounds = torch.tensor([[-1.0] * 3, [1.0] * 3], dtype=torch.float64)
    grid = voxelize(corners, 64, bounds)
    vol = grid.sum().item() * (2 / 64) ** 3
    assert abs(vol - 0.18) < 0.01


def test_inside_cuboids_boundary_inclusive():
    corners = boxes([0, 0, 0], [1, 1, 1])
    p = torch.tensor([[0.5, 0.0, 0.0], [0.5 + 1e-9, 0, 0], [0, 0, 0], [-0.5, -0.5, -0.5]], dtype=torch.float64)
    assert inside_cuboids(p, corners).tolist() == [True, False, True, True]


def test_lattice_voxelize_matches_shift_rule():
    root = torch.tensor([2.0, 1.0, 1.0], dtype=torch.float64)
    # a slab occupying x in [0.0, 1.0] (the positive half of the root bbox)
    corners = boxes([0.5, 0.0, 0.0], [1.0, 1.0, 1.0])
    occ = lattice_voxelize(corners, root)
    assert occ.shape == (20, 20, 20)
    # lattice x = (i/19 - .5) * 2, offset 2/40 = 0.05; occupied iff x - 0.05 <= 1 and x + 0.05 >= 0
    x = (torch.arange(20, dtype=torch.float64) / 19 - 0.5) * 2
    expect_x = (x + 0.05 >= 0) & (x - 0.05 <= 1.0)
    assert occ.all(dim=(1, 2)).tolist() == expect_x.tolist()
    assert occ.any(dim=(1, 2)).tolist() == expect_x.tolist()
    # a full box the size of the root occupies everything
    assert lattice_voxelize(boxes([0, 0, 0], root), root).all()
    # nothing
    assert not lattice_voxelize(boxes([5, 5, 5], [0.1, 0.1, 0.1]), root).any()
