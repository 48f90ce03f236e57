"""shapeprog.pointcloud.tables: free cuboid fitting, the protocol's inputs, and both table layouts."""
import numpy as np
import pytest
import torch

from shapeprog import corpus, execute
from shapeprog.__main__ import main
from shapeprog.lang import parse
from shapeprog.metrics import chamfer
from shapeprog.pointcloud.data import corpus_cloud, corpus_splits, make_clouds
from shapeprog.pointcloud.tables import KEEP_MARK, TableResult, _inputs, evaluate, fit_cuboids, write_tables

SPLITS = corpus_splits("chair")


def test_free_cuboids_start_where_they_are_and_move_towards_the_cloud():
    p = parse(corpus.read("chair", SPLITS["test"][0]))
    c = execute(p).corners
    assert torch.allclose(fit_cuboids(c, torch.rand(50, 3), steps=0), c, atol=1e-5)
    target = torch.from_numpy(corpus_cloud("chair", SPLITS["test"][0], 2000)).double() * 1.15
    g = torch.Generator().manual_seed(0)
    fitted = fit_cuboids(c, target, steps=60, lr=1e-2, generator=g)
    assert fitted.shape == c.shape

    def cd(corners):
        from shapeprog.sampling import sample_surface
        pts, _ = sample_surface(corners.double(), 4000, generator=torch.Generator().manual_seed(1))
        return float(chamfer(pts, target))
    assert cd(fitted) < 0.8 * cd(c)


def test_inputs_are_noisy_moved_and_scaled_copies_with_the_transform_given():
    clean = corpus_cloud("chair", 173, 5000).astype(np.float64)
    x, k, b = _inputs(clean, 173, seed=0)
    assert x.shape == (2048, 3) and 0.1 <= k <= 10.0
    back = (x - b) / k
    d = np.linalg.norm(back[:, None, :] - clean[None, :500, :], axis=2).min(1)  # near the clean surface
    assert np.median(np.abs(back - back.mean(0))) > 0.05 and np.quantile(d, 0.5) < 0.1
    x2, k2, b2 = _inputs(clean, 173, seed=0)
    assert np.array_equal(x, x2) and k == k2


def _tiny_cache_and_weights(tmp_path, train: int, test: int):
    """A cloud cache of ``train`` + ``test`` chairs and a tiny untrained encoder's weights file."""
    from shapeprog.pointcloud.encoder import PointNet2SSG
    make_clouds("chair", tmp_path / "c", n_points=512, workers=1, ids=SPLITS["train"][:train] + SPLITS["test"][:test])
    torch.manual_seed(0)
    enc = PointNet2SSG(out_dim=256, npoints=[16, 8], nsamples=[8, 8], widths=[[8, 8, 16], [16, 16, 32], [32, 32, 64]])
    w = tmp_path / "w.pt"
    torch.save({"format": "shapeprog-pointcloud", "version": 1, "recipe": "latent", "category": "chair",
                "config": enc.config, "hidden_dim": 256, "encoder": enc.state_dict(), "meta": {}}, w)
    return w


def test_evaluate_and_write_both_layouts(tmp_path):
    w = _tiny_cache_and_weights(tmp_path, 4, 2)
    res = evaluate(tmp_path / "c", "chair", weights=w, limit=2, steps=3, stability=False)
    assert res.shapes == 2 and set(res.rows) == {"model", "opt_program", "opt_cuboids", "retrieval"}
    for m in res.rows.values():
        assert 0.0 <= m["fscore"] <= 100.0 and m["n"] == 2 and m["stable"] is None
    out = write_tables(res, tmp_path / "t.md", "python -m shapeprog pointcloud-tables ...")
    text = out.read_text()
    assert "ShapeMOD Table 3 layout" in text and "ShapeAssembly Table 7 layout" in text
    assert "| ShapeMOD paper, No Macros | 44.2 | 54.8 | 93.7 | 83.6 |" in text
    for row in ("| ShapeAssembly paper | 31.1 | 95.5 | 84.4 |", "| ShapeAssembly paper, Opt Program | 75.8 | 95.3 | 80.2 |",
                "| ShapeAssembly paper, Opt Cuboids | 77.6 | 93.1 | 72.9 |"):  # Table 7's three paper rows
        assert row in text
    assert "the paper's Table 7 used its adaptive F-score threshold" in text
    assert "Nearest training shape (retrieval)" in text
    m = res.rows["model"]  # the measured row is the one written, number for number
    assert f"| {m['cd']:.1f} | {m['fscore']:.1f} | {m['rooted']:.1f} | n/a |" in text
    assert res.settings["macros"] is False and "ShapeMOD (macros)" not in text
    # a model of macro programs labels its rows and shows the paper's ShapeMOD row beside them
    res.settings["macros"] = True
    text = write_tables(res, tmp_path / "m.md").read_text()
    assert "| ShapeMOD paper, ShapeMOD (macros) | 41.7 | 56.1 | 96.9 | 88.0 |" in text
    assert "| Ours, ShapeMOD macros: PointNet++" in text and "| Ours: PointNet++" not in text
    assert main(["pointcloud", "tables", "--clouds", str(tmp_path / "c"), "--weights", str(w), "--limit", "1",
                 "--steps", "1", "--no-stability", "--no-retrieval", "--quiet", "--out", str(tmp_path / "t2.md")]) == 0
    assert "--limit 1" in (tmp_path / "t2.md").read_text()


def test_the_latent_search_rows_are_measured_on_request(tmp_path):
    w = _tiny_cache_and_weights(tmp_path, 3, 1)
    res = evaluate(tmp_path / "c", "chair", weights=w, limit=1, steps=2, stability=False, search=True)
    assert {"search", "search_opt_program"} <= set(res.rows) and res.settings["search"] is True
    text = write_tables(res, tmp_path / "t.md").read_text()
    assert "Ours + latent search (not the papers' protocol; no fitting)" in text
    assert "With latent search the model" in text


def test_a_fit_that_fails_empties_its_own_row_only(tmp_path, monkeypatch):
    import shapeprog.pointcloud.tables as tables

    w = _tiny_cache_and_weights(tmp_path, 3, 1)
    real = tables.infer

    def no_fit(*args, **kwargs):
        if kwargs.get("fit"):
            raise ValueError("the fit failed")
        return real(*args, **kwargs)

    monkeypatch.setattr(tables, "infer", no_fit)
    res = evaluate(tmp_path / "c", "chair", weights=w, limit=1, steps=2, stability=False, retrieval=False)
    assert res.rows["opt_program"]["fscore"] == 0.0 and res.rows["opt_program"]["rooted"] == 0.0
    assert res.rows["model"]["fscore"] > 0.0 and res.rows["opt_cuboids"]["fscore"] > 0.0
    # the shape and the error are named under the tables, per row
    test_id = SPLITS["test"][0]
    assert res.failed == {"model": 0, "opt_program": 1, "opt_cuboids": 0}
    assert res.errors == {"model": [], "opt_program": [(test_id, "the fit failed")], "opt_cuboids": []}
    text = write_tables(res, tmp_path / "t.md").read_text()
    assert f"* opt_program: chair/{test_id}: the fit failed\n" in text


def test_rewriting_a_table_file_keeps_what_follows_the_keep_mark(tmp_path):
    model_row = {"cd": 80.0, "fscore": 50.0, "rooted": 100.0, "stable": None, "n": 1}
    res = TableResult("storage", 1, rows={"model": model_row})
    out = tmp_path / "t.md"
    section = KEEP_MARK + "\n## Harder test conditions\n\n<!-- result: x.json -->\nold\n<!-- end result -->\n"
    out.write_text("the old tables\n" + section)
    text = write_tables(res, out, "python -m shapeprog pointcloud tables ...").read_text()
    assert "the old tables" not in text and "| 80.0 | 50.0 | 100.0 | n/a |" in text
    assert text.endswith("    python -m shapeprog pointcloud tables ...\n\n" + section) and text.count(KEEP_MARK) == 1
    out.write_text("the old tables\n")
    text = write_tables(res, out).read_text()
    assert KEEP_MARK not in text and "the old tables" not in text
