"""REINFORCE fine-tuning: reward, baseline, loss, learning on a tiny problem, checkpoints, data, configs."""
import math
import warnings
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch

import csgnet
from csgnet import metrics
from csgnet.decode import sample
from csgnet.models import CSGNet, preset
from csgnet.renderer import render_tokens
from csgnet.train.checkpoint import AtomicCheckpointIO
from csgnet.train.reinforce import (ReinforceModule, TargetDataModule, episode_rewards, load_initial, load_targets,
                                    policy_loss, update_baseline)

ROOT = Path(__file__).resolve().parents[3]
TINY = {"hidden": 32, "channels": [4, 4, 4], "embed": 16, "dropout": 0.0, "enc_dropout": 0.0}
SHAPES = ["c(32,32,16)", "s(24,40,12)", "t(40,24,16)"]


def tiny_module(**kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # "REINFORCE from random weights"
        return ReinforceModule(dim=2, model=TINY, log_images=0, **kw)


def save_weights(path, stack=False, **over):
    model = CSGNet(preset("small", 2, stack, **{**TINY, **over}))
    torch.save({"config": model.config.to_dict(), "state_dict": model.state_dict()}, path)
    return model


# ---------------------------------------------------------------------------------------------
# reward

def test_reward_of_perfect_invalid_and_empty_programs():
    targets = csgnet.render(SHAPES)
    r, cd = episode_rewards(targets, targets)
    assert np.array_equal(r, np.ones(3)) and np.array_equal(cd, np.zeros(3))
    invalid = np.array([True, False, True])
    r, _ = episode_rewards(targets, targets, valid=invalid)
    assert r.tolist() == [1.0, 0.0, 1.0]
    empty = np.zeros_like(targets)
    r, cd = episode_rewards(empty, targets)
    assert r.tolist() == [0.0] * 3 and cd.tolist() == [16.0] * 3
    r, _ = episode_rewards(empty, targets, invalid="reference")
    expected = (1 - 16 / (64 * math.sqrt(2))) ** 20
    assert r.tolist() == pytest.approx([expected] * 3, abs=0) and round(expected, 4) == 0.0204
    r, _ = episode_rewards(targets, targets, valid=~invalid, invalid="reference")
    assert r.tolist() == [expected, 1.0, expected]


def test_batched_reward_equals_the_metric_and_its_formula():
    targets = csgnet.render(SHAPES * 2)
    preds = csgnet.render(["c(32,32,12)", "s(24,40,16)", "t(32,24,16)c(40,24,8)+", "c(8,8,8)",
                           "s(32,32,8)", "c(40,40,8)t(40,40,8)-"])
    preds[4] = False  # one empty render
    valid = np.array([True, True, True, False, True, True])
    for mode in ("zero", "reference"):
        r, cd = episode_rewards(preds, targets, valid=valid, invalid=mode)
        assert np.array_equal(r, metrics.reward(preds, targets, invalid=mode, valid=valid))
        assert np.array_equal(cd, metrics.chamfer(preds, targets))
    r, cd = episode_rewards(preds, targets, valid=valid)
    ok = valid & preds.reshape(6, -1).any(1)
    assert np.allclose(r[ok], (1 - cd[ok] / (64 * math.sqrt(2))) ** 20, rtol=0, atol=1e-15)
    assert 0 < r[ok].min() and r[ok].max() < 1
    with pytest.raises(ValueError, match="invalid must be"):
        episode_rewards(preds, targets, invalid="none")


# ---------------------------------------------------------------------------------------------
# baseline and loss

def test_baseline_is_updated_before_the_advantage():
    m = tiny_module()
    assert float(m.baseline) == 0.0
    r1 = torch.tensor([0.2, 0.4, 0.9])
    adv1 = m.advantage(r1)
    b1 = 0.3 * 0.5
    assert float(m.baseline) == pytest.approx(b1)
    assert torch.allclose(adv1, r1 - b1)  # this batch's mean is already in the baseline
    r2 = torch.tensor([1.0, 0.0])
    adv2 = m.advantage(r2)
    b2 = 0.7 * b1 + 0.3 * 0.5
    assert float(m.baseline) == pytest.approx(b2)
    assert torch.allclose(adv2, r2 - b2)
    assert float(update_baseline(torch.tensor(b1), r2)) == pytest.approx(b2)
    # the baseline is not differentiated
    r3 = torch.tensor([0.5, 0.7], requires_grad=True)
    assert not update_baseline(torch.tensor(0.1), r3).requires_grad
    assert "baseline" in m.state_dict()  # checkpointed, so resuming continues the average


def test_loss_counts_only_the_program_steps_and_the_stop():
    torch.manual_seed(0)
    lp = torch.randn(3, 5).requires_grad_()
    counted = torch.tensor([[1, 1, 0, 0, 0], [1, 1, 1, 1, 1], [1, 0, 0, 0, 0]], dtype=torch.bool)
    adv = torch.tensor([0.5, -1.0, 2.0], requires_grad=True)
    loss = policy_loss(lp, counted, adv)
    manual = -(0.5 * lp[0, :2].sum() - 1.0 * lp[1].sum() + 2.0 * lp[2, 0]) / 3
    assert float(loss.detach()) == pytest.approx(float(manual.detach()), rel=1e-6)
    loss.backward()
    assert (lp.grad[~counted] == 0).all()
    assert torch.allclose(lp.grad[counted], (-adv.detach()[:, None].expand(3, 5) / 3)[counted])
    assert adv.grad is None  # the advantage is a constant
    with pytest.raises(ValueError, match="must be"):
        policy_loss(lp, counted[:, :4], adv)


def test_sampled_programs_count_their_tokens_and_stop():
    """n_i = tokens before the first '$' plus one (the '$'), or T if no '$' was sampled."""
    torch.manual_seed(0)
    model = CSGNet(preset("small", 2, False, **TINY)).train()
    targets = torch.from_numpy(csgnet.render(SHAPES * 10))
    s = sample(model, targets, 5, generator=torch.Generator().manual_seed(1))
    T = s.tokens.shape[1]
    n = torch.where(s.lengths < T, s.lengths + 1, torch.full_like(s.lengths, T))
    assert torch.equal(s.counted.sum(1), n)
    assert torch.equal(s.counted, torch.arange(T)[None] < n[:, None])
    loss = policy_loss(s.log_probs, s.counted, torch.ones(len(n)))
    assert float(loss.detach()) == pytest.approx(-float(s.log_probs.detach().sum() / len(n)), rel=1e-6)


# ---------------------------------------------------------------------------------------------
# learning

def _expected_reward(model, targets, max_len, n=100):
    g = torch.Generator().manual_seed(123)
    model.eval()
    with torch.no_grad():
        t = torch.from_numpy(np.repeat(targets, n, 0))
        s = sample(model, t, max_len, generator=g, constrained=True)
        r, _ = episode_rewards(render_tokens(s.tokens, 2, s.lengths), t, s.valid)
    return float(r.mean())


def test_reinforce_raises_the_reward_on_a_tiny_problem():
    """A tiny random model, three target shapes, 40 updates of 30 sampled programs: the policy's mean
    reward (estimated with the same 300 fixed-seed samples before and after) goes up clearly."""
    targets = csgnet.render(SHAPES)
    L.seed_everything(0, verbose=False)
    m = tiny_module(lr=0.5, max_len=3, constrained=True, augment=False, seed=0)
    before = _expected_reward(m.model, targets, 3)
    m.model.train()
    dm = TargetDataModule.from_arrays(targets, batch_size=30, steps_per_epoch=40)
    trainer = L.Trainer(max_steps=40, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0,
                        gradient_clip_val=10)
    trainer.fit(m, dm)
    after = _expected_reward(m.model, targets, 3)
    assert after > before + 0.1, (before, after)
    assert 0 < float(m.baseline) < 1


# ---------------------------------------------------------------------------------------------
# initial weights, checkpoints, resume

def test_init_loads_matching_tensors(tmp_path):
    src = save_weights(tmp_path / "w.pt", stack=True)
    m, report = load_initial(tmp_path / "w.pt", {"dropout": 0.3})
    assert m.config.dropout == 0.3 and not report["skipped"] and not report["missing"]
    assert all(torch.equal(m.state_dict()[k], v) for k, v in src.state_dict().items())
    # a different stack depth changes the first conv's input channels: that tensor is left out
    m2, report2 = load_initial(tmp_path / "w.pt", {"stack_k": 3})
    assert report2["skipped"] == ["encoder.net.0.weight"]
    assert torch.equal(m2.state_dict()["gru.weight_hh_l0"], src.state_dict()["gru.weight_hh_l0"])
    mod = ReinforceModule(init=str(tmp_path / "w.pt"), log_images=0)
    assert mod.config == src.config
    with pytest.raises(ValueError, match="stack=True"):
        ReinforceModule(init=str(tmp_path / "w.pt"), stack=False)
    with pytest.raises(FileNotFoundError, match="train.py fit"):
        ReinforceModule(init=str(tmp_path / "missing.pt"))


class _StepAtStart(L.Callback):
    def on_train_start(self, trainer, pl_module):
        self.step, self.baseline = trainer.global_step, float(pl_module.baseline)


def _trainer(tmp_path, steps, cb=None, logger=False):
    from lightning.pytorch.callbacks import ModelCheckpoint

    return L.Trainer(max_steps=steps, accelerator="cpu", devices=1, logger=logger, enable_progress_bar=False,
                     enable_model_summary=False, default_root_dir=tmp_path, plugins=[AtomicCheckpointIO()],
                     callbacks=[ModelCheckpoint(dirpath=tmp_path / "ckpt", save_last=True, every_n_train_steps=1,
                                                monitor="val/reward", mode="max")] + ([cb] if cb else []),
                     limit_val_batches=1, val_check_interval=2, num_sanity_val_steps=0, gradient_clip_val=10,
                     accumulate_grad_batches=2, log_every_n_steps=1)


def test_fit_logs_checkpoints_resumes_and_exports(tmp_path):
    from lightning.pytorch.loggers import TensorBoardLogger

    from csgnet.inference import load_model
    from csgnet.inference import export_weights

    save_weights(tmp_path / "w.pt", stack=True)
    targets = csgnet.render(SHAPES)
    dm = TargetDataModule.from_arrays(targets, batch_size=4, steps_per_epoch=4)
    torch.manual_seed(0)
    m = ReinforceModule(init=str(tmp_path / "w.pt"), image_every_n_steps=1, log_images=2, constrained=True)
    logger = TensorBoardLogger(tmp_path, name="tb")
    t = _trainer(tmp_path, 2, logger=logger)
    t.fit(m, dm)
    assert t.global_step == 2
    for key in ("val/reward", "val/chamfer", "val/iou", "val/valid", "train/reward", "train/reward_std",
                "train/chamfer", "train/valid", "train/length", "train/entropy"):
        assert key in t.callback_metrics, key
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ev = EventAccumulator(str(Path(logger.log_dir)), size_guidance={"images": 0})
    ev.Reload()
    assert {"train/targets_vs_samples", "val/targets_vs_greedy"} <= set(ev.Tags()["images"])
    assert {"train/reward", "train/entropy", "train/length"} <= set(ev.Tags()["scalars"])
    ckpt = tmp_path / "ckpt" / "last.ckpt"
    assert ckpt.is_file() and not list((tmp_path / "ckpt").glob("*.tmp"))
    saved_baseline = float(m.baseline)
    assert saved_baseline != 0.0
    cb = _StepAtStart()
    t2 = _trainer(tmp_path, 3, cb)
    t2.fit(ReinforceModule(init=str(tmp_path / "w.pt"), log_images=0, constrained=True), dm, ckpt_path=str(ckpt))
    assert cb.step == 2 and t2.global_step == 3 and cb.baseline == pytest.approx(saved_baseline)
    # the RL checkpoint is a model file for inference and export
    loaded = load_model(ckpt)
    assert loaded.config == m.config
    w = export_weights(ckpt, tmp_path / "rl.pt", half=False)
    assert load_model(w).config == m.config


def test_training_targets_are_jittered_and_validation_targets_are_not(monkeypatch):
    import csgnet.train.reinforce as rl

    targets = torch.from_numpy(csgnet.render(SHAPES * 4))
    m = tiny_module(augment=True, seed=3)
    seen = {}
    real = m.rollout

    def spy(t):
        seen["train"] = t.clone()
        return real(t)

    monkeypatch.setattr(m, "rollout", spy)
    m.training_step(targets, 0)
    assert not torch.equal(seen["train"], targets)  # 12 random affine maps: some move the shape
    real_greedy = rl.greedy

    def spy_greedy(model, t, **kw):
        seen["val"] = t.clone()
        return real_greedy(model, t, **kw)

    monkeypatch.setattr(rl, "greedy", spy_greedy)
    m.on_validation_epoch_start()
    m.validation_step([targets], 0)
    assert torch.equal(seen["val"], targets)
    m.hparams.augment = False
    m.training_step(targets, 0)
    assert torch.equal(seen["train"], targets)


# ---------------------------------------------------------------------------------------------
# data

def test_target_sources_and_their_errors(tmp_path):
    from PIL import Image

    imgs = csgnet.render(SHAPES)
    np.savez(tmp_path / "t.npz", train=imgs, val_images=imgs[:2])
    assert np.array_equal(load_targets("npz", "train", tmp_path / "t.npz"), imgs)
    assert load_targets("npz", "val", tmp_path / "t.npz").shape == (2, 64, 64)
    with pytest.raises(ValueError, match="no array 'test'"):
        load_targets("npz", "test", tmp_path / "t.npz")
    (tmp_path / "f" / "train").mkdir(parents=True)
    for i, im in enumerate(imgs):
        Image.fromarray(np.where(im, 0, 255).astype(np.uint8)).save(tmp_path / "f" / "train" / f"{i}.png")
    assert np.array_equal(load_targets("folder", "train", tmp_path / "f"), imgs)
    with pytest.raises(FileNotFoundError, match="f/val"):
        load_targets("folder", "val", tmp_path / "f")
    with pytest.raises(ValueError, match="unknown target source"):
        load_targets("pictures", "train", tmp_path)
    with pytest.raises(ValueError, match="empty target image"):
        TargetDataModule.from_arrays(np.zeros((2, 64, 64), bool))
    with pytest.raises(ValueError, match=r"\(N, 64, 64\)"):
        TargetDataModule.from_arrays(np.ones((2, 32, 32), bool))
    sil = load_targets("silhouettes", "test")
    assert sil.shape[1:] == (64, 64) and sil.dtype == bool and len(sil) > 100


@pytest.mark.parametrize("config", sorted(p.name for p in (ROOT / "configs" / "csgnet").glob("rl_*.yaml")))
def test_rl_configs_parse_and_build(config, tmp_path, monkeypatch, train_main):
    monkeypatch.chdir(ROOT)
    text = (ROOT / "configs" / "csgnet" / config).read_text()
    stack = "stack: true" in text
    save_weights(tmp_path / "w.pt", stack=stack)
    cli = train_main(["--config", f"configs/csgnet/{config}", "--trainer.logger", "false",
                      "--model.init", str(tmp_path / "w.pt")], run=False)
    assert isinstance(cli.model, ReinforceModule) and isinstance(cli.datamodule, TargetDataModule)
    assert cli.model.config.stack == ("stack" in config) == stack
    hp = cli.model.hparams
    assert (hp.lr, hp.momentum, hp.gamma, hp.max_len, hp.invalid_reward) == (0.01, 0.9, 20.0, 13, "zero")
    assert cli.trainer.gradient_clip_val == 10.0
    if "paper" in config:
        assert cli.datamodule.batch_size == 300 and cli.trainer.accumulate_grad_batches == 10
    assert cli.datamodule.source == "silhouettes"
