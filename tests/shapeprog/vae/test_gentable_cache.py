"""The ground-truth row of evaluate-generation is measured once per key and read back whole from the cache."""
from types import SimpleNamespace

from shapeprog.vae import gentable
from shapeprog.vae.genmetrics import FoolResult


def test_ground_truth_row_is_cached(monkeypatch, tmp_path):
    monkeypatch.setenv("SHAPE_PROGRAMS_CACHE", str(tmp_path))
    calls, lines = [], []

    def fake_evaluate(samples, refs, name, with_coverage, **kw):
        calls.append((name, with_coverage, kw["fool_epochs"]))
        return gentable.GenerationRow(name, 3, 2, rooted=50.0, stable=None, fool=41.5, fd=12.25, leaf_parts=4.5,
                                      generalization=0.1, coverage=None, variety=0.2, novelty=0.0,
                                      fool_detail=FoolResult(41.5, 40.0, 43.0, [41.0, 42.0], 10, 2),
                                      errors=["sample 2: no leaf cuboid"], seconds={"fd": 1.5})

    monkeypatch.setattr(gentable, "evaluate_generation", fake_evaluate)
    refs = SimpleNamespace(category="chair", val_programs=[object()] * 3, seed=0)
    kw = dict(model=None, executor=None, stability=True, fool=True, fool_epochs=12, fool_average_last=4,
              fool_points=512, candidates=16, chamfer_points=2048, seed=0, log=lines.append)
    first = gentable.ground_truth_row(refs, "abc", **kw)
    again = gentable.ground_truth_row(refs, "abc", **kw)
    assert calls == [("ground truth: corpus val", False, 12)] and len(lines) == 1
    assert again == first and again.fool_detail == FoolResult(41.5, 40.0, 43.0, [41.0, 42.0], 10, 2)
    gentable.ground_truth_row(refs, "abc", **dict(kw, fool_epochs=3))  # other settings: another key
    gentable.ground_truth_row(refs, "other-classifier", **kw)
    gentable.ground_truth_row(refs, None, **kw)  # a classifier of unknown digest: never cached
    gentable.ground_truth_row(refs, None, **kw)
    assert [c[2] for c in calls] == [12, 3, 12, 12, 12]
