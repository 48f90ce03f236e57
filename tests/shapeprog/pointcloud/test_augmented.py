"""Retrieval-augmented decoding: ``infer(..., retrieval=index)`` keeps, of the decoded program and the
shortlisted training programs, the one of lowest selection chamfer to the input; the index's shortlist, the
index sampled from the corpus, the command line and the tables' rows."""
import json

import numpy as np
import pytest
import torch

from shapeprog import corpus
from shapeprog.__main__ import main
from shapeprog.lang import parse, to_text
from shapeprog.metrics import chamfer
from shapeprog.pointcloud.data import corpus_cloud, corpus_splits, make_clouds, sample_clouds
from shapeprog.pointcloud.encoder import PointNet2SSG
from shapeprog.pointcloud.infer import CloudModel, infer
from shapeprog.pointcloud.normalize import normalize
from shapeprog.pointcloud.retrieval import RetrievalIndex
from shapeprog.pointcloud.search import QUICK_SEARCH_SCHEDULE, SEARCH_POINTS, parse_schedule, selection_chamfers
from shapeprog.pointcloud.tables import evaluate, write_tables
from shapeprog.vae.pretrained import load_pretrained as load_vae

SPLITS = corpus_splits("chair")
TRAIN = SPLITS["train"][:10]
TINY = dict(npoints=[16, 8], radii=[0.3, 0.6], nsamples=[8, 8], widths=[[8, 8, 16], [16, 16, 32], [32, 32, 64]])


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return CloudModel(PointNet2SSG(out_dim=256, **TINY), load_vae("chair"), "chair", "latent")


@pytest.fixture(scope="module")
def index():
    return RetrievalIndex.from_corpus("chair", points=SEARCH_POINTS, ids=TRAIN, grid=12, candidates=4)


def test_the_corpus_index_holds_the_normalised_clouds_of_the_training_shapes(index):
    refs = sample_clouds("chair", TRAIN, n_points=SEARCH_POINTS)
    assert index.ids.tolist() == sorted(TRAIN) == refs.ids.tolist()
    for k, x in enumerate(refs.points):
        unit, t = normalize(x.astype(np.float64))
        assert np.allclose(index.clouds[k].numpy(), unit, atol=1e-6)
        assert np.allclose(index.centers[k], t.center) and index.scales[k] == pytest.approx(t.scale)
    with pytest.raises(ValueError, match=f"chair/{SPLITS['test'][0]} is not in the corpus train split"):
        RetrievalIndex.from_corpus("chair", points=50, ids=[TRAIN[0], SPLITS["test"][0]])


def test_the_shortlist_is_ordered_by_the_coarse_estimate_and_starts_with_the_shape_itself(index):
    for k in (0, 3, 7):
        short = index.shortlist(index.clouds[k], 5)
        assert len(short) == 5 and short[0].id == int(index.ids[k])
        est = [m.distance for m in short]
        assert est == sorted(est) and len({m.id for m in short}) == 5
    assert len(index.shortlist(index.clouds[0], 100)) == len(index)  # at most every reference
    for bad in (0, -2, 2.5, True):
        with pytest.raises(ValueError, match="`k` must be an integer >= 1"):
            index.shortlist(index.clouds[0], bad)
    assert torch.equal(index.reference_cloud(TRAIN[5]), index.clouds[index.ids.tolist().index(TRAIN[5])])
    with pytest.raises(KeyError, match=f"chair/{SPLITS['test'][0]} is not in the index"):
        index.reference_cloud(SPLITS["test"][0])
    # the shortlist's first rows are the candidates that search() measures exactly
    assert index.search(index.clouds[2:3])[0].id in {m.id for m in index.shortlist(index.clouds[2], 4)}


def test_the_kept_program_is_the_candidate_closest_to_the_input(model, index):
    shape = TRAIN[4]
    cloud = corpus_cloud("chair", shape, n_points=3000).astype(np.float64)
    plain = infer(cloud, model=model, physics=False)
    r = infer(cloud, model=model, physics=False, retrieval=index, retrieval_candidates=3)
    v = r.retrieval
    assert plain.retrieval is None and v["candidates"] == 3 and "retrieval" in r.seconds
    # the untrained model's decode loses to the training shape itself, which is on the shortlist
    assert v["chosen"] == f"chair/{shape}" and v["cd"] < v["decoded_cd"] and r.macro_text is None
    # the same selection, recomputed: the decoded program and the three shortlisted training shapes' clouds
    unit, _ = normalize(cloud)
    g = torch.Generator().manual_seed(0)
    target = torch.from_numpy(unit)[torch.randperm(len(unit), generator=g)[:SEARCH_POINTS]]
    pick = np.sort(np.random.default_rng(0).choice(len(unit), 2048, replace=False))  # the encoder's subset
    matches = index.shortlist(torch.from_numpy(unit[pick].astype(np.float32)).double(), 3)
    cds = selection_chamfers([plain.canonical], target, SEARCH_POINTS, 0)  # the decoded program: surface samples
    cds += [float(chamfer(index.reference_cloud(m.id).double(), target, eps=0.0)) for m in matches]  # references
    assert cds[0] == pytest.approx(v["decoded_cd"]) and min(cds) == pytest.approx(v["cd"])
    assert matches[int(np.argmin(cds)) - 1].name == v["chosen"]
    # the kept program lies on the input: its cuboids span the cloud's box, in any frame
    lo, hi = r.corners().reshape(-1, 3).min(0), r.corners().reshape(-1, 3).max(0)
    assert np.abs(lo - cloud.min(0)).max() < 0.05 and np.abs(hi - cloud.max(0)).max() < 0.05
    k, b = 3.0, np.array([2.0, -1.0, 0.5])
    moved = infer(cloud * k + b, model=model, physics=False, retrieval=index, retrieval_candidates=3)
    assert to_text(moved.canonical) == to_text(r.canonical)
    assert np.allclose(moved.corners(), r.corners() * k + b, atol=1e-3 * k)
    # with a search, the searched program is the one that competes
    searched = infer(cloud, model=model, physics=False, retrieval=index, retrieval_candidates=3, search=True,
                     search_schedule=parse_schedule("quick"))
    assert parse_schedule("quick") == QUICK_SEARCH_SCHEDULE == ((4, 0.5),)
    assert searched.search["decodes"] == 5 and searched.retrieval["decoded_cd"] == pytest.approx(searched.search["cd"])
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="retrieval_candidates"):
            infer(cloud, model=model, physics=False, retrieval=index, retrieval_candidates=bad)


def test_a_decoded_program_that_is_closer_is_kept(model, monkeypatch):
    shape = TRAIN[4]
    cloud = corpus_cloud("chair", shape, n_points=3000).astype(np.float64)
    # a model that decodes the shape's own program, against an index of the other training chairs
    others = RetrievalIndex.from_corpus("chair", points=SEARCH_POINTS, ids=[i for i in TRAIN if i != shape], grid=12)
    own = parse(corpus.read("chair", shape))
    monkeypatch.setattr(model, "decode", lambda codes: [own for _ in range(len(codes))])
    r = infer(cloud, model=model, physics=False, retrieval=others, retrieval_candidates=9)
    assert r.retrieval["chosen"] is None and r.retrieval["cd"] == r.retrieval["decoded_cd"]
    assert to_text(r.canonical) == to_text(infer(cloud, model=model, physics=False).canonical)


def test_an_index_that_does_not_fit_the_model_is_refused(model, index):
    cloud = corpus_cloud("chair", TRAIN[0], n_points=2000)
    sparse = RetrievalIndex.from_corpus("chair", points=300, ids=TRAIN[:3], grid=8)
    with pytest.raises(ValueError, match=f"clouds have 300 points; retrieval-augmented decoding scores with {SEARCH_POINTS}"):
        infer(cloud, model=model, physics=False, retrieval=sparse)
    tables = RetrievalIndex("table", [1, 2], index.clouds[:2], grid=8)
    with pytest.raises(ValueError, match="holds table shapes but the model is the chair model"):
        infer(cloud, model=model, physics=False, retrieval=tables)


def test_cli_retrieval_from_a_cache_prints_and_records_it(tmp_path, model, capsys):
    make_clouds("chair", tmp_path / "c", n_points=SEARCH_POINTS, workers=1, ids=TRAIN[:5] + SPLITS["test"][:1])
    path = tmp_path / "tiny.pt"
    torch.save({"format": "shapeprog-pointcloud", "version": 1, "recipe": "latent", "category": "chair",
                "config": model.encoder.config, "hidden_dim": 256, "encoder": model.encoder.state_dict(),
                "meta": {}}, path)
    cloud = tmp_path / "q.npy"
    np.save(cloud, corpus_cloud("chair", TRAIN[2], n_points=2000))
    assert main(["pointcloud", "infer", str(cloud), "--weights", str(path), "--retrieval", "2", "--clouds", str(tmp_path / "c"),
                 "--no-stability", "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr()
    assert "retrieval: 2 training programs against the decoded one" in out.out
    assert "retrieval index: 5 chair training shapes" in out.err
    record = json.loads((tmp_path / "o" / "q.json").read_text())
    assert record["retrieval"]["candidates"] == 2 and record["retrieval"]["chosen"] == f"chair/{TRAIN[2]}"
    with pytest.raises(SystemExit, match="--clouds is only used with --retrieval"):
        main(["pointcloud", "infer", str(cloud), "--weights", str(path), "--clouds", str(tmp_path / "c"), "--out", str(tmp_path / "p")])
    with pytest.raises(SystemExit, match="nowhere"):
        main(["pointcloud", "infer", str(cloud), "--weights", str(path), "--retrieval", "--clouds", str(tmp_path / "nowhere"),
              "--out", str(tmp_path / "p")])


def test_the_retrieval_augmented_rows_are_measured_on_request(tmp_path, model):
    make_clouds("chair", tmp_path / "c", n_points=SEARCH_POINTS, workers=1, ids=TRAIN[:4] + SPLITS["test"][:1])
    w = tmp_path / "w.pt"
    torch.save({"format": "shapeprog-pointcloud", "version": 1, "recipe": "latent", "category": "chair",
                "config": model.encoder.config, "hidden_dim": 256, "encoder": model.encoder.state_dict(),
                "meta": {}}, w)
    res = evaluate(tmp_path / "c", "chair", weights=w, limit=1, steps=2, stability=False, augmented=True)
    assert {"augmented", "augmented_opt_program"} <= set(res.rows) and res.settings["augmented"] is True
    for row in ("augmented", "augmented_opt_program"):
        m = res.rows[row]
        assert m["n"] == 1 and 0.0 <= m["fscore"] <= 100.0 and m["cd"] is not None and m["stable"] is None
    text = write_tables(res, tmp_path / "t.md").read_text()
    assert "Ours + quick search + retrieval-augmented decoding (not the papers' protocol; no fitting)" in text
    assert "retrieval alone on F-score without fitting" in text
