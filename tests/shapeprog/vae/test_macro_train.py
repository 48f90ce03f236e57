"""Training the VAE on macro programs through the one entry point, resuming, and its weights file."""
import json
from pathlib import Path

import pytest
import torch

from shapeprog.macros import load_library
from shapeprog.macros.execute import execute_hierarchy
from shapeprog.macros.hierarchy import parse as parse_hierarchy
from shapeprog.vae.layout import MacroNode
from shapeprog.vae.macro_decode import sample_macro
from shapeprog.vae.macro_model import MacroVAE
from shapeprog.vae.model import VAE
from shapeprog.vae.pretrained import export_weights, load_model, load_pretrained, read_weights, save_weights
from shapeprog.vae.train import VAEDataModule, VAEModule

ROOT = Path(__file__).resolve().parents[3]


def test_fit_resume_and_export_of_the_chair_macro_config(tmp_path, train_main, tiny_vae_config):
    path = tiny_vae_config("vae_chair_macros", dict(hidden_dim=8, recon_every_n_epochs=1, recon_shapes=2,
                                                    recon_points=200, image_shapes=0), dict(every_n_epochs=1))
    cli = train_main(["fit", "--config", str(path)])
    assert isinstance(cli.model.vae, MacroVAE) and all(isinstance(t, MacroNode) for t in cli.datamodule.train_trees)
    assert cli.trainer.global_step == 2
    metrics = cli.trainer.callback_metrics
    assert {"val/loss", "val/fscore", "val/float", "val/cube"} <= set(metrics)
    assert 0.0 <= float(metrics["val/fscore"]) <= 100.0
    ckpt = torch.load(tmp_path / "ckpt" / "last.ckpt", map_location="cpu", weights_only=False)
    assert ckpt["shapeprog_vae"]["library_text"] == load_library("chair").to_text()
    split = json.loads((tmp_path / "vae_chair_macros" / "version_0" / "split.json").read_text())
    assert split["library"] == "chair" and split["val"] == cli.datamodule.val_keys
    resumed = train_main(["fit", "--config", str(path), "--trainer.max_steps", "3", "--ckpt_path", "last"])
    assert resumed.trainer.global_step == 3
    # the weights file holds the library; the model comes back as a MacroVAE that samples executable programs
    out = export_weights(tmp_path / "ckpt" / "last.ckpt", tmp_path / "w.pt", half=False)
    info, _ = read_weights(out)
    assert info["library"] == load_library("chair").to_text() and info["category"] == "chair"
    vae = load_model(out, category="chair")
    assert isinstance(vae, MacroVAE) and vae.layout.functions == tuple(load_library("chair"))
    for d in sample_macro(vae, 2, seed=0):
        shape = execute_hierarchy(parse_hierarchy(d.text, library=vae.library), vae.library)
        assert shape.corners.shape[0] >= 1


def test_a_macro_weights_file_round_trips_and_the_base_files_stay_base(tmp_path):
    from shapeprog.vae.layout import LineLayout
    vae = MacroVAE(LineLayout(load_library("chair")), hidden_dim=16)
    back = load_model(save_weights(vae, tmp_path / "m.pt", "chair", half=False))
    assert isinstance(back, MacroVAE)
    assert all(torch.equal(a, b) for a, b in zip(vae.state_dict().values(), back.state_dict().values()))
    base = load_pretrained("chair")
    assert type(base) is VAE and "library" not in read_weights(ROOT / "shapeprog" / "weights" / "vae_chair.pt")[0]


def test_model_and_data_must_agree_on_the_library():
    with pytest.raises(ValueError, match="one category"):
        VAEDataModule("all", library="chair")
    with pytest.raises(ValueError, match="needs a `library`"):
        VAEDataModule("chair", programs="x")
    with pytest.raises(FileNotFoundError, match=r"no/such/library\.txt: neither a ShapeMOD library file nor a shipped"):
        VAEModule("chair", hidden_dim=8, library="no/such/library.txt")
    with pytest.raises(ValueError, match="unknown loss term"):
        VAEModule("chair", hidden_dim=8, library="chair", loss_weights={"cub_prm": 1.0})


def test_evaluate_generation_samples_a_macro_model_through_its_expansions(tmp_path):
    import argparse

    import shapeprog
    from shapeprog.vae.commands import vae_samples
    from shapeprog.lang import Program
    from shapeprog.vae.layout import LineLayout

    torch.manual_seed(0)
    path = save_weights(MacroVAE(LineLayout(load_library("chair")), hidden_dim=16), tmp_path / "m.pt", "chair")
    args = argparse.Namespace(weights=str(path), category="chair", n=3, seed=0)
    programs, name, line = vae_samples(args)
    assert len(programs) == 3 and all(isinstance(p, Program) for p in programs)
    assert all(shapeprog.execute(p).corners.shape[0] >= 1 for p in programs)
    assert "macro programs" in line and str(path) in name


def test_the_sample_command_writes_macro_programs_and_others_refuse_a_macro_model(tmp_path, capsys):
    from shapeprog.__main__ import main
    from shapeprog.vae.layout import LineLayout

    torch.manual_seed(0)
    lib = load_library("chair")
    weights = str(save_weights(MacroVAE(LineLayout(lib), hidden_dim=16), tmp_path / "m.pt", "chair"))
    out = tmp_path / "samples"
    assert main(["vae", "sample", "--category", "chair", "-n", "2", "--out", str(out), "--weights", weights, "--quiet"]) == 0
    assert "2 samples of chair" in capsys.readouterr().out
    for i in range(2):
        h = parse_hierarchy((out / f"sample_{i:04d}.txt").read_text(), library=lib)  # macro text, reads back
        assert execute_hierarchy(h, lib).corners.shape[0] >= 1 and (out / f"sample_{i:04d}.obj").is_file()
    with pytest.raises(SystemExit, match="macro programs"):
        main(["vae", "reconstruct", "chair/173", "--weights", weights])


def test_the_shipped_macro_chair_model_samples_valid_macro_programs():
    path = ROOT / "shapeprog" / "weights" / "vae_chair_macros.pt"
    info, _ = read_weights(path)
    assert info["category"] == "chair" and {"epoch", "global_step", "command"} <= set(info["meta"])
    vae = load_model(path)
    assert isinstance(vae, MacroVAE) and vae.layout.functions == tuple(load_library("chair"))
    out = sample_macro(vae, 4, seed=0)
    assert [d.text for d in out] == [d.text for d in sample_macro(vae, 4, seed=0)]  # deterministic under a seed
    for d in out:
        shape = execute_hierarchy(parse_hierarchy(d.text, library=vae.library), vae.library)
        assert shape.corners.shape[0] >= 2  # a trained model writes parts, not a lone bbox
