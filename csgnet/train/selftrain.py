"""Self-training of a CSGNet / CSGNetStack on targets without programs (PLAD-style), 2D images or 3D volumes.

Each round decodes every training target with beam search, keeps per target the best program found so
far (:class:`~csgnet.train.labels.PseudoLabels`, replaced only by a better one: by the chamfer distance in
2D, by the IoU in 3D), then trains the model supervised on these (target, program) pairs mixed with
synthetic programs (:class:`~csgnet.train.labels.PseudoLabelBatches`). :class:`SelfTrainModule` validates
2D models as REINFORCE does, so the curves of the two methods compare, and 3D models by the greedy decode's
IoU; :class:`SelfTrainDataModule` serves the targets and owns the label table, which travels in the
checkpoint. ``docs/csgnet.md`` ("Self-training") describes a round and how to run it:
``python train.py fit --config configs/csgnet/st_csgnet2d_small.yaml`` (or ``st_csgnet3d_lite.yaml``;
``--ckpt_path last`` resumes).
"""
from __future__ import annotations

import lightning as L
import numpy as np
import torch

from ..decode import beam_search, check_beam, greedy
from ..models import CSGNet, ModelConfig, preset
from ..renderer import render_tokens
from ..score import score_beams, score_renders
from .augment import jitter, mirror_pairs
from .labels import PseudoLabelBatches, PseudoLabels
from .logs import EpochValues, log_means, log_pairs
from .reinforce import greedy_scores, load_initial, log_greedy_validation
from .streams import MixedLengthBatches, distributed, set_stream_epoch, stream_loader
from .supervised import DEFAULT_LENGTHS, teacher_forced_loss, teacher_inputs
from .targets import TargetDataModule, target_batch

__all__ = ["PseudoLabels", "PseudoLabelBatches", "SelfTrainDataModule", "SelfTrainModule", "DEFAULT_MAX_LEN"]

#: The decoding horizon in tokens per dimension (the paper's longest programs: 13 in 2D, 7 in 3D).
DEFAULT_MAX_LEN = {2: 13, 3: 7}


class SelfTrainDataModule(TargetDataModule):
    """Targets for self-training, their pseudo-label table, and the mixed training batches.

    Takes the arguments of :class:`~csgnet.train.targets.TargetDataModule` (``source``, ``path``,
    ``batch_size``, ``steps_per_epoch``, ``val_size``, ``train_size``, ``val_split``, ``num_workers``,
    ``seed``, ``dim``) and:

    Args:
        synthetic_fraction: the share of each batch that is synthetic programs (rendered), spread evenly
            over ``lengths`` (at least one per length when above 0); the rest are labelled targets.
        lengths: the synthetic program lengths (default as supervised training: 3..13 in 2D, 3..7 in 3D).
        max_len: the longest pseudo-label in tokens, at least the module's decoding horizon (default
            :data:`DEFAULT_MAX_LEN`: 13 in 2D, 7 in 3D).

    The label table (:class:`PseudoLabels`, ``self.labels``) is part of the data module's state, saved
    in and restored from Lightning checkpoints.
    """

    def __init__(self, *args, synthetic_fraction: float = 0.5, lengths: list[int] | None = None,
                 max_len: int | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        if not 0.0 <= synthetic_fraction <= 1.0:
            raise ValueError(f"synthetic_fraction must lie in [0, 1], got {synthetic_fraction}")
        self.synthetic_fraction = float(synthetic_fraction)
        self.lengths = sorted(lengths or DEFAULT_LENGTHS[self.dim])
        self.max_len = int(DEFAULT_MAX_LEN[self.dim] if max_len is None else max_len)
        self.labels: PseudoLabels | None = None
        self._pending: dict | None = None

    @property
    def width(self) -> int:
        return max(self.max_len, max(self.lengths)) + 1

    def split_batch(self) -> tuple[int, int]:
        """``(labelled targets, synthetic programs per length)`` in each training batch."""
        synthetic = round(self.batch_size * self.synthetic_fraction)
        per_length = max(1, synthetic // len(self.lengths)) if synthetic else 0
        return max(0, self.batch_size - per_length * len(self.lengths)), per_length

    def setup(self, stage: str | None = None) -> None:
        super().setup(stage)
        if self.train_images is not None and self.labels is None:
            self.labels = PseudoLabels(len(self.train_images), self.width, self.dim)
            if self._pending is not None:
                self.labels.load_state_dict(self._pending)
                self._pending = None

    def state_dict(self) -> dict:
        return {"labels": self.labels.state_dict()} if self.labels is not None else {}

    def load_state_dict(self, state_dict: dict) -> None:
        if "labels" not in state_dict:
            return
        if self.labels is None:
            self._pending = state_dict["labels"]
        else:
            self.labels.load_state_dict(state_dict["labels"])

    def train_dataloader(self):
        rank, world = distributed(self.trainer)
        steps = self.steps_per_epoch or max(1, len(self.train_images) // self.batch_size)
        pseudo, per_length = self.split_batch()
        synth = (MixedLengthBatches(self.dim, self.lengths, per_length * len(self.lengths), steps, self.width - 1)
                 if per_length else None)
        ds = PseudoLabelBatches(self.train_images, self.labels, pseudo, synth, steps, self.seed, rank, world)
        return stream_loader(ds, self.trainer, self.num_workers)


class SelfTrainModule(L.LightningModule):
    """Self-training of a CSGNet / CSGNetStack (2D or 3D) by rounds of pseudo-labelling and supervised training.

    Args:
        init: weights to start from (a weights file or Lightning checkpoint, as
            :func:`~csgnet.train.reinforce.load_initial` reads); ``None``: random weights of ``size``.
        stack: CSGNetStack; ``None``: from ``init`` (else False). Must agree with ``init`` when given.
        size: preset when ``init`` is None (``"small"`` / ``"paper"`` / ``"lite"``).
        model: :class:`~csgnet.models.ModelConfig` fields to override.
        lr: Adam learning rate (1e-3, as supervised training).
        loss_norm: ``"per_step"`` or ``"sum"``; default as supervised training: per step in 2D, summed in 3D.
        round_epochs: training epochs per round; the targets are relabelled at the start of every
            ``round_epochs``-th epoch (the first included).
        beam_width: beams per target when relabelling (10).
        beam_batch: targets per beam-search call.
        constrained_labels: relabel with constrained beam search (every hypothesis valid).
        max_len: decoding horizon in tokens, for relabelling and validation (default
            :data:`DEFAULT_MAX_LEN`: 13 in 2D, 7 in 3D).
        constrained: constrained greedy decoding in validation (off, as REINFORCE validates).
        augment: 2D: jitter the training images, labelled and synthetic; 3D: map each training pair (a
            label and its target, or a synthetic program) by one of the 16 mirror symmetries of the canvas
            (:func:`~csgnet.train.augment.mirror_pairs`). On; validation never.
        gamma: 2D validation reward exponent (20, as REINFORCE).
        invalid_reward: 2D validation reward of invalid programs (``"zero"`` / ``"reference"``).
        log_images: pairs in the validation image grid (0: none).
        seed: seed of the augmentation draws.
        reward_workers: threads for the chamfer distance transforms of 2D validation.
        dim: 2 or 3 when ``init`` is None (else from ``init``, and must agree with it when given).
    """

    def __init__(self, init: str | None = None, stack: bool | None = None, size: str | None = None,
                 model: dict | None = None, lr: float = 1e-3, loss_norm: str | None = None, round_epochs: int = 2,
                 beam_width: int = 10, beam_batch: int = 100, constrained_labels: bool = True,
                 max_len: int | None = None, constrained: bool = False, augment: bool = True, gamma: float = 20.0,
                 invalid_reward: str = "zero", log_images: int = 16, seed: int = 0,
                 reward_workers: int | None = None, dim: int | None = None):
        super().__init__()
        self.save_hyperparameters()
        check_beam(beam_width, "beam_width")
        for name, value in (("round_epochs", round_epochs), ("beam_batch", beam_batch), ("max_len", max_len)):
            if value is not None and value < 1:
                raise ValueError(f"{name} must be positive, got {value}")
        if dim not in (None, 2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim!r}")
        if init is not None:
            self.model, _ = load_initial(init, model)
            for name, want in (("dim", dim), ("stack", stack)):
                if want is not None and getattr(self.model.config, name) != want:
                    raise ValueError(f"{init} holds a model with {name}={getattr(self.model.config, name)!r}, but "
                                     f"{name}={want!r} was asked for")
        else:
            self.model = CSGNet(preset(size or "small", dim or 2, bool(stack), **(model or {})))
        self.config: ModelConfig = self.model.config
        self.dim = self.config.dim
        loss_norm = loss_norm or ("per_step" if self.dim == 2 else "sum")
        if loss_norm not in ("per_step", "sum"):
            raise ValueError(f"loss_norm must be 'per_step' or 'sum', got {loss_norm!r}")
        full = self.config.to_dict()  # the form csgnet.inference.read_checkpoint reads
        self.hparams.update(dim=full.pop("dim"), stack=full.pop("stack"), size=size or "small", model=full,
                            loss_norm=loss_norm, max_len=int(max_len or DEFAULT_MAX_LEN[self.dim]))
        self._rng = np.random.default_rng([int(seed), 0])
        self._val = EpochValues()

    # ------------------------------------------------------------------------------------------
    @torch.no_grad()
    def relabel(self, images: torch.Tensor, labels: PseudoLabels) -> dict[str, float]:
        """One labelling pass: beam-search every target, score every beam by the label table's score
        against the target (2D chamfer: invalid or empty programs ``inf``; 3D IoU: invalid or empty
        programs ``-inf``) and offer each target's best beam to ``labels``.

        Args:
            images: ``(N, 64, 64)`` or ``(N, 64, 64, 64)`` bool targets, in the order of ``labels``.
            labels: the table to update (only with strictly better programs).

        Returns:
            ``{"replaced", "labelled", <metric>}``: the fraction of targets whose label changed, the
            fraction with a label, and the mean score of the labels held (``chamfer`` or ``iou``).
        """
        hp = self.hparams
        want = (64,) * self.dim
        if images.dim() != self.dim + 1 or tuple(images.shape[1:]) != want:
            raise ValueError(f"a {self.dim}D model relabels (N, {', '.join(map(str, want))}) targets, got "
                             f"{tuple(images.shape)}")
        if labels.dim != self.dim or len(labels) != len(images):
            raise ValueError(f"{len(images)} {self.dim}D targets against a {labels.dim}D label table of {len(labels)}")
        was_training = self.model.training
        self.model.eval()
        device = next(self.model.parameters()).device
        replaced = 0
        try:
            for lo in range(0, len(images), hp.beam_batch):
                targets = images[lo: lo + hp.beam_batch].to(device).bool()
                dec = beam_search(self.model, targets, hp.beam_width, hp.max_len, constrained=hp.constrained_labels)
                pred, iou, cd = score_beams(dec, targets)
                empty = ~pred.reshape(len(pred), -1).any(1).reshape(iou.shape).cpu().numpy()
                ok = dec.valid.cpu().numpy() & ~empty
                score = np.where(ok, iou if labels.higher_better else cd, labels.worst)
                best = torch.as_tensor(score.argmax(1) if labels.higher_better else score.argmin(1))  # ties: the more likely beam
                rows = torch.arange(len(targets))
                replaced += int(labels.offer(torch.arange(lo, lo + len(targets)), dec.tokens[rows, best].cpu(),
                                             dec.lengths[rows, best].cpu(), score[rows.numpy(), best.numpy()]).sum())
        finally:
            self.model.train(was_training)
        return {"replaced": replaced / len(labels), "labelled": len(labels.labelled()) / len(labels),
                labels.metric: labels.mean_score()}

    def on_train_epoch_start(self):
        set_stream_epoch(self.trainer, self.current_epoch)
        self._maybe_relabel()

    def on_train_batch_start(self, batch, batch_idx):
        self._maybe_relabel()  # a run resumed mid-epoch may skip on_train_epoch_start

    def _maybe_relabel(self):
        dm = self.trainer.datamodule
        if not isinstance(dm, SelfTrainDataModule):
            raise TypeError(f"SelfTrainModule trains with a SelfTrainDataModule, got {type(dm).__name__}")
        if dm.dim != self.dim:
            raise ValueError(f"a {self.dim}D model cannot self-train on {dm.dim}D targets: set data.dim to {self.dim}")
        labels, epoch = dm.labels, self.current_epoch
        if epoch % self.hparams.round_epochs or labels.last_epoch >= epoch:
            return
        # rank 0 relabels and every rank takes its table: one decoding pass, the same labels everywhere
        stats = None
        if self.trainer.is_global_zero:
            stats = self.relabel(dm.train_images, labels)
            labels.rounds, labels.last_epoch = labels.rounds + 1, epoch
        if self.trainer.world_size > 1:
            state, stats = self.trainer.strategy.broadcast((labels.state_dict(), stats), src=0)
            labels.load_state_dict(state)
        for name, value in stats.items():
            self.log(f"round/{name}", value, on_step=False, on_epoch=True, rank_zero_only=True)
        self.log("round/index", float(labels.rounds), on_step=False, on_epoch=True, rank_zero_only=True)

    def training_step(self, batch, batch_idx):
        tokens, lengths, images, from_target = batch
        target = images.clone()
        synthetic = ~from_target
        if bool(synthetic.any()):
            target[synthetic] = render_tokens(tokens[synthetic], self.dim, lengths[synthetic]).to(target.device)
        if self.hparams.augment:
            if self.dim == 2:
                target = jitter(target, self._rng)
            else:
                tokens, target = mirror_pairs(tokens, target, self._rng)
        tokens_out, tokens_in, stack = teacher_inputs(self.model, tokens, lengths)
        loss, exact = teacher_forced_loss(self.model, target, tokens_out, tokens_in, stack, lengths,
                                          self.hparams.loss_norm)
        n = tokens.shape[0]
        self.log("train/loss", loss, prog_bar=True, batch_size=n)
        self.log("train/exact", exact, batch_size=n)
        self.log("train/pseudo", from_target.float().mean(), batch_size=n)
        return loss

    # ------------------------------------------------------------------------------------------
    def on_validation_epoch_start(self):
        self._val = EpochValues(self.hparams.log_images)

    def validation_step(self, batch, batch_idx):
        hp, targets = self.hparams, target_batch(batch, self.dim)
        if self.dim == 2:
            pred, values = greedy_scores(self.model, targets, hp.max_len, hp.constrained, hp.gamma, hp.invalid_reward,
                                         hp.reward_workers)  # as REINFORCE validates
        else:
            dec = greedy(self.model, targets, max_len=hp.max_len, constrained=hp.constrained)
            pred = render_tokens(dec.tokens[:, 0], 3, dec.lengths[:, 0])
            iou, _ = score_renders(pred, targets, 3)
            values = dict(iou=iou, valid=dec.valid[:, 0].cpu().numpy(), length=dec.lengths[:, 0].cpu().numpy())
        self._val.add(targets, pred, **values)

    def on_validation_epoch_end(self):
        if self.dim == 2:
            log_greedy_validation(self, self._val)
        elif self._val:
            v = self._val.arrays()
            log_means(self, {f"val/{k}": v[k].mean() for k in ("iou", "valid", "length")}, prog_bar=("val/iou",))
            if self._val.grid is not None:
                log_pairs(self, "val/targets_vs_greedy", *self._val.grid)

    def configure_optimizers(self):
        return torch.optim.Adam(self.model.parameters(), lr=self.hparams.lr)
