"""Training of the ShapeAssembly VAE with PyTorch Lightning: the only module of :mod:`shapeprog.vae` that imports it.

* :class:`VAEDataModule` holds the corpus programs of a category as line-vector trees (built once in
  ``setup``), the corpus's train split less a seeded validation carve-out (the corpus's own val split is
  the test split of every table, and is not read), and DataLoaders whose collate keeps the trees as a
  list with their batch plan (:class:`~shapeprog.vae.batch.TreeBatch`).
* :class:`VAEModule` trains :class:`~shapeprog.vae.model.VAE` teacher-forced with the spec's loss, Adam
  (lr 1e-4, eps 1e-6, no decay) and ``batch_shapes`` shapes per optimizer step (1: the reference), through
  the batched pass (:func:`~shapeprog.vae.batch.batch_forward`). It logs every loss term and the KL
  (``train/*``, ``val/*``) and, every ``recon_every_n_epochs`` epochs, the reconstruction F-score of a fixed set of validation shapes (``val/fscore``) with image
  grids of reconstructions and of samples.

``python train.py fit --config configs/shapeassembly/vae_chair.yaml`` runs it through the repository's
LightningCLI; settings and measurements: ``docs/shapeassembly_vae.md`` ("Training").

**Macro programs (ShapeMOD, Appendix C).** Both classes take a ``library`` (a shipped category's, e.g.
``"chair"``, or a library file): the data module then reads the macro-refactored corpus (the shipped
archive of :func:`shapeprog.macros.load_refactored`, or ``programs``, a folder or archive of
:func:`shapeprog.macros.write_refactored`) for the same carved keys, as
:class:`~shapeprog.vae.layout.MacroNode` trees, and the module trains a
:class:`~shapeprog.vae.macro_model.MacroVAE` with :func:`~shapeprog.vae.losses.macro_program_loss`; its
reconstructions and samples are macro programs, expanded and executed for the F-score and the pictures.
``python train.py fit --config configs/shapeassembly/vae_chair_macros.yaml``; ``docs/shapemod.md``.
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader

from shapeio import atomic_write
from shapeio.weights import checkpoint_entry

from ..picture import render_grid
from .batch import TreeBatch, batch_forward, batch_loss, collate_trees
from .macro_batch import MacroTreeBatch, collate_macro_trees, macro_batch_loss
from .decode import sample
from .layout import LineLayout
from .macro_decode import sample_macro
from .losses import LOSS_WEIGHTS, MACRO_LOSS_WEIGHTS
from .macro_model import MacroVAE
from .model import VAE
from .vectors import VectorNode
from .data import (
    _check_category, _read_macro_programs, load_macro_library, load_macro_trees, load_trees,
    validation_split,
)
from .reconstruct import (
    _corners, _same_trees, reconstruct, reconstruction_fscores, target_surfaces, tree_program,
)
from .pretrained import read_weights

__all__ = [
    "CHECKPOINT_FORMAT",
    "VAEDataModule",
    "VAEModule",
]

#: Version of what :class:`VAEModule` adds to its checkpoints (``checkpoint["shapeprog_vae"]``).
CHECKPOINT_FORMAT = 1


class VAEDataModule(L.LightningDataModule):
    """Corpus programs as line-vector trees for :class:`VAEModule`.

    The corpus's train split less a seeded validation carve-out (:func:`validation_split`) is trained on;
    the carve-out validates. The corpus's val split is the test split and is never read. ``setup`` builds
    the trees once and writes the split (``split_file``, JSON: the settings and both lists of keys) into
    the run's log folder (``trainer.log_dir``) on the global rank 0.

    Args:
        category: ``chair``, ``table``, ``storage`` or ``all``.
        val_fraction: share of each category's train split held out for validation (5%).
        val_count: held-out shapes per category instead of the fraction.
        seed: the carve-out's draw (42, the reference's seed).
        batch_shapes: shapes per training batch; None takes the model's ``batch_shapes`` (one knob: set it on
            the model).
        val_batch_shapes: shapes per validation batch (the loss does not depend on it).
        num_workers: DataLoader workers (0: batches are built in the training process).
        max_train_shapes: train on the first N shapes of the carved train split only (smoke runs,
            overfitting checks); None: all.
        split_file: name of the split file in the log folder.
        library: train on macro programs calling this library (:func:`load_macro_library`: a shipped
            category's name or a library file); None: the corpus's ShapeAssembly programs.
        programs: with ``library``, the macro-refactored corpus to read (a folder or ``.tar.xz`` of
            :func:`shapeprog.macros.write_refactored`); None: the shipped one of the category.
    """

    def __init__(self, category: str = "chair", val_fraction: float = 0.05, val_count: int | None = None,
                 seed: int = 42, batch_shapes: int | None = None, val_batch_shapes: int = 32, num_workers: int = 0,
                 max_train_shapes: int | None = None, split_file: str = "split.json", library: str | None = None,
                 programs: str | None = None):
        super().__init__()
        _check_category(category)
        if library is not None and category == "all":
            raise ValueError("a macro library belongs to one category; set category to chair, table or storage")
        if programs is not None and library is None:
            raise ValueError("`programs` (macro programs) needs a `library`")
        self.library, self.programs = library, programs
        self.layout: LineLayout | None = None
        for name, v in (("batch_shapes", batch_shapes), ("val_batch_shapes", val_batch_shapes),
                        ("max_train_shapes", max_train_shapes)):
            if v is not None and int(v) < 1:
                raise ValueError(f"{name} must be >= 1, got {v!r}")
        self.category, self.val_fraction, self.val_count = category, float(val_fraction), val_count
        self.seed = int(seed)
        self.batch_shapes, self.val_batch_shapes = batch_shapes, int(val_batch_shapes)
        self.num_workers, self.max_train_shapes, self.split_file = int(num_workers), max_train_shapes, split_file
        self.train_keys: list[str] | None = None
        self.val_keys: list[str] | None = None
        self.train_trees: list[VectorNode] | None = None
        self.val_trees: list[VectorNode] | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.val_trees is None:
            train, val = validation_split(self.category, self.val_fraction, self.val_count, self.seed)
            if self.max_train_shapes is not None:
                train = train[: int(self.max_train_shapes)]
            if self.library is None:
                self.train_keys, self.train_trees = load_trees(train)
                self.val_keys, self.val_trees = load_trees(val)
            else:
                lib = load_macro_library(self.library)
                self.layout = LineLayout(lib)
                progs = _read_macro_programs(self.category, train + val, self.programs, lib)
                self.train_keys, self.train_trees = load_macro_trees(train, self.layout, progs)
                self.val_keys, self.val_trees = load_macro_trees(val, self.layout, progs)
        if self.trainer is not None and stage in (None, "fit"):
            folder = self.trainer.log_dir  # broadcasts: every rank asks
            if self.trainer.logger is None or folder is None:
                # no run folder: beside the checkpoints (a checkpoint callback without a folder of its own writes
                # into <default_root_dir>/checkpoints), never in the working folder; nowhere without checkpoints
                cbs = self.trainer.checkpoint_callbacks
                dirs = [cb.dirpath for cb in cbs if getattr(cb, "dirpath", None)]
                folder = dirs[0] if dirs else (Path(self.trainer.default_root_dir) / "checkpoints" if cbs else None)
            if folder is not None and self.trainer.is_global_zero:
                self.write_split(Path(folder) / self.split_file)

    def split(self) -> dict:
        """The split as written to the split file."""
        return {"category": self.category, "seed": self.seed, "val_fraction": self.val_fraction,
                "val_count": self.val_count, "max_train_shapes": self.max_train_shapes,
                "source": "the corpus's train split (its val split is the test split)",
                "library": self.library, "programs": self.programs,
                "val": self.val_keys, "train": self.train_keys}

    def write_split(self, path: str | Path) -> Path:
        """Write :meth:`split` as JSON to ``path`` (atomically; the folder is created)."""
        if self.val_keys is None:
            raise RuntimeError("the split is drawn in setup(); call it first")
        return atomic_write(path, json.dumps(self.split(), indent=1) + "\n", mkdir=True)

    def _train_batch(self) -> int:
        if self.batch_shapes is not None:
            return int(self.batch_shapes)
        module = self.trainer.lightning_module if self.trainer is not None else None
        return int(module.hparams.get("batch_shapes", 1)) if module is not None else 1

    def _collate(self):
        return collate_trees if self.library is None else collate_macro_trees

    def train_dataloader(self) -> DataLoader:
        return DataLoader(self.train_trees, batch_size=self._train_batch(), shuffle=True, collate_fn=self._collate(),
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0)

    def val_dataloader(self) -> DataLoader:
        return DataLoader(self.val_trees, batch_size=self.val_batch_shapes, shuffle=False, collate_fn=self._collate(),
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0)

    def state_dict(self) -> dict:
        return {"category": self.category, "seed": self.seed, "val": self.val_keys}

    def load_state_dict(self, state: dict) -> None:
        """Refuse to resume a run whose validation shapes were others (they would now be trained on)."""
        if self.val_keys is not None and state.get("val") is not None and state["val"] != self.val_keys:
            raise ValueError(f"the checkpoint's run validated on another carve-out ({state.get('category')}, seed "
                             f"{state.get('seed')}, {len(state['val'])} shapes) than this one ({self.category}, seed "
                             f"{self.seed}, {len(self.val_keys)} shapes); resume with the same data settings")


# ------------------------------------------------------------------------------------------ module


def check_data_category(module: L.LightningModule) -> None:
    """Refuse a training run whose data module's ``category`` differs from the model's
    (``hparams.category``); shared by the VAE and the point-cloud modules."""
    dm = module.trainer.datamodule if module.trainer is not None else None
    other = getattr(dm, "category", None)
    if other is not None and other != module.hparams.category:
        raise ValueError(f"the model is set up for category {module.hparams.category!r} and the data module for "
                         f"{other!r}; set model.init_args.category and data.init_args.category alike")


class VAEModule(L.LightningModule):
    """Teacher-forced training of the ShapeAssembly VAE (spec section (d), "Training hyper-parameters").

    Args:
        category: what the run trains on (``chair``, ``table``, ``storage`` or ``all``); stored in the
            checkpoint and checked against the data module's.
        hidden_dim: H of :class:`~shapeprog.vae.model.VAE` (256 in the reference).
        lr: Adam's learning rate (1e-4); no decay.
        eps: Adam's eps (1e-6).
        weight_decay: 0 (the reference): Adam without weight decay; above 0, AdamW's decoupled weight decay
            of this factor (ours, a regulariser for small corpora such as the macro-refactored ones).
        dropout: dropout on the decoder's GRU input embeddings in training (0, the reference: none; ours).
        loss_weights: weights by term name that replace those of
            :data:`~shapeprog.vae.losses.LOSS_WEIGHTS` (the others are kept).
        kl_weight: the KL term's weight (default: that of ``loss_weights``, else 0.1).
        batch_shapes: shapes per optimizer step; the loss is their mean (1: the reference's one shape per
            step). The data module's training batches take it.
        recon_every_n_epochs: compute ``val/fscore`` and the image grids at the end of every N-th epoch
            (epochs N-1, 2N-1, ...; 0: never); a checkpoint callback that monitors ``val/fscore`` must save
            on those epochs (``every_n_epochs`` a multiple of N).
        recon_shapes: validation shapes (the first ones the validation loader gives) of the F-score.
        recon_points: surface samples per shape for the F-score (10,000 in the paper).
        image_shapes: reconstructions and samples shown in each image grid (0: no images).
        image_size: pixels per picture in the grids.
        seed: the draws of the F-score's surface samples and of the sampled shapes.
        init: start from these weights (a file of :func:`~shapeprog.vae.pretrained.save_weights` or a training
            checkpoint of the same category and size); the optimiser and the epoch count start afresh
            (``--ckpt_path last`` resumes a run instead).
        library: train a :class:`~shapeprog.vae.macro_model.MacroVAE` on macro programs calling this library
            (:func:`load_macro_library`; the data module's ``library`` must be the same); its loss terms are
            those of :data:`~shapeprog.vae.losses.MACRO_LOSS_WEIGHTS`. None: the base-language VAE.
    """

    def __init__(self, category: str = "chair", hidden_dim: int = 256, lr: float = 1e-4, eps: float = 1e-6,
                 weight_decay: float = 0.0, dropout: float = 0.0, loss_weights: dict[str, float] | None = None,
                 kl_weight: float | None = None, batch_shapes: int = 1,
                 recon_every_n_epochs: int = 5, recon_shapes: int = 32, recon_points: int = 10_000,
                 image_shapes: int = 8, image_size: int = 128, seed: int = 42, init: str | None = None,
                 library: str | None = None):
        super().__init__()
        _check_category(category)
        if int(batch_shapes) < 1:
            raise ValueError(f"batch_shapes must be >= 1, got {batch_shapes!r}")
        if not 0.0 <= float(weight_decay) < 1.0:
            raise ValueError(f"weight_decay must be in [0, 1), got {weight_decay!r}")
        base_weights = LOSS_WEIGHTS if library is None else MACRO_LOSS_WEIGHTS
        unknown = sorted(set(loss_weights or {}) - set(base_weights))
        if unknown:
            raise ValueError(f"unknown loss term(s) {unknown}; the terms are {', '.join(base_weights)}")
        self.save_hyperparameters()
        self.weights = {**base_weights, **(loss_weights or {})}
        if kl_weight is not None:
            self.weights["kl"] = float(kl_weight)
        self.layout = None if library is None else LineLayout(load_macro_library(library))
        self.vae = VAE(hidden_dim, dropout) if library is None else MacroVAE(self.layout, hidden_dim, dropout)
        if init is not None:
            self._load_init(init)
        self._recon_trees: list[VectorNode] = []
        # the F-score's shapes and their target samples, drawn on the first reconstruction epoch
        self._recon_targets: tuple[list[VectorNode], list[torch.Tensor]] | None = None
        self._window: torch.Tensor | None = None  # the training terms summed since they were last logged
        self._window_shapes = 0

    def _load_init(self, path: str) -> None:
        """Start from the weights of ``path`` (a weights file or a training checkpoint) of the same VAE."""
        info, state = read_weights(path)
        mine = {"category": self.hparams.category, "hidden_dim": self.hparams.hidden_dim, "library": self._library_text()}
        theirs = {"category": info["category"], "hidden_dim": info["hidden_dim"], "library": info.get("library")}
        if theirs != mine:
            raise ValueError(f"{path}: the weights are of a VAE with {theirs}, this run is {mine}")
        self.vae.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in state.items()})

    def _library_text(self) -> str | None:
        return None if self.layout is None else self.layout.library.to_text()

    def forward(self, batch: TreeBatch, sample: bool = True):
        """:func:`~shapeprog.vae.batch.batch_forward` of the model on ``batch`` (base-language model)."""
        return batch_forward(self.vae, batch, sample=sample)

    def _loss(self, batch, sample: bool):
        """``(total (B,), terms)`` of a batch: the level-by-level batched pass of base or macro programs."""
        if isinstance(batch, MacroTreeBatch):
            return macro_batch_loss(self.vae, batch, sample=sample, weights=self.weights)
        return batch_loss(batch_forward(self.vae, batch, sample=sample), batch, self.weights)

    # ------------------------------------------------------------------ checks
    def setup(self, stage: str) -> None:
        check_data_category(self)
        dm = self.trainer.datamodule if self.trainer is not None else None
        if dm is not None and hasattr(dm, "library") and dm.library != self.hparams.library:
            raise ValueError(f"the model's library is {self.hparams.library!r} and the data module's {dm.library!r}; "
                             f"set model.init_args.library and data.init_args.library alike")

    def on_fit_start(self) -> None:
        n = self.hparams.recon_every_n_epochs
        for cb in self.trainer.checkpoint_callbacks:
            if getattr(cb, "monitor", None) != "val/fscore":
                continue
            every = getattr(cb, "_every_n_epochs", 1)
            if not n or every % n:
                raise ValueError(f"a checkpoint callback monitors val/fscore every {every} epoch(s) but the model "
                                 f"computes it every {n} (model.recon_every_n_epochs); make every_n_epochs a "
                                 f"multiple of it")

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["shapeprog_vae"] = {"format": CHECKPOINT_FORMAT, "category": self.hparams.category,
                                       "hidden_dim": self.hparams.hidden_dim}
        if self.layout is not None:
            checkpoint["shapeprog_vae"]["library_text"] = self._library_text()

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        info = checkpoint_entry(checkpoint, "shapeprog_vae", CHECKPOINT_FORMAT, "shapeprog.vae.train.VAEModule")
        mine = {"category": self.hparams.category, "hidden_dim": self.hparams.hidden_dim}
        theirs = {k: info.get(k) for k in mine}
        if theirs != mine:
            raise ValueError(f"the checkpoint is of a VAE with {theirs}, this run is {mine}")
        if info.get("library_text") != self._library_text():
            raise ValueError("the checkpoint's macro library differs from this run's (or one of them has none)")

    # ------------------------------------------------------------------ steps
    def _cast(self, batch: TreeBatch) -> TreeBatch:
        """The batch in the model's dtype (the trees are float32; a ``64-true`` or ``16-true`` run differs)."""
        return batch if batch.dtype == self.dtype else batch.to(self.device, self.dtype)

    def training_step(self, batch: TreeBatch, batch_idx: int) -> torch.Tensor:
        """The mean loss of the batch's shapes (z sampled). ``train/loss`` is logged every step; the terms are
        summed over the steps in between and logged as their mean per shape at the steps the logger writes
        (every ``log_every_n_steps``): a ``self.log`` call costs milliseconds, and fifteen of them every
        step slowed one-shape steps by about a third."""
        batch = self._cast(batch)
        total, terms = self._loss(batch, sample=True)
        loss = total.mean()
        self.log("train/loss", loss, prog_bar=True, batch_size=batch.size)
        sums = torch.stack([v.detach().sum() for v in terms.values()])
        self._window = sums if self._window is None else self._window + sums
        self._window_shapes += batch.size
        if (self.global_step + 1) % max(1, self.trainer.log_every_n_steps) == 0:
            for name, value in zip(terms, self._window / self._window_shapes):
                self.log(f"train/{name}", value, batch_size=self._window_shapes)
            self._window, self._window_shapes = None, 0
        return loss

    def validation_step(self, batch: TreeBatch, batch_idx: int) -> None:
        """The loss with z = mu (deterministic); keeps the epoch's first ``recon_shapes`` trees."""
        batch = self._cast(batch)
        total, terms = self._loss(batch, sample=False)
        self.log("val/loss", total.mean(), prog_bar=True, batch_size=batch.size, sync_dist=True)
        for name, value in terms.items():
            self.log(f"val/{name}", value.mean(), batch_size=batch.size, sync_dist=True)
        room = self.hparams.recon_shapes - len(self._recon_trees)
        if room > 0:
            self._recon_trees += batch.trees[:room]

    def on_validation_epoch_start(self) -> None:
        self._recon_trees = []

    def recon_epoch(self) -> bool:
        """Whether this epoch's validation computes the F-score and the image grids."""
        n = self.hparams.recon_every_n_epochs
        return bool(n) and not self.trainer.sanity_checking and (self.current_epoch + 1) % n == 0

    def on_validation_epoch_end(self) -> None:
        """The reconstruction hook: on :meth:`recon_epoch` epochs, log ``val/fscore`` (mean F-score of the kept validation shapes, a failed decode scoring 0) and
        ``val/recon_failed`` (the share of them), and on the global rank 0 the image grids
        ``val/reconstructions`` (target | decoded pairs) and ``val/samples`` (samples from N(0, I))."""
        trees, self._recon_trees = self._recon_trees, []
        if not trees or not self.recon_epoch():
            return
        points, seed = self.hparams.recon_points, self.hparams.seed
        if self._recon_targets is None or not _same_trees(self._recon_targets[0], trees):
            self._recon_targets = (trees, target_surfaces(trees, points, seed, self.layout))
        programs = reconstruct(self.vae, trees)
        scores = reconstruction_fscores(trees, programs, points, seed, targets=self._recon_targets[1],
                                        layout=self.layout)
        self.log("val/fscore", float(np.mean([s or 0.0 for s in scores])), sync_dist=True, prog_bar=True)
        self.log("val/recon_failed", sum(s is None for s in scores) / len(scores), sync_dist=True)
        k = self.hparams.image_shapes
        if self.trainer.is_global_zero and k:
            self.log_images(trees[:k], programs[:k])

    def log_images(self, trees: list[VectorNode], programs: list) -> None:
        """Add the image grids ``val/reconstructions`` (each tree's program beside its reconstruction in
        ``programs``) and ``val/samples`` (:func:`~shapeprog.vae.decode.sample` of ``image_shapes`` shapes) to
        the TensorBoard logger, if there is one. Sampling that fails with a ``ValueError`` or ``RuntimeError`` is reported
        as a warning, not raised: a picture is not worth a long run."""
        exp = getattr(self.logger, "experiment", None) if self.logger is not None else None
        if not hasattr(exp, "add_image"):
            return
        size = self.hparams.image_size
        pairs = [_corners(p) for t, r in zip(trees, programs) for p in (tree_program(t, self.layout), r)]
        exp.add_image("val/reconstructions", render_grid(pairs, cols=4, size=size), self.global_step,
                      dataformats="HWC")
        try:
            if self.layout is not None:
                samples = sample_macro(self.vae, self.hparams.image_shapes, seed=self.hparams.seed)
            else:
                samples = sample(self.vae, self.hparams.image_shapes, seed=self.hparams.seed)
        except (ValueError, RuntimeError) as e:
            warnings.warn(f"no val/samples grid at step {self.global_step}: {e}", stacklevel=2)
            return
        if samples:
            exp.add_image("val/samples", render_grid([_corners(d.program) for d in samples], cols=4, size=size),
                          self.global_step, dataformats="HWC")

    def configure_optimizers(self):
        fused = self.device.type in ("cpu", "cuda")
        wd = float(self.hparams.get("weight_decay", 0.0))  # checkpoints written before the option have none
        if wd > 0:
            return torch.optim.AdamW(self.parameters(), lr=self.hparams.lr, eps=self.hparams.eps, weight_decay=wd,
                                     fused=fused)
        return torch.optim.Adam(self.parameters(), lr=self.hparams.lr, eps=self.hparams.eps, fused=fused)
