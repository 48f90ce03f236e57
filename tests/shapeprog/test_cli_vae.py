"""Command line of the VAE: sample, interpolate, reconstruct (with a small untrained model's weights file)."""
import pytest
import torch

from shapeprog.__main__ import main
from shapeprog.lang import parse
from shapeprog.vae import VAE
from shapeprog.vae.pretrained import save_weights


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    torch.manual_seed(0)
    return str(save_weights(VAE(hidden_dim=16), tmp_path_factory.mktemp("w") / "chair.pt", "chair"))


def test_sample_writes_programs_meshes_and_grid(weights, tmp_path, capsys):
    out, png = tmp_path / "samples", tmp_path / "grid.png"
    assert main(["vae", "sample", "--category", "chair", "-n", "3", "--seed", "1", "--out", str(out), "--png", str(png),
                 "--weights", weights, "--quiet", "--size", "32"]) == 0
    report = capsys.readouterr().out
    assert "3 samples of chair" in report and "valid on the first try" in report
    for i in range(3):
        parse((out / f"sample_{i:04d}.txt").read_text())  # the text written reads back
        assert (out / f"sample_{i:04d}.obj").is_file()  # an untrained model writes bbox-only programs: no leaf
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    first = (out / "sample_0000.txt").read_text()
    again = tmp_path / "again"
    assert main(["vae", "sample", "--category", "chair", "-n", "3", "--seed", "1", "--out", str(again), "--weights", weights, "--quiet"]) == 0
    assert (again / "sample_0000.txt").read_text() == first  # the same seed gives the same programs
    # a second run into a folder with samples is refused before sampling: no mix of two runs' files
    (out / "sample_0001.txt").unlink()
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(SystemExit, match=r"sample_0000\.txt: exists \(5 of the outputs do\)"):
        main(["vae", "sample", "--category", "chair", "-n", "3", "--seed", "7", "--out", str(out), "--weights", weights, "--quiet"])
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    # ... unless --overwrite: the folder then holds the new run's files
    assert main(["vae", "sample", "-n", "3", "--seed", "1", "--out", str(out), "--weights", weights, "--quiet",
                 "--overwrite"]) == 0
    assert (out / "sample_0000.txt").read_text() == first and (out / "sample_0001.txt").is_file()


def test_the_vae_aliases_run_and_name_the_new_form(weights, tmp_path, capsys):
    # the earlier `sample CATEGORY` form: the positional category is accepted by the alias only
    assert main(["sample", "chair", "-n", "2", "--seed", "4", "--out", str(tmp_path / "a"), "--weights", weights,
                 "--quiet"]) == 0
    assert capsys.readouterr().err == "note: 'sample' is now 'vae sample'\n"
    assert main(["vae", "sample", "--category", "chair", "-n", "2", "--seed", "4", "--out", str(tmp_path / "b"),
                 "--weights", weights, "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    for name in ("sample_0000.txt", "sample_0001.txt"):
        assert (tmp_path / "a" / name).read_text() == (tmp_path / "b" / name).read_text()


def test_sample_usage_errors(weights, capsys):
    for argv in (["-n", "0"], ["--seed", "x"], ["-n", "2.5"]):
        with pytest.raises(SystemExit) as e:
            main(["vae", "sample", "--category", "chair", "--weights", weights, *argv])
        assert e.value.code == 2
    with pytest.raises(SystemExit, match=r"chair\.pt: weights of category 'chair', not 'table'"):
        main(["vae", "sample", "--category", "table", "--weights", weights])
    # the category is an option, with the same choices and error as every command's --category
    for argv in (["chair"], ["--category", "sofa"]):
        with pytest.raises(SystemExit) as e:
            main(["vae", "sample", "--weights", weights, *argv])
        assert e.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("usage: python -m shapeprog vae sample [-h]")  # the command's usage, not the top's
    assert "python -m shapeprog vae sample: error: unrecognized arguments: chair" in err
    assert err[-1].endswith("error: argument --category: invalid choice: 'sofa' (choose from 'chair', 'table', "
                            "'storage')")


def test_interpolate_and_reconstruct(weights, tmp_path, capsys):
    png, out = tmp_path / "interp.png", tmp_path / "steps"
    assert main(["vae", "interpolate", "chair/173", "chair/44017", "--steps", "3", "--png", str(png), "--out", str(out),
                 "--weights", weights, "--size", "32"]) == 0
    assert sorted(p.name for p in out.iterdir()) == [f"step_{i:03d}.{s}" for i in range(3) for s in ("obj", "txt")]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    recon = tmp_path / "recon.txt"
    assert main(["vae", "reconstruct", "chair/173", "-o", str(recon), "--weights", weights]) == 0
    report = capsys.readouterr().out
    assert "chair/173: reconstructed with" in report
    # the score names its metric and threshold: fscore's default, the input's adaptive threshold
    from shapeprog import corpus, execute
    from shapeprog.metrics import adaptive_threshold
    from shapeprog.sampling import sample_surface

    target = execute(corpus.read("chair", 173))
    g = torch.Generator().manual_seed(0)
    decoded = execute(parse(recon.read_text()))
    if len(decoded):
        sample_surface(decoded.corners, 10000, generator=g)  # the report samples the decoded shape first
    y, _ = sample_surface(target.corners, 10000, generator=g)
    assert f"F-score @{float(adaptive_threshold(y)):.3g} " in report
    parse(recon.read_text())
    with pytest.raises(SystemExit):
        main(["vae", "interpolate", "chair/173", "chair/44017", "--steps", "1", "--weights", weights])
    # an input among the outputs, or outputs of an earlier run: refused, the input unchanged
    src = tmp_path / "mine"
    src.mkdir()
    (src / "step_000.txt").write_text((out / "step_000.txt").read_text())
    before = (src / "step_000.txt").read_bytes()
    with pytest.raises(SystemExit, match=r"step_000\.txt"):
        main(["vae", "interpolate", str(src / "step_000.txt"), "chair/173", "--steps", "3", "--out", str(src),
              "--weights", weights])
    assert (src / "step_000.txt").read_bytes() == before and [p.name for p in src.iterdir()] == ["step_000.txt"]
    with pytest.raises(SystemExit, match="exists"):
        main(["vae", "interpolate", "chair/173", "chair/44017", "--steps", "3", "--out", str(out), "--weights", weights])


def test_export_weights_from_a_checkpoint(tmp_path, capsys):
    from shapeprog.vae.pretrained import load_model

    torch.manual_seed(1)
    vae = VAE(hidden_dim=8)
    ckpt = {"state_dict": {f"vae.{k}": v for k, v in vae.state_dict().items()},
            "hyper_parameters": {"category": "storage", "hidden_dim": 8}, "epoch": 4, "global_step": 40}
    torch.save(ckpt, tmp_path / "last.ckpt")
    assert main(["vae", "export-weights", str(tmp_path / "last.ckpt"), "--out", str(tmp_path / "w.pt")]) == 0
    assert "wrote" in capsys.readouterr().out
    back = load_model(tmp_path / "w.pt", category="storage")
    assert back.meta == {"epoch": 4, "global_step": 40}
    with pytest.raises(SystemExit, match="no such weights file"):
        main(["vae", "export-weights", str(tmp_path / "missing.ckpt"), "--out", str(tmp_path / "x.pt")])
    with pytest.raises(SystemExit, match="is also an input|same file|input"):
        main(["vae", "export-weights", str(tmp_path / "w.pt"), "--out", str(tmp_path / "w.pt")])
    # several checkpoints: the mean of their weights, in float32 with --float32
    other = VAE(hidden_dim=8)
    torch.save({**ckpt, "state_dict": {f"vae.{k}": v for k, v in other.state_dict().items()}, "epoch": 9},
               tmp_path / "e9.ckpt")
    assert main(["vae", "export-weights", str(tmp_path / "last.ckpt"), str(tmp_path / "e9.ckpt"), "--out",
                 str(tmp_path / "mean.pt"), "--float32"]) == 0
    mean = load_model(tmp_path / "mean.pt", category="storage")
    w = "decoder.bbdimNet.l1.weight"
    assert torch.allclose(mean.state_dict()[w], (vae.state_dict()[w] + other.state_dict()[w]) / 2, atol=1e-7)
    assert mean.meta["epoch"] == 9 and len(mean.meta["averaged"]) == 2
    with pytest.raises(SystemExit, match="is also an input|same file|input"):
        main(["vae", "export-weights", str(tmp_path / "last.ckpt"), str(tmp_path / "mean.pt"), "--out",
              str(tmp_path / "mean.pt"), "--overwrite"])


def test_evaluate_generation_of_vae_samples(weights, tmp_path, monkeypatch):
    from shapeprog import corpus

    load = corpus.load
    monkeypatch.setattr(corpus, "load", lambda *a, **k: load(*a, **k)[:6])  # 6 reference shapes per split
    out = tmp_path / "table.md"
    assert main(["vae", "evaluate", "--category", "chair", "-n", "2", "--weights", weights, "--no-ground-truth",
                 "--no-stability", "--no-fool", "--quiet", "--max-tries", "10", "1", "--paper-decoding",
                 "--out", str(out), "--json", str(tmp_path / "t.json")]) == 0
    text = out.read_text()
    assert text.startswith(f"VAE samples ({weights}; rejection, at most 10 draws each): 2 samples")
    assert "valid on the first draw" in text and "No Reject: one draw each" in text and "the paper's rules" in text
    from shapeio.results import read_result

    result = read_result(tmp_path / "t.json")  # the table's figures as data: one row per row of the table
    rows = [ln for ln in text.splitlines() if ln.startswith("| VAE samples")]
    ours = [r for r in result["rows"] if r["row"].startswith("VAE samples")]
    assert len(rows) == len(ours) == 3 and [r["category"] for r in ours] == ["chair"] * 3
    assert [r["row"] for r in result["rows"][3:]] == ["paper: ShapeAssembly", "paper: ground truth"]
    def cell(v, digits):
        return "—" if v is None else f"{v:.{digits}f}"

    for line, r in zip(rows, ours):
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[0].startswith(f"{r['row']} (") and r["samples"] == 2 and r["stable"] is None and r["fool"] is None
        assert cells[1] == cell(r["rooted"], 1) and cells[-1] == cell(r["novelty_structure"], 1)
        assert cells[6] == cell(r["leaf_parts"], 2)
    assert any("No Reject" in n for n in result["notes"])
    with pytest.raises(SystemExit, match=r"missing\.pt: no such weights file"):
        main(["vae", "evaluate", "--category", "chair", "--classifier", str(tmp_path / "missing.pt")])
    with pytest.raises(SystemExit, match="not both"):
        main(["vae", "evaluate", "--category", "chair", "-n", "2", "--programs", str(tmp_path)])


def test_evaluate_generation_with_another_classifier(weights, tmp_path, monkeypatch):
    from shapeprog import corpus
    from shapeprog.vae.pointnet import PointNetCls, save_classifier

    load = corpus.load
    monkeypatch.setattr(corpus, "load", lambda *a, **k: load(*a, **k)[:6])
    torch.manual_seed(0)
    mine = save_classifier(tmp_path / "mine.pt", PointNetCls(k=3), ["chair", "table", "storage"])
    out = tmp_path / "table.md"
    assert main(["vae", "evaluate", "--category", "chair", "-n", "2", "--weights", weights, "--no-ground-truth",
                 "--no-stability", "--no-fool", "--quiet", "--classifier", str(mine), "--out", str(out)]) == 0
    text = out.read_text()
    assert "VAE samples" in text and "these use the classifier the caller passed" in text  # not the shipped one
