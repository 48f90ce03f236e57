import importlib

import pytest

#: Training shapes in the small retrieval index that stands in for the robust method's default index in tests
#: (the full index samples the whole corpus train split once per machine: about a minute per category).
SMALL_INDEX_SHAPES = 40

_INDEXES: dict = {}


def small_index(category: str):
    """A retrieval index of the first :data:`SMALL_INDEX_SHAPES` training shapes of ``category`` (one per session)."""
    if category not in _INDEXES:
        from shapeprog.pointcloud.data import corpus_splits
        from shapeprog.pointcloud.retrieval import RetrievalIndex

        _INDEXES[category] = RetrievalIndex.from_corpus(category, ids=corpus_splits(category)["train"][:SMALL_INDEX_SHAPES])
    return _INDEXES[category]


@pytest.fixture(autouse=True)
def _small_default_index(monkeypatch):
    """``infer``'s default retrieval index is the small one here, so that tests of the default method stay fast."""
    infer_module = importlib.import_module("shapeprog.pointcloud.infer")

    monkeypatch.setattr(infer_module, "default_index", small_index)
