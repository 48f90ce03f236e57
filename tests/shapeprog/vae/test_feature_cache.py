"""The classifier-feature fit of a category's training shapes (FD's reference) is computed once and cached."""
import numpy as np
import torch

from shapeio import cache
from shapeprog.vae import gentable


def test_the_feature_fit_is_cached_by_classifier_and_computed_without_one(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.CACHE_ENV, str(tmp_path / "c"))
    calls = []

    def features(clouds, model=None):
        calls.append(len(clouds))
        g = torch.Generator().manual_seed(len(calls))
        return torch.randn(len(clouds), 4, generator=g).numpy()

    monkeypatch.setattr(gentable, "classifier_features", features)
    clouds = torch.zeros(6, 32, 3)
    lines = []
    a = gentable.train_feature_fit("chair", clouds, None, 0, "sha-1", lines.append)
    b = gentable.train_feature_fit("chair", clouds, None, 0, "sha-1", lines.append)
    assert calls == [6] and len(lines) == 1 and "cached after this run" in lines[0]
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) and a[1].shape == (4, 4)
    gentable.train_feature_fit("chair", clouds, None, 0, "sha-2")  # another classifier: computed again
    gentable.train_feature_fit("chair", clouds, None, 1, "sha-1")  # another seed: computed again
    assert calls == [6, 6, 6]
    gentable.train_feature_fit("chair", clouds, None, 0, None)
    gentable.train_feature_fit("chair", clouds, None, 0, None)  # no digest: never cached
    assert calls == [6, 6, 6, 6, 6]
