"""Tests for shapeprog.geometry: corner order, meshes, the corner validators."""
import math

import numpy as np
import pytest
import torch

from shapeprog.geometry import CUBOID_TRIANGLES, check_corners, cuboid_corners, mesh_arrays, numpy_corners


def _rot(angle):
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def test_corner_order_and_signs():
    dims = torch.tensor([[2.0, 4.0, 6.0]])
    c = cuboid_corners(torch.tensor([[1.0, 1.0, 1.0]]), dims, torch.eye(3)[None])[0]
    for i in range(8):
        sx = -1 if i & 4 else 1
        sy = -1 if i & 2 else 1
        sz = -1 if i & 1 else 1
        assert c[i].tolist() == [1 + sx * 1.0, 1 + sy * 2.0, 1 + sz * 3.0]


def test_faces_point_outward_for_rotated_cuboid():
    axes = _rot(0.3)[None]
    c = cuboid_corners(torch.tensor([[0.2, -0.1, 0.4]]), torch.tensor([[1.0, 0.5, 0.25]]), axes)
    v, f = mesh_arrays(c)
    centre = v.mean(0)
    for tri in f:
        a, b, d = v[tri]
        n = torch.linalg.cross(b - a, d - a)
        assert float(n @ ((a + b + d) / 3 - centre)) > 0
    assert f.shape == (12, 3) and CUBOID_TRIANGLES.shape == (12, 3)


def test_mesh_offsets_and_shapes():
    c = cuboid_corners(torch.zeros(3, 3), torch.ones(3, 3), torch.eye(3).expand(3, 3, 3))
    v, f = mesh_arrays(c)
    assert v.shape == (24, 3) and f.shape == (36, 3)
    assert f[12:24].min() == 8 and f[24:].max() == 23


def test_shape_errors_name_expected():
    with pytest.raises(ValueError, match=r"\(L, 3\)"):
        cuboid_corners(torch.zeros(3), torch.ones(1, 3), torch.eye(3)[None])


def test_gradcheck_corners():
    args = (
        torch.randn(2, 3, dtype=torch.float64, requires_grad=True),
        torch.rand(2, 3, dtype=torch.float64, requires_grad=True),
        torch.randn(2, 3, 3, dtype=torch.float64, requires_grad=True),
    )
    assert torch.autograd.gradcheck(cuboid_corners, args)


def test_check_corners_names_the_argument_and_the_place():
    ok = cuboid_corners(torch.zeros(2, 3), torch.ones(2, 3), torch.eye(3).expand(2, 3, 3))
    assert check_corners(ok) is ok
    with pytest.raises(ValueError, match=r"^`pred` must have shape \(L, 8, 3\), got \(2, 4, 3\)"):
        check_corners(torch.zeros(2, 4, 3), "pred")
    bad = ok.clone()
    bad[1, 3, 0] = float("nan")
    with pytest.raises(ValueError, match=r"^out\.obj: `corners` contains NaN or infinite values \(cuboids \[1\]\)"):
        check_corners(bad, where="out.obj")
    with pytest.raises(TypeError, match="floating point"):
        check_corners(torch.zeros(1, 8, 3, dtype=torch.int64))
    with pytest.raises(TypeError, match="torch.Tensor"):
        check_corners(ok.numpy())
    arr = ok.numpy()
    assert check_corners(arr, arrays=True) is arr  # returned unchanged


def test_numpy_corners_casts_to_float64_and_rejects_empty():
    ok = cuboid_corners(torch.zeros(1, 3), torch.ones(1, 3), torch.eye(3)[None])
    arr = numpy_corners(ok)
    assert isinstance(arr, np.ndarray) and arr.dtype == np.float64 and arr.shape == (1, 8, 3)
    assert numpy_corners(arr.tolist()).tolist() == arr.tolist()
    with pytest.raises(ValueError, match=r"L = 0"):
        numpy_corners(torch.zeros(0, 8, 3))
