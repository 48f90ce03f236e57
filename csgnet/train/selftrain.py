"""Self-training of a 2D CSGNet / CSGNetStack on target images without programs (PLAD-style).

Each round decodes every training target with beam search, keeps per target the best program found so
far by the chamfer distance (:class:`PseudoLabels`, replaced only by a better one), then trains the
model supervised on these (target image, program) pairs mixed with synthetic programs
(:class:`PseudoLabelBatches`). :class:`SelfTrainModule` validates as REINFORCE does, so the curves of the
two methods compare; :class:`SelfTrainDataModule` serves the targets and owns the label table, which
travels in the checkpoint. ``docs/csgnet.md`` ("Self-training") describes a round and how to run it:
``python train.py fit --config configs/csgnet/st_csgnet2d_small.yaml`` (``--ckpt_path last`` resumes).
"""
from __future__ import annotations

import lightning as L
import numpy as np
import torch

from ..decode import beam_search, check_beam
from ..models import CSGNet, ModelConfig, preset
from ..renderer import render_tokens
from ..score import score_beams
from ..vocab import vocabulary
from .augment import jitter
from .logs import EpochValues
from .reinforce import TargetDataModule, _images, greedy_scores, load_initial, log_greedy_validation
from .streams import MixedLengthBatches, ShardedBatches, distributed, set_stream_epoch, stream_loader
from .supervised import DEFAULT_LENGTHS, teacher_forced_loss, teacher_inputs

__all__ = ["PseudoLabels", "PseudoLabelBatches", "SelfTrainDataModule", "SelfTrainModule"]


class PseudoLabels:
    """The best program found so far for each of ``n`` targets, with its chamfer distance.

    The tensors live in shared memory, so DataLoader workers read the labels of the latest round.

    Attributes:
        tokens: ``(n, width) int64`` token indices, ``$``-padded.
        lengths: ``(n,) int64`` program tokens (0: no label yet).
        chamfer: ``(n,) float64`` chamfer distance of the label's render to its target (``inf``: none).
        rounds: relabelling rounds done.
        last_epoch: the training epoch of the latest round (-1: none).
    """

    def __init__(self, n: int, width: int, dim: int = 2):
        if n < 1 or width < 2:
            raise ValueError(f"a label table needs n >= 1 targets and width >= 2 tokens, got {n} and {width}")
        self.width, self.stop = int(width), vocabulary(dim).stop
        self.tokens = torch.full((n, width), self.stop, dtype=torch.int64).share_memory_()
        self.lengths = torch.zeros(n, dtype=torch.int64).share_memory_()
        self.chamfer = torch.full((n,), float("inf"), dtype=torch.float64).share_memory_()
        self.rounds, self.last_epoch = 0, -1

    def __len__(self) -> int:
        return self.lengths.shape[0]

    def labelled(self) -> torch.Tensor:
        """``(K,) int64`` indices of the targets that have a label."""
        return torch.nonzero(torch.isfinite(self.chamfer)).flatten()

    def offer(self, index: torch.Tensor, tokens: torch.Tensor, lengths: torch.Tensor, chamfer) -> torch.Tensor:
        """Replace the labels of ``index`` whose offered program is strictly better (a lower chamfer).

        Args:
            index: ``(M,) int64`` target indices (distinct).
            tokens: ``(M, T) int64`` programs, ``$``-padded; ``T`` may differ from the table's width as
                long as every program fits in it (``lengths < width``).
            lengths: ``(M,) int64`` program tokens.
            chamfer: ``(M,)`` chamfer distances (``inf`` or NaN: never taken).

        Returns:
            ``(M,) bool``, which offers replaced the label.
        """
        index, lengths = torch.as_tensor(index).long().cpu(), torch.as_tensor(lengths).long().cpu()
        tokens = torch.as_tensor(tokens).long().cpu()
        cd = torch.as_tensor(np.asarray(chamfer, np.float64))
        M = index.shape[0]
        if tokens.dim() != 2 or tokens.shape[0] != M or lengths.shape != (M,) or cd.shape != (M,):
            raise ValueError(f"offer needs index (M,), tokens (M, T), lengths (M,) and chamfer (M,); got "
                             f"{tuple(index.shape)}, {tuple(tokens.shape)}, {tuple(lengths.shape)} and {tuple(cd.shape)}")
        if M and int(lengths.max()) >= self.width:
            raise ValueError(f"a program of {int(lengths.max())} tokens does not fit the label table's width "
                             f"{self.width} (data.max_len must be at least the decoding horizon model.max_len)")
        better = torch.nan_to_num(cd, nan=float("inf")) < self.chamfer[index]
        if bool(better.any()):
            rows = index[better]
            padded = torch.full((int(better.sum()), self.width), self.stop, dtype=torch.int64)
            n = min(tokens.shape[1], self.width)
            padded[:, :n] = tokens[better, :n]
            padded[torch.arange(self.width)[None] >= lengths[better, None]] = self.stop
            self.tokens[rows] = padded
            self.lengths[rows] = lengths[better]
            self.chamfer[rows] = cd[better]
        return better

    def state_dict(self) -> dict:
        return {"tokens": self.tokens.clone(), "lengths": self.lengths.clone(), "chamfer": self.chamfer.clone(),
                "rounds": self.rounds, "last_epoch": self.last_epoch}

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` in place (the tensors stay shared with running workers)."""
        want = {"tokens": tuple(self.tokens.shape), "lengths": (len(self),), "chamfer": (len(self),)}
        for key, shape in want.items():
            if key not in state or tuple(state[key].shape) != shape:
                got = tuple(state[key].shape) if key in state else "missing"
                raise ValueError(f"pseudo-label table {key!r}: expected shape {shape}, got {got} (a checkpoint of "
                                 f"a run on other targets, or with another data.max_len?)")
        for key in want:
            getattr(self, key).copy_(state[key])
        self.rounds, self.last_epoch = int(state["rounds"]), int(state["last_epoch"])


class PseudoLabelBatches(ShardedBatches):
    """``steps`` batches, each ``pseudo`` labelled targets (drawn uniformly from those with a label when
    the batch is drawn) followed by the batches of ``synthetic`` (a :class:`MixedLengthBatches` sampling
    programs on the fly; None for none). Before any target has a label a batch holds only its
    synthetic programs.

    Yields:
        ``(tokens (B, W) int64, lengths (B,) int64, images (B, 64, 64) bool, from_target (B,) bool)``:
        the programs and, for the labelled targets, their target images (all False for synthetic rows,
        which the training step renders).
    """

    def __init__(self, images: torch.Tensor, labels: PseudoLabels, pseudo: int, synthetic: MixedLengthBatches | None,
                 steps: int, seed: int = 0, rank: int = 0, world: int = 1):
        super().__init__(steps, seed, rank, world)
        if len(images) != len(labels):
            raise ValueError(f"{len(images)} target images but a label table of {len(labels)}")
        if synthetic is not None and synthetic.max_len + 1 != labels.width:
            raise ValueError(f"synthetic programs of width {synthetic.max_len + 1} against labels of width {labels.width}")
        self.images, self.labels, self.pseudo, self.synthetic = images, labels, int(pseudo), synthetic

    def _batches(self, steps: int, rng: np.random.Generator):
        synth = self.synthetic._batches(steps, rng) if self.synthetic is not None else None
        for _ in range(steps):
            parts = []
            have = self.labels.labelled().numpy()
            if self.pseudo and len(have):
                idx = torch.as_tensor(rng.choice(have, self.pseudo, replace=len(have) < self.pseudo))
                parts.append((self.labels.tokens[idx], self.labels.lengths[idx], self.images[idx].bool(),
                              torch.ones(len(idx), dtype=torch.bool)))
            if synth is not None:
                toks, lengths = next(synth)
                parts.append((toks, lengths, torch.zeros((len(toks), 64, 64), dtype=torch.bool),
                              torch.zeros(len(toks), dtype=torch.bool)))
            if not parts:
                raise RuntimeError("no training pairs: no target has a pseudo-label yet (every beam was invalid) and "
                                   "data.synthetic_fraction is 0; start from supervised weights or mix in synthetic "
                                   "programs")
            yield tuple(torch.cat(cols) for cols in zip(*parts))


class SelfTrainDataModule(TargetDataModule):
    """Target images for self-training, their pseudo-label table, and the mixed training batches.

    Takes the arguments of :class:`~csgnet.train.reinforce.TargetDataModule` (``source``, ``path``,
    ``batch_size``, ``steps_per_epoch``, ``val_size``, ``train_size``, ``val_split``, ``num_workers``,
    ``seed``) and:

    Args:
        synthetic_fraction: the share of each batch that is synthetic programs (rendered), spread evenly
            over ``lengths`` (at least one per length when above 0); the rest are labelled targets.
        lengths: the synthetic program lengths (default: 3..13, as supervised training).
        max_len: the longest pseudo-label in tokens (at least the module's decoding horizon).

    The label table (:class:`PseudoLabels`, ``self.labels``) is part of the data module's state, saved
    in and restored from Lightning checkpoints.
    """

    def __init__(self, *args, synthetic_fraction: float = 0.5, lengths: list[int] | None = None, max_len: int = 13,
                 **kwargs):
        super().__init__(*args, **kwargs)
        if not 0.0 <= synthetic_fraction <= 1.0:
            raise ValueError(f"synthetic_fraction must lie in [0, 1], got {synthetic_fraction}")
        self.synthetic_fraction = float(synthetic_fraction)
        self.lengths = sorted(lengths or DEFAULT_LENGTHS[2])
        self.max_len = int(max_len)
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
            self.labels = PseudoLabels(len(self.train_images), self.width)
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
        synth = (MixedLengthBatches(2, self.lengths, per_length * len(self.lengths), steps, self.width - 1)
                 if per_length else None)
        ds = PseudoLabelBatches(self.train_images, self.labels, pseudo, synth, steps, self.seed, rank, world)
        return stream_loader(ds, self.trainer, self.num_workers)


class SelfTrainModule(L.LightningModule):
    """Self-training of a 2D CSGNet / CSGNetStack by rounds of pseudo-labelling and supervised training.

    Args:
        init: weights to start from (a weights file or Lightning checkpoint, as
            :func:`~csgnet.train.reinforce.load_initial` reads); ``None``: random weights of ``size``.
        stack: CSGNetStack; ``None``: from ``init`` (else False). Must agree with ``init`` when given.
        size: preset when ``init`` is None (``"small"`` / ``"paper"``).
        model: :class:`~csgnet.models.ModelConfig` fields to override.
        lr: Adam learning rate (1e-3, as supervised training).
        loss_norm: ``"per_step"`` (as 2D supervised training) or ``"sum"``.
        round_epochs: training epochs per round; the targets are relabelled at the start of every
            ``round_epochs``-th epoch (the first included).
        beam_width: beams per target when relabelling (10).
        beam_batch: targets per beam-search call.
        constrained_labels: relabel with constrained beam search (every hypothesis valid).
        max_len: decoding horizon in tokens, for relabelling and validation (13).
        constrained: constrained greedy decoding in validation (off, as REINFORCE validates).
        augment: jitter the training images, labelled and synthetic (on; validation never).
        gamma: validation reward exponent (20, as REINFORCE).
        invalid_reward: validation reward of invalid programs (``"zero"`` / ``"reference"``).
        log_images: pairs in the validation image grid (0: none).
        seed: seed of the jitter draws.
        reward_workers: threads for the chamfer distance transforms of validation.
    """

    def __init__(self, init: str | None = None, stack: bool | None = None, size: str | None = None,
                 model: dict | None = None, lr: float = 1e-3, loss_norm: str = "per_step", round_epochs: int = 2,
                 beam_width: int = 10, beam_batch: int = 100, constrained_labels: bool = True, max_len: int = 13,
                 constrained: bool = False, augment: bool = True, gamma: float = 20.0, invalid_reward: str = "zero",
                 log_images: int = 16, seed: int = 0, reward_workers: int | None = None):
        super().__init__()
        self.save_hyperparameters()
        check_beam(beam_width, "beam_width")
        for name, value in (("round_epochs", round_epochs), ("beam_batch", beam_batch), ("max_len", max_len)):
            if value < 1:
                raise ValueError(f"{name} must be positive, got {value}")
        if loss_norm not in ("per_step", "sum"):
            raise ValueError(f"loss_norm must be 'per_step' or 'sum', got {loss_norm!r}")
        if init is not None:
            self.model, _ = load_initial(init, model)
            if stack is not None and self.model.config.stack != stack:
                raise ValueError(f"{init} holds a model with stack={self.model.config.stack!r}, but stack={stack!r} "
                                 f"was asked for")
        else:
            self.model = CSGNet(preset(size or "small", 2, bool(stack), **(model or {})))
        self.config: ModelConfig = self.model.config
        if self.config.dim != 2:
            raise ValueError(f"self-training is for 2D models (labels are ranked by the 2D chamfer distance); got "
                             f"a {self.config.dim}D model")
        full = self.config.to_dict()  # the form csgnet.inference.read_checkpoint reads
        self.hparams.update(dim=full.pop("dim"), stack=full.pop("stack"), size=size or "small", model=full)
        self._rng = np.random.default_rng([int(seed), 0])
        self._val = EpochValues()

    # ------------------------------------------------------------------------------------------
    @torch.no_grad()
    def relabel(self, images: torch.Tensor, labels: PseudoLabels) -> dict[str, float]:
        """One labelling pass: beam-search every target, score every beam by its chamfer distance to the
        target (invalid or empty programs: ``inf``) and offer each target's best beam to ``labels``.

        Args:
            images: ``(N, 64, 64)`` bool targets, in the order of ``labels``.
            labels: the table to update (only with strictly better programs).

        Returns:
            ``{"replaced", "labelled", "chamfer"}``: the fraction of targets whose label changed, the
            fraction with a label, and the mean chamfer of the labels held.
        """
        hp = self.hparams
        was_training = self.model.training
        self.model.eval()
        device = next(self.model.parameters()).device
        replaced = 0
        try:
            for lo in range(0, len(images), hp.beam_batch):
                targets = images[lo: lo + hp.beam_batch].to(device).bool()
                dec = beam_search(self.model, targets, hp.beam_width, hp.max_len, constrained=hp.constrained_labels)
                pred, _, cd = score_beams(dec, targets)
                empty = ~pred.reshape(len(pred), -1).any(1).reshape(cd.shape).cpu().numpy()
                cd = np.where(dec.valid.cpu().numpy() & ~empty, cd, np.inf)
                best = torch.as_tensor(cd.argmin(1))  # ties: the more likely beam
                rows = torch.arange(len(targets))
                replaced += int(labels.offer(torch.arange(lo, lo + len(targets)), dec.tokens[rows, best].cpu(),
                                             dec.lengths[rows, best].cpu(), cd[rows.numpy(), best.numpy()]).sum())
        finally:
            self.model.train(was_training)
        have = labels.labelled()
        return {"replaced": replaced / len(labels), "labelled": len(have) / len(labels),
                "chamfer": float(labels.chamfer[have].mean()) if len(have) else float("inf")}

    def on_train_epoch_start(self):
        set_stream_epoch(self.trainer, self.current_epoch)
        self._maybe_relabel()

    def on_train_batch_start(self, batch, batch_idx):
        self._maybe_relabel()  # a run resumed mid-epoch may skip on_train_epoch_start

    def _maybe_relabel(self):
        dm = self.trainer.datamodule
        if not isinstance(dm, SelfTrainDataModule):
            raise TypeError(f"SelfTrainModule trains with a SelfTrainDataModule, got {type(dm).__name__}")
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
            target[synthetic] = render_tokens(tokens[synthetic], 2, lengths[synthetic]).to(target.device)
        if self.hparams.augment:
            target = jitter(target, self._rng)
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
        hp, targets = self.hparams, _images(batch)
        pred, values = greedy_scores(self.model, targets, hp.max_len, hp.constrained, hp.gamma, hp.invalid_reward,
                                     hp.reward_workers)  # as REINFORCE validates
        self._val.add(targets, pred, **values)

    def on_validation_epoch_end(self):
        log_greedy_validation(self, self._val)

    def configure_optimizers(self):
        return torch.optim.Adam(self.model.parameters(), lr=self.hparams.lr)
