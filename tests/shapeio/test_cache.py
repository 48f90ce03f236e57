"""The on-disk cache: keyed entries, atomic, never trusted under another key; the retrieval index uses it."""
import os

import numpy as np
import pytest

from shapeio import cache


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.CACHE_ENV, str(tmp_path / "c"))
    return tmp_path / "c"


def test_cache_folder_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.CACHE_ENV, str(tmp_path / "mine"))
    assert cache.cache_dir() == tmp_path / "mine"
    monkeypatch.setenv(cache.CACHE_ENV, "off")
    assert cache.cache_dir() is None and cache.entry_path("x", {}) is None
    monkeypatch.delenv(cache.CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.cache_dir() == tmp_path / "xdg" / "shape-programs"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache.cache_dir() == tmp_path / "home" / ".cache" / "shape-programs"


def test_an_entry_is_computed_once_per_key(folder):
    calls = []

    def compute(n):
        calls.append(n)
        return {"x": np.arange(n, dtype=np.float32)}

    a = cache.cached("t", {"n": 3, "tag": "a"}, lambda: compute(3))
    b = cache.cached("t", {"tag": "a", "n": 3}, lambda: compute(3))  # the same key in another order
    c = cache.cached("t", {"n": 4, "tag": "a"}, lambda: compute(4))
    assert calls == [3, 4] and a["x"].tolist() == b["x"].tolist() == [0, 1, 2] and len(c["x"]) == 4
    assert sorted(p.name.split("-")[0] for p in folder.iterdir()) == ["t", "t"]  # no temporary file left


def test_an_entry_under_another_key_or_damaged_is_recomputed(folder):
    key = {"n": 1}
    cache.cached("t", key, lambda: {"x": np.zeros(1)})
    path = cache.entry_path("t", key)
    # an entry whose stored key differs (a digest collision, or a copied file) is not trusted
    cache.store("t", {"n": 2}, {"x": np.ones(1)})
    os.replace(cache.entry_path("t", {"n": 2}), path)
    assert cache.load("t", key) is None
    assert cache.cached("t", key, lambda: {"x": np.full(1, 7.0)})["x"].tolist() == [7.0]
    path.write_bytes(b"not an npz")
    assert cache.load("t", key) is None
    assert cache.cached("t", key, lambda: {"x": np.full(1, 8.0)})["x"].tolist() == [8.0]
    assert cache.load("t", key)["x"].tolist() == [8.0]


def test_retrieval_index_is_cached_by_its_key(folder, monkeypatch):
    from shapeprog.pointcloud import retrieval

    ids = retrieval.corpus_splits("chair")["train"][:3]
    calls = []
    real = retrieval.sample_clouds

    def counting(*args, **kwargs):
        calls.append(kwargs.get("seed"))
        return real(*args, **kwargs)

    monkeypatch.setattr(retrieval, "sample_clouds", counting)
    progress = []
    a = retrieval.RetrievalIndex.from_corpus("chair", points=64, ids=ids, progress=lambda d, t: progress.append(d))
    b = retrieval.RetrievalIndex.from_corpus("chair", points=64, ids=ids, progress=lambda d, t: progress.append(d))
    assert calls == [0] and progress == [1, 2, 3]  # sampled (with progress) the first time only
    assert a.ids.tolist() == b.ids.tolist() == sorted(ids)
    assert np.array_equal(a.clouds.numpy(), b.clouds.numpy()) and np.array_equal(a.scales, b.scales)
    retrieval.RetrievalIndex.from_corpus("chair", points=64, ids=ids, seed=1)
    retrieval.RetrievalIndex.from_corpus("chair", points=64, ids=ids, cache=False)
    assert calls == [0, 1, 0]  # another seed is another key; cache=False always samples
