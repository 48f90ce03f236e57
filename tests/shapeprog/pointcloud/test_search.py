"""shapeprog.pointcloud.search: the latent search never does worse than the predicted code, is seeded, and
checks its schedule; ``infer(..., search=True)`` and ``python -m shapeprog infer --search`` use it."""
import json
import math

import numpy as np
import pytest
import torch

from shapeprog import corpus
from shapeprog.__main__ import main
from shapeprog.lang import to_text
from shapeprog.pointcloud.data import corpus_cloud
from shapeprog.pointcloud.encoder import PointNet2SSG
from shapeprog.pointcloud.infer import CloudModel, infer, shape_metrics
from shapeprog.pointcloud.normalize import align_program, _corners_of
from shapeprog.pointcloud.normalize import normalize
from shapeprog.pointcloud.search import (MAX_SEARCH_DECODES, SEARCH_SCHEDULE, aligned_corners, check_schedule,
                                         latent_search, parse_schedule)
from shapeprog.vae.pretrained import load_pretrained as load_vae

TINY = dict(npoints=[16, 8], radii=[0.3, 0.6], nsamples=[8, 8], widths=[[8, 8, 16], [16, 16, 32], [32, 32, 64]])
CHAIR = corpus.ids("chair", "val")[0]
SHORT = ((4, 0.75), (4, 0.4))


@pytest.fixture(scope="module")
def model():
    torch.manual_seed(0)
    return CloudModel(PointNet2SSG(out_dim=256, **TINY), load_vae("chair"), "chair", "latent")


@pytest.fixture(scope="module")
def unit():
    cloud, _ = normalize(corpus_cloud("chair", CHAIR, n_points=3000).astype(np.float64))
    return torch.from_numpy(cloud)


class Counting:
    """A model whose decode counts the codes it is given."""

    def __init__(self, model):
        self.model, self.codes = model, []

    def decode(self, codes):
        self.codes.extend(codes)
        return self.model.decode(codes)


def test_the_result_is_never_worse_than_the_predicted_code_and_is_seeded(model, unit):
    code = model.codes(unit[None, :2048].float())[0]
    counted = Counting(model)
    r = latent_search(counted, code, unit, SHORT, seed=3)
    assert r.decodes == len(counted.codes) == 1 + 4 + 4
    assert torch.equal(counted.codes[0], code)  # the predicted code is the first candidate
    assert r.cd <= r.start_cd and math.isfinite(r.cd)
    # the reported chamfer is the kept program's, scored the way the search scores
    again = latent_search(model, code, unit, SHORT, seed=3)
    assert to_text(again.program) == to_text(r.program) and again.cd == r.cd and torch.equal(again.code, r.code)
    assert to_text(model.decode(r.code[None])[0]) == to_text(r.program)


def _selection_chamfers(model, codes, unit, seed):
    """Each code's selection chamfer, computed as the search computes it (inf for no shape)."""
    target = unit[torch.randperm(len(unit), generator=torch.Generator().manual_seed(seed))[:1024]]
    out = []
    for p in model.decode(torch.stack(list(codes))):
        if p is None:
            out.append(math.inf)
            continue
        canon, off = align_program(p)
        corners = _corners_of(canon).double() + torch.from_numpy(off)
        out.append(shape_metrics(corners, target, points=1024, seed=seed, physics=False)["cd"])
    return out


def test_every_step_samples_around_the_best_code_so_far(model, unit):
    code = model.codes(unit[None, :2048].float())[0]
    counted = Counting(model)
    r = latent_search(counted, code, unit, ((3, 0.5), (3, 1e-4)), seed=0)
    # the second step's sigma is tiny: its codes sit around the best code of the first step (the predicted
    # code wins ties), and around no other
    first = [code] + counted.codes[1:4]
    cds = _selection_chamfers(model, first, unit, seed=0)
    best = min(range(4), key=lambda i: (cds[i], i))
    second = torch.stack(counted.codes[4:7])
    near = [torch.allclose(second, c[None].expand_as(second), atol=1e-2) for c in first]
    assert near[best] and sum(near) == 1
    assert r.improved <= 2


def test_the_kept_program_has_the_lowest_selection_chamfer_among_the_candidates(model, unit):
    code = model.codes(unit[None, :2048].float())[0]
    counted = Counting(model)
    r = latent_search(counted, code, unit, ((6, 0.8),), seed=1)
    scores = [c for c in _selection_chamfers(model, counted.codes, unit, seed=1) if math.isfinite(c)]
    # shape_metrics draws the surface samples with the search's seed: the same chamfer, exactly
    assert len(scores) >= 2 and r.cd == pytest.approx(min(scores), rel=1e-12)


def test_batched_alignment_gives_the_numbers_of_aligning_one_program_at_a_time(model):
    codes = 0.7 * torch.randn(12, 256, generator=torch.Generator().manual_seed(5))
    programs = model.decode(codes) + [None]
    got = aligned_corners(programs)
    assert got[-1] is None and sum(c is not None for c in got) >= 6
    for p, c in zip(programs, got):
        if p is None:
            assert c is None
            continue
        canon, off = align_program(p)
        assert torch.equal(c, _corners_of(canon).double() + torch.from_numpy(off))



def test_a_batch_that_fails_to_execute_is_run_one_program_at_a_time(model, monkeypatch):
    import shapeprog.pointcloud.search as search

    programs = [p for p in model.decode(0.7 * torch.randn(6, 256, generator=torch.Generator().manual_seed(6)))
                if p is not None]
    want = aligned_corners(programs)
    real, calls = search.execute_batch, []

    def fails_in_batches(batch):
        calls.append(len(batch))
        if len(batch) > 1:
            raise ValueError("a program of the batch cannot be executed")
        return real(batch)

    monkeypatch.setattr(search, "execute_batch", fails_in_batches)
    got = aligned_corners(programs)
    assert len(programs) >= 2 and calls[0] == len(programs)
    assert all(a is not None and torch.equal(a, b) for a, b in zip(got, want))


@pytest.mark.parametrize("schedule, match", [
    ((), "no step"), (((0, 0.5),), "samples must be"), (((2, 0.0),), "sigma must"), (((2, float("nan")),), "sigma"),
    (((True, 0.5),), "samples"), ((3,), r"expected \(samples, sigma\)"), (((MAX_SEARCH_DECODES + 1, 0.5),), "at most"),
])
def test_bad_schedules_are_refused(schedule, match):
    with pytest.raises(ValueError, match=match):
        check_schedule(schedule)


def test_schedules_parse_from_text():
    assert parse_schedule("16:0.75, 8:0.5") == ((16, 0.75), (8, 0.5))
    assert check_schedule(SEARCH_SCHEDULE) == SEARCH_SCHEDULE
    assert parse_schedule("fast") == ((8, 0.5), (8, 0.25)) and parse_schedule(" default ") == SEARCH_SCHEDULE
    for bad in ("16", "a:0.5", "16:0.5:1", ""):
        with pytest.raises(ValueError, match="search step 0"):
            parse_schedule(bad)


def test_infer_with_search_reports_it_and_keeps_the_frame(model):
    cloud = corpus_cloud("chair", CHAIR, n_points=3000).astype(np.float64)
    k, b = 4.0, np.array([1.0, 2.0, -3.0])
    plain = infer(cloud, model=model, physics=False, method="decode")
    r = infer(cloud, model=model, physics=False, search=True, search_schedule=SHORT)
    moved = infer(cloud * k + b, model=model, physics=False, search=True, search_schedule=SHORT)
    assert r.search["decodes"] == 9 and r.search["cd"] <= r.search["start_cd"]
    assert "search" in r.seconds and plain.search is None
    assert to_text(moved.canonical) == to_text(r.canonical)
    assert np.allclose(moved.corners(), r.corners() * k + b, atol=1e-3 * k)
    with pytest.raises(ValueError, match="sigma"):
        infer(cloud, model=model, physics=False, search=True, search_schedule=((2, -1.0),))
    # the CLI's text form and names are accepted too, and a schedule without search=True is refused
    as_text = ",".join(f"{n}:{sigma}" for n, sigma in SHORT)
    t = infer(cloud, model=model, physics=False, search=True, search_schedule=as_text)
    assert t.text == r.text and t.search == r.search
    assert infer(cloud, model=model, physics=False, search=True, search_schedule="fast").search["decodes"] == 17
    with pytest.raises(ValueError, match="search step 0: expected samples:sigma"):
        infer(cloud, model=model, physics=False, search=True, search_schedule="fast-ish")
    with pytest.raises(ValueError, match="search_schedule is given but search is False"):
        infer(cloud, model=model, physics=False, search_schedule=SHORT)


def test_cli_search_prints_and_records_it(tmp_path, model, capsys):
    path = tmp_path / "tiny.pt"
    torch.save({"format": "shapeprog-pointcloud", "version": 1, "recipe": "latent", "category": "chair",
                "config": model.encoder.config, "hidden_dim": 256, "encoder": model.encoder.state_dict(),
                "meta": {}}, path)
    cloud = tmp_path / "c.npy"
    np.save(cloud, corpus_cloud("chair", CHAIR, n_points=2000))
    assert main(["pointcloud", "infer", str(cloud), "--weights", str(path), "--search-schedule", "3:0.5", "--no-stability",
                 "--out", str(tmp_path / "o")]) == 0
    assert "latent search: 4 decodes" in capsys.readouterr().out
    record = json.loads((tmp_path / "o" / "c.json").read_text())
    assert record["search"]["decodes"] == 4
    with pytest.raises(SystemExit, match="search step 0"):
        main(["pointcloud", "infer", str(cloud), "--weights", str(path), "--search-schedule", "3", "--out", str(tmp_path / "p")])
