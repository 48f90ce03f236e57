"""Self-training: the label table, the mixed batches, learning on a tiny problem, resume, configs."""
from pathlib import Path

import lightning as L
import pytest
import torch

import csgnet
from csgnet.train.checkpoint import AtomicCheckpointIO
from csgnet.train.reinforce import greedy_scores
from csgnet.train.selftrain import PseudoLabels, SelfTrainDataModule, SelfTrainModule
from csgnet.vocab import vocabulary

ROOT = Path(__file__).resolve().parents[3]
TINY = {"hidden": 64, "channels": [8, 16, 16], "embed": 16, "dropout": 0.0, "enc_dropout": 0.0, "input_pool": 2}
SHAPES = ["c(32,32,16)", "s(24,40,12)", "t(40,24,16)"]
STOP = vocabulary(2).stop


def test_a_label_is_replaced_only_by_a_better_one():
    labels = PseudoLabels(3, 4)
    assert len(labels.labelled()) == 0 and labels.lengths.tolist() == [0, 0, 0]
    toks = torch.tensor([[5, 6, 7, STOP, STOP], [8, STOP, STOP, STOP, STOP]])
    got = labels.offer(torch.tensor([0, 2]), toks, torch.tensor([3, 1]), [2.0, float("nan")])
    assert got.tolist() == [True, False] and labels.labelled().tolist() == [0]
    assert labels.tokens[0].tolist() == [5, 6, 7, STOP] and labels.score[0] == 2.0
    # equal or worse: kept; better: replaced
    assert labels.offer(torch.tensor([0]), toks[1:], torch.tensor([1]), [2.0]).tolist() == [False]
    assert labels.offer(torch.tensor([0]), toks[1:], torch.tensor([1]), [1.5]).tolist() == [True]
    assert labels.tokens[0].tolist() == [8, STOP, STOP, STOP] and labels.lengths[0] == 1
    with pytest.raises(ValueError, match="does not fit"):
        labels.offer(torch.tensor([1]), torch.tensor([[1, 2, 3, 4, 5]]), torch.tensor([4]), [0.0])
    with pytest.raises(ValueError, match="offer needs"):
        labels.offer(torch.tensor([1]), toks, torch.tensor([4]), [0.0])
    other = PseudoLabels(3, 4)
    other.load_state_dict(labels.state_dict())
    assert torch.equal(other.tokens, labels.tokens) and torch.equal(other.score, labels.score)
    with pytest.raises(ValueError, match="expected shape"):
        PseudoLabels(2, 4).load_state_dict(labels.state_dict())


def test_batches_mix_labelled_targets_and_synthetic_programs():
    targets = csgnet.render(SHAPES)
    dm = SelfTrainDataModule.from_arrays(targets, batch_size=10, steps_per_epoch=2, synthetic_fraction=0.4,
                                         lengths=[3, 5], max_len=5)
    dm.setup("fit")
    assert dm.split_batch() == (6, 2)
    tokens, lengths, images, from_target = next(iter(dm.train_dataloader()))
    assert tokens.shape == (4, 6) and not from_target.any()  # no labels yet: synthetic only
    dm.labels.offer(torch.tensor([1]), torch.tensor([[7, STOP]]), torch.tensor([1]), [1.0])
    tokens, lengths, images, from_target = next(iter(dm.train_dataloader()))
    assert tokens.shape == (10, 6) and from_target.tolist() == [True] * 6 + [False] * 4
    assert (tokens[:6, 0] == 7).all() and (lengths[:6] == 1).all() and sorted(lengths[6:].tolist()) == [3, 3, 5, 5]
    assert torch.equal(images[:6], torch.from_numpy(targets[[1] * 6])) and not images[6:].any()
    with pytest.raises(ValueError, match="synthetic_fraction"):
        SelfTrainDataModule(synthetic_fraction=1.5)


class _Labels(L.Callback):
    """The label table at the first batch of each epoch (after that epoch's relabelling)."""

    def __init__(self):
        self.tables = []

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        if batch_idx == 0:
            self.tables.append(trainer.datamodule.labels.state_dict())


def _greedy_reward(module, targets, max_len):
    module.model.eval()
    _, v = greedy_scores(module.model, torch.from_numpy(targets), max_len, constrained=True)
    module.model.train()
    return float(v["reward"].mean())


def test_self_training_raises_the_reward_on_a_tiny_problem():
    """A random tiny model, three one-primitive targets, six rounds of 20 steps: the greedy decodes'
    mean reward rises clearly, and each label only ever gives way to a better one."""
    targets = csgnet.render(SHAPES)
    L.seed_everything(0, verbose=False)
    m = SelfTrainModule(model=TINY, lr=0.003, round_epochs=1, beam_width=32, max_len=1, augment=False,
                        log_images=0)
    before = _greedy_reward(m, targets, 1)
    dm = SelfTrainDataModule.from_arrays(targets, batch_size=8, steps_per_epoch=20, synthetic_fraction=0.0, max_len=1)
    seen = _Labels()
    trainer = L.Trainer(max_epochs=6, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0, callbacks=[seen])
    trainer.fit(m, dm)
    after = _greedy_reward(m, targets, 1)
    assert after > before + 0.1, (before, after)
    assert dm.labels.rounds == 6 and len(seen.tables) == 6
    for old, new in zip(seen.tables, seen.tables[1:]):
        assert new["metric"] == "chamfer" and (new["score"] <= old["score"]).all()
        same = new["score"] == old["score"]
        assert torch.equal(new["tokens"][same], old["tokens"][same])
    assert trainer.callback_metrics["round/labelled"] == 1.0


class _AtStart(L.Callback):
    def on_train_start(self, trainer, pl_module):
        self.step, self.table = trainer.global_step, trainer.datamodule.labels.state_dict()


def _fit(tmp_path, epochs, cb=None):
    from lightning.pytorch.callbacks import ModelCheckpoint

    return L.Trainer(max_epochs=epochs, accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                     enable_model_summary=False, default_root_dir=tmp_path, plugins=[AtomicCheckpointIO()],
                     callbacks=[ModelCheckpoint(dirpath=tmp_path / "ckpt", save_last=True, every_n_train_steps=1, monitor="val/chamfer",
                                                mode="min")] + ([cb] if cb else []),
                     num_sanity_val_steps=0, log_every_n_steps=1)


def test_fit_validates_checkpoints_the_labels_and_resumes(tmp_path):
    from csgnet.inference import load_model

    targets = csgnet.render(SHAPES)

    def parts():
        dm = SelfTrainDataModule.from_arrays(targets, batch_size=6, steps_per_epoch=2, synthetic_fraction=0.5,
                                             lengths=[3], max_len=3)
        return SelfTrainModule(model=TINY, round_epochs=2, beam_width=4, max_len=3, log_images=0), dm

    m, dm = parts()
    t = _fit(tmp_path, 2)
    t.fit(m, dm)
    for key in ("val/reward", "val/chamfer", "val/iou", "val/valid", "train/loss", "train/pseudo", "round/chamfer"):
        assert key in t.callback_metrics, key
    assert t.global_step == 4, t.global_step
    saved = dm.labels.state_dict()
    assert saved["rounds"] == 1 and saved["last_epoch"] == 0 and torch.isfinite(saved["score"]).any()
    ckpt = tmp_path / "ckpt" / "last.ckpt"
    assert torch.load(ckpt, weights_only=False)["global_step"] == 4, torch.load(ckpt, weights_only=False)["global_step"]
    cb = _AtStart()
    m2, dm2 = parts()
    t2 = _fit(tmp_path, 3, cb)
    t2.fit(m2, dm2, ckpt_path=str(ckpt))
    assert cb.step == 4 and cb.table["rounds"] == 1
    assert all(torch.equal(cb.table[k], saved[k]) for k in ("tokens", "lengths", "score"))
    assert t2.global_step == 6, t2.global_step
    assert dm2.labels.rounds == 2 and dm2.labels.last_epoch == 2  # epoch 2 starts the second round
    assert load_model(ckpt).config == m.config  # a self-training checkpoint is a model file


def test_errors_name_the_problem(tmp_path):
    with pytest.raises(ValueError, match="beam_width"):
        SelfTrainModule(model=TINY, beam_width=0)
    with pytest.raises(ValueError, match="round_epochs"):
        SelfTrainModule(model=TINY, round_epochs=0)


@pytest.mark.parametrize("config", sorted(p.name for p in (ROOT / "configs" / "csgnet").glob("st_*.yaml")))
def test_st_configs_parse_and_build(config, tmp_path, monkeypatch, train_main):
    from csgnet.models import CSGNet, preset

    monkeypatch.chdir(ROOT)
    stack, dim = "stack" in config, 3 if "3d" in config else 2
    tiny = {k: v for k, v in TINY.items() if k != "input_pool"}
    if dim == 3:
        tiny["channels"] = [2, 2, 2, 2]
    model = CSGNet(preset("lite" if dim == 3 else "small", dim, stack, **tiny))
    torch.save({"config": model.config.to_dict(), "state_dict": model.state_dict()}, tmp_path / "w.pt")
    cli = train_main(["--config", f"configs/csgnet/{config}", "--trainer.logger", "false",
                      "--model.init", str(tmp_path / "w.pt")], run=False)
    assert isinstance(cli.model, SelfTrainModule) and isinstance(cli.datamodule, SelfTrainDataModule)
    assert cli.model.config.stack == stack and cli.model.config.dim == dim == cli.datamodule.dim
    hp = cli.model.hparams
    want = (10, 13, "chamfer", "silhouettes", "per_step") if dim == 2 else (10, 7, "iou", "volumes", "sum")
    assert (hp.beam_width, hp.max_len, hp.loss_norm) == (want[0], want[1], want[4])
    assert cli.datamodule.source == want[3] and cli.datamodule.max_len >= hp.max_len
    if dim == 2:
        assert (hp.gamma, hp.invalid_reward) == (20.0, "zero")
    from lightning.pytorch.callbacks import EarlyStopping, ModelCheckpoint
    stops = [c for c in cli.trainer.callbacks if isinstance(c, EarlyStopping)]
    assert stops and stops[0].monitor == f"val/{want[2]}" and stops[0].mode == ("min" if dim == 2 else "max")
    saves = [c for c in cli.trainer.callbacks if isinstance(c, ModelCheckpoint)]
    assert any(c.save_last for c in saves) and any(c.monitor == f"val/{want[2]}" for c in saves)
