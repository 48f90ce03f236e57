"""Tests of shapeprog.silhouettes: exact cuboid rasterisation, fit, views, splits, determinism, CLI."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial import ConvexHull

from csgnet.shapes2d import load_silhouettes
from sa_testutil import boxes, random_cuboids
from shapeprog import corpus, execute, parse
from shapeprog import silhouettes as S
from shapeprog.__main__ import main


def rect(r0, r1, c0, c1, size=64):
    img = np.zeros((size, size), bool)
    img[r0:r1 + 1, c0:c1 + 1] = True
    return img


def test_axis_aligned_cuboid_is_the_exact_rectangle():
    corners = boxes([3.0, -2.0, 5.0], [2.0, 1.0, 0.5])
    # front: x spans 56 px -> columns 4..59; y is half as long -> 28 px -> rows 31.5 +- 14 -> 18..45
    assert np.array_equal(S.silhouette(corners, "front"), rect(18, 45, 4, 59))
    # side: y is the longer extent (56 px, rows 4..59), z is half of it (columns 18..45)
    assert np.array_equal(S.silhouette(corners, "side"), rect(4, 59, 18, 45))
    # a third of the length: 56 / 3 px -> rows 31.5 +- 9.33 -> 23..40
    assert np.array_equal(S.silhouette(boxes([0, 0, 0], [3.0, 1.0, 1.0]), "front"), rect(23, 40, 4, 59))
    # no margin, 16 px: the box fills the columns
    assert np.array_equal(S.silhouette(boxes([0, 0, 0], [2.0, 1.0, 1.0]), "front", size=16, margin=0),
                          rect(4, 11, 0, 15, size=16))


def test_parts_thinner_than_a_pixel_draw_one_pixel_wide():
    # a base 0.28 px thick (its centre line at row 45.43) and a post 2.8 px wide
    corners = boxes([[0, 0, 0], [0, 0.5, 0]], [[2.0, 0.01, 1.0], [0.1, 1.0, 0.1]])
    want = rect(45, 45, 4, 59) | rect(18, 45, 31, 32)
    assert np.array_equal(S.silhouette(corners, "front"), want)
    # a flat shape seen edge-on is a line, not an empty image
    flat = S.silhouette(boxes([0, 0, 0], [2.0, 0.001, 2.0]), "side")
    rows, cols = np.nonzero(flat)
    assert flat.sum() > 0 and set(rows) <= {31, 32} and cols.min() == 4 and cols.max() == 59


def test_views_orientation():
    # a wide base and a post standing on its +x end, toward the front (+z)
    corners = boxes([[0, 0, 0], [0.9, 1.0, 0.4]], [[2.0, 0.2, 1.0], [0.2, 2.0, 0.2]])
    front = S.silhouette(corners, "front")
    side = S.silhouette(corners, "side")
    rows, cols = np.nonzero(front)
    top_cols = cols[rows == rows.min()]
    assert top_cols.min() > 48  # the post (+x, +y) is at the top right of the front view
    rows, cols = np.nonzero(side)
    top_cols = cols[rows == rows.min()]
    assert top_cols.max() < 32  # seen from +x, the shape's front (+z) is on the left


def test_rotated_cuboids_match_their_convex_hull():
    """Pixel centres inside the hull of the 8 projected corners, computed independently."""
    g = torch.Generator().manual_seed(0)
    for trial in range(12):
        n = 1 + trial % 3
        corners = random_cuboids(g, n, min_dim=0.05)
        for view in S.VIEWS:
            img = S.silhouette(corners, view)
            pts = S._project(corners.numpy(), view).reshape(-1, 2)
            lo, hi = pts.min(0), pts.max(0)
            scale = 56 / (hi - lo).max()
            mid = (lo + hi) / 2
            px = np.stack([31.5 + scale * (pts[:, 0] - mid[0]), 31.5 - scale * (pts[:, 1] - mid[1])], -1)
            cols, rows = np.meshgrid(np.arange(64.0), np.arange(64.0))
            grid = np.stack([cols.ravel(), rows.ravel()], -1)
            want = np.zeros(64 * 64, bool)
            for part in range(n):
                eq = ConvexHull(px[8 * part:8 * part + 8]).equations
                want |= (grid @ eq[:, :2].T + eq[:, 2] <= 1e-9).all(axis=1)
            assert np.array_equal(img, want.reshape(64, 64)), (trial, view)


def test_corpus_shapes_are_centred_and_fit_the_margin():
    for cat, i in (("chair", 173), ("table", 33075), ("storage", 46436)):
        shape = execute(parse(corpus.read(cat, i)), dtype=torch.float64)
        for img in S.silhouettes(shape.corners):
            rows, cols = np.nonzero(img)
            assert rows.min() >= 4 and cols.min() >= 4 and rows.max() <= 59 and cols.max() <= 59
            # the longer extent spans the 56 pixels, both extents are centred on 31.5
            assert max(rows.max() - rows.min(), cols.max() - cols.min()) >= 54
            assert abs((rows.min() + rows.max()) / 2 - 31.5) <= 1.0
            assert abs((cols.min() + cols.max()) / 2 - 31.5) <= 1.0


def test_split_rule():
    for cat in corpus.CATEGORIES:
        s = S.split_ids(cat)
        val = corpus.ids(cat, "val")
        assert s["train"] == corpus.ids(cat, "train")
        assert s["val"] == val[0::2] and s["test"] == val[1::2]
        assert sorted(s["val"] + s["test"]) == sorted(val) and not set(s["val"]) & set(s["test"])


def test_build_is_deterministic_and_matches_single_shapes():
    a = S.build(limit=1, progress=False)
    b = S.build(limit=1, progress=False)
    for split in S.SPLITS:
        assert np.array_equal(a[split].images, b[split].images)
        assert a[split].images.shape == (6, 64, 64) and a[split].images.dtype == bool
        assert list(a[split].views) == ["front", "side"] * 3
        assert [x.split("/")[0] for x in a[split].ids[::2]] == list(corpus.CATEGORIES)
    cat, ident = a["test"].ids[2].split("/")
    assert ident == str(S.split_ids(cat)["test"][0])
    shape = execute(parse(corpus.read(cat, int(ident))), dtype=torch.float64)
    assert np.array_equal(a["test"].images[2:4], S.silhouettes(shape.corners))


def test_cli_writes_what_the_loader_reads(tmp_path, capsys):
    out = tmp_path / "sil.npz"
    assert main(["assembly", "silhouettes", "--out", str(out), "--limit", "1", "--quiet"]) == 0
    assert "train 6, val 6, test 6 images" in capsys.readouterr().out
    built = S.build(limit=1, progress=False)
    for split in S.SPLITS:
        got = load_silhouettes(split, path=out, with_ids=True)
        assert np.array_equal(got.images, built[split].images)
        assert list(got.ids) == list(built[split].ids) and list(got.views) == list(built[split].views)


def test_shipped_set_matches_the_generator():
    """The shipped file holds what the code renders (first shape of each category in each split)."""
    for split in S.SPLITS:
        data = load_silhouettes(split, with_ids=True)
        assert data.images.shape[1:] == (64, 64) and len(data.ids) == len(data.images) == len(data.views)
        assert list(data.views[:4]) == ["front", "side", "front", "side"]
        for cat in corpus.CATEGORIES:
            first = f"{cat}/{S.split_ids(cat)[split][0]}"
            k = list(data.ids).index(first)
            shape = execute(parse(corpus.read(*first.split("/"))), dtype=torch.float64)
            assert np.array_equal(data.images[k:k + 2], S.silhouettes(shape.corners)), first
    sizes = {split: len(load_silhouettes(split)) for split in S.SPLITS}
    expect = {split: 2 * sum(len(S.split_ids(c)[split]) for c in corpus.CATEGORIES) for split in S.SPLITS}
    assert sizes == expect


def test_bad_input():
    with pytest.raises(ValueError, match=r"shape \(L, 8, 3\), got \(8, 3\)"):
        S.silhouette(np.zeros((8, 3)), "front")
    with pytest.raises(ValueError, match="unknown view 'top'"):
        S.silhouette(boxes([0, 0, 0], [1, 1, 1]), "top")
    with pytest.raises(ValueError, match="NaN or infinite"):
        S.silhouette(np.full((1, 8, 3), np.nan), "front")
    with pytest.raises(ValueError, match=r"no cuboid \(L = 0\)"):
        S.silhouette(np.zeros((0, 8, 3)), "side")
    with pytest.raises(ValueError, match="margin < size / 2"):
        S.silhouette(boxes([0, 0, 0], [1, 1, 1]), "front", size=8, margin=4)


def test_bad_frame_is_refused_before_building(tmp_path):
    """A size / margin that no image accepts is an error up front, not a set of skipped shapes."""
    with pytest.raises(ValueError, match="got size=64, margin=40"):
        S.build(margin=40, limit=1, progress=False)
    out = tmp_path / "sil.npz"
    with pytest.raises(SystemExit, match="error: need an int margin with 0 <= margin < size / 2"):
        main(["assembly", "silhouettes", "--out", str(out), "--margin", "40", "--limit", "1", "--quiet"])
    assert not out.exists()
