"""The default method of ``infer`` (robust): candidates from encoder subsets and training programs, the one closest to
the input kept, a polish kept only when it helps; the up-axis check; a mesh against its own points."""
import importlib
import warnings

import numpy as np
import pytest
import torch

from shapeprog import corpus
from shapeprog.lang import to_text
from shapeprog.pointcloud import tables
from shapeprog.pointcloud.data import corpus_cloud
from shapeprog.pointcloud.infer import (DEFAULT_METHOD, SELECT_POINTS, UpAxisWarning, _corners_of, infer,
                                        load_pretrained, selection_scores, shape_metrics)
from shapeprog.pointcloud.normalize import Transform
from shapeprog.sampling import sample_surface

CHAIR = corpus.ids("chair", "val")[0]


@pytest.fixture(scope="module")
def model():
    return load_pretrained("chair")


def box_chair():
    """A box chair as one trimesh mesh, y up: a seat, four legs and a back (overlapping boxes, as a user builds it)."""
    import trimesh

    def box(size, centre):
        return trimesh.creation.box(extents=size, transform=trimesh.transformations.translation_matrix(centre))

    parts = [box((1.0, 0.1, 1.0), (0.0, 0.5, 0.0)), box((1.0, 1.0, 0.1), (0.0, 1.05, -0.45))]
    parts += [box((0.1, 0.5, 0.1), (x, 0.225, z)) for x in (-0.45, 0.45) for z in (-0.45, 0.45)]
    return trimesh.util.concatenate(parts)


def test_the_default_is_the_robust_method_and_the_tables_decode_once(model, monkeypatch):
    assert DEFAULT_METHOD == "robust"
    cloud = corpus_cloud("chair", CHAIR, n_points=3000)
    assert infer(cloud, model=model, physics=False).robust is not None
    assert infer(cloud, model=model, physics=False, method="decode").robust is None
    calls = []
    real = tables.infer
    monkeypatch.setattr(tables, "infer", lambda *a, **kw: calls.append(kw) or real(*a, **kw))
    tables._shape_job((None, "chair", CHAIR, corpus_cloud("chair", CHAIR, n_points=3000).astype(np.float64), None, 2,
                       False, 0, False, None))
    assert [kw.get("method") for kw in calls] == ["decode", "decode"]  # the model and Opt Program rows


def test_bad_settings_are_refused(model):
    cloud = corpus_cloud("chair", CHAIR, n_points=3000)
    with pytest.raises(ValueError, match="method must be one of 'robust', 'decode'"):
        infer(cloud, model=model, method="best")
    with pytest.raises(ValueError, match="subsets must be an integer >= 1"):
        infer(cloud, model=model, subsets=0)
    with pytest.raises(ValueError, match="polish_steps must be an integer >= 0"):
        infer(cloud, model=model, polish_steps=-1)
    with pytest.raises(ValueError, match="select must be 'fscore' or 'chamfer'"):
        infer(cloud, model=model, select="iou")


def test_the_robust_method_is_deterministic_under_its_seed_and_frame_free(model):
    cloud = corpus_cloud("chair", CHAIR, n_points=5000).astype(np.float64)
    a = infer(cloud, model=model, physics=False, seed=3)
    b = infer(cloud, model=model, physics=False, seed=3)
    assert a.text == b.text and a.robust == b.robust
    k, shift = 7.5, np.array([10.0, -3.0, 0.5])
    moved = infer(cloud * k + shift, model=model, physics=False, seed=3)
    assert to_text(moved.canonical) == to_text(a.canonical)
    assert np.allclose(moved.corners(), a.corners() * k + shift, atol=1e-3 * k)


@pytest.mark.parametrize("select", ["fscore", "chamfer"])
def test_the_result_is_never_worse_than_its_best_candidate(model, select):
    cloud = corpus_cloud("chair", CHAIR, n_points=5000).astype(np.float64)
    r = infer(cloud, model=model, physics=False, seed=1, select=select)
    key = (lambda s: (-s[0], s[1])) if select == "fscore" else (lambda s: (s[1], -s[0]))
    rec = r.robust
    assert rec["decoded"] == 4 and rec["retrieved"] == 16 and len(rec["scores"]) == 20
    assert key(rec["score"]) == min(key(s) for s in rec["scores"])
    final = rec["polished"] or rec["score"]
    assert key(final) <= key(rec["score"])
    # the recorded score is the returned program's, in the frame it was scored in
    unit = r.transform.apply(cloud)
    g = torch.Generator().manual_seed(1)
    target = torch.from_numpy(unit)[torch.randperm(len(unit), generator=g)[:SELECT_POINTS]]
    pts = sample_surface(_corners_of(r.canonical).double() + torch.from_numpy(r.canonical_offset), SELECT_POINTS,
                         generator=torch.Generator().manual_seed(1))[0]
    if rec["polished"] is not None or rec["chosen"] is None:
        assert selection_scores([pts], target)[0] == pytest.approx(final, abs=1e-9)


def test_a_polish_that_does_not_help_is_dropped(model, monkeypatch):
    infer_module = importlib.import_module("shapeprog.pointcloud.infer")

    cloud = corpus_cloud("chair", CHAIR, n_points=5000).astype(np.float64)
    plain = infer(cloud, model=model, physics=False, polish_steps=0)
    real = infer_module.fit_program

    def worse(program, points, **kw):  # a polish that moves every number far away
        r = real(program, points, **kw)
        return type(r)(**{**r.__dict__, "program": infer_module.scale_program(program, 0.5)})

    monkeypatch.setattr(infer_module, "fit_program", worse)
    r = infer(cloud, model=model, physics=False)
    assert r.robust["polished"] is None and r.text == plain.text


def test_selection_scores_are_the_f_score_and_chamfer():
    a = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    b = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.1, 0.0]], dtype=torch.float64)
    (f, cd), (f0, cd0) = selection_scores([b, None], a)
    assert cd == pytest.approx(0.1) and f == pytest.approx(50.0, abs=1e-6)  # half of each side within 0.03
    assert f0 == 0.0 and cd0 == float("inf")


def test_a_mesh_and_its_points_give_the_same_result(model, tmp_path):
    from shapeio.points import MESH_POINTS, read_cloud

    mesh = box_chair()
    mesh.export(tmp_path / "chair.obj")
    pts, _ = __import__("trimesh").sample.sample_surface(mesh, 5000, seed=np.random.default_rng(5))
    np.savetxt(tmp_path / "chair.xyz", pts)
    from_mesh = read_cloud(tmp_path / "chair.obj")
    assert from_mesh.shape == (MESH_POINTS, 3)
    dense = read_cloud(tmp_path / "chair.obj", n_points=20_000, seed=9)  # the reference both results are scored on
    fs = []
    for cloud in (from_mesh, read_cloud(tmp_path / "chair.xyz")):
        for seed in range(2):
            r = infer(cloud, model=model, physics=False, seed=seed)
            fs.append(shape_metrics(torch.from_numpy(r.transform.apply(r.corners())),
                                    torch.from_numpy(r.transform.apply(dense.astype(np.float64))),
                                    physics=False)["fscore"])
    assert max(fs) - min(fs) < 3.0, fs


def test_a_z_up_chair_is_detected_or_named_in_a_warning(model):
    import trimesh

    pts, _ = trimesh.sample.sample_surface(box_chair(), 5000, seed=np.random.default_rng(0))
    z_up = pts @ Transform((0.0, 0.0, 0.0), 1.0, "z").rotation  # canonical = rotation @ input: a z-up file
    with pytest.warns(UpAxisWarning, match=r"up='z'.*--up z"):
        wrong = infer(z_up, model=model, physics=False)
    assert wrong.up_scores["z"] < 0.7 * wrong.up_scores["y"]
    auto = infer(z_up, model=model, physics=False, up="auto")
    assert auto.transform.up == "z" and min(auto.up_scores, key=auto.up_scores.get) == "z"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the y-up chair: no warning
        right = infer(pts, model=model, physics=False)
    assert right.metrics["fscore"] > wrong.metrics["fscore"] + 15
    assert auto.metrics["fscore"] == pytest.approx(right.metrics["fscore"], abs=5)


def test_the_command_line_runs_the_robust_method_and_prints_the_up_hint_on_one_line(tmp_path, capsys):
    import json

    import trimesh

    from shapeprog.__main__ import main

    pts, _ = trimesh.sample.sample_surface(box_chair(), 5000, seed=np.random.default_rng(0))
    src = tmp_path / "zchair.npy"
    np.save(src, pts @ Transform((0.0, 0.0, 0.0), 1.0, "z").rotation)
    assert main(["pointcloud", "infer", str(src), "--no-stability", "--polish-steps", "0", "--out",
                 str(tmp_path / "o")]) == 0
    out, err = capsys.readouterr()
    assert [ln for ln in err.splitlines() if ln.startswith("warning:")] == [
        ln for ln in err.splitlines() if "--up z" in ln]
    assert sum("--up z" in ln for ln in err.splitlines()) == 1
    assert "robust: 4 decoded and " in out and "against 2048 input points" in out
    record = json.loads((tmp_path / "o" / "zchair.json").read_text())
    assert record["method"] == "robust" and record["robust"]["decoded"] == 4 and set(record["up_scores"]) >= {"y", "z"}
    assert main(["pointcloud", "infer", str(src), "--up", "auto", "--method", "decode", "--no-stability", "--out",
                 str(tmp_path / "d")]) == 0
    record = json.loads((tmp_path / "d" / "zchair.json").read_text())
    assert record["method"] == "decode" and record["robust"] is None and record["transform"]["up"] == "z"
