"""Tests for shapeprog.vae.genmetrics, shapeprog.vae.pointnet and shapeprog.vae.gentable: the generation metrics."""
import shutil
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch

from sa_testutil import boxes
from shapeprog import corpus, execute, parse
from shapeprog.vae.genmetrics import (
    FoolResult,
    chamfer_clouds,
    classifier_clouds,
    classifier_features,
    coverage,
    execute_samples,
    feature_variance,
    frechet_distance,
    gaussian_fit,
    generalization,
    leaf_parts,
    nearest_chamfer,
    novelty,
    percent_fool,
    program_key,
    variety,
)
from shapeprog.vae.gentable import (PAPER, GenerationRow, References, evaluate_generation, format_table,
                                    generation_result, paper_rows, table_notes)
from shapeprog.vae.structure import structure_key
from shapeprog.metrics import chamfer
from shapeprog.vae.pointnet import (PRETRAINED, PRETRAINED_SHA256, PointNetCls, accuracy, fit_classifier,
                                load_classifier, save_classifier, sha256_file)
from sa_testutil import FLAT

TINY = dict(widths=(8, 16, 32), head=(16, 8))


@pytest.fixture(scope="module")
def classifier():
    return load_classifier()


@pytest.fixture(scope="module")
def val_shapes():
    """Six executed val shapes of each category."""
    out = {}
    for cat in corpus.CATEGORIES:
        out[cat], errors = execute_samples([corpus.read(cat, i) for i in corpus.ids(cat, "val")[:6]])
        assert not errors
    return out


# ---------------------------------------------------------------- leaf parts




def test_leaf_parts_of_a_hand_written_program():
    # cube0, cube1, cube0's reflected copy and cube0's two translated copies: bbox is no leaf
    assert leaf_parts(FLAT) == 5
    p = parse(FLAT)
    shape = execute(p)
    assert leaf_parts(p) == leaf_parts(shape) == leaf_parts(shape.corners) == 5
    assert shape.mesh()[0].shape[0] / 8 == 5  # the reference's vertices / 8
    assert leaf_parts(corpus.read("chair", 173)) == 6
    with pytest.raises(TypeError, match="corners"):
        leaf_parts(torch.zeros(3, 3))


def test_execute_samples_reports_failures_by_index():
    corners, errors = execute_samples([FLAT, "bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cubiod(1)\n",
                                       "bbox = Cuboid(1.0, 1.0, 1.0, True)\n"])
    assert corners[0].shape == (5, 8, 3) and corners[1] is None and corners[2] is None
    assert len(errors) == 2 and "sample 1" in errors[0] and "sample 2: no leaf cuboid" in errors[1]


# ---------------------------------------------------------------- Fréchet distance


def test_frechet_distance_of_a_set_with_itself_is_zero_and_shift_adds_its_square():
    a = np.random.default_rng(0).normal(size=(300, 6))
    assert frechet_distance(a, a) == pytest.approx(0.0, abs=1e-9)
    shift = np.array([1.0, 2.0, 0.0, 0.0, 0.0, -1.0])
    assert frechet_distance(a, a + shift) == pytest.approx(6.0, rel=1e-9)  # same covariance: |shift|^2
    assert frechet_distance(gaussian_fit(a), a + shift) == pytest.approx(6.0, rel=1e-9)


def test_frechet_distance_is_symmetric_and_both_methods_agree():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(400, 5))
    b = rng.normal(size=(350, 5)) @ rng.normal(size=(5, 5)) + 0.3
    d = frechet_distance(a, b)
    assert d > 0 and frechet_distance(b, a) == pytest.approx(d, rel=1e-9)
    assert frechet_distance(a, b, method="sqrtm") == pytest.approx(d, rel=1e-7)
    # Gaussians: N(0, I) and N(0, 4 I) in 5-d: tr(I + 4I - 2 * 2I) = 5
    assert frechet_distance((np.zeros(5), np.eye(5)), (np.zeros(5), 4 * np.eye(5))) == pytest.approx(5.0)


def test_frechet_distance_with_fewer_shapes_than_dimensions_is_finite():
    rng = np.random.default_rng(2)
    a, b = rng.normal(size=(20, 64)), rng.normal(size=(30, 64)) + 0.1
    d = frechet_distance(a, b)
    assert np.isfinite(d) and d > 0 and frechet_distance(b, a) == pytest.approx(d, rel=1e-6)
    assert frechet_distance(a, a) == pytest.approx(0.0, abs=1e-6)


def test_frechet_distance_bad_input():
    with pytest.raises(ValueError, match="S >= 2"):
        frechet_distance(np.zeros((1, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match="feature sizes differ"):
        frechet_distance(np.ones((4, 3)), np.ones((4, 2)))
    with pytest.raises(ValueError, match="method"):
        frechet_distance(np.eye(3), np.eye(3), method="svd")


def test_feature_variance():
    f = np.array([[0.0, 1.0], [2.0, 1.0]])
    assert feature_variance(f) == pytest.approx(0.5)  # variances 1 and 0


# ---------------------------------------------------------------- classifier


def test_shipped_classifier_loads_with_its_checksum(classifier):
    model, classes, meta = classifier
    assert sha256_file(PRETRAINED) == PRETRAINED_SHA256
    assert classes == ("chair", "table", "storage") and isinstance(model, PointNetCls) and not model.training
    assert model.feature_dim == 1024 and meta["val_accuracy"] > 90
    assert PRETRAINED.stat().st_size < 4 * 2**20


def test_wrong_checksum_and_bad_files_are_refused(tmp_path):
    with pytest.raises(ValueError, match="SHA-256"):
        load_classifier(PRETRAINED, sha256="0" * 64)
    copy = tmp_path / "cls.pt"
    shutil.copy(PRETRAINED, copy)
    load_classifier(copy)  # another path: no expected checksum unless given
    load_classifier(copy, sha256=PRETRAINED_SHA256.upper())
    copy.write_bytes(copy.read_bytes()[:1000])
    with pytest.raises(ValueError, match="SHA-256"):
        load_classifier(copy, sha256=PRETRAINED_SHA256)
    with pytest.raises(ValueError, match="not a PointNet classifier weights file"):
        load_classifier(copy)
    with pytest.raises(FileNotFoundError):
        load_classifier(tmp_path / "missing.pt")


def test_classifier_recognises_val_shapes_above_chance(classifier, val_shapes):
    model, classes, _ = classifier
    clouds = torch.cat([classifier_clouds(val_shapes[c], seed=5) for c in classes])
    labels = torch.arange(3).repeat_interleave(6)
    assert accuracy(model, clouds, labels) > 60  # chance: 33 %


def test_features_fd_between_categories(classifier, val_shapes):
    model = classifier[0]
    chairs = classifier_features(val_shapes["chair"], model)
    tables = classifier_features(val_shapes["table"], model)
    assert chairs.shape == (6, 1024) and chairs.dtype == np.float64
    assert torch.equal(torch.as_tensor(classifier_features(val_shapes["chair"], model)), torch.as_tensor(chairs))
    d = frechet_distance(chairs, tables)
    assert d > 0 and frechet_distance(tables, chairs) == pytest.approx(d, rel=1e-6)
    assert frechet_distance(chairs, chairs) == pytest.approx(0.0, abs=1e-6 * d)


def test_save_load_round_trip_and_seeded_training(tmp_path):
    g = torch.Generator().manual_seed(0)
    clouds = torch.rand(12, 40, 3, generator=g)
    labels = torch.arange(12) % 2
    clouds[labels == 1, :, 1] *= 3  # tall clouds are class 1
    state = torch.get_rng_state()
    a = fit_classifier(clouds, labels, epochs=2, batch_size=4, points=20, seed=3, **TINY)
    b = fit_classifier(clouds, labels, epochs=2, batch_size=4, points=20, seed=3, **TINY)
    assert torch.equal(state, torch.get_rng_state())  # global RNG untouched
    for x, y in zip(a.state_dict().values(), b.state_dict().values()):
        assert torch.equal(x, y)
    path = save_classifier(tmp_path / "w" / "m.pt", a, ["short", "tall"], {"note": 1})
    model, classes, meta = load_classifier(path, sha256=sha256_file(path))
    assert classes == ("short", "tall") and meta == {"note": 1}
    assert torch.equal(model(clouds), a(clouds))


# ---------------------------------------------------------------- % fool


def test_percent_fool_runs_on_a_tiny_budget():
    g = torch.Generator().manual_seed(0)
    real = torch.rand(10, 64, 3, generator=g) - 0.5
    fake = (torch.rand(12, 64, 3, generator=g) - 0.5) * torch.tensor([1.0, 0.2, 1.0])
    res = percent_fool(fake, real, epochs=3, average_last=2, holdout=0.2, points=32, batch_size=4, **TINY)
    assert isinstance(res, FoolResult) and 0.0 <= res.percent <= 100.0
    assert len(res.per_epoch) == 2 and res.train == 8 and res.held_out == 2
    assert res.percent == pytest.approx((res.generated_as_real + res.real_as_generated) / 2)
    again = percent_fool(fake, real, epochs=3, average_last=2, holdout=0.2, points=32, batch_size=4, **TINY)
    assert again.percent == res.percent
    with pytest.raises(ValueError, match="average_last"):
        percent_fool(fake, real, epochs=2, average_last=3)


# ---------------------------------------------------------------- chamfer: generalization, coverage, variety


def _points(*xs):
    """Clouds of one point each, on the x axis."""
    return torch.tensor([[[x, 0.0, 0.0]] for x in xs])


@pytest.mark.parametrize("candidates", [None, 1, 2])
def test_nearest_chamfer_known_answers(candidates):
    # single-point clouds: chamfer = 2 |a - b| (both directions)
    d, i = nearest_chamfer(_points(0.0, 0.35), _points(0.1, 0.3, -0.45), candidates=candidates)
    assert np.allclose(d, [0.2, 0.1]) and i.tolist() == [0, 1]
    assert variety(_points(0.0, 0.1, 0.4), candidates=candidates) == pytest.approx((0.2 + 0.2 + 0.6) / 3)
    assert coverage(_points(0.0, 0.4), _points(0.1, 0.3), candidates=candidates) == pytest.approx(0.2)
    assert generalization(_points(0.1, 0.3), _points(0.1, 0.3, 0.2), candidates=candidates) == 0.0


def test_identical_and_translated_shapes_have_zero_generalization():
    shapes = [boxes([[0, 0.5, 0], [0, 1.2, 0.3]], [[1, 1, 1], [0.2, 0.4, 0.6]]),
              boxes([[0, 0, 0]], [[2.0, 0.1, 1.0]]), boxes([[0, 0, 0], [1, 0, 0]], [[1, 1, 1], [1, 1, 1]])]
    clouds = chamfer_clouds(shapes, 256)
    assert clouds.abs().max() <= 0.5
    assert generalization(clouds, clouds) == 0.0
    moved = chamfer_clouds([(s + torch.tensor([3.0, -1.0, 0.5])) * 2.5 for s in shapes], 256)
    assert generalization(moved, clouds) < 1e-5  # normalised: translation and scale do not count
    assert variety(clouds) > 0.05


def test_nearest_chamfer_exact_stage_is_the_metrics_chamfer_and_coarse_finds_the_nearest():
    g = torch.Generator().manual_seed(0)
    refs = (torch.rand(40, 48, 3, generator=g) - 0.5) * torch.rand(40, 1, 3, generator=g)
    queries = refs[:25] + 0.02 * torch.randn(25, 48, 3, generator=g)
    queries = queries.clamp(-0.5, 0.5)
    exact, idx = nearest_chamfer(queries, refs, candidates=None)
    want = [min(float(chamfer(q, r, eps=0.0)) for r in refs) for q in queries]
    assert np.allclose(exact, want, atol=1e-6)
    coarse, cidx = nearest_chamfer(queries, refs, candidates=4)
    assert (coarse >= exact - 1e-12).all() and (cidx == idx).mean() >= 0.9
    with ThreadPoolExecutor(2) as pool:
        threaded = nearest_chamfer(queries, refs, candidates=4, executor=pool, chunk=3)
    assert np.array_equal(threaded[0], coarse) and np.array_equal(threaded[1], cidx)
    with pytest.raises(ValueError, match=r"\[-0.5, 0.5\]"):
        nearest_chamfer(queries * 3, refs)


# ---------------------------------------------------------------- novelty


def test_novelty_on_known_texts():
    train = [FLAT, corpus.read("chair", 173)]
    respaced = FLAT.replace(", ", ",   ").replace("1.0", "1").replace("0.8)", "0.8000001)")
    other = FLAT.replace("0.8)", "0.7)")
    assert program_key(respaced) == program_key(FLAT)
    assert novelty([respaced, parse(FLAT)], train) == 0.0
    assert novelty([respaced, other], train) == 50.0
    assert novelty([other], train) == 100.0


# ---------------------------------------------------------------- the table


def test_evaluate_generation_end_to_end_on_a_small_reference(classifier, val_shapes):
    model = classifier[0]
    train_programs = [parse(corpus.read("chair", i)) for i in corpus.ids("chair", "train")[:10]]
    train_corners = execute_samples(train_programs)[0]
    val_programs = [corpus.read("chair", i) for i in corpus.ids("chair", "val")[:6]]
    train_clouds = classifier_clouds(train_corners)
    refs = References("chair", train_programs, val_programs, train_corners, val_shapes["chair"], train_clouds,
                      gaussian_fit(classifier_features(train_clouds, model)), chamfer_clouds(train_corners, 128),
                      chamfer_clouds(val_shapes["chair"], 128))
    samples = [train_programs[0], val_programs[1], "not a program", val_programs[2], FLAT]
    row = evaluate_generation(samples, refs, model=model, stability=False, fool_epochs=1, fool_average_last=1,
                              fool_points=32, chamfer_points=128)
    assert (row.samples, row.valid) == (5, 4) and len(row.errors) == 1
    assert row.novelty == 75.0 and row.stable is None and row.stable_paper is None and 0 <= row.rooted <= 100
    known = {structure_key(p) for p in train_programs}
    valid = [train_programs[0], val_programs[1], val_programs[2], FLAT]
    assert row.novelty_structure == 100.0 * sum(structure_key(p) not in known for p in valid) / 4 < 100.0
    assert 0 <= row.fool <= 100 and row.fd > 0 and row.leaf_parts > 0
    assert row.generalization >= 0 and row.coverage > 0 and row.variety > 0
    table = format_table([row], "chair", ["FD values are comparable only within one classifier."])
    assert ("| % rooted | % stable (code rule, 2.5 %) | % stable (paper rule, 10 %) | % fool | FD | leaf parts |"
            in table and "| % novel (text) | % novel (structure) |" in table)
    # the paper's stability is under its 10 % rule: its figure sits in that column, the code-rule cell is empty
    assert "generated (4 of 5 programs)" in table and "| paper: ShapeAssembly | 94.5 | — | 84.7 | 25.06 | 22.34 |" in table
    notes = " ".join(table_notes({}, None, 12, 4, 512, 1024, 16, True))
    assert "compare orderings between rows, not values with the paper's" in notes and "10 % column" in notes
    assert "FD values are comparable only within one classifier." in table and "| — |" in table


def test_paper_figures():
    assert PAPER["table"]["fd"] == 49.07 and PAPER["storage"]["gt_leaf_parts"] == 10.8
    assert format_table([GenerationRow("x", 3, 3, leaf_parts=2.0)], "storage").count("\n| ") == 4


def test_paper_rows_of_either_paper():
    assert [n for n, _ in paper_rows("chair")] == ["paper: ShapeAssembly", "paper: ground truth"]
    (no_macros, nm), (_, mod) = paper_rows("chair", "shapemod")
    assert no_macros == "paper: ShapeMOD Table 2, No Macros" and (nm["fool"], nm["stable_paper"], nm["stable"]) == (
        21.2, 82.3, None)
    assert mod["leaf_parts"] == 8.6 and paper_rows("table", "shapemod") == [] and paper_rows("chair", None) == []
    table = format_table([GenerationRow("x", 3, 3, leaf_parts=2.0)], "chair", paper="shapemod")
    assert "ShapeAssembly" not in table and "| paper: ShapeMOD Table 2, ShapeMOD | 92.7 | — | 79.5 | 25.60 |" in table
    with pytest.raises(ValueError, match="unknown paper 'csgnet'"):
        paper_rows("chair", "csgnet")


def test_generation_result_rows():
    row = GenerationRow("x", 3, 2, rooted=50.0, stable=50.0, stable_paper=100.0, leaf_parts=2.0, novelty=100.0,
                        novelty_structure=50.0)
    result = generation_result([("storage", [row]), ("chair", [])], ["a note"], command="cmd")
    assert [(r["category"], r["row"]) for r in result["rows"]] == [
        ("storage", "x"), ("storage", "paper: ShapeAssembly"), ("storage", "paper: ground truth"),
        ("chair", "paper: ShapeAssembly"), ("chair", "paper: ground truth")]
    mine, paper, truth = result["rows"][:3]
    assert (mine["stable"], mine["stable_paper"], mine["novelty_structure"], mine["valid"]) == (50.0, 100.0, 50.0, 2)
    assert (paper["stable"], paper["stable_paper"], paper["rooted"]) == (None, 83.7, 95.3)
    assert truth["leaf_parts"] == 10.8 and truth["fd"] is None
    labels = [c["label"] for c in result["columns"]]
    assert "% stable (paper rule, 10 %)" in labels and "% novel (structure)" in labels
    assert result["notes"] == ["a note"] and result["command"] == "cmd"


def test_pointnet_with_input_transform_and_bad_input():
    net = PointNetCls(k=4, stn=True, **TINY).eval()
    assert tuple(net(torch.rand(3, 50, 3)).shape) == (3, 4) and net.feature_dim == 32
    with pytest.raises(ValueError, match=r"\(B, N, 3\)"):
        net(torch.rand(3, 50))
    with pytest.raises(ValueError, match="at least 2 classes"):
        PointNetCls(k=1)


# ---------------------------------------------------------------- command line


def test_evaluate_generation_command(tmp_path, monkeypatch, capsys):
    import shapeprog.vae.commands as cli
    from shapeprog.__main__ import main

    calls = []

    def fake_rows(sets, category, **kw):
        calls.append((sets[0][1], category, kw))
        return [], []

    monkeypatch.setattr(cli, "generation_rows", fake_rows)
    monkeypatch.setattr(cli, "format_table", lambda rows, category, notes, paper: "| table |\n")
    folder = tmp_path / "samples"
    folder.mkdir()
    (folder / "a.txt").write_text(FLAT)
    (folder / "b.txt").write_text("bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = cubiod(1)\n")
    out = tmp_path / "t.md"
    assert main(["vae", "evaluate", "--category", "table", "--programs", str(folder), "--out", str(out),
                     "--no-stability", "--fool-epochs", "3", "--candidates", "0", "--quiet"]) == 0
    (samples, category, kw), = calls
    assert category == "table" and samples[0] == parse(FLAT) and isinstance(samples[1], str)
    assert kw["stability"] is False and kw["fool_epochs"] == 3 and kw["candidates"] is None and kw["log"] is None
    assert out.read_text() == "| table |\n"
    captured = capsys.readouterr()
    assert "| table |" in captured.out and "b.txt:2:9: unknown command 'cubiod'" in captured.err
    with pytest.raises(SystemExit, match="no such folder"):
        main(["vae", "evaluate", "--category", "chair", "--programs", str(tmp_path / "none")])
    with pytest.raises(SystemExit, match="no .txt program files"):
        main(["vae", "evaluate", "--category", "chair", "--programs", str(tmp_path)])
    with pytest.raises(SystemExit, match="nothing to evaluate"):
        main(["vae", "evaluate", "--category", "chair", "--no-ground-truth"])
    with pytest.raises(SystemExit, match="belong to one category"):
        main(["vae", "evaluate", "--category", "chair", "table", "--programs", str(folder)])
    with pytest.raises(SystemExit, match="give -n N"):
        main(["vae", "evaluate", "--category", "chair", "--max-tries", "1"])
    with pytest.raises(SystemExit, match="give -n N"):
        main(["vae", "evaluate", "--category", "chair", "--programs", str(folder), "--paper-decoding"])
