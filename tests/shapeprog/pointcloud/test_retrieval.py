"""shapeprog.pointcloud.retrieval: the nearest training shape by chamfer distance."""
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch

from shapeprog.execute import execute
from shapeprog.pointcloud.data import corpus_splits, make_clouds, sample_clouds
from shapeprog.pointcloud.normalize import normalize
from shapeprog.pointcloud.retrieval import RetrievalIndex

SPLITS = corpus_splits("chair")
TRAIN = SPLITS["train"][:12] + SPLITS["val"][:2]
TEST = SPLITS["test"][:2]


def _normalised(clouds):
    return np.stack([normalize(c)[0] for c in clouds]).astype(np.float32)


@pytest.fixture(scope="module")
def index():
    refs = sample_clouds("chair", TRAIN, n_points=400)
    return RetrievalIndex("chair", refs.ids, _normalised(refs.points), grid=12, candidates=4), refs


def test_a_training_cloud_finds_its_own_shape(index):
    idx, refs = index
    ours = _normalised(refs.points)
    found = idx.search(ours)
    assert [m.id for m in found] == TRAIN and all(m.distance == 0.0 for m in found)
    # the same clouds moved and scaled: normalised back onto the references (another sample of a shape is
    # not always nearest to its own reference: near-duplicate chairs differ less than the sampling noise)
    moved = [normalize(c.astype(np.float64) * 2.5 + [1.0, -3.0, 0.5])[0] for c in refs.points]
    again = idx.search(moved)
    assert [m.id for m in again] == TRAIN and all(m.distance < 1e-6 for m in again)
    assert idx.query(torch.from_numpy(ours[3])).id == TRAIN[3]


def test_the_two_stages_agree_with_the_exhaustive_search(index):
    idx, _ = index
    queries = _normalised(sample_clouds("chair", SPLITS["test"][:6], n_points=300).points)
    fast = idx.search(queries)
    full = idx.search(queries, candidates=None)
    with ThreadPoolExecutor(2) as ex:
        pooled = idx.search(list(queries), executor=ex, chunk=2)
    assert [(m.id, m.distance) for m in fast] == [(m.id, m.distance) for m in pooled]
    # the candidates' best is never below the exhaustive best, and equal when it is the same shape
    for a, b in zip(fast, full):
        assert a.distance >= b.distance and (a.id != b.id or a.distance == b.distance)
    assert sum(a.id == b.id for a, b in zip(fast, full)) >= 5  # 4 candidates of 14 on a 12^3 grid
    assert [m.id for m in idx.search(queries, candidates=len(idx))] == [m.id for m in full]
    # the exhaustive search against the definition: mean nearest-point distance both ways, brute force
    for q, m in zip(queries, full):
        q = torch.from_numpy(q).double()
        cds = []
        for ref in idx.clouds.double():
            d = torch.cdist(q, ref)
            cds.append(float(d.min(1).values.mean() + d.min(0).values.mean()))
        best = int(np.argmin(cds))
        assert m.id == int(idx.ids[best]) and m.distance == pytest.approx(cds[best], rel=1e-9)


def test_the_index_of_a_cache_leaves_out_the_test_split(tmp_path):
    make_clouds("chair", tmp_path, n_points=256, workers=1, ids=TRAIN[:3] + TEST)
    idx = RetrievalIndex.from_cache(tmp_path, "chair", points=200, grid=8)
    assert sorted(idx.ids.tolist()) == sorted(TRAIN[:3]) and idx.clouds.shape == (3, 200, 3)
    with pytest.raises(ValueError, match="test split"):
        RetrievalIndex.from_cache(tmp_path, "chair", splits=("train", "test"))
    # the match's program, scaled into the canonical frame, executes onto the reference's normalised cloud
    m = idx.query(idx.clouds[1].float())
    assert m.id == int(idx.ids[1]) and m.distance == 0.0 and m.name == f"chair/{m.id}"
    program, offset = m.canonical_program()
    corners = execute(program, dtype=torch.float64).corners.reshape(-1, 3).numpy() + offset
    cloud = idx.clouds[1].double().numpy()
    assert np.abs(corners.min(0) - cloud.min(0)).max() < 0.02 and np.abs(corners.max(0) - cloud.max(0)).max() < 0.02


def test_bad_queries(index):
    idx, _ = index
    with pytest.raises(ValueError, match=r"one \(N, 3\) cloud"):
        idx.search(np.zeros((10, 3)))
    with pytest.raises(ValueError, match=r"queries`\[1\] has a NaN"):
        idx.search([np.zeros((10, 3)), np.full((10, 3), np.nan)])
    with pytest.raises(ValueError, match="R = len"):
        RetrievalIndex("chair", [1, 2], np.zeros((3, 5, 3)))
