"""Tests for shapeprog.physics: box distances, rootedness, stability."""
import math
import os

import numpy as np
import pytest
import torch
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from sa_testutil import boxes, rot_y
from shapeprog.physics import (CODE_STABILITY_TOLERANCE, PAPER_STABILITY_TOLERANCE, box_distances, rooted_parts,
                               rootedness, stability, stability_displacement)


def table(top_y=0.95, leg_h=0.9):
    legs = [[x, leg_h / 2, z] for x in (-0.45, 0.45) for z in (-0.25, 0.25)]
    return boxes([[0, top_y, 0]] + legs, [[1.0, 0.1, 0.6]] + [[0.06, leg_h, 0.06]] * 4)


# ---------------------------------------------------------------- box distances and rootedness

def test_box_distances_hand_cases():
    c = boxes([[0, 0, 0], [1.3, 0, 0], [1.3, 1.4, 0]], [[1, 1, 1]] * 3)
    d = box_distances(c)
    assert d[0, 1] == pytest.approx(0.3) and d[1, 0] == pytest.approx(0.3)
    assert d[1, 2] == pytest.approx(0.4)
    assert d[0, 2] == pytest.approx(math.hypot(0.3, 0.4))  # corner to corner
    # a box rotated 45 degrees about y: its vertical edge points at the other box's face
    r = boxes([[0, 0, 0], [0.5 + 0.2 + math.sqrt(0.5), 0, 0]], [[1, 1, 1]] * 2,
              axes=torch.stack([torch.eye(3, dtype=torch.float64), rot_y(math.pi / 4)]))
    assert box_distances(r)[0, 1] == pytest.approx(0.2)
    # skew edges: two long bars crossing at a vertical gap of 0.5
    bars = boxes([[0, 0, 0], [0, 0.6, 0]], [[2, 0.1, 0.1], [0.1, 0.1, 2]])
    assert box_distances(bars)[0, 1] == pytest.approx(0.5)
    # overlapping, touching
    o = boxes([[0, 0, 0], [0.5, 0.2, 0], [1.0, 0, 0]], [[1, 1, 1]] * 3)
    assert box_distances(o)[0, 1] == 0.0 and box_distances(o)[0, 2] == 0.0
    # nested: surface to surface (mesh semantics) or 0 as solids
    nest = boxes([[0, 0, 0], [0.1, 0, 0]], [[1, 1, 1], [0.2, 0.2, 0.2]])
    assert box_distances(nest)[0, 1] == pytest.approx(0.3)
    assert box_distances(nest, surface=False)[0, 1] == 0.0


def test_box_distances_against_numerical_minimum():
    rng = np.random.default_rng(0)
    for seed in range(8):
        rots = Rotation.random(2, random_state=seed).as_matrix().transpose(0, 2, 1)  # rows = axes
        centers, dims = rng.uniform(-1, 1, (2, 3)), rng.uniform(0.2, 1.2, (2, 3))
        c = boxes(centers, dims, axes=torch.tensor(rots))
        d = box_distances(c, surface=False)[0, 1]

        def f(x):  # squared distance between a point of box 0 and a point of box 1 (local coords)
            p = centers[0] + x[:3] @ rots[0]
            q = centers[1] + x[3:] @ rots[1]
            return float(((p - q) ** 2).sum())

        bounds = [(-h / 2, h / 2) for h in dims[0]] + [(-h / 2, h / 2) for h in dims[1]]
        best = min(minimize(f, rng.uniform(-0.1, 0.1, 6), bounds=bounds, method="L-BFGS-B", tol=1e-14).fun
                   for _ in range(3))
        assert d == pytest.approx(math.sqrt(max(best, 0.0)), abs=1e-5)


def test_table_on_its_legs_is_rooted_floating_cuboid_is_not():
    t = table()
    assert rootedness(t)
    assert rooted_parts(t).all()
    floating = torch.cat([t, boxes([0, 1.6, 0], [0.2, 0.2, 0.2])])
    assert not rootedness(floating)
    assert rooted_parts(floating).tolist() == [True] * 5 + [False]
    # a top hovering above its legs is not rooted (the legs are)
    hover = table(top_y=1.3)
    assert rooted_parts(hover).tolist() == [False, True, True, True, True]


def test_rootedness_two_percent_of_the_diagonal():
    # a unit cube on the ground and a second one above it with a gap; the tolerance is 2% of the
    # bounding-box diagonal sqrt(1 + H^2 + 1) (H = total height)
    gap_ok = boxes([[0, 0.5, 0], [0, 1.545, 0]], [[1, 1, 1], [1, 1.0, 1]])  # gap 0.045 < 0.02 * 2.4864
    gap_bad = boxes([[0, 0.5, 0], [0, 1.555, 0]], [[1, 1, 1], [1, 1.0, 1]])  # gap 0.055 > 0.02 * 2.4946
    assert rootedness(gap_ok)
    assert not rootedness(gap_bad)
    assert rootedness(gap_bad, tolerance=0.03)


def test_rootedness_accepts_arrays_and_checks_input():
    assert rootedness(table().numpy())
    with pytest.raises(ValueError, match=r"\(L, 8, 3\)"):
        rootedness(np.zeros((2, 4, 3)))
    with pytest.raises(ValueError, match="NaN"):
        rootedness(np.full((1, 8, 3), np.nan))


# ---------------------------------------------------------------- stability

def test_stability(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert stability(boxes([0, 0.5, 0], [1, 1, 1]))
    assert stability(table())
    # a tall thin box standing on a tiny base near its edge: its centre of mass is not supported
    tiny_base = boxes([[0.12, 0.025, 0], [0, 1.05, 0]], [[0.05, 0.05, 0.05], [0.3, 2.0, 0.3]])
    assert rootedness(tiny_base)
    assert not stability(tiny_base)
    # a floating overhang: a long heavy beam attached at one end to a thin post
    overhang = boxes([[0, 0.5, 0], [0.8, 1.05, 0]], [[0.1, 1.0, 0.1], [1.6, 0.1, 0.5]])
    assert not stability(overhang)
    # the same beam centred on a wide post stands
    assert stability(boxes([[0, 0.5, 0], [0.0, 1.05, 0]], [[0.4, 1.0, 0.4], [1.6, 0.1, 0.5]]))
    # not rooted -> not stable
    assert not stability(torch.cat([table(), boxes([0, 1.6, 0], [0.2, 0.2, 0.2])]))
    # the paper's looser 10% rule still flags the toppled tower; a 30% rule does not (the base
    # link, the tiny cube, only rises a little as the tower falls)
    assert not stability(tiny_base, tolerance=0.1)
    assert stability(tiny_base, tolerance=0.3)
    # physical box inertia: a heavy block balanced on a centred tiny cube is knocked over by the kick
    balanced = boxes([[0, 0.025, 0], [0, 1.05, 0]], [[0.05, 0.05, 0.05], [0.5, 2.0, 0.5]])
    assert not stability(balanced, inertia="box")
    with pytest.raises(ValueError, match="inertia"):
        stability(balanced, inertia="unit")
    # headless and file-free
    assert os.listdir(tmp_path) == []


def test_stability_displacement_answers_both_rules():
    """One simulation: the displacement decides the code's 2.5 % and the paper's 10 % rules as stability() does."""
    tiny_base = boxes([[0.12, 0.025, 0], [0, 1.05, 0]], [[0.05, 0.05, 0.05], [0.3, 2.0, 0.3]])
    shapes = [boxes([0, 0.5, 0], [1, 1, 1]), table(), tiny_base,
              boxes([[0, 0.5, 0], [0.8, 1.05, 0]], [[0.1, 1.0, 0.1], [1.6, 0.1, 0.5]])]
    moved = [stability_displacement(s, steps=2000) for s in shapes]
    assert moved[0] < CODE_STABILITY_TOLERANCE and moved[2] > PAPER_STABILITY_TOLERANCE
    for s, d in zip(shapes, moved):
        for rule in (CODE_STABILITY_TOLERANCE, PAPER_STABILITY_TOLERANCE, 0.3):
            assert stability(s, tolerance=rule, steps=2000) == (d <= rule)
    assert (CODE_STABILITY_TOLERANCE, PAPER_STABILITY_TOLERANCE) == (0.025, 0.10)
    floating = torch.cat([table(), boxes([0, 1.6, 0], [0.2, 0.2, 0.2])])
    assert stability_displacement(floating) == math.inf  # not rooted: unstable under every rule


def test_stability_is_deterministic():
    shape = boxes([[0, 0.25, 0], [0.3, 0.75, 0]], [[0.6, 0.5, 0.4], [0.5, 0.5, 0.4]])
    runs = {stability(shape, steps=2000) for _ in range(2)}
    assert runs == {True}  # the upper box overhangs by less than half its width: it stays
    moved = boxes([[0, 0.25, 0], [0.6, 0.75, 0]], [[0.6, 0.5, 0.4], [0.5, 0.5, 0.4]])
    assert {stability(moved, steps=2000) for _ in range(2)} == {False}  # its centre beyond the edge: it falls


def test_stability_prints_no_pybullet_banner():
    """pybullet writes its build banner from C on import and connect; stability() silences both, while the
    caller's own output (Python and C) before and after is kept, in order."""
    import subprocess
    import sys

    code = ("import ctypes, sys\n"
            "from sa_testutil import boxes\n"
            "from shapeprog.physics import stability\n"
            "print('before', flush=True)\n"
            "print(stability(boxes([0, 0.5, 0], [1, 1, 1])))\n"
            "print(stability(boxes([0, 0.5, 0], [1, 1, 1])))\n"
            "print('err', file=sys.stderr)\n"
            "ctypes.CDLL(None).printf(b'c-after\\n')\n")
    tests = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([tests, os.environ.get("PYTHONPATH", "")]))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "before\nTrue\nTrue\nc-after\n"
    assert r.stderr == "err\n"
