"""Tests for shapeprog.attach: the attach rules called directly on batched cuboid states."""
import math

import torch

from sa_testutil import rotation
from shapeprog.attach import _min_rotation, _nearest_grid_points, point, rule_aligned, rule_first, to_local

EYE = torch.eye(3, dtype=torch.float64)


def state(centers, dims, axes=None):
    c = torch.tensor(centers, dtype=torch.float64).reshape(-1, 3)
    d = torch.tensor(dims, dtype=torch.float64).reshape(-1, 3)
    a = EYE.expand(c.shape[0], 3, 3).clone() if axes is None else axes
    return c, d, a


def test_point_and_to_local_are_inverse():
    pos, dims, ax = state([[0.1, 0.2, 0.3]], [[1.0, 2.0, 0.5]], rotation([1.0, 2.0, 3.0], 0.7)[None])
    local = torch.tensor([[0.25, 0.5, 1.0]], dtype=torch.float64)
    g = point(pos, dims, ax, local)
    assert torch.allclose(to_local(pos, dims, ax, g[:, None])[:, 0], local)


def test_first_rule_translates_each_row_onto_its_target():
    pos, dims, ax = state([[0, 0, 0], [1, 1, 1]], [[1, 1, 1], [2, 2, 2]])
    src = torch.tensor([[0.5, 0.0, 0.5], [1.0, 1.0, 1.0]], dtype=torch.float64)
    g = torch.tensor([[0.0, -0.5, 0.0], [3.0, 3.0, 3.0]], dtype=torch.float64)
    p1, d1, a1 = rule_first(pos, dims, ax, src, g)
    assert torch.allclose(point(p1, d1, a1, src), g)
    assert d1 is dims and a1 is ax


def test_aligned_rule_grows_towards_the_target_and_leaves_overlaps_alone():
    # A at the origin, B 1.0 above along y: A grows upwards until its top meets B's bottom
    pos, dims, ax = state([[0, 0, 0], [0, 0, 0]], [[1, 1, 1], [1, 1, 1]])
    posB, dimsB, axB = state([[0, 2, 0], [0, 0.5, 0]], [[1, 1, 1], [1, 1, 1]])
    p1, d1, a1 = rule_aligned(pos, dims, ax, posB, dimsB, axB)
    assert torch.allclose(d1[0], torch.tensor([1.0, 2.0, 1.0], dtype=torch.float64))
    assert torch.allclose(p1[0] + d1[0] / 2, torch.tensor([0.5, 1.5, 0.5], dtype=torch.float64))
    assert torch.equal(p1[1], pos[1]) and torch.equal(d1[1], dims[1])  # overlapping: unchanged
    assert a1 is ax


def test_nearest_grid_points_do_not_depend_on_the_dtype():
    pos, dims, ax = state([[0, 0, 0]], [[1, 1, 1]])
    posB, dimsB, axB = state([[0, 3, 0]], [[1, 1, 1]])
    G = torch.stack(torch.meshgrid(*[torch.arange(10, dtype=torch.float64) / 9] * 3, indexing="ij"), -1)
    G = G.flip(-1).reshape(-1, 3)  # x fastest
    out = [_nearest_grid_points(*(t.to(dt) for t in (pos, dims, ax, posB, dimsB, axB, G)))
           for dt in (torch.float32, torch.float64)]
    r32, c32 = out[0]
    r64, c64 = out[1]
    assert r32.double().tolist() == r64.tolist() and c32.double().tolist() == c64.tolist()
    # every A top point ties: the lowest index (x = z = 0) wins; B's nearest point is its bottom
    assert r64.tolist() == [[0.0, 1.0, 0.0]] and c64.tolist() == [[0.0, 0.0, 0.0]]


def test_min_rotation_takes_one_direction_to_the_other_and_keeps_the_reference_degenerate_case():
    nb = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    nc = torch.tensor([[0.0, 2.0, 0.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    act = torch.tensor([True, True, False])
    R = _min_rotation(nb, nc, act)
    assert torch.allclose(R[0] @ nb[0], nc[0] / 2, atol=1e-12)
    # anti-parallel: as the reference, a half turn about nb turned +90 degrees about the first world
    # axis on which nb is non-zero; for nb = +y that axis is y itself
    assert torch.allclose(R[1], torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=torch.float64)), atol=1e-12)
    assert math.isclose(float(torch.det(R[1])), 1.0)
    assert torch.equal(R[2], EYE)  # inactive rows keep the identity
