"""VAE training: the batched pass against the per-tree one, the data split, a tiny overfit, the Lightning
module and data module, and ``train.py`` with the shipped configs."""
import json
from dataclasses import dataclass
from pathlib import Path

import lightning as L
import pytest
import torch

import shapeprog
from shapeprog import corpus
from shapeprog.lang import Program, numbers, parse, replace_numbers, to_text
from shapeprog.vae import reconstruct as vae_reconstruct
from shapeprog.vae import train as vae_train
from shapeprog.vae.batch import TreeBatch, batch_forward, batch_loss, collate_trees
from shapeprog.vae.losses import program_loss
from shapeprog.vae.model import VAE, VAEOutput, prediction_tree
from shapeprog.vae.train import VAEDataModule, VAEModule
from shapeprog.vae.data import validation_split
from shapeprog.vae.vectors import program_to_tree, tree_to_program

ROOT = Path(__file__).resolve().parents[3]
CONFIGS = sorted((ROOT / "configs" / "shapeassembly").glob("vae_*.yaml"))
# flat with every command; two nodes; three nodes over two depths; larger shapes of each category
SMALL = [("storage", 45192), ("storage", 46128), ("table", 25985)]
OVERFIT = [("storage", 45192), ("table", 18822)]  # every command (flat); a sub-program
MIXED = SMALL + [("chair", 173), ("table", 18933), ("chair", 2498), ("storage", 46192)]


def _tree(cat, i, dtype=torch.float32):
    return program_to_tree(shapeprog.parse(corpus.read(cat, i), f"{cat}/{i}.txt"), dtype=dtype)


# ------------------------------------------------------------------------------------------ batched pass


def _per_tree(vae, trees, eps=None):
    """VAE.forward per tree with z = mu, or z = mu + eps[b] * exp(logvar / 2)."""
    outs = []
    for b, t in enumerate(trees):
        if eps is None:
            outs.append(vae(t, sample=False))
            continue
        _, mu, logvar = vae.encode(t, sample=False)
        z = mu + eps[b] * torch.exp(0.5 * logvar)
        outs.append(VAEOutput(vae.decoder.teacher_forced(t, z), vae.decoder.bbox(z), mu, logvar, z))
    return outs


@pytest.mark.parametrize("dtype, rtol", [(torch.float64, 1e-10), (torch.float32, 1e-5)])
def test_batched_loss_and_gradients_equal_the_per_tree_pass(dtype, rtol, two_levels):
    trees = [_tree(c, i, dtype) for c, i in MIXED] + [program_to_tree(parse(two_levels), dtype=dtype)]
    torch.manual_seed(0)
    vae = VAE(24).to(dtype)
    eps = torch.randn(len(trees), 24, dtype=dtype)
    batch = TreeBatch(trees)
    for e in (None, eps):
        ref = [program_loss(o, t) for o, t in zip(_per_tree(vae, trees, e), trees)]
        total, terms = batch_loss(batch_forward(vae, batch, sample=e is not None, eps=e), batch)
        torch.testing.assert_close(total, torch.stack([r[0] for r in ref]), rtol=rtol, atol=rtol)
        for name in terms:
            torch.testing.assert_close(terms[name], torch.stack([r[1][name] for r in ref]), rtol=rtol, atol=10 * rtol)
    # gradients of the summed losses, z sampled with the same eps
    vae.zero_grad()
    sum(program_loss(o, t)[0] for o, t in zip(_per_tree(vae, trees, eps), trees)).backward()
    ref_grads = {k: p.grad.clone() for k, p in vae.named_parameters()}
    vae.zero_grad()
    batch_loss(batch_forward(vae, batch, eps=eps), batch)[0].sum().backward()
    for k, p in vae.named_parameters():
        torch.testing.assert_close(p.grad, ref_grads[k], rtol=100 * rtol, atol=100 * rtol * ref_grads[k].abs().max(),
                                   msg=lambda m: f"{k}: {m}")


def test_split_lays_out_the_batch_as_the_per_tree_output(two_levels):
    trees = [_tree(c, i) for c, i in SMALL] + [program_to_tree(parse(two_levels))]
    torch.manual_seed(0)
    vae = VAE(16)
    batch = TreeBatch(trees)
    assert batch.size == len(batch) == 4 and batch.num_nodes == sum(len(list(t.nodes())) for t in trees)
    parts = batch.split(batch_forward(vae, batch, sample=False))
    for out, ref, tree in zip(parts, _per_tree(vae, trees), trees):
        assert [tuple(n.lines.shape) for n in out.nodes] == [tuple(n.lines.shape) for n in ref.nodes]
        for a, b in zip(out.nodes, ref.nodes):
            torch.testing.assert_close(a.lines, b.lines, rtol=1e-5, atol=1e-5)
            torch.testing.assert_close(a.leaf, b.leaf, rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(program_loss(out, tree)[0], program_loss(ref, tree)[0], rtol=1e-5, atol=1e-4)
        prediction_tree(out, tree)


def test_tree_batch_moves_casts_and_refuses_bad_input(two_levels):
    tree = program_to_tree(parse(two_levels))
    batch = collate_trees([tree, tree])
    moved = batch.to("cpu", torch.float64)
    assert moved.dtype == torch.float64 and moved.trees[0] is tree and batch.dtype == torch.float32
    assert "size=2" in repr(batch)
    with pytest.raises(ValueError, match="at least one tree"):
        TreeBatch([])
    with pytest.raises(TypeError, match=r"trees\[1\] is a str"):
        TreeBatch([tree, "x"])
    with pytest.raises(ValueError, match="node 1 of the batch is torch.float64"):
        TreeBatch([tree, tree.to(dtype=torch.float64)])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_batched_pass_on_cuda_equals_cpu(two_levels):
    trees = [_tree(c, i) for c, i in SMALL] + [program_to_tree(parse(two_levels))]
    torch.manual_seed(0)
    vae = VAE(16)
    batch = TreeBatch(trees)
    cpu = batch_loss(batch_forward(vae, batch, sample=False), batch)[0]
    vae = vae.cuda()
    for on_device in (batch.to("cuda"), TreeBatch([t.to("cuda") for t in trees])):
        assert on_device.device.type == "cuda"
        gpu = batch_loss(batch_forward(vae, on_device, sample=False), on_device)[0]
        torch.testing.assert_close(gpu.cpu(), cpu, rtol=1e-4, atol=1e-3)


# ------------------------------------------------------------------------------------------ overfit


def _structure(p: Program) -> str:
    return to_text(replace_numbers(p, [0.0] * len(numbers(p))))


def test_tiny_overfit_reconstructs_corpus_programs_through_the_batched_pass():
    """Two corpus programs (every command; a sub-program) come back teacher-forced: commands, cuboid slots,
    faces, axes, counts, aligned flags and sub-program choices exact, numbers within 0.01 (about 200 steps)."""
    trees = [_tree(c, i) for c, i in OVERFIT]
    targets = [tree_to_program(t, decimals=3) for t in trees]
    batch = TreeBatch(trees)
    torch.manual_seed(0)
    vae = VAE(48)
    opt = torch.optim.Adam(vae.parameters(), lr=1e-2)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min(1.0, 0.97 ** (s - 100)))

    def reconstructed() -> bool:
        with torch.no_grad():
            outs = batch.split(batch_forward(vae, batch, sample=False))
        for out, tree, target in zip(outs, trees, targets):
            try:
                pred = tree_to_program(prediction_tree(out, tree), decimals=3)
            except ValueError:  # a node that does not start with a Cuboid line yet
                return False
            if _structure(pred) != _structure(target):
                return False
            if max(abs(a - b) for a, b in zip(numbers(pred), numbers(target))) > 0.01:
                return False
        return True

    for step in range(300):
        loss = batch_loss(batch_forward(vae, batch, sample=False), batch, kl=False)[0].sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if step >= 149 and step % 10 == 9 and reconstructed():
            break
    else:
        pytest.fail(f"not reconstructed after 300 steps (loss {loss.item():.3f})")


# ------------------------------------------------------------------------------------------ data


def test_validation_split_is_seeded_disjoint_from_the_test_split_and_written(tmp_path):
    train, val = validation_split("storage", 0.05, seed=42)
    ids = corpus.ids("storage", "train")
    assert len(val) == round(0.05 * len(ids)) and len(train) + len(val) == len(ids)
    assert set(train).isdisjoint(val) and set(train) | set(val) == {f"storage/{i}" for i in ids}
    test = {f"storage/{i}" for i in corpus.ids("storage", "val")}
    assert test.isdisjoint(val) and test.isdisjoint(train)
    assert validation_split("storage", 0.05, seed=42) == (train, val)
    assert validation_split("storage", 0.05, seed=7)[1] != val
    tr_all, val_all = validation_split("all", count=3, seed=42)
    assert [k.split("/")[0] for k in val_all] == ["chair"] * 3 + ["table"] * 3 + ["storage"] * 3
    assert [k for k in val_all if k.startswith("storage/")] == validation_split("storage", count=3, seed=42)[1]
    with pytest.raises(ValueError, match="unknown category 'sofa'"):
        validation_split("sofa")
    with pytest.raises(ValueError, match="cannot hold out 5000"):
        validation_split("storage", count=5000)

    dm = VAEDataModule("storage", val_count=4, max_train_shapes=6, seed=42)
    dm.setup("fit")
    assert dm.val_keys == validation_split("storage", count=4, seed=42)[1] and len(dm.train_keys) == 6
    assert len(dm.val_trees) == 4 and len(dm.train_trees) == 6
    dm.write_split(tmp_path / "split.json")
    written = json.loads((tmp_path / "split.json").read_text())
    assert written["val"] == dm.val_keys and written["train"] == dm.train_keys and written["seed"] == 42
    batch = next(iter(dm.val_dataloader()))
    assert isinstance(batch, TreeBatch) and batch.size == 4 and batch.trees[0] is dm.val_trees[0]
    assert next(iter(dm.train_dataloader())).size == 1  # no model attached: one shape per batch
    with pytest.raises(ValueError, match="another carve-out"):
        dm.load_state_dict({"category": "storage", "seed": 1, "val": dm.val_keys[:2]})


# ------------------------------------------------------------------------------------------ module


def _tiny_trainer(tmp_path, **kw):
    args = dict(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False, enable_model_summary=False,
                enable_checkpointing=False, default_root_dir=str(tmp_path))
    args.update(kw)
    return L.Trainer(**args)


def test_fast_dev_run_of_module_and_data_module(tmp_path):
    model = VAEModule("storage", hidden_dim=16, batch_shapes=2)
    dm = VAEDataModule("storage", val_count=3, max_train_shapes=4)
    trainer = _tiny_trainer(tmp_path, fast_dev_run=True, log_every_n_steps=1)  # the terms log every N steps
    trainer.fit(model, dm)
    metrics = trainer.callback_metrics
    # no logger and no checkpoint folder: no run folder, so the split file is not written (never into the
    # working or root folder)
    assert not (tmp_path / "split.json").exists()
    # no logger, the default checkpoint callback: the split goes where its checkpoints go
    ckpt = _tiny_trainer(tmp_path / "b", fast_dev_run=True, enable_checkpointing=True)
    ckpt.fit(VAEModule("storage", hidden_dim=16, batch_shapes=2), VAEDataModule("storage", val_count=3, max_train_shapes=4))
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["checkpoints"]
    assert json.loads((tmp_path / "b" / "checkpoints" / "split.json").read_text())["category"] == "storage"
    for stage in ("train", "val"):
        for name in ("loss", "kl", "cmd", "leaf", "bb", "xyz_prm"):
            assert torch.isfinite(metrics[f"{stage}/{name}"]), f"{stage}/{name}"
    assert dm._train_batch() == 2  # the model's batch_shapes
    with pytest.raises(ValueError, match="category 'chair' and the data module for 'storage'"):
        _tiny_trainer(tmp_path, fast_dev_run=True).fit(VAEModule("chair", hidden_dim=8), dm)


def test_checkpoint_info_and_refusals():
    model = VAEModule("table", hidden_dim=8, loss_weights={"bb": 10.0}, kl_weight=0.5)
    assert model.weights["bb"] == 10.0 and model.weights["kl"] == 0.5 and model.weights["cmd"] == 1.0
    ckpt = {}
    model.on_save_checkpoint(ckpt)
    assert ckpt["shapeprog_vae"] == {"format": vae_train.CHECKPOINT_FORMAT, "category": "table", "hidden_dim": 8}
    model.on_load_checkpoint(ckpt)
    with pytest.raises(ValueError, match="'category': 'table'.*this run is.*'category': 'chair'"):
        VAEModule("chair", hidden_dim=8).on_load_checkpoint(ckpt)
    with pytest.raises(ValueError, match="no 'shapeprog_vae' entry"):
        model.on_load_checkpoint({})
    with pytest.raises(ValueError, match=r"unknown loss term\(s\) \['bbox'\]"):
        VAEModule("chair", loss_weights={"bbox": 1.0})


def test_weight_decay_is_decoupled_and_zero_keeps_the_reference_adam():
    torch.manual_seed(0)
    ref = VAEModule("table", hidden_dim=8)
    opt = ref.configure_optimizers()
    assert type(opt) is torch.optim.Adam and opt.defaults["weight_decay"] == 0
    wd = VAEModule("table", hidden_dim=8, weight_decay=0.01)
    opt = wd.configure_optimizers()
    assert type(opt) is torch.optim.AdamW and opt.defaults["weight_decay"] == 0.01
    # with zero gradients, one AdamW step shrinks every weight by exactly lr * weight_decay
    p = next(wd.parameters())
    before = p.detach().clone()
    for q in wd.parameters():
        q.grad = torch.zeros_like(q)
    opt.step()
    assert torch.allclose(p.detach(), before * (1 - 1e-4 * 0.01), rtol=0, atol=1e-12)
    for bad in (-0.1, 1.0):
        with pytest.raises(ValueError, match="weight_decay must be in"):
            VAEModule("table", hidden_dim=8, weight_decay=bad)


def test_init_starts_from_weights_and_refuses_another_vae(tmp_path):
    from shapeprog.vae.pretrained import save_weights
    torch.manual_seed(0)
    src = VAEModule("table", hidden_dim=8)
    path = save_weights(src.vae, tmp_path / "w.pt", "table", half=False)
    torch.manual_seed(1)  # another initialisation, replaced by init
    again = VAEModule("table", hidden_dim=8, init=str(path))
    mine, theirs = again.vae.state_dict(), src.vae.state_dict()
    assert mine.keys() == theirs.keys() and all(torch.equal(mine[k], theirs[k]) for k in mine)
    with pytest.raises(ValueError, match="w.pt: the weights are of a VAE with .*'table'.*this run is.*'chair'"):
        VAEModule("chair", hidden_dim=8, init=str(path))
    with pytest.raises(ValueError, match="this run is .*'hidden_dim': 16"):
        VAEModule("table", hidden_dim=16, init=str(path))


@dataclass
class _Decoded:
    program: Program
    text: str


def _fake_decode(monkeypatch, program: Program) -> None:
    """Decoding (and sampling) that always gives ``program``."""
    monkeypatch.setattr(vae_reconstruct, "decode_latent",
                        lambda decoder, z, *, reject=False: _Decoded(program, to_text(program)))
    monkeypatch.setattr(vae_train, "sample",
                        lambda vae, n, seed=0, max_tries=10: [_Decoded(program, to_text(program))] * n)


def test_reconstruction_hook_logs_fscore_and_images(tmp_path, monkeypatch):
    from lightning.pytorch.callbacks import ModelCheckpoint
    from lightning.pytorch.loggers import TensorBoardLogger
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    dm = VAEDataModule("storage", val_count=3, max_train_shapes=2)
    dm.setup("fit")
    # decoding always gives the first validation shape: a high F-score for it (two draws of 500 points
    # each), less for the other
    target = tree_to_program(dm.val_trees[0])
    _fake_decode(monkeypatch, target)
    model = VAEModule("storage", hidden_dim=8, recon_every_n_epochs=1, recon_shapes=2, recon_points=500,
                      image_shapes=2, image_size=32)
    logger = TensorBoardLogger(str(tmp_path), name="tb")
    best = ModelCheckpoint(dirpath=str(tmp_path / "ckpt"), monitor="val/fscore", mode="max")
    trainer = _tiny_trainer(tmp_path, max_epochs=1, logger=logger, callbacks=[best], enable_checkpointing=True,
                            num_sanity_val_steps=0)
    trainer.fit(model, dm)
    scores = vae_reconstruct.reconstruction_fscores(dm.val_trees[:2], [target, target], points=500, seed=42)
    assert scores[0] > 80 and scores[0] > scores[1]
    targets = vae_reconstruct.target_surfaces(dm.val_trees[:2], points=500, seed=42)  # drawn once, as the hook keeps them
    assert vae_reconstruct.reconstruction_fscores(dm.val_trees[:2], [target, target], 500, 42, targets=targets) == scores
    assert trainer.callback_metrics["val/fscore"] == pytest.approx(sum(scores) / 2, rel=1e-5)
    assert trainer.callback_metrics["val/recon_failed"] == 0.0
    assert best.best_model_path and (Path(logger.log_dir) / "split.json").is_file()
    events = EventAccumulator(logger.log_dir, size_guidance={"images": 0})
    events.Reload()
    assert {"val/reconstructions", "val/samples"} <= set(events.Tags()["images"])
    # a failed decode scores 0 and is counted
    assert vae_reconstruct.reconstruction_fscores(dm.val_trees[:1], [None], points=100) == [None]


# ------------------------------------------------------------------------------------------ train.py


def test_shipped_configs_parse_through_train_py(train_main):
    assert [p.name for p in CONFIGS] == ["vae_all.yaml", "vae_chair.yaml", "vae_chair_baseline_macros.yaml",
                                         "vae_chair_baseline_macros_kl.yaml", "vae_chair_kl.yaml",
                                         "vae_chair_macros.yaml", "vae_chair_macros_kl.yaml",
                                         "vae_storage.yaml", "vae_storage_macros.yaml", "vae_table.yaml",
                                         "vae_table_macros.yaml"]
    for path in CONFIGS:
        cat = path.stem.split("_")[1]
        run = path.stem
        text = path.read_text()
        assert f"python train.py fit --config configs/shapeassembly/{path.name}" in text
        cli = train_main(["--config", str(path)], run=False)
        assert isinstance(cli.model, VAEModule) and isinstance(cli.datamodule, VAEDataModule)
        assert cli.model.hparams.category == cli.datamodule.category == cat
        baseline = run.startswith("vae_chair_baseline_macros")
        kl = run.endswith("_kl")  # the chair recipe's last step: continues a file with the KL weight 0.3
        # the first run of the Baseline Macros model has the shipped macro VAEs' recipe: 8 shapes a step, lr 3e-4
        assert cli.model.hparams.lr == (2e-4 if kl else 3e-4 if baseline else 1e-4)
        assert cli.model.weights["kl"] == (0.3 if kl else 0.1)
        if kl:
            assert (ROOT / cli.model.hparams.init).is_file() and cli.model.hparams.batch_shapes == 8
        assert cli.model.hparams.eps == 1e-6 and cli.model.hparams.hidden_dim == 256
        assert cli.trainer.logger.log_dir.startswith(f"runs/{run}/")
        dirs = {cb.dirpath for cb in cli.trainer.checkpoint_callbacks}
        assert dirs == {str(ROOT / "runs" / run / "checkpoints")} or dirs == {f"runs/{run}/checkpoints"}
        library = ("shapeprog/macros/libs/chair_baseline.txt" if baseline else cat if "_macros" in run else None)
        assert cli.model.hparams.library == cli.datamodule.library == library


def test_fit_and_resume_through_train_py(tmp_path, train_main, tiny_vae_config):
    # no decoder pass here: the loss picks the best checkpoint
    path = tiny_vae_config("vae_storage", dict(hidden_dim=8, recon_every_n_epochs=0),
                           dict(monitor="val/loss", mode="min", every_n_epochs=1))
    cli = train_main(["fit", "--config", str(path)])
    assert cli.trainer.global_step == 2 and "val/loss" in cli.trainer.callback_metrics
    ckpt = torch.load(tmp_path / "ckpt" / "last.ckpt", map_location="cpu", weights_only=False)
    assert ckpt["shapeprog_vae"]["category"] == "storage" and ckpt["hyper_parameters"]["hidden_dim"] == 8
    log_dir = tmp_path / "vae_storage" / "version_0"
    assert json.loads((log_dir / "split.json").read_text())["val"] == cli.datamodule.val_keys
    assert (log_dir / "config.yaml").is_file()
    resumed = train_main(["fit", "--config", str(path), "--trainer.max_steps", "3", "--ckpt_path", "last"])
    assert resumed.trainer.global_step == 3
