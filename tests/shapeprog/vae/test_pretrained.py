"""Weights files of the VAE: round trip, the Lightning checkpoint layout, and refusals with messages."""
from __future__ import annotations

import pytest
import torch

from shapeprog.macros import load_library
from shapeprog.vae import VAE
from shapeprog.vae.pretrained import (FORMAT, PRETRAINED_MACROS, VERSION, decoder_fingerprint, export_weights,
                                      load_model, load_pretrained, read_weights, save_weights)


@pytest.fixture()
def vae():
    torch.manual_seed(0)
    return VAE(hidden_dim=16)


def _same(a: VAE, b: VAE, half: bool = False) -> bool:
    """Equal state dicts, exactly; ``half``: ``a`` holds ``b``'s floating tensors rounded to float16."""
    sa, sb = a.state_dict(), b.state_dict()
    rounded = {k: v.half().float() if half and v.is_floating_point() else v for k, v in sb.items()}
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], rounded[k]) for k in sa)


def test_round_trip_float32_exact_and_half_close(vae, tmp_path):
    full = load_model(save_weights(vae, tmp_path / "a.pt", "chair", half=False), category="chair")
    assert _same(full, vae) and full.category == "chair" and not full.training
    half = load_model(save_weights(vae, tmp_path / "b.pt", "chair", meta={"epoch": 3}))
    assert next(half.parameters()).dtype == torch.float32
    assert _same(half, vae, half=True) and half.meta == {"epoch": 3}


def test_lightning_checkpoint_layout_and_export(vae, tmp_path):
    ckpt = {"state_dict": {f"vae.{k}": v for k, v in vae.state_dict().items()},
            "hyper_parameters": {"category": "table", "hidden_dim": 16}, "epoch": 7, "global_step": 70}
    torch.save(ckpt, tmp_path / "last.ckpt")
    info, state = read_weights(tmp_path / "last.ckpt")
    assert info == {"category": "table", "hidden_dim": 16, "meta": {"epoch": 7, "global_step": 70}}
    assert state.keys() == vae.state_dict().keys()
    out = export_weights(tmp_path / "last.ckpt", tmp_path / "w.pt", meta={"command": "x"})
    back = load_model(out, category="table")
    assert _same(back, vae, half=True) and back.meta == {"epoch": 7, "global_step": 70, "command": "x"}


def test_export_of_several_checkpoints_averages_their_weights(vae, tmp_path):
    torch.manual_seed(1)
    other, third = VAE(hidden_dim=16), VAE(hidden_dim=16)
    paths = [save_weights(m, tmp_path / f"{i}.pt", "chair", meta={"epoch": i}, half=False)
             for i, m in enumerate((vae, other, third))]
    out = export_weights(paths, tmp_path / "mean.pt", half=False)
    mean = load_model(out, category="chair")
    for k, v in mean.state_dict().items():
        want = (vae.state_dict()[k].double() + other.state_dict()[k].double() + third.state_dict()[k].double()) / 3
        assert torch.allclose(v.double(), want, atol=1e-6), k
    assert mean.meta == {"epoch": 2, "averaged": [str(p) for p in paths]}
    # one checkpoint in a list is that checkpoint; the fingerprint follows the weights, at float16 precision
    alone = load_model(export_weights(paths[:1], tmp_path / "one.pt", half=False))
    assert _same(alone, vae)
    assert decoder_fingerprint(alone.decoder.state_dict()) == decoder_fingerprint(vae.decoder.state_dict())
    assert decoder_fingerprint(mean.decoder.state_dict()) != decoder_fingerprint(vae.decoder.state_dict())
    half = load_model(save_weights(vae, tmp_path / "half.pt", "chair"))
    assert decoder_fingerprint(half.decoder.state_dict()) == decoder_fingerprint(vae.decoder.state_dict())
    # models that cannot be averaged are refused, naming the file
    table = save_weights(other, tmp_path / "table.pt", "table", half=False)
    with pytest.raises(ValueError, match=r"0\.pt: not a model of the same kind as .*table\.pt"):
        export_weights([paths[0], table], tmp_path / "bad.pt")
    small = save_weights(VAE(hidden_dim=8), tmp_path / "small.pt", "chair", half=False)
    with pytest.raises(ValueError, match=r"small\.pt: not a model of the same kind"):
        export_weights([small, paths[0]], tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="no checkpoint to export"):
        export_weights([], tmp_path / "bad.pt")


def test_refusals_name_the_file(vae, tmp_path):
    path = save_weights(vae, tmp_path / "w.pt", "chair")
    with pytest.raises(ValueError, match=r"w\.pt.*'chair', not 'table'"):
        load_model(path, category="table")
    payload = torch.load(path, weights_only=True)
    torch.save({**payload, "version": VERSION + 1}, tmp_path / "new.pt")
    with pytest.raises(ValueError, match=rf"new\.pt: '{FORMAT}' weights file version {VERSION + 1}; this version of the software reads version {VERSION}$"):
        load_model(tmp_path / "new.pt")
    torch.save({**payload, "format": "csgnet"}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match=rf"other\.pt: a 'csgnet' weights file, not a '{FORMAT}' one$"):
        load_model(tmp_path / "other.pt")
    torch.save({**payload, "hidden_dim": 32}, tmp_path / "size.pt")
    with pytest.raises(ValueError, match=r"size\.pt: tensors do not fit a VAE of hidden size 32"):
        load_model(tmp_path / "size.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match=r"junk\.pt: not a ShapeAssembly VAE weights file or checkpoint"):
        read_weights(tmp_path / "junk.pt")
    torch.save({"hyper_parameters": {"dim": 2}, "state_dict": {"model.x": torch.zeros(1)}}, tmp_path / "csg.ckpt")
    with pytest.raises(ValueError, match=r"csg\.ckpt: a Lightning checkpoint, but not of the ShapeAssembly VAE"):
        read_weights(tmp_path / "csg.ckpt")
    with pytest.raises(FileNotFoundError, match="no such weights file"):
        read_weights(tmp_path / "missing.pt")
    with pytest.raises(ValueError, match="no shipped VAE for category 'lamp'; shipped: chair, table, storage"):
        load_pretrained("lamp")
    with pytest.raises(ValueError, match="no shipped macro-program VAE for category 'lamp'; shipped: chair"):
        load_pretrained("lamp", macros=True)
    for category in PRETRAINED_MACROS:  # each shipped macro model speaks its category's shipped library
        macro = load_pretrained(category, macros=True)
        assert macro.category == category and macro.layout.library.to_text() == load_library(category).to_text()


@pytest.mark.parametrize("category", ["chair", "table", "storage"])
def test_shipped_models_sample_valid_programs(category):
    import shapeprog
    from shapeprog.vae import sample

    vae = load_pretrained(category)
    assert vae.category == category and vae.decoder.hidden_dim == 256 and not vae.training
    assert {"epoch", "global_step", "command"} <= set(vae.meta)
    out = sample(vae, 4, seed=0)
    assert [d.text for d in out] == [d.text for d in sample(vae, 4, seed=0)]  # deterministic under a seed
    for d in out:
        assert shapeprog.parse(d.text) == d.program
        assert len(shapeprog.execute(d.program)) >= 2  # a trained model writes parts, not a lone bbox
        assert_corpus_precision(d.text)


def assert_corpus_precision(text):
    """Every number of a program text has at most the corpus's 3 decimals (and no ``-0.0``)."""
    import re

    from shapeprog.lang import CORPUS_DECIMALS

    nums = re.findall(r"-?\d+\.\d+(?:e-?\d+)?", text)
    assert nums and CORPUS_DECIMALS == 3
    assert [n for n in nums if "e" in n or len(n.split(".")[1]) > CORPUS_DECIMALS or n == "-0.0"] == []


def test_reconstruct_and_interpolate_write_corpus_precision():
    import shapeprog
    from shapeprog import corpus
    from shapeprog.vae import decode, encode, interpolate

    vae = load_pretrained("chair")
    a, b = shapeprog.parse(corpus.read("chair", 173)), shapeprog.parse(corpus.read("chair", 44017))
    for d in [decode(vae, encode(vae, a))] + interpolate(vae, a, b, 3):
        assert shapeprog.parse(d.text) == d.program and shapeprog.to_text(d.program) == d.text
        assert_corpus_precision(d.text)


def test_the_shipped_baseline_macros_model_speaks_the_shipped_baseline_library():
    from pathlib import Path

    from shapeprog.macros import Library
    from shapeprog.vae.pretrained import load_model

    root = Path(__file__).resolve().parents[3] / "shapeprog"
    vae = load_model(root / "weights" / "vae_chair_baseline_macros.pt", category="chair")
    lib = Library.from_text((root / "macros" / "libs" / "chair_baseline.txt").read_text())
    assert vae.category == "chair" and vae.layout.library.to_text() == lib.to_text()
    # the chair VAEs' recipe: the mean of the KL run's eight checkpoints, the last at epoch 39
    assert vae.meta["epoch"] == 39 and len(vae.meta["averaged"]) == 8 and len(lib.macros) == 51
