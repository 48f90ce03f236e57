"""shapeprog.pointcloud.train: the data module, both recipes' losses, a fit step, resume, export, the configs."""
from pathlib import Path

import lightning as L
import pytest
import torch

import train as train_cli
from csgnet.train.checkpoint import AtomicCheckpointIO
from shapeprog.lang import to_text
from shapeprog.pointcloud.data import corpus_splits, make_clouds
from shapeprog.pointcloud.infer import load_model
from shapeprog.pointcloud.train import CloudDataModule, EndToEndModule, LatentRegressionModule, export_weights
from shapeprog.vae.batch import TreeBatch
from shapeprog.vae.macro_batch import MacroTreeBatch, macro_batch_loss
from shapeprog.vae.losses import macro_program_loss, program_loss
from shapeprog.vae.macro_model import MacroVAE
from shapeprog.vae.pretrained import decoder_fingerprint
from shapeprog.vae.model import VAEOutput

ROOT = Path(__file__).resolve().parents[3]
CONFIGS = sorted((ROOT / "configs" / "pointcloud").glob("*.yaml"))
SPLITS = corpus_splits("chair")
IDS = SPLITS["train"][:6] + SPLITS["val"][:2]
# a tiny encoder: 64-point clouds, 16 and 8 centres
TINY = dict(npoints=[16, 8], radii=[0.3, 0.6], nsamples=[8, 8], widths=[[8, 8, 16], [16, 16, 32], [32, 32, 64]])


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    root = tmp_path_factory.mktemp("clouds")
    make_clouds("chair", root, n_points=256, workers=1, ids=IDS)
    return root


def _data(root, **kw):
    args = dict(points=64, val_points=64, batch_size=4, seed=0)
    args.update(kw)
    return CloudDataModule(str(root), "chair", **args)


def _module(cls, **kw):
    args = dict(TINY, recon_every_n_epochs=1, recon_shapes=2, recon_points=256, image_shapes=2, image_size=32)
    args.update(kw)
    return cls("chair", **args)


def test_data_module_serves_train_clouds_with_trees_and_validates_on_the_carve_out(clouds):
    dm = _data(clouds)
    dm.setup("fit")
    assert sorted(int(i) for i in dm.train_set.clouds.ids) == sorted(SPLITS["train"][:6])
    assert sorted(int(i) for i in dm.val_set.clouds.ids) == sorted(SPLITS["val"][:2])
    batch = next(iter(dm.train_dataloader()))
    assert batch["points"].shape == (4, 64, 3) and isinstance(batch["trees"], TreeBatch)
    assert batch["trees"].size == 4
    # each cloud comes with its own program's tree
    first = dm.train_set[0]
    assert first["tree"] is dm.train_set.trees[first["program"]]


def test_latent_loss_is_the_summed_squared_error_to_the_frozen_mu(clouds):
    dm = _data(clouds)
    dm.setup("fit")
    m = _module(LatentRegressionModule)
    batch = next(iter(dm.val_dataloader()))
    z = torch.randn(batch["trees"].size, 256)
    mu = torch.stack([m.vae.encoder(t)[0] for t in batch["trees"].trees])
    loss, terms = m.losses(z, batch["trees"])
    assert torch.allclose(loss, ((z - mu) ** 2).sum(1).mean(), rtol=1e-4)
    # the VAE is frozen: an optimizer step leaves it alone, and train() keeps it in eval mode
    before = {k: v.clone() for k, v in m.vae.state_dict().items()}
    opt = m.configure_optimizers()
    m.train()
    m.losses(m.code(batch["points"]), batch["trees"])[0].backward()
    opt.step()
    assert not m.vae.training
    assert all(torch.equal(before[k], v) for k, v in m.vae.state_dict().items())


def test_end_to_end_loss_is_the_vae_program_loss_of_the_cloud_code(clouds):
    dm = _data(clouds)
    dm.setup("fit")
    m = _module(EndToEndModule)
    batch = next(iter(dm.val_dataloader()))
    z = torch.randn(batch["trees"].size, 256)
    loss, terms = m.losses(z, batch["trees"])
    ref = []
    for zi, tree in zip(z, batch["trees"].trees):
        out = VAEOutput(m.vae.decoder.teacher_forced(tree, zi), m.vae.decoder.bbox(zi), zi, zi * 0, zi)
        ref.append(program_loss(out, tree, m.weights, kl=False)[0])
    assert torch.allclose(loss, torch.stack(ref).mean(), rtol=1e-4)
    assert "kl" not in terms


def _trainer(folder, epochs):
    ckpt = L.pytorch.callbacks.ModelCheckpoint(dirpath=folder / "ck", filename="latest", save_top_k=1, save_last="link")
    return L.Trainer(max_epochs=epochs, accelerator="cpu", devices=1, logger=L.pytorch.loggers.TensorBoardLogger(
        folder, name="tb"), callbacks=[ckpt], plugins=[AtomicCheckpointIO()], enable_progress_bar=False,
        enable_model_summary=False, log_every_n_steps=1)


@pytest.mark.parametrize("cls", [LatentRegressionModule, EndToEndModule])
def test_fit_logs_images_and_resumes_from_last(clouds, tmp_path, cls):
    L.seed_everything(0)
    m = _module(cls)
    _trainer(tmp_path, 1).fit(m, datamodule=_data(clouds))
    last = tmp_path / "ck" / "last.ckpt"
    assert last.exists()
    events = list((tmp_path / "tb").rglob("events.out.tfevents.*"))
    assert events
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    ea = EventAccumulator(str(events[0].parent))
    ea.Reload()
    assert "val/clouds" in ea.Tags()["images"] and "val/fscore" in ea.Tags()["scalars"]
    steps = m.global_step
    assert steps == 2  # 6 clouds in batches of 4
    m2 = _module(cls)
    t2 = _trainer(tmp_path, 2)
    t2.fit(m2, datamodule=_data(clouds), ckpt_path=str(last))
    assert m2.global_step == 2 * steps and t2.current_epoch == 2
    # a checkpoint of the other recipe (or another encoder) is refused
    other = _module(LatentRegressionModule if cls is EndToEndModule else EndToEndModule)
    with pytest.raises(ValueError, match="checkpoint is of a model"):
        _trainer(tmp_path / "o", 3).fit(other, datamodule=_data(clouds), ckpt_path=str(last))
    # the weights file round-trips (weights_only) into the model infer uses
    path = export_weights(last, tmp_path / "w.pt", half=False)
    payload = torch.load(path, weights_only=True)
    assert payload["recipe"] == cls.recipe and ("decoder" in payload) == (cls is EndToEndModule)
    if cls is LatentRegressionModule:  # it records the VAE it regresses, and is refused with another
        assert payload["vae_decoder"] == decoder_fingerprint(m.vae.decoder.state_dict())
        torch.save({**payload, "vae_decoder": "0" * 16}, tmp_path / "other_vae.pt")
        with pytest.raises(ValueError, match="other_vae.pt: a latent-regression model trained for another chair VAE"):
            load_model(tmp_path / "other_vae.pt", "chair")
    model = load_model(path, "chair")
    x = torch.rand(2, 64, 3) - 0.5
    m2.eval()
    with torch.no_grad():
        assert torch.allclose(model.codes(x), m2.encoder(x), atol=1e-5)
    with pytest.raises(ValueError, match="not 'table'"):
        load_model(path, "table")
    # the export command recognises a point-cloud checkpoint
    from shapeprog.__main__ import main
    assert main(["pointcloud", "export-weights", str(last), "--out", str(tmp_path / "cli.pt")]) == 0
    assert load_model(tmp_path / "cli.pt").recipe == cls.recipe


def test_end_to_end_starts_its_encoder_from_a_weights_file(clouds, tmp_path):
    L.seed_everything(0)
    latent = _module(LatentRegressionModule)
    _trainer(tmp_path, 1).fit(latent, datamodule=_data(clouds))
    path = export_weights(tmp_path / "ck" / "last.ckpt", tmp_path / "latent.pt", half=False)
    start = load_model(path, "chair")
    m = _module(EndToEndModule, init_encoder=str(path))
    for name, value in start.encoder.state_dict().items():
        assert torch.equal(m.encoder.state_dict()[name], value), name
    assert not torch.equal(_module(EndToEndModule).encoder.state_dict()["fc.weight"],
                           m.encoder.state_dict()["fc.weight"])
    # another encoder size or category is refused, naming the file
    with pytest.raises(ValueError, match="latent.pt: its encoder has sizes"):
        _module(EndToEndModule, init_encoder=str(path), nsamples=[4, 4])
    with pytest.raises(ValueError, match="not 'table'"):
        EndToEndModule("table", init_encoder=str(path), **TINY)
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        _module(EndToEndModule, init_encoder=str(tmp_path / "missing.pt"))


def test_latent_regression_overfits_a_handful_of_clouds(clouds):
    L.seed_everything(0)
    dm = _data(clouds, batch_size=6)
    dm.setup("fit")
    m = _module(LatentRegressionModule, lr=3e-3)
    batch = next(iter(dm.train_dataloader()))
    opt = m.configure_optimizers()
    m.train()
    losses = []
    for _ in range(150):
        opt.zero_grad()
        loss = m.losses(m.code(batch["points"]), batch["trees"])[0]
        loss.backward()
        opt.step()
        losses.append(float(loss))
    assert losses[-1] < 0.1 * losses[0], (losses[0], losses[-1])


def test_categories_must_agree(clouds, tmp_path):
    m = LatentRegressionModule("table", **TINY)
    with pytest.raises(ValueError, match="category"):
        _trainer(tmp_path, 1).fit(m, datamodule=_data(clouds))


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_every_config_parses_and_builds(config, tmp_path):
    cli = train_cli.main(["--config", str(config), "--data.root", str(tmp_path),
                          "--trainer.logger.init_args.save_dir", str(tmp_path)], run=False)
    recipe, category, *macros = config.stem.split("_")
    assert cli.model.recipe == recipe and cli.model.hparams.category == category == cli.datamodule.category
    assert cli.model.encoder.config["out_dim"] == cli.model.vae.decoder.hidden_dim == 256
    assert isinstance(cli.model.vae, MacroVAE) == (macros == ["macros"])
    assert cli.datamodule.library == (category if macros else None)
    assert len(CONFIGS) == 9


# ------------------------------------------------------------------ macro programs (ShapeMOD's Table 3)


def test_macro_end_to_end_loss_is_the_macro_program_loss_of_the_cloud_code(clouds):
    dm = _data(clouds, library="chair")
    dm.setup("fit")
    assert len(dm.train_set) == 6 and len(dm.val_set) == 2  # every carved shape has its macro program
    # resuming compares the libraries themselves: the shipped library's file is the same library, a base run not
    from shapeprog.macros import load_library
    lib_file = clouds / "chair_lib.txt"
    lib_file.write_text(load_library("chair").to_text())
    state = dm.state_dict()
    same = _data(clouds, library=str(lib_file))
    same.setup("fit")
    same.load_state_dict(state)
    base = _data(clouds)
    base.setup("fit")
    with pytest.raises(ValueError, match="trained on programs of library 'chair'"):
        base.load_state_dict(state)
    batch = next(iter(dm.val_dataloader()))
    assert isinstance(batch["trees"], MacroTreeBatch)
    m = _module(EndToEndModule, macros=True)
    assert isinstance(m.vae, MacroVAE) and m.library_text() == m.vae.layout.library.to_text()
    z = torch.randn(batch["trees"].size, 256)
    loss, terms = m.losses(z, batch["trees"])
    ref = []
    for zi, tree in zip(z, batch["trees"].trees):
        out = VAEOutput(m.vae.decoder.teacher_forced(tree, zi), m.vae.decoder.bbox(zi), zi, zi * 0, zi)
        ref.append(macro_program_loss(out, tree, m.layout, m.weights, kl=False)[0])
    assert torch.allclose(loss, torch.stack(ref).mean(), rtol=1e-4)
    assert "kl" not in terms and "cmd" in terms
    with pytest.raises(ValueError, match="no posterior"):  # codes from elsewhere have no KL term
        macro_batch_loss(m.vae, batch["trees"], codes=z)
    # the gradient reaches the encoder through the code
    m.losses(m.code(batch["points"]), batch["trees"])[0].backward()
    assert m.encoder.fc.weight.grad is not None and m.encoder.fc.weight.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="unknown loss term"):
        _module(EndToEndModule, macros=True, loss_weights={"sym_cub": 1.0})
    with pytest.raises(ValueError, match="latent recipe is built for the base language"):
        _module(LatentRegressionModule, vae_weights=str(ROOT / "shapeprog" / "weights" / "vae_chair_macros.pt"))
    with pytest.raises(ValueError, match="macros=True needs a VAE trained on macro programs"):
        _module(EndToEndModule, macros=True, vae_weights=str(ROOT / "shapeprog" / "weights" / "vae_chair.pt"))


def test_macro_model_trains_exports_and_infers_macro_programs(clouds, tmp_path):
    L.seed_everything(0)
    m = _module(EndToEndModule, macros=True)
    # a data module serving other programs than the decoder writes is refused
    with pytest.raises(ValueError, match="set data.init_args.library"):
        _trainer(tmp_path / "x", 1).fit(_module(EndToEndModule, macros=True), datamodule=_data(clouds))
    _trainer(tmp_path, 1).fit(m, datamodule=_data(clouds, library="chair"))
    last = tmp_path / "ck" / "last.ckpt"
    # a base-language run does not resume from it
    with pytest.raises(ValueError, match="checkpoint is of a model"):
        _trainer(tmp_path / "o", 2).fit(_module(EndToEndModule), datamodule=_data(clouds), ckpt_path=str(last))
    path = export_weights(last, tmp_path / "w.pt", half=False)
    model = load_model(path, "chair")
    assert model.layout is not None and model.layout.library.to_text() == m.library_text()
    x = torch.rand(2, 64, 3) - 0.5
    m.eval()
    with torch.no_grad():
        assert torch.allclose(model.codes(x), m.encoder(x), atol=1e-5)
        for name, value in m.vae.decoder.state_dict().items():
            assert torch.equal(model.vae.decoder.state_dict()[name], value), name
    codes = model.codes(x)
    from shapeprog.macros.execute import compile_hierarchy
    from shapeprog.vae.macro_decode import decode_macro
    for z, d, prog in zip(codes, model.decode_macros(codes), model.decode(codes)):
        # the training module's decoder gives the same macro program, and decode gives its expansion
        try:
            ref = decode_macro(m.vae, z)
        except ValueError:
            assert d is None and prog is None
            continue
        assert d.text == ref.text
        assert to_text(prog) == to_text(compile_hierarchy(ref.hierarchy, m.layout.library).program)
    from shapeprog.pointcloud import infer
    from shapeprog.pointcloud.data import corpus_cloud
    cloud = corpus_cloud("chair", SPLITS["val"][0], n_points=500)
    try:
        r = infer(cloud * 3.0 + 1.0, model=model, physics=False, method="decode")
    except ValueError as e:  # a one-epoch model may decode nothing; it must say so
        assert "decoded no shape" in str(e)
    else:
        assert r.macro_text is not None and r.macro_text.strip()
    assert infer(cloud, "chair", physics=False, method="decode").macro_text is None  # the shipped base model writes no macros
    with pytest.raises(ValueError, match="not macro programs"):
        load_model(ROOT / "shapeprog" / "weights" / "pointcloud_e2e_chair.pt").decode_macros(codes)
    # a run continues from the exported weights (init): encoder and decoder equal, the library checked
    again = _module(EndToEndModule, macros=True, init=str(path))
    for part in ("encoder", "vae.decoder"):
        ref = dict(m.named_parameters())
        for name, value in again.named_parameters():
            if name.startswith(part + "."):
                assert torch.equal(value, ref[name]), name
    assert not torch.equal(_module(EndToEndModule, macros=True).encoder.state_dict()["fc.weight"],
                           again.encoder.state_dict()["fc.weight"])
    with pytest.raises(ValueError, match="w.pt: its decoder writes a macro library, this run's the base language"):
        _module(EndToEndModule, init=str(path))
    with pytest.raises(ValueError, match="w.pt: its encoder has sizes"):
        _module(EndToEndModule, macros=True, init=str(path), nsamples=[4, 4])
    latent = ROOT / "shapeprog" / "weights" / "pointcloud_latent_chair.pt"
    with pytest.raises(ValueError, match="a 'latent' model"):
        _module(EndToEndModule, init=str(latent))
