"""Supervised training: data stream, loss, Lightning loop, checkpoints, configs."""
from functools import partial
from pathlib import Path

import lightning as L
import pytest
import torch
import torch.nn.functional as F

from csgnet.train.checkpoint import AtomicCheckpointIO
from csgnet.train.streams import MixedLengthBatches
from csgnet.inference import export_weights
from csgnet.models import preset
from csgnet.train.supervised import CSGDataModule, CSGNetModule, packed_inputs
from csgnet.vocab import vocabulary

ROOT = Path(__file__).resolve().parents[3]
TINY = {"hidden": 16, "channels": [2, 2, 2], "embed": 8, "dropout": 0.0, "enc_dropout": 0.0}


def test_loss_is_the_spec_normalisation():
    torch.manual_seed(0)
    m = CSGNetModule(dim=2, stack=False, model=TINY, augment=False)
    tok = torch.cat([b[0] for b in MixedLengthBatches(2, [3, 5], 4, 1, 5, None, seed=1)])
    lengths = (tok != vocabulary(2).stop).sum(1)
    loss, _, target = m._loss(tok, lengths, augment=False)
    T = int(lengths.max()) + 1
    tok_in = torch.cat([torch.full((4, 1), m.model.start), tok[:, : T - 1]], 1)
    lp = F.log_softmax(m.model(target, tok_in), -1)
    manual = []
    for i in range(4):
        k = int(lengths[i])
        nll = -lp[i, torch.arange(k + 1), tok[i, : k + 1]].sum()
        manual.append(nll / (k + 1))
    assert float(loss) == pytest.approx(float(torch.stack(manual).mean()), rel=1e-5)
    m3 = CSGNetModule(dim=2, stack=False, model=TINY, augment=False, loss_norm="sum")
    m3.model.load_state_dict(m.model.state_dict())
    loss3, _, _ = m3._loss(tok, lengths, augment=False)
    assert float(loss3) == pytest.approx(float(torch.stack([x * (int(n) + 1) for x, n in zip(manual, lengths)]).mean()),
                                          rel=1e-5)


def test_stack_model_trains_on_the_stack_trace():
    from csgnet.renderer import stack_trace

    m = CSGNetModule(dim=2, stack=True, model=TINY, augment=False)
    tok, lengths = next(iter(MixedLengthBatches(2, [3, 5], 4, 1, 5, None, seed=2)))
    target, out, tok_in, stack = m._inputs(tok, lengths, augment=False)
    assert stack.shape[:3] == (tok_in.shape[1], 4, m.config.stack_k)
    full = stack_trace(tok[:, : int(lengths.max())], 2, k=m.config.stack_k, lengths=lengths)
    assert torch.equal(stack, full)
    assert (tok_in[:, 0] == m.model.start).all() and torch.equal(tok_in[:, 1:], out[:, :-1])


@pytest.mark.parametrize("dim,stack", [(2, True), (2, False), (3, True)])
def test_inputs_rendered_in_workers_equal_the_training_steps_own(dim, stack):
    lens = [3, 5] if dim == 2 else [3]
    m = CSGNetModule(dim=dim, stack=stack, model=TINY if dim == 2 else {"hidden": 8, "embed": 8}, augment=False)
    k = m.config.stack_k if stack else None
    ds = MixedLengthBatches(dim, lens, 4, 1, max(lens), None, seed=3,
                            prepare=partial(packed_inputs, dim=dim, stack_k=k))
    tok, lengths, target_w, stack_w = next(iter(ds))
    assert target_w.dtype == torch.int64 and (stack_w is None) == (not stack)
    own = m._inputs(tok, lengths, augment=False)
    pre = m._inputs(tok, lengths, augment=False, packed=(target_w, stack_w))
    for a, b in zip(own, pre):
        assert (a is None and b is None) or torch.equal(a, b)


def test_fit_with_rendering_in_a_worker_gives_the_same_losses(tmp_path):
    losses, sizes = {}, {}
    for workers in (0, 1):
        class Record(L.Callback):
            def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
                seen.append(float(outputs["loss"]))
                parts.add(len(batch))

        seen, parts = [], set()
        torch.manual_seed(0)
        dm = CSGDataModule(dim=2, data_dir=None, lengths=[3, 5], batch_size=4, steps_per_epoch=3, val_per_length=2,
                           num_workers=workers, render_in_workers=bool(workers))
        m = CSGNetModule(dim=2, stack=True, model=TINY)
        L.Trainer(max_steps=3, accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                  enable_model_summary=False, enable_checkpointing=False, default_root_dir=tmp_path,
                  limit_val_batches=1, num_sanity_val_steps=0, callbacks=[Record()]).fit(m, dm)
        losses[workers], sizes[workers] = seen, parts
    # the worker run's batches carry the packed renders (tokens, lengths, target, stack); the other's do not
    assert sizes == {0: {2}, 1: {4}}
    assert len(losses[0]) == 3 and losses[0] == pytest.approx(losses[1], rel=1e-6)


def test_rendering_in_workers_needs_the_csgnet_module_of_the_data():
    dm = CSGDataModule(dim=3, data_dir=None, lengths=[3], batch_size=2, steps_per_epoch=1, render_in_workers=True)
    dm.trainer = L.Trainer(accelerator="cpu", logger=False)
    dm.trainer.strategy.connect(CSGNetModule(dim=2, stack=True, model=TINY))
    with pytest.raises(ValueError, match="render_in_workers needs a CSGNetModule of the same dim"):
        dm._prepare()


class _StepAtStart(L.Callback):
    def on_train_start(self, trainer, pl_module):
        self.step = trainer.global_step


def _trainer(tmp_path, steps, cb=None):
    from lightning.pytorch.callbacks import ModelCheckpoint

    return L.Trainer(max_steps=steps, accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                     enable_model_summary=False, default_root_dir=tmp_path, plugins=[AtomicCheckpointIO()],
                     callbacks=[ModelCheckpoint(dirpath=tmp_path / "ckpt", save_last=True, every_n_train_steps=1)]
                     + ([cb] if cb else []), limit_val_batches=1, val_check_interval=2, num_sanity_val_steps=0)


def test_fit_validates_checkpoints_and_resumes(tmp_path):
    torch.manual_seed(0)
    dm = CSGDataModule(dim=2, data_dir=None, lengths=[3, 5], batch_size=4, steps_per_epoch=2, val_per_length=2)
    m = CSGNetModule(dim=2, stack=True, model=TINY)
    t = _trainer(tmp_path, 2)
    t.fit(m, dm)
    assert (tmp_path / "ckpt" / "last.ckpt").is_file()
    assert "val/chamfer" in t.callback_metrics and "val_iou/len03" in t.callback_metrics
    assert not list((tmp_path / "ckpt").glob("*.tmp"))
    cb = _StepAtStart()
    t2 = _trainer(tmp_path, 4, cb)
    t2.fit(CSGNetModule(dim=2, stack=True, model=TINY), dm, ckpt_path=str(tmp_path / "ckpt" / "last.ckpt"))
    assert cb.step == 2 and t2.global_step == 4


def test_export_weights_round_trip(tmp_path):
    from csgnet.inference import load_model

    m = CSGNetModule(dim=2, stack=True, model=TINY)
    ckpt = {"hyper_parameters": dict(m.hparams), "state_dict": m.state_dict(), "epoch": 3, "global_step": 7}
    torch.save(ckpt, tmp_path / "m.ckpt")
    out = export_weights(tmp_path / "m.ckpt", tmp_path / "w.pt")
    loaded = load_model(out)
    assert loaded.config == m.config
    for k, v in m.model.state_dict().items():
        assert torch.equal(loaded.state_dict()[k], v.half().float() if v.is_floating_point() else v)
    direct = load_model(tmp_path / "m.ckpt")  # a Lightning checkpoint loads too
    assert all(torch.equal(direct.state_dict()[k], v) for k, v in m.model.state_dict().items())


def test_init_starts_from_exported_weights_and_refuses_another_configuration(tmp_path):
    m = CSGNetModule(dim=2, stack=True, model=TINY)
    torch.save({"hyper_parameters": dict(m.hparams), "state_dict": m.state_dict()}, tmp_path / "m.ckpt")
    w = export_weights(tmp_path / "m.ckpt", tmp_path / "w.pt", half=False)
    torch.manual_seed(123)  # a different initialisation, overwritten by init
    again = CSGNetModule(dim=2, stack=True, model=TINY, init=str(w))
    assert all(torch.equal(again.model.state_dict()[k], v) for k, v in m.model.state_dict().items())
    with pytest.raises(ValueError, match="configuration differs"):
        CSGNetModule(dim=2, stack=False, model=TINY, init=str(w))


def test_init_widen_starts_a_wider_run_from_a_narrower_models_outputs(tmp_path):
    m = CSGNetModule(dim=3, size="lite", model=TINY)
    torch.save({"hyper_parameters": dict(m.hparams), "state_dict": m.state_dict()}, tmp_path / "m.ckpt")
    w = str(export_weights(tmp_path / "m.ckpt", tmp_path / "w.pt", half=False))
    wide = {**TINY, "hidden": 24, "channels": [3, 2, 4]}
    with pytest.raises(ValueError, match="init_widen"):
        CSGNetModule(dim=3, size="lite", model=wide, init=w)
    big = CSGNetModule(dim=3, size="lite", model=wide, init=w, init_widen=True)
    assert big.config.hidden == 24 and big.config.channels == (3, 2, 4)
    target = torch.rand(2, 64, 64, 64) > 0.6
    tokens = torch.randint(0, big.config.vocab_size, (2, 4))
    m.model.eval(), big.model.eval()
    with torch.no_grad():
        assert torch.allclose(m.model(target, tokens), big.model(target, tokens), atol=1e-5)  # summation order only
    with pytest.raises(ValueError, match=r"w\.pt: widen needs"):  # narrower than the weights: refused, named
        CSGNetModule(dim=3, size="lite", model={**TINY, "hidden": 8}, init=w, init_widen=True)


def test_missing_dataset_names_the_generate_command(tmp_path):
    dm = CSGDataModule(dim=2, data_dir=str(tmp_path / "nothing"))
    with pytest.raises(FileNotFoundError, match="csgnet generate"):
        dm.setup("fit")


@pytest.mark.parametrize("config", sorted(p.name for p in (ROOT / "configs" / "csgnet").glob("*.yaml")
                                           if not p.name.startswith(("rl_", "st_"))))  # rl_*, st_*: their own tests
def test_configs_parse_and_build(config, monkeypatch, train_main):
    monkeypatch.chdir(ROOT)
    cli = train_main(["--config", f"configs/csgnet/{config}", "--trainer.logger", "false"], run=False)
    assert isinstance(cli.model, CSGNetModule) and isinstance(cli.datamodule, CSGDataModule)
    assert cli.model.config.dim == cli.datamodule.dim
    steps = cli.datamodule.steps_per_epoch
    assert steps is None or cli.trainer.log_every_n_steps <= steps // 4  # a curve within the first epoch
    name = config[:-5]
    assert cli.model.config.stack == ("stack" in name)
    # the name's second word is the preset, or "medium": the small preset with a wider GRU
    word = name.split("_")[1]
    if word == "medium":
        assert cli.model.hparams.size == "small" and cli.model.config.hidden > preset("small", 2, False).hidden
    else:
        assert cli.model.hparams.size == word


def test_exclude_removes_another_sets_held_out_programs_from_training(tmp_path):
    from csgnet.data import generate_dataset, load_dataset
    generate_dataset(tmp_path / "a", dim=3, scale=0.0002, seed=0, lengths=[3], progress=False)
    generate_dataset(tmp_path / "b", dim=3, scale=0.0005, seed=0, lengths=[3], progress=False)
    held = {p.text() for s in ("val", "test") for p in load_dataset(tmp_path / "a", 3, s, [3])[3]}
    train_b = [p.text() for p in load_dataset(tmp_path / "b", 3, "train", [3])[3]]
    from csgnet.train.augment import symmetry_tables
    vocab = vocabulary(3)
    images = set()
    for t in held:
        row = torch.tensor(vocab.encode(t))
        images.update(tuple(m.tolist()) for m in symmetry_tables(3)[:, row] if (m >= 0).all())
    overlap = sum(tuple(vocab.encode(t)) in images for t in train_b)
    assert overlap >= sum(t in held for t in train_b) > 0  # the same seed: a's programs lead b's training split
    dm = CSGDataModule(dim=3, data_dir=str(tmp_path / "b"), lengths=[3], exclude=[str(tmp_path / "a")],
                       val_per_length=1)
    dm.setup("fit")
    kept = {vocab.text([i for i in row.tolist() if i != vocab.stop]) for row in dm.train_tables[3]}
    assert dm.excluded == overlap and len(dm.train_tables[3]) == len(train_b) - overlap
    assert not {vocab.text(vocab.encode(t)) for t in held} & kept
    # a mirror image of a held-out program, added to b's training programs, is left out too
    import shutil
    shutil.copytree(tmp_path / "b", tmp_path / "c")
    test_a = load_dataset(tmp_path / "a", 3, "test", [3])[3][0]
    mirrored = next(m for m in symmetry_tables(3)[1:, torch.tensor(vocab.encode(test_a))] if (m >= 0).all())
    text = vocab.decode(mirrored.tolist()).text()
    assert text != test_a.text()
    with open(tmp_path / "c" / "3d" / "len_03" / "train.txt", "a") as f:
        f.write(text + "\n")
    dm = CSGDataModule(dim=3, data_dir=str(tmp_path / "c"), lengths=[3], exclude=[str(tmp_path / "a")],
                       val_per_length=1)
    dm.setup("fit")
    assert dm.excluded == overlap + 1
    with pytest.raises(ValueError, match="needs a data_dir"):
        CSGDataModule(dim=3, data_dir=None, exclude=["x"])
