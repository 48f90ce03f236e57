"""Tests of shapeprog.volumes: exact cuboid voxelisation, fit, widening, splits and order, the executor, CLI."""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch

from csgnet.shapes3d import load_volumes
from sa_testutil import boxes, random_cuboids
from shapeprog import corpus, execute, parse
from shapeprog import volumes as V
from shapeprog.__main__ import main
from shapeprog.sampling import inside_cuboids
from shapeprog.silhouettes import split_ids


def test_axis_aligned_box_fills_the_exact_block():
    vol = V.volume(boxes([0, 0, 0], [2.0, 1.0, 0.5]))
    want = np.zeros((64, 64, 64), bool)
    # x spans the 56 middle voxels 4..59; y (28 voxels) and z (14) are centred on 31.5
    want[4:60, 18:46, 25:39] = True
    assert np.array_equal(vol, want)


def test_rotated_cuboids_match_the_inside_test_at_voxel_centres():
    """Voxel centres mapped back to the shape's units, tested by shapeprog.sampling.inside_cuboids."""
    g = torch.Generator().manual_seed(0)
    for trial in range(6):
        n = 1 + trial % 3
        corners = random_cuboids(g, n, min_dim=0.2)
        vol = V.volume(corners)
        flat = corners.reshape(-1, 3)
        lo, hi = flat.min(0).values, flat.max(0).values
        scale = 56 / float((hi - lo).max())
        idx = torch.stack(torch.meshgrid(*[torch.arange(64, dtype=torch.float64)] * 3, indexing="ij"), -1).reshape(-1, 3)
        world = (idx - 31.5) / scale + (lo + hi) / 2
        want = inside_cuboids(world, corners).reshape(64, 64, 64).numpy()
        assert np.array_equal(vol, want), trial


def test_parts_thinner_than_a_voxel_stay_one_voxel_thick():
    """A plate and a rod 0.002 thick (0.1 voxel): the plate at voxel y 31.5 + 56 (0 - 0.15) = 23.1, the rod at
    39.9; widened to one voxel, each covers one layer (the rod's centre x 31.5 lies between two voxels: both)."""
    seat = boxes([[0, 0, 0], [0, 0.3, 0]], [[1.0, 0.002, 1.0], [0.002, 0.002, 0.6]])
    vol = V.volume(seat)
    assert np.nonzero(vol.any(axis=(0, 2)))[0].tolist() == [23, 40]
    assert vol[4:60, 23, 4:60].all() and vol[:, 23].sum() == 56 * 56
    want = np.zeros((64, 64), bool)
    want[31:33, 15:49] = True  # z: 31.5 +- 56 * 0.3
    assert np.array_equal(vol[:, 40], want)


def test_corpus_shapes_are_centred_and_fit_the_margin():
    for cat, i in (("chair", 173), ("table", 33075)):
        vol = V.volume(execute(parse(corpus.read(cat, i)), dtype=torch.float64).corners)
        idx = np.nonzero(vol)
        lo, hi = np.array([a.min() for a in idx]), np.array([a.max() for a in idx])
        assert lo.min() >= 4 and hi.max() <= 59 and (hi - lo).max() >= 54
        assert np.all(np.abs((lo + hi) / 2 - 31.5) <= 1.0)


def test_build_splits_order_and_executor():
    a = V.build(limit=3, progress=False)
    with ThreadPoolExecutor(2) as pool:
        b = V.build(limit=3, executor=pool, progress=False)
    ids = {split: set(a[split].ids) for split in V.SPLITS}
    for split in V.SPLITS:
        assert np.array_equal(a[split].packed, b[split].packed) and list(a[split].ids) == list(b[split].ids)
        assert a[split].packed.shape == (6, 64, 64, 8) and a[split].size == 64
        want = {f"{c}/{i}" for c in V.CATEGORIES for i in split_ids(c)[split][:3]}
        assert ids[split] == want
        order = np.random.default_rng(V.ORDER_SEED).permutation(6)
        unshuffled = [f"{c}/{i}" for c in V.CATEGORIES for i in split_ids(c)[split][:3]]
        assert list(a[split].ids) == [unshuffled[k] for k in order]
    assert not (ids["train"] & ids["val"]) and not (ids["val"] & ids["test"]) and not (ids["train"] & ids["test"])
    cat, ident = a["val"].ids[0].split("/")
    shape = execute(parse(corpus.read(cat, int(ident))), dtype=torch.float64)
    assert np.array_equal(a["val"].volumes(1)[0], V.volume(shape.corners))


def test_cli_writes_what_the_loader_reads(tmp_path, capsys):
    out = tmp_path / "new" / "vol.npz"
    assert main(["assembly", "volumes", "--out", str(out), "--limit", "2", "--workers", "2", "--quiet"]) == 0
    assert "train 4, val 4, test 4 volumes" in capsys.readouterr().out
    built = V.build(limit=2, progress=False)
    for split in V.SPLITS:
        assert np.array_equal(load_volumes(split, out), built[split].volumes())
    assert load_volumes("train", out, limit=1).shape == (1, 64, 64, 64)


def test_bad_input(tmp_path):
    with pytest.raises(ValueError, match=r"shape \(L, 8, 3\), got \(8, 3\)"):
        V.volume(np.zeros((8, 3)))
    with pytest.raises(ValueError, match=r"no cuboid \(L = 0\)"):
        V.volume(np.zeros((0, 8, 3)))
    with pytest.raises(ValueError, match="got size=64, margin=40"):
        V.build(margin=40, limit=1, progress=False)
    with pytest.raises(ValueError, match=r"categories must be some of chair, table, storage, got \['sofa'\]"):
        V.build(categories=("sofa",), limit=1, progress=False)
    out = tmp_path / "vol.npz"
    with pytest.raises(SystemExit, match="error: need an int margin with 0 <= margin < size / 2"):
        main(["assembly", "volumes", "--out", str(out), "--margin", "40", "--limit", "1", "--quiet"])
    assert not out.exists()
    assert main(["assembly", "volumes", "--out", str(out), "--size", "32", "--limit", "1", "--quiet"]) == 0
    with pytest.raises(ValueError, match=r"vol\.npz: volumes of side 32; CSGNet's 3D targets are 64-sided"):
        load_volumes("train", out)
