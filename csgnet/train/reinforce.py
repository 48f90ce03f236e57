"""REINFORCE fine-tuning of a supervised 2D CSGNet / CSGNetStack on target images without programs.

The pieces of the objective are plain functions (:func:`episode_rewards`, :func:`update_baseline`,
:func:`policy_loss`); :class:`ReinforceModule` samples programs from the policy, scores them with the
chamfer reward against a running-average baseline and validates greedily;
:class:`~csgnet.train.targets.TargetDataModule` serves the target images (:func:`~csgnet.train.targets.load_targets`). ``docs/csgnet.md`` ("REINFORCE") describes the procedure
and how to run it:
``python train.py fit --config configs/csgnet/rl_csgnet2d_small.yaml`` (``--ckpt_path last`` resumes).
"""
from __future__ import annotations

import warnings
from pathlib import Path

import lightning as L
import numpy as np
import torch

from .. import metrics
from .augment import jitter
from ..decode import Sampled, greedy, sample
from ..inference import load_model
from ..models import CSGNet, ModelConfig, preset
from ..renderer import render_tokens
from .logs import EpochValues, log_means, log_pairs
from .streams import set_stream_epoch
from .targets import SOURCES, TargetDataModule, load_targets, target_batch

__all__ = ["ReinforceModule", "TargetDataModule", "load_targets", "load_initial", "episode_rewards",
           "update_baseline", "policy_loss", "greedy_scores", "log_greedy_validation", "SOURCES"]


# ---------------------------------------------------------------------------------------------
# the pieces of the objective (plain functions, tested on their own)

def episode_rewards(pred, target, valid=None, gamma: float = 20.0, invalid: str = "zero",
                    workers: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rewards and chamfer distances of a batch of rendered programs, one chamfer pass for both
    (:func:`csgnet.metrics.reward` with ``return_chamfer=True``, always as arrays).

    Args:
        pred: ``(N, 64, 64)`` bool renders (invalid programs render empty).
        target: ``(N, 64, 64)`` bool targets.
        valid: ``(N,)`` bool, programs marked False count as invalid whatever they render.
        gamma: the shaping exponent (20).
        invalid: ``"zero"`` (invalid or empty programs get 0) or ``"reference"`` (they get the
            reference's ``(1 - 16 / (64 sqrt 2)) ** gamma``, 0.0204 for ``gamma = 20``).

    Returns:
        ``(reward (N,) float64, chamfer (N,) float64)``.
    """
    r, cd = metrics.reward(pred, target, gamma, invalid, valid, workers, return_chamfer=True)
    return np.atleast_1d(np.asarray(r, np.float64)), np.atleast_1d(np.asarray(cd, np.float64))


def update_baseline(baseline: torch.Tensor, rewards: torch.Tensor, decay: float = 0.7) -> torch.Tensor:
    """The running-average baseline after one batch: ``decay * b + (1 - decay) * mean(R)`` (detached)."""
    return (decay * baseline + (1.0 - decay) * rewards.detach().mean()).detach()


def policy_loss(log_probs: torch.Tensor, counted: torch.Tensor, advantage: torch.Tensor) -> torch.Tensor:
    """REINFORCE loss ``-mean_i(advantage_i * sum_t counted[i, t] * log_probs[i, t])``.

    Args:
        log_probs: ``(N, T)`` log-probabilities of the sampled tokens (differentiable).
        counted: ``(N, T)`` bool, the steps that count (program tokens and the ``$``).
        advantage: ``(N,)`` reward minus baseline (not differentiated).
    """
    if log_probs.shape != counted.shape or advantage.shape != log_probs.shape[:1]:
        raise ValueError(f"log_probs {tuple(log_probs.shape)}, counted {tuple(counted.shape)} and advantage "
                         f"{tuple(advantage.shape)} must be (N, T), (N, T) and (N,)")
    per_program = torch.where(counted, log_probs, torch.zeros_like(log_probs)).sum(1)
    return -(advantage.detach().to(per_program.dtype) * per_program).mean()


# ---------------------------------------------------------------------------------------------
# initial weights

def load_initial(path, overrides: dict | None = None) -> tuple[CSGNet, dict]:
    """A model initialised from supervised weights, loading the tensors whose names and shapes match.

    Args:
        path: a weights file (:func:`csgnet.inference.export_weights`) or a Lightning checkpoint of
            :class:`csgnet.train.supervised.CSGNetModule` (or of :class:`ReinforceModule`).
        overrides: :class:`~csgnet.models.ModelConfig` fields to change (e.g. ``{"dropout": 0.2}``);
            tensors whose shape changes as a result are left at their initial values.

    Returns:
        ``(model, report)`` where ``report`` lists the ``loaded``, ``skipped`` (shape mismatch) and
        ``missing`` tensor names.
    """
    src = load_model(path)
    config = src.config
    if overrides:
        config = ModelConfig.from_dict({**config.to_dict(), **dict(overrides)})
    model = CSGNet(config) if config != src.config else src
    own = model.state_dict()
    loaded, skipped = [], []
    update = {}
    for k, v in src.state_dict().items():
        if k in own and own[k].shape == v.shape:
            update[k] = v
            loaded.append(k)
        elif k in own:
            skipped.append(k)
    own.update(update)
    model.load_state_dict(own)
    missing = [k for k in own if k not in update]
    return model.train(), {"loaded": loaded, "skipped": skipped, "missing": missing}


# ---------------------------------------------------------------------------------------------
# module

class ReinforceModule(L.LightningModule):
    """REINFORCE fine-tuning of a 2D CSGNet / CSGNetStack (spec section (f)).

    Args:
        init: supervised weights to start from (a weights file or a Lightning checkpoint; tensors with
            matching names and shapes are loaded). ``None`` starts from random weights of the
            ``size`` preset, which the paper reports does not work for real shapes (useful for tests).
        dim: 2 (the reward is the 2D chamfer distance). ``None``: from ``init``.
        stack: CSGNetStack; ``None``: from ``init`` (else False). Must agree with ``init`` when given.
        size: preset when ``init`` is None (``"small"`` / ``"paper"``).
        model: :class:`~csgnet.models.ModelConfig` fields to override (e.g. ``{dropout: 0.2}``).
        lr: SGD learning rate (0.01).
        momentum: SGD momentum (0.9).
        gamma: reward shaping exponent (20).
        invalid_reward: ``"zero"`` (the paper) or ``"reference"`` (0.0204, the published code).
        baseline_decay: the running-average weight of the old baseline (0.7).
        max_len: sampling horizon in tokens (13 as the paper; 15 is the reference's training horizon).
        constrained: mask tokens that cannot lead to a valid program while sampling (off, as the paper).
        augment: jitter the training targets (on, as the reference; validation is never jittered).
        plateau_patience: epochs without a better validation reward before the lr drops (8).
        plateau_factor: the drop (0.2).
        log_images: pairs shown in the TensorBoard image grids (0: none).
        image_every_n_steps: optimizer steps between training image grids (targets vs sampled programs).
        seed: seed of the sampling and jitter streams (re-derived from the global step on resume).
        reward_workers: threads for the chamfer distance transforms (default: metrics' default).
    """

    def __init__(self, init: str | None = None, dim: int | None = None, stack: bool | None = None,
                 size: str | None = None, model: dict | None = None, lr: float = 0.01, momentum: float = 0.9,
                 gamma: float = 20.0, invalid_reward: str = "zero", baseline_decay: float = 0.7, max_len: int = 13,
                 constrained: bool = False, augment: bool = True, plateau_patience: int = 8,
                 plateau_factor: float = 0.2, log_images: int = 16, image_every_n_steps: int = 100, seed: int = 0,
                 reward_workers: int | None = None):
        super().__init__()
        self.save_hyperparameters()
        if invalid_reward not in ("zero", "reference"):
            raise ValueError(f"invalid_reward must be 'zero' or 'reference', got {invalid_reward!r}")
        if max_len < 1:
            raise ValueError(f"max_len must be positive, got {max_len}")
        if not 0.0 <= baseline_decay <= 1.0:
            raise ValueError(f"baseline_decay must lie in [0, 1], got {baseline_decay}")
        if init is not None:
            path = Path(init)
            if not path.is_file():
                raise FileNotFoundError(
                    f"{path}: no such weights file to start REINFORCE from; train a supervised model first "
                    f"(python train.py fit --config configs/csgnet/csgnet2d_small.yaml) or pass its weights with "
                    f"--model.init")
            self.model, report = load_initial(path, model)
            if report["skipped"] or report["missing"]:
                warnings.warn(f"{path}: {len(report['loaded'])} tensors loaded; left at initial values: "
                              f"{', '.join(report['skipped'] + report['missing'])}", UserWarning, stacklevel=2)
            cfg = self.model.config
            for name, want in (("dim", dim), ("stack", stack)):
                if want is not None and getattr(cfg, name) != want:
                    raise ValueError(f"{path} holds a model with {name}={getattr(cfg, name)!r}, but {name}={want!r} "
                                     f"was asked for")
        else:
            warnings.warn("REINFORCE from random weights: the paper reports that fine-tuning needs a supervised "
                          "start (pass init=...)", UserWarning, stacklevel=2)
            self.model = CSGNet(preset(size or "small", 2 if dim is None else dim, bool(stack), **(model or {})))
        self.config: ModelConfig = self.model.config
        if self.config.dim != 2:
            raise ValueError(f"REINFORCE fine-tuning is for 2D models (the reward is the 2D chamfer distance); "
                             f"got a {self.config.dim}D model")
        # the full configuration, in the form csgnet.inference.read_checkpoint reads
        full = self.config.to_dict()
        self.hparams.update(dim=full.pop("dim"), stack=full.pop("stack"), size=size or "small", model=full)
        self.register_buffer("baseline", torch.zeros((), dtype=torch.float64))
        self._gen: torch.Generator | None = None
        self._rng = np.random.default_rng([int(seed), 0])
        self._val = EpochValues()
        self._last_image_step = -1

    # ------------------------------------------------------------------------------------------
    def forward(self, targets: torch.Tensor) -> Sampled:
        """Sample one program per target (``(B, 64, 64)`` bool)."""
        return sample(self.model, targets, self.hparams.max_len, generator=self._generator(targets.device),
                      constrained=self.hparams.constrained)

    def _generator(self, device) -> torch.Generator:
        device = torch.device(device)
        if self._gen is None or self._gen.device != device:
            self._gen = torch.Generator(device=device)
            self._gen.manual_seed(self._stream_seed())
        return self._gen

    def _stream_seed(self) -> int:
        step = self.trainer.global_step if self._trainer is not None else 0
        return int(np.random.SeedSequence([int(self.hparams.seed), int(step)]).generate_state(1)[0])

    def on_train_start(self):
        # a resumed run continues with streams of its own instead of replaying the first steps
        self._gen = None
        self._rng = np.random.default_rng([int(self.hparams.seed), 1, int(self.trainer.global_step)])

    def on_train_epoch_start(self):
        set_stream_epoch(self.trainer, self.current_epoch)

    def advantage(self, rewards: torch.Tensor) -> torch.Tensor:
        """Update the running baseline with this batch's rewards ``(N,)``, then return ``R - b``."""
        mean = rewards.detach().double().mean()
        if self._trainer is not None and self.trainer.world_size > 1:
            mean = self.trainer.strategy.reduce(mean, reduce_op="mean")
        self.baseline.copy_(update_baseline(self.baseline, mean, self.hparams.baseline_decay))
        return (rewards.double() - self.baseline).float()

    def rollout(self, targets: torch.Tensor):
        """Sample programs for ``targets``, render them and score them.

        Returns:
            ``(sampled, renders (B, 64, 64) bool, rewards (B,) float32 tensor, chamfer (B,) float64)``.
        """
        s = self(targets)
        pred = render_tokens(s.tokens, 2, s.lengths)
        r, cd = episode_rewards(pred, targets, s.valid, self.hparams.gamma, self.hparams.invalid_reward,
                                self.hparams.reward_workers)
        return s, pred, torch.as_tensor(r, dtype=torch.float32, device=targets.device), cd

    def training_step(self, batch, batch_idx):
        targets = target_batch(batch)
        if self.hparams.augment:
            targets = jitter(targets, self._rng)
        s, pred, rewards, cd = self.rollout(targets)
        adv = self.advantage(rewards)
        loss = policy_loss(s.log_probs, s.counted, adv)
        n = targets.shape[0]
        steps = s.counted.sum()
        log = dict(on_step=True, on_epoch=False, batch_size=n)
        self.log("train/reward", rewards.mean(), prog_bar=True, **log)
        self.log("train/reward_std", rewards.std() if n > 1 else torch.zeros(()), **log)
        self.log("train/chamfer", float(cd.mean()), **log)
        self.log("train/valid", s.valid.float().mean(), **log)
        self.log("train/length", s.lengths.float().mean(), **log)
        self.log("train/entropy", (s.entropy.sum() / steps.clamp(min=1)).detach(), **log)
        self.log("train/baseline", self.baseline.float(), **log)
        self.log("train/loss", loss.detach(), **log)
        self._maybe_log_training_grid(targets, pred)
        return loss

    def _maybe_log_training_grid(self, targets, pred):
        n, every = int(self.hparams.log_images), int(self.hparams.image_every_n_steps)
        step = self.global_step
        if not n or every <= 0 or step % every or step == self._last_image_step:
            return
        if log_pairs(self, "train/targets_vs_samples", targets[:n], pred[:n]):
            self._last_image_step = step

    # ------------------------------------------------------------------------------------------
    def on_validation_epoch_start(self):
        self._val = EpochValues(self.hparams.log_images)

    def validation_step(self, batch, batch_idx):
        targets = target_batch(batch)
        hp = self.hparams
        pred, values = greedy_scores(self.model, targets, hp.max_len, hp.constrained, hp.gamma, hp.invalid_reward,
                                     hp.reward_workers)
        self._val.add(targets, pred, **values)

    def on_validation_epoch_end(self):
        log_greedy_validation(self, self._val)

    def configure_optimizers(self):
        opt = torch.optim.SGD(self.model.parameters(), lr=self.hparams.lr, momentum=self.hparams.momentum)
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, mode="max", factor=self.hparams.plateau_factor,
                                                           patience=self.hparams.plateau_patience)
        return {"optimizer": opt,
                "lr_scheduler": {"scheduler": sched, "monitor": "val/reward", "interval": "epoch", "strict": False}}


def greedy_scores(model: CSGNet, targets: torch.Tensor, max_len: int = 13, constrained: bool = False,
                  gamma: float = 20.0, invalid: str = "zero", workers: int | None = None
                  ) -> tuple[torch.Tensor, dict[str, np.ndarray]]:
    """The validation of the fine-tuning methods: greedy decodes of ``targets`` ``(B, 64, 64)`` bool,
    rendered and scored.

    Returns:
        ``(renders (B, 64, 64) bool, values)`` with ``values`` the ``(B,)`` arrays ``reward``,
        ``chamfer``, ``iou`` (union denominator), ``valid`` and ``length`` (program tokens).
    """
    dec = greedy(model, targets, max_len=max_len, constrained=constrained)
    pred = render_tokens(dec.tokens[:, 0], 2, dec.lengths[:, 0])
    r, cd = episode_rewards(pred, targets, dec.valid[:, 0], gamma, invalid, workers)
    iou = np.nan_to_num(np.asarray(metrics.iou(pred.cpu(), targets.cpu(), denominator="union"), np.float64))
    return pred, dict(reward=r, chamfer=cd, iou=iou, valid=dec.valid[:, 0].cpu().numpy(),
                      length=dec.lengths[:, 0].cpu().numpy())


def log_greedy_validation(module: L.LightningModule, val: EpochValues) -> None:
    """Log the means of a validation epoch of :func:`greedy_scores` values as ``val/<name>`` (and the
    ``val/targets_vs_greedy`` image grid); nothing for an empty epoch."""
    if not val:
        return
    v = val.arrays()
    log_means(module, {f"val/{k}": v[k].mean() for k in ("reward", "chamfer", "iou", "valid", "length")},
              prog_bar=("val/reward", "val/chamfer"))
    if val.grid is not None:
        log_pairs(module, "val/targets_vs_greedy", *val.grid)
