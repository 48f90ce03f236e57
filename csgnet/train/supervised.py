"""Supervised training of CSGNet / CSGNetStack with PyTorch Lightning (spec section (e)).

* :class:`CSGDataModule` streams synthetic programs, from files written by
  :func:`csgnet.data.generate_dataset` or sampled on the fly, as batches that mix the program lengths in
  equal counts (the reference's "equal batch"). Batches hold token indices; targets and stack traces are
  rendered on the training device by the batched renderer, or, with ``render_in_workers``, by the
  DataLoader workers on the CPU (bit-packed, unpacked on the device): on a GPU the stack machine's
  token-by-token steps then leave the training step's critical path.
* :class:`CSGNetModule` is teacher-forced supervised training: Adam, the spec's loss normalisation,
  reduce-on-plateau ×0.2 after more than 8 epochs without improvement of the validation chamfer (2D) or
  IoU (3D), validation by greedy decoding with IoU and chamfer per program length, and image grids of
  targets beside predicted renders in TensorBoard.

The batch stream is :class:`csgnet.train.streams.MixedLengthBatches`. ``python train.py fit --config
configs/csgnet/csgnetstack2d_small.yaml`` runs it through LightningCLI (``docs/csgnet.md``, "Training").
"""
from __future__ import annotations

import math
from functools import partial
from pathlib import Path

import lightning as L
from lightning.pytorch.utilities import rank_zero_info
import numpy as np
import torch
import torch.nn.functional as F

from ..data import ProgramDataset, load_dataset, split_sizes
from ..synth import sample_programs
from .augment import jitter, mirror_programs, symmetry_tables
from ..decode import greedy
from ..inference import load_model
from ..models import CSGNet, ModelConfig, preset, widen
from ..renderer import render_tokens, stack_trace, unpack
from ..score import score_renders
from ..vocab import vocabulary
from .logs import EpochValues, log_means, log_pairs
from .streams import MixedLengthBatches, distributed, set_stream_epoch, stream_loader

__all__ = ["CSGDataModule", "CSGNetModule", "DEFAULT_LENGTHS", "teacher_inputs", "teacher_forced_loss",
           "packed_inputs"]

DEFAULT_LENGTHS = {2: [3, 5, 7, 9, 11, 13], 3: [3, 5, 7]}


def teacher_inputs(model: CSGNet, tokens: torch.Tensor, lengths: torch.Tensor, stack: torch.Tensor | None = None):
    """The teacher-forcing inputs of a batch of ``$``-padded programs.

    Args:
        model: the CSGNet / CSGNetStack trained (its start token and stack depth).
        tokens: ``(B, T') int64`` token indices, ``$``-padded, ``T' > max(lengths)``.
        lengths: ``(B,) int64`` program tokens before the ``$``.
        stack: the batch's stack trace when it is already rendered (unpacked :func:`packed_inputs`); else
            CSGNetStack's is rendered here.

    Returns:
        ``(tokens_out (B, T) int64, tokens_in (B, T) int64, stack)`` with ``T = max(lengths) + 1`` (the
        ``k + 1`` steps of the longest program): the targets, the inputs (START then the targets shifted
        by one) and, for CSGNetStack, the stack trace of the program's prefixes (else None).
    """
    cfg = model.config
    T = int(lengths.max()) + 1  # k + 1 targets for the longest program
    tokens = tokens[:, :T]
    start = torch.full_like(tokens[:, :1], model.start)
    tokens_in = torch.cat([start, tokens[:, :-1]], dim=1)
    if cfg.stack and stack is None:
        stack = stack_trace(tokens[:, :-1], cfg.dim, k=cfg.stack_k, lengths=lengths)
    return tokens, tokens_in, stack


def packed_inputs(tokens: torch.Tensor, lengths: torch.Tensor, dim: int, stack_k: int | None):
    """The renders a training step needs, bit-packed, computed where the batch is made (a DataLoader worker).

    Args:
        tokens: ``(B, T') int64`` ``$``-padded programs, as :class:`MixedLengthBatches` yields them.
        lengths: ``(B,) int64`` program tokens.
        dim: 2 or 3.
        stack_k: CSGNetStack's stack depth (``None`` for CSGNet: no trace).

    Returns:
        ``(target, stack)``: int64 words of the programs' renders ``(B, *C)`` and, for CSGNetStack, of
        their stack trace ``(T, B, K, *C)`` (``T = max(lengths) + 1``), else None. :func:`csgnet.renderer.unpack`
        gives exactly what :func:`csgnet.renderer.render_tokens` and :func:`teacher_inputs` compute (tested).
        Both are fresh tensors (the renderer recycles its CPU buffers), so a batch may be queued safely.
    """
    T = int(lengths.max()) + 1
    tokens = tokens[:, :T]
    target = render_tokens(tokens, dim, lengths, packed=True).clone()
    stack = None
    if stack_k:
        stack = stack_trace(tokens[:, :-1], dim, k=stack_k, lengths=lengths, packed=True).clone()
    return target, stack


def teacher_forced_loss(model: CSGNet, target: torch.Tensor, tokens_out: torch.Tensor, tokens_in: torch.Tensor,
                        stack, lengths: torch.Tensor, loss_norm: str = "per_step"):
    """The supervised loss of programs given the images they should draw (:func:`teacher_inputs`).

    Args:
        target: ``(B, 64, 64[, 64])`` bool images, the encoder's input.
        tokens_out, tokens_in, stack: from :func:`teacher_inputs`.
        lengths: ``(B,) int64`` program tokens.
        loss_norm: ``"per_step"`` (a program's summed NLL over its ``k + 1`` steps divided by ``k + 1``)
            or ``"sum"``.

    Returns:
        ``(loss, exact)``: the mean per-program loss (differentiable) and the fraction of programs
        whose every step the arg-max predicts.
    """
    logits = model(target, tokens_in, stack)
    nll = F.cross_entropy(logits.transpose(1, 2), tokens_out, reduction="none")
    steps = torch.arange(tokens_out.shape[1], device=tokens_out.device)[None] <= lengths[:, None]
    per_prog = (nll * steps).sum(1)
    if loss_norm == "per_step":
        per_prog = per_prog / (lengths + 1)
    acc = ((logits.argmax(-1) == tokens_out) | ~steps).all(1).float().mean()
    return per_prog.mean(), acc


class CSGDataModule(L.LightningDataModule):
    """Synthetic CSG programs for supervised training.

    Args:
        dim: 2 or 3.
        data_dir: a dataset written by ``python -m csgnet generate`` (``None``: sample training programs
            on the fly and a fixed validation set from ``seed``).
        lengths: program lengths to train on (default: 3..13 in 2D, 3..7 in 3D).
        batch_size: programs per batch, split evenly over the lengths (2D reference: 100; 3D: 66).
        steps_per_epoch: batches per epoch (default: the reference's train_size // batch_size).
        val_per_length: validation programs per length.
        num_workers: DataLoader workers (on-the-fly sampling scales with them).
        seed: stream seed.
        render_in_workers: render each training batch's targets (and CSGNetStack's stack traces) in the
            DataLoader workers (:func:`packed_inputs`) instead of in the training step; for GPU runs,
            with ``num_workers`` > 0. The losses are the same (tested).
        exclude: dataset folders whose validation and test programs are removed from the training
            programs (``data_dir`` only), so that a model trained on one generated set can be tested on
            another set's test split; in 3D their mirror images (:func:`csgnet.train.augment.symmetry_tables`)
            are removed too, so that the ``mirror`` augmentation cannot draw them. The programs removed are
            counted in ``excluded``.
        train_fraction: the share of each length's training programs used (the first ones, at least one),
            for data-size studies (``python -m csgnet datasize``).
    """

    def __init__(self, dim: int = 2, data_dir: str | None = "data/synthetic", lengths: list[int] | None = None,
                 batch_size: int = 100, steps_per_epoch: int | None = None, val_per_length: int = 200,
                 num_workers: int = 0, seed: int = 0, render_in_workers: bool = False,
                 exclude: list[str] | None = None, train_fraction: float = 1.0):
        super().__init__()
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim!r}")
        if not 0.0 < float(train_fraction) <= 1.0:
            raise ValueError(f"train_fraction must lie in (0, 1], got {train_fraction!r}")
        if train_fraction != 1.0 and data_dir is None:
            raise ValueError("train_fraction needs a data_dir (programs sampled on the fly are unlimited)")
        self.train_fraction = float(train_fraction)
        self.dim, self.data_dir = dim, data_dir
        self.lengths = sorted(lengths or DEFAULT_LENGTHS[dim])
        self.max_len = max(self.lengths)
        self.batch_size, self.steps_per_epoch = int(batch_size), steps_per_epoch
        self.val_per_length, self.num_workers, self.seed = int(val_per_length), int(num_workers), int(seed)
        self.render_in_workers = bool(render_in_workers)
        self.exclude = [str(e) for e in (exclude or [])]
        if self.exclude and data_dir is None:
            raise ValueError("exclude needs a data_dir (programs sampled on the fly are not filtered)")
        self.excluded = 0
        self.train_tables: dict[int, torch.Tensor] | None = None
        self.val_tokens: torch.Tensor | None = None

    def _held_out(self) -> set[tuple[int, ...]]:
        """The token rows of the ``exclude`` folders' val and test programs (3D: and of their mirror images)."""
        rows: set[tuple[int, ...]] = set()
        maps = symmetry_tables(3) if self.dim == 3 else torch.arange(len(vocabulary(self.dim)))[None]
        for folder in self.exclude:
            for split in ("val", "test"):
                for ps in load_dataset(folder, self.dim, split, self.lengths).values():
                    if ps:
                        tokens = ProgramDataset(ps, self.dim, max_len=self.max_len).tokens
                        for table in maps:
                            mapped = table[tokens]
                            rows.update(map(tuple, mapped[(mapped >= 0).all(1)].tolist()))
        return rows

    def _tables(self, split: str) -> dict[int, torch.Tensor]:
        progs = load_dataset(self.data_dir, self.dim, split, self.lengths)
        out = {}
        held = self._held_out() if split == "train" and self.exclude else set()
        if held:
            self.excluded = 0
        for n, ps in progs.items():
            if not ps:
                raise ValueError(f"the {split} split of {self.data_dir!r} has no {self.dim}D programs of length {n}")
            if split == "train" and self.train_fraction < 1.0:
                ps = ps[: max(1, math.ceil(self.train_fraction * len(ps)))]
            tokens = ProgramDataset(ps, self.dim, max_len=self.max_len).tokens
            if held:
                keep = torch.tensor([tuple(r) not in held for r in tokens.tolist()], dtype=torch.bool)
                self.excluded += int((~keep).sum())
                tokens = tokens[keep]
            out[n] = tokens
        if held:
            rank_zero_info(f"{self.excluded} training programs of {self.data_dir} are held-out programs of "
                           f"{', '.join(self.exclude)} (or their mirror images): left out")
        return out

    def setup(self, stage: str | None = None) -> None:
        if self.data_dir is not None:
            if not (Path(self.data_dir) / f"{self.dim}d").is_dir():
                raise FileNotFoundError(
                    f"no {self.dim}D dataset under {self.data_dir!r}; write one with "
                    f"`python -m csgnet generate --dim {self.dim} --scale 0.05 --out {self.data_dir}` "
                    f"or set data.data_dir to null to sample programs on the fly")
            if stage in (None, "fit"):
                self.train_tables = self._tables("train")
            val = self._tables("val")
        else:
            rng = np.random.default_rng([self.seed, 10**6])
            vocab = vocabulary(self.dim)
            val = {}
            for n in self.lengths:
                rows = np.asarray(sample_programs(self.dim, n, self.val_per_length, rng))
                t = torch.full((len(rows), self.max_len + 1), vocab.stop, dtype=torch.int64)
                t[:, :n] = torch.as_tensor(rows)
                val[n] = t
        self.val_tokens = torch.cat([val[n][: self.val_per_length] for n in self.lengths])

    def _steps(self) -> int:
        if self.steps_per_epoch:
            return int(self.steps_per_epoch)
        if self.train_tables is not None:
            total = sum(t.shape[0] for t in self.train_tables.values())
        else:
            total = sum(s["train"] for s in split_sizes(self.dim, 1.0, self.lengths).values())
        return max(1, total // self.batch_size)

    def train_dataloader(self):
        rank, world = distributed(self.trainer)
        ds = MixedLengthBatches(self.dim, self.lengths, self.batch_size, self._steps(), self.max_len,
                                self.train_tables, self.seed, rank, world, prepare=self._prepare())
        return stream_loader(ds, self.trainer, self.num_workers)

    def _prepare(self):
        """The per-batch rendering of ``render_in_workers`` (None when off), with the trained model's stack depth."""
        if not self.render_in_workers:
            return None
        module = getattr(self.trainer, "lightning_module", None)
        config = getattr(getattr(module, "model", None), "config", None)
        if getattr(config, "dim", None) != self.dim:
            raise ValueError("render_in_workers needs a CSGNetModule of the same dim as the data "
                             f"(data dim {self.dim}, model dim {getattr(config, 'dim', None)})")
        return partial(packed_inputs, dim=self.dim, stack_k=config.stack_k if config.stack else None)

    def val_dataloader(self):
        lengths = (self.val_tokens != vocabulary(self.dim).stop).sum(1)
        ds = torch.utils.data.TensorDataset(self.val_tokens, lengths)
        return torch.utils.data.DataLoader(ds, batch_size=self.batch_size, shuffle=False)


class CSGNetModule(L.LightningModule):
    """Teacher-forced supervised training of a CSGNet or CSGNetStack.

    Args:
        dim: 2 or 3.
        stack: CSGNetStack instead of CSGNet.
        size: preset name, ``"small"`` or ``"paper"`` (:func:`csgnet.models.preset`).
        model: overrides of :class:`~csgnet.models.ModelConfig` fields (e.g. ``{hidden: 512}``).
        lr: Adam learning rate (1e-3).
        loss_norm: ``"per_step"`` (2D reference: a program's summed NLL divided by its k + 1 steps) or
            ``"sum"`` (3D reference: not divided); default by ``dim``.
        augment: the 2D jitter of the targets (default: on in 2D, as the reference); no effect in 3D.
        mirror: 3D only: each training program is mapped by one of the 16 mirror symmetries of the canvas
            (:func:`csgnet.train.augment.mirror_programs`) before its target is rendered, so that a dataset of
            N programs gives up to 16 N (off by default: the reference trains on the programs as sampled).
            The targets must then be rendered in the step (``render_in_workers`` off).
        plateau_patience: epochs without improvement before the learning rate drops (8).
        plateau_factor: the drop (0.2).
        log_images: targets / predictions shown in the TensorBoard grid each validation.
        seed: seed of the jitter draws.
        init: a weights file or checkpoint (:func:`csgnet.inference.load_model`) whose tensors the
            model starts from, e.g. to continue a run from its exported weights when its checkpoint is
            gone (the optimiser and schedule start afresh); its configuration must equal this one's.
        init_widen: ``init`` may be a narrower model (smaller ``hidden`` or ``channels``, all else equal):
            it is widened to this run's configuration with :func:`csgnet.models.widen`, which keeps its
            outputs and gives the new units zero output weights, so the run starts where ``init`` ended.
    """

    def __init__(self, dim: int = 2, stack: bool = False, size: str = "small", model: dict | None = None,
                 lr: float = 1e-3, loss_norm: str | None = None, augment: bool | None = None,
                 plateau_patience: int = 8, plateau_factor: float = 0.2, log_images: int = 16, seed: int = 0,
                 init: str | None = None, mirror: bool = False, init_widen: bool = False):
        super().__init__()
        self.save_hyperparameters()
        self.config: ModelConfig = preset(size, dim, stack, **(model or {}))
        self.model = CSGNet(self.config)
        if init is not None:
            start = load_model(init)
            if init_widen and start.config != self.config:
                try:
                    start = widen(start, self.config)
                except ValueError as e:
                    raise ValueError(f"{init}: {e}") from None
            if start.config != self.config:
                raise ValueError(f"{init}: its model configuration differs from this run's "
                                 f"({start.config.to_dict()} against {self.config.to_dict()}); "
                                 "init_widen starts from a narrower model")
            self.model.load_state_dict(start.state_dict())
        self.loss_norm = loss_norm or ("per_step" if dim == 2 else "sum")
        if self.loss_norm not in ("per_step", "sum"):
            raise ValueError(f"loss_norm must be 'per_step' or 'sum', got {loss_norm!r}")
        self.augment = (dim == 2) if augment is None else bool(augment and dim == 2)
        if mirror and dim != 3:
            raise ValueError("mirror is a 3D augmentation (2D training jitters its targets: augment)")
        self.mirror = bool(mirror)
        self.monitor = "val/chamfer" if dim == 2 else "val/iou"
        self._rng = np.random.default_rng(seed)
        self._val = EpochValues()

    # ------------------------------------------------------------------------------------------
    def _inputs(self, tokens: torch.Tensor, lengths: torch.Tensor, augment: bool, packed=None):
        """Encoder input, targets, teacher inputs and stack trace of a batch; ``packed`` is the batch's
        :func:`packed_inputs` when the DataLoader workers rendered it."""
        target = trace = None
        if packed is not None:
            target, trace = (None if w is None else unpack(w, self.config.dim) for w in packed)
        tokens, tokens_in, stack = teacher_inputs(self.model, tokens, lengths, trace)
        if target is None:
            target = render_tokens(tokens, self.config.dim, lengths)
        if augment:
            target = jitter(target, self._rng)
        return target, tokens, tokens_in, stack

    def _loss(self, tokens, lengths, augment, packed=None):
        target, tokens_out, tokens_in, stack = self._inputs(tokens, lengths, augment, packed)
        loss, acc = teacher_forced_loss(self.model, target, tokens_out, tokens_in, stack, lengths, self.loss_norm)
        return loss, acc, target

    def training_step(self, batch, batch_idx):
        tokens, lengths, *packed = batch
        if self.mirror:
            if packed:
                raise ValueError("mirror needs the targets rendered in the training step: set "
                                 "data.init_args.render_in_workers to false")
            tokens = mirror_programs(tokens, self._rng)
        loss, acc, _ = self._loss(tokens, lengths, self.augment, packed or None)
        self.log("train/loss", loss, prog_bar=True, batch_size=tokens.shape[0])
        self.log("train/exact", acc, batch_size=tokens.shape[0])
        return loss

    def on_train_epoch_start(self):
        set_stream_epoch(self.trainer, self.current_epoch)

    def on_validation_epoch_start(self):
        self._val = EpochValues(self.hparams.log_images)

    def validation_step(self, batch, batch_idx):
        tokens, lengths = batch
        loss, _, target = self._loss(tokens, lengths, self.augment)
        dec = greedy(self.model, target)
        pred = render_tokens(dec.tokens[:, 0], self.config.dim, dec.lengths[:, 0])
        iou, cd = score_renders(pred, target, self.config.dim)
        self._val.add(target, pred, length=lengths.cpu().numpy(), iou=iou, chamfer=cd,
                      valid=dec.valid[:, 0].cpu().numpy(), loss=float(loss) * len(lengths))

    def on_validation_epoch_end(self):
        if not self._val:
            return
        v = self._val.arrays()
        length, iou, cd = v["length"], v["iou"], v["chamfer"]
        means = {"val/loss": sum(v["loss"].tolist()) / len(length), "val/iou": np.nanmean(iou),
                 "val/valid": v["valid"].mean()}
        if self.config.dim == 2:
            means["val/chamfer"] = cd.mean()
        for n in np.unique(length):
            sel = length == n
            means[f"val_iou/len{int(n):02d}"] = np.nanmean(iou[sel])
            if self.config.dim == 2:
                means[f"val_chamfer/len{int(n):02d}"] = cd[sel].mean()
        log_means(self, means, prog_bar=("val/iou", "val/chamfer"))
        if self._val.grid is not None:
            log_pairs(self, "val/targets_vs_predictions", *self._val.grid)

    def configure_optimizers(self):
        opt = torch.optim.Adam(self.parameters(), lr=self.hparams.lr)
        mode = "min" if self.config.dim == 2 else "max"
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, mode=mode, factor=self.hparams.plateau_factor,
                                                           patience=self.hparams.plateau_patience)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "monitor": self.monitor, "interval": "epoch"}}
