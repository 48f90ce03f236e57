"""Supervised training of CSGNet / CSGNetStack with PyTorch Lightning (spec section (e)).

* :class:`CSGDataModule` streams synthetic programs, from files written by
  :func:`csgnet.data.generate_dataset` or sampled on the fly, as batches that mix the program lengths in
  equal counts (the reference's "equal batch"). Batches hold token indices only; targets and stack
  traces are rendered on the training device by the batched renderer.
* :class:`CSGNetModule` is teacher-forced supervised training: Adam, the spec's loss normalisation,
  reduce-on-plateau ×0.2 after more than 8 epochs without improvement of the validation chamfer (2D) or
  IoU (3D), validation by greedy decoding with IoU and chamfer per program length, and image grids of
  targets beside predicted renders in TensorBoard.
* :class:`AtomicCheckpointIO` writes checkpoints through a temporary file and a rename, so an
  interrupted run never leaves a truncated checkpoint behind.

``python train.py fit --config configs/csgnet/csgnetstack2d_small.yaml`` runs it through LightningCLI.
"""
from __future__ import annotations

import os
from pathlib import Path

import lightning as L
import numpy as np
import torch
import torch.nn.functional as F
from lightning.pytorch.plugins.io import TorchCheckpointIO

from shapeio import atomic_write

from .. import metrics
from ..data import ProgramDataset, load_dataset, split_sizes
from ..synth import sample_programs
from .augment import jitter
from ..decode import greedy
from ..models import CSGNet, ModelConfig, preset
from ..renderer import render_tokens, stack_trace
from ..vocab import vocabulary

__all__ = ["CSGDataModule", "CSGNetModule", "AtomicCheckpointIO", "ShardedBatches", "MixedLengthBatches", "Cycle",
           "export_weights", "image_grid", "DEFAULT_LENGTHS"]

DEFAULT_LENGTHS = {2: [3, 5, 7, 9, 11, 13], 3: [3, 5, 7]}


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning checkpoint IO that writes to a temporary file and renames it into place."""

    def save_checkpoint(self, checkpoint, path, storage_options=None):
        if storage_options is not None:
            raise TypeError(f"{type(self).__name__} does not take storage_options")
        atomic_write(path, lambda f: torch.save(checkpoint, f), mkdir=True)


class ShardedBatches(torch.utils.data.IterableDataset):
    """Base of the batch streams: ``steps`` batches per epoch, split over distributed ranks and DataLoader
    workers; each shard draws from its own generator seeded by ``(seed, epoch, shard)``, so the stream
    is deterministic for a given seed, epoch, rank and worker count. Subclasses implement
    :meth:`_batches`.
    """

    def __init__(self, steps: int, seed: int = 0, rank: int = 0, world: int = 1):
        self.steps, self.seed, self.rank, self.world = int(steps), int(seed), int(rank), int(world)
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def __len__(self) -> int:
        return self.steps

    def __iter__(self):
        info = torch.utils.data.get_worker_info()
        wid, nw = (info.id, info.num_workers) if info is not None else (0, 1)
        shard = self.rank * nw + wid
        rng = np.random.default_rng([self.seed, self.epoch, shard])
        return self._batches(len(range(shard, self.steps, self.world * nw)), rng)

    def _batches(self, steps: int, rng: np.random.Generator):
        raise NotImplementedError


class Cycle:
    """Indices ``0 .. n - 1`` in a random order, drawn ``k`` at a time and reshuffled whenever used up."""

    def __init__(self, n: int, rng: np.random.Generator):
        self.n, self.rng = int(n), rng
        self.order, self.pos = rng.permutation(self.n), 0

    def take(self, k: int) -> np.ndarray:
        parts = []
        while k:
            if self.pos >= self.n:
                self.order, self.pos = self.rng.permutation(self.n), 0
            m = min(k, self.n - self.pos)
            parts.append(self.order[self.pos: self.pos + m])
            self.pos += m
            k -= m
        return np.concatenate(parts)


def distributed(trainer) -> tuple[int, int]:
    """``(rank, world size)`` of a trainer (``(0, 1)`` without one)."""
    return (trainer.global_rank, trainer.world_size) if trainer is not None else (0, 1)


def stream_loader(ds: ShardedBatches, trainer, num_workers: int = 0) -> torch.utils.data.DataLoader:
    """A DataLoader over a batch stream (each item already a batch), at the trainer's current epoch."""
    if trainer is not None:
        ds.set_epoch(trainer.current_epoch)
    return torch.utils.data.DataLoader(ds, batch_size=1, collate_fn=_collate_first, num_workers=num_workers)


def _collate_first(batch):
    return batch[0]


def set_stream_epoch(trainer, epoch: int) -> None:
    """Tell the training stream (a :class:`ShardedBatches`) which epoch starts, so it reseeds."""
    ds = getattr(trainer.train_dataloader, "dataset", None)
    if isinstance(ds, ShardedBatches):
        ds.set_epoch(epoch)


class MixedLengthBatches(ShardedBatches):
    """A stream of ``steps`` batches, each with ``batch // len(lengths)`` programs per length.

    Programs come from per-length token tables (``tables[L]``: ``(N_L, max_len + 1)``), reshuffled
    whenever a length's table is used up (short-program sets cycle more often, as in the reference), or
    are sampled on the fly with :func:`csgnet.synth.sample_programs` when ``tables`` is None.

    Yields:
        ``(tokens (B, T + 1) int64, lengths (B,) int64)``, ``$``-padded.
    """

    def __init__(self, dim: int, lengths: list[int], batch: int, steps: int, max_len: int,
                 tables: dict[int, torch.Tensor] | None = None, seed: int = 0, rank: int = 0, world: int = 1):
        super().__init__(steps, seed, rank, world)
        self.dim, self.lengths, self.max_len = dim, list(lengths), int(max_len)
        self.per_length = max(1, int(batch) // len(self.lengths))
        self.tables = tables

    def _batches(self, steps: int, rng: np.random.Generator):
        stop = vocabulary(self.dim).stop
        lengths = torch.tensor([n for n in self.lengths for _ in range(self.per_length)])
        cycles = None if self.tables is None else {n: Cycle(self.tables[n].shape[0], rng) for n in self.lengths}
        for _ in range(steps):
            parts = []
            for n in self.lengths:
                if cycles is None:
                    toks = torch.full((self.per_length, self.max_len + 1), stop, dtype=torch.int64)
                    toks[:, :n] = torch.as_tensor(sample_programs(self.dim, n, self.per_length, rng))
                else:
                    toks = self.tables[n][torch.as_tensor(cycles[n].take(self.per_length))]
                parts.append(toks)
            yield torch.cat(parts), lengths.clone()


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
    """

    def __init__(self, dim: int = 2, data_dir: str | None = "data/synthetic", lengths: list[int] | None = None,
                 batch_size: int = 100, steps_per_epoch: int | None = None, val_per_length: int = 200,
                 num_workers: int = 0, seed: int = 0):
        super().__init__()
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim!r}")
        self.dim, self.data_dir = dim, data_dir
        self.lengths = sorted(lengths or DEFAULT_LENGTHS[dim])
        self.max_len = max(self.lengths)
        self.batch_size, self.steps_per_epoch = int(batch_size), steps_per_epoch
        self.val_per_length, self.num_workers, self.seed = int(val_per_length), int(num_workers), int(seed)
        self.train_tables: dict[int, torch.Tensor] | None = None
        self.val_tokens: torch.Tensor | None = None

    def _tables(self, split: str) -> dict[int, torch.Tensor]:
        progs = load_dataset(self.data_dir, self.dim, split, self.lengths)
        out = {}
        for n, ps in progs.items():
            if not ps:
                raise ValueError(f"the {split} split of {self.data_dir!r} has no {self.dim}D programs of length {n}")
            out[n] = ProgramDataset(ps, self.dim, max_len=self.max_len).tokens
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
                                self.train_tables, self.seed, rank, world)
        return stream_loader(ds, self.trainer, self.num_workers)

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
        plateau_patience: epochs without improvement before the learning rate drops (8).
        plateau_factor: the drop (0.2).
        log_images: targets / predictions shown in the TensorBoard grid each validation.
        seed: seed of the jitter draws.
    """

    def __init__(self, dim: int = 2, stack: bool = False, size: str = "small", model: dict | None = None,
                 lr: float = 1e-3, loss_norm: str | None = None, augment: bool | None = None,
                 plateau_patience: int = 8, plateau_factor: float = 0.2, log_images: int = 16, seed: int = 0):
        super().__init__()
        self.save_hyperparameters()
        self.config: ModelConfig = preset(size, dim, stack, **(model or {}))
        self.model = CSGNet(self.config)
        self.loss_norm = loss_norm or ("per_step" if dim == 2 else "sum")
        if self.loss_norm not in ("per_step", "sum"):
            raise ValueError(f"loss_norm must be 'per_step' or 'sum', got {loss_norm!r}")
        self.augment = (dim == 2) if augment is None else bool(augment and dim == 2)
        self.monitor = "val/chamfer" if dim == 2 else "val/iou"
        self._rng = np.random.default_rng(seed)
        self._val: dict[str, list] = {}

    # ------------------------------------------------------------------------------------------
    def _inputs(self, tokens: torch.Tensor, lengths: torch.Tensor, augment: bool):
        cfg = self.config
        T = int(lengths.max()) + 1  # k + 1 targets for the longest program
        tokens = tokens[:, :T]
        target = render_tokens(tokens, cfg.dim, lengths)
        if augment:
            target = jitter(target, self._rng)
        start = torch.full_like(tokens[:, :1], self.model.start)
        tokens_in = torch.cat([start, tokens[:, :-1]], dim=1)
        stack = stack_trace(tokens[:, :-1], cfg.dim, k=cfg.stack_k, lengths=lengths) if cfg.stack else None
        return target, tokens, tokens_in, stack

    def _loss(self, tokens, lengths, augment):
        target, tokens_out, tokens_in, stack = self._inputs(tokens, lengths, augment)
        logits = self.model(target, tokens_in, stack)
        nll = F.cross_entropy(logits.transpose(1, 2), tokens_out, reduction="none")
        steps = torch.arange(tokens_out.shape[1], device=tokens.device)[None] <= lengths[:, None]
        per_prog = (nll * steps).sum(1)
        if self.loss_norm == "per_step":
            per_prog = per_prog / (lengths + 1)
        acc = ((logits.argmax(-1) == tokens_out) | ~steps).all(1).float().mean()
        return per_prog.mean(), acc, target

    def training_step(self, batch, batch_idx):
        tokens, lengths = batch
        loss, acc, _ = self._loss(tokens, lengths, self.augment)
        self.log("train/loss", loss, prog_bar=True, batch_size=tokens.shape[0])
        self.log("train/exact", acc, batch_size=tokens.shape[0])
        return loss

    def on_train_epoch_start(self):
        set_stream_epoch(self.trainer, self.current_epoch)

    def on_validation_epoch_start(self):
        self._val = {"length": [], "iou": [], "chamfer": [], "valid": [], "loss": []}
        self._grid = None

    def validation_step(self, batch, batch_idx):
        tokens, lengths = batch
        loss, _, target = self._loss(tokens, lengths, self.augment)
        dec = greedy(self.model, target)
        pred = render_tokens(dec.tokens[:, 0], self.config.dim, dec.lengths[:, 0])
        if self.config.dim == 2:
            iou = metrics.iou(pred.cpu(), target.cpu(), denominator="union")
            cd = metrics.chamfer(pred.cpu(), target.cpu())
        else:
            iou = metrics.iou_3d(pred.cpu(), target.cpu())
            cd = np.full(len(iou), np.nan)
        v = self._val
        v["length"].append(lengths.cpu().numpy())
        v["iou"].append(np.asarray(iou, dtype=np.float64))
        v["chamfer"].append(np.asarray(cd, dtype=np.float64))
        v["valid"].append(dec.valid[:, 0].cpu().numpy())
        v["loss"].append(float(loss) * len(lengths))
        if self._grid is None and self.hparams.log_images:
            n = int(self.hparams.log_images)
            self._grid = (target[:n].cpu(), pred[:n].cpu())

    def on_validation_epoch_end(self):
        v = self._val
        if not v.get("length"):
            return
        length = np.concatenate(v["length"])
        iou = np.concatenate(v["iou"])
        cd = np.concatenate(v["chamfer"])
        # under DDP each rank holds a shard of the validation set: sync_dist averages the ranks' means
        self.log("val/loss", sum(v["loss"]) / len(length), sync_dist=True)
        self.log("val/iou", float(np.nanmean(iou)), prog_bar=True, sync_dist=True)
        self.log("val/valid", float(np.concatenate(v["valid"]).mean()), sync_dist=True)
        if self.config.dim == 2:
            self.log("val/chamfer", float(cd.mean()), prog_bar=True, sync_dist=True)
        for n in np.unique(length):
            sel = length == n
            self.log(f"val_iou/len{int(n):02d}", float(np.nanmean(iou[sel])), sync_dist=True)
            if self.config.dim == 2:
                self.log(f"val_chamfer/len{int(n):02d}", float(cd[sel].mean()), sync_dist=True)
        self._log_grid()

    def _log_grid(self):
        exp = image_logger(self)
        if self._grid is None or exp is None:
            return
        tgt, pred = self._grid
        if tgt.dim() == 4:  # 3D: silhouettes along z
            tgt, pred = tgt.any(-1), pred.any(-1)
        exp.add_image("val/targets_vs_predictions", image_grid(tgt, pred), self.global_step)

    def configure_optimizers(self):
        opt = torch.optim.Adam(self.parameters(), lr=self.hparams.lr)
        mode = "min" if self.config.dim == 2 else "max"
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, mode=mode, factor=self.hparams.plateau_factor,
                                                           patience=self.hparams.plateau_patience)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "monitor": self.monitor, "interval": "epoch"}}


def image_grid(targets: torch.Tensor, preds: torch.Tensor, cols: int = 4) -> torch.Tensor:
    """A ``(1, H, W)`` float image: pairs target | prediction (black shapes on white), ``cols`` per row."""
    targets, preds = targets.bool().cpu(), preds.bool().cpu()
    gap = torch.ones(targets.shape[1], 2, dtype=torch.bool)
    pairs = [torch.cat([a, gap, b], 1) for a, b in zip(targets, preds)]
    rows = [torch.cat([p, torch.ones(2, p.shape[1], dtype=torch.bool)], 0) for p in pairs]
    rows += [torch.ones_like(rows[0])] * (-len(rows) % cols)
    grid = torch.cat([torch.cat(rows[i:i + cols], 1) for i in range(0, len(rows), cols)], 0)
    return (~grid).float()[None]


def image_logger(module: L.LightningModule):
    """The module's logger experiment if it takes images (TensorBoard), else None."""
    exp = getattr(module.logger, "experiment", None) if module.logger is not None else None
    return exp if hasattr(exp, "add_image") else None


def export_weights(checkpoint: str | os.PathLike, out: str | os.PathLike, half: bool = True) -> Path:
    """Write the model of a training checkpoint as a small weights file ``{"config", "state_dict"}``.

    ``half`` stores float16 tensors (loaded back as float32 by :func:`csgnet.load_pretrained`).
    """
    ckpt = torch.load(checkpoint, map_location="cpu", weights_only=True)
    hp = ckpt.get("hyper_parameters", {})
    config = preset(hp.get("size", "small"), hp.get("dim", 2), hp.get("stack", False), **(hp.get("model") or {}))
    state = {k[len("model."):]: v for k, v in ckpt["state_dict"].items() if k.startswith("model.")}
    if half:
        state = {k: (v.half() if v.is_floating_point() else v) for k, v in state.items()}
    payload = {"config": config.to_dict(), "state_dict": state,
               "meta": {"epoch": int(ckpt.get("epoch", -1)), "global_step": int(ckpt.get("global_step", -1))}}
    return atomic_write(out, lambda f: torch.save(payload, f), mkdir=True)
