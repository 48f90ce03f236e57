"""shapeprog.pointcloud.normalize: the canonical frame, its inverse, and programs at another scale."""
import json

import numpy as np
import pytest
import torch

from shapeprog import corpus
from shapeprog.execute import execute
from shapeprog.lang import parse, to_text
from shapeprog.pointcloud.normalize import CANONICAL_DIAGONAL, UP_AXES, Transform, normalize, scale_program

# flat, hierarchical with reflect, translate and squeeze, aligned and unaligned cuboids
PROGRAMS = [("chair", 173), ("table", 33075), ("storage", 46436), ("chair", 2620), ("table", 19833)]


def _cloud(seed=0, n=500):
    return np.random.default_rng(seed).normal(size=(n, 3)) * [0.7, 1.2, 0.4] + [0.1, 0.5, -0.2]


def test_a_moved_and_scaled_cloud_normalises_to_the_same_points():
    x = _cloud()
    a, ta = normalize(x)
    b, tb = normalize(x * 3.7 + [5.0, -2.0, 1.0])
    assert np.allclose(a, b, atol=1e-12)
    assert tb.scale == pytest.approx(ta.scale / 3.7) and np.allclose(tb.center, np.array(ta.center) * 3.7 + [5, -2, 1])
    lo, hi = a.min(0), a.max(0)
    assert np.allclose((lo + hi) / 2, 0, atol=1e-12) and np.linalg.norm(hi - lo) == pytest.approx(CANONICAL_DIAGONAL)
    assert np.allclose(ta.invert(a), x, atol=1e-12) and np.allclose(ta.apply(x), a, atol=1e-12)


def test_types_dtypes_and_batches_are_kept():
    x = torch.from_numpy(_cloud()).float()
    y, t = normalize(x)
    assert isinstance(y, torch.Tensor) and y.dtype == torch.float32 and y.shape == x.shape
    assert torch.allclose(t.invert(y), x, atol=1e-5)
    batch = t.apply(np.stack([_cloud(1), _cloud(2)]))
    assert batch.shape == (2, 500, 3) and batch.dtype == np.float64
    assert np.allclose(batch[1], t.apply(_cloud(2)))


@pytest.mark.parametrize("up", UP_AXES)
def test_the_up_axis_becomes_y(up):
    t = Transform((0.0, 0.0, 0.0), 1.0, up)
    r = t.rotation
    assert np.allclose(r @ r.T, np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)
    axis = np.zeros(3)
    axis["xyz".index(up[-1])] = -1.0 if up.startswith("-") else 1.0
    assert np.allclose(r @ axis, [0, 1, 0])
    # a y-up cloud turned so that `up` points up is normalised back to the y-up result
    x = _cloud()
    assert np.allclose(normalize(x @ r, up=up)[0], normalize(x)[0], atol=1e-12)


def test_transform_records_round_trip():
    t = normalize(_cloud(), up="z")[1]
    record = json.loads(json.dumps(t.to_dict()))
    assert Transform.from_dict(record) == t and record["rotation"] == t.rotation.tolist()
    with pytest.raises(ValueError, match="not a Transform record"):
        Transform.from_dict({"scale": 1.0})


def test_bad_inputs():
    with pytest.raises(ValueError, match="one place"):
        normalize(np.ones((5, 3)))
    with pytest.raises(ValueError, match="NaN"):
        normalize(np.array([[0.0, 0, 0], [1, np.nan, 0]]))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        normalize(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="`up`"):
        normalize(_cloud(), up="up")
    with pytest.raises(ValueError, match="scale"):
        Transform((0, 0, 0), 0.0)
    with pytest.raises(ValueError, match="factor"):
        scale_program(parse(corpus.read("chair", 173)), -1.0)


@pytest.mark.parametrize("category, shape_id", PROGRAMS)
def test_scaling_the_cuboids_scales_the_executed_shape(category, shape_id):
    program = parse(corpus.read(category, shape_id))
    base = execute(program).corners
    for k in (0.5, 1.7):
        scaled = scale_program(program, k)
        assert execute(scaled).corners.sub(base * k).abs().max() <= 1e-5 * k
        assert parse(to_text(scaled)) == scaled  # the scaled numbers print and parse back


def test_a_canonical_program_goes_back_to_the_input_frame():
    program = parse(corpus.read("chair", 173))
    t = Transform((3.0, -1.0, 0.5), 0.25, up="z")  # the input was 4x larger, z up, centred at (3, -1, 0.5)
    canonical = execute(program).corners.double()
    text = t.program_to_input(program)
    placed = t.place(execute(text, dtype=torch.float64).corners)
    assert torch.allclose(placed, t.invert(canonical), atol=1e-9)
    back = execute(t.program_to_canonical(text), dtype=torch.float64).corners
    assert torch.allclose(back, canonical, atol=1e-6)
