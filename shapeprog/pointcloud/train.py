"""Training cloud -> program models with PyTorch Lightning: the only module of :mod:`shapeprog.pointcloud` that
imports it.

Two published recipes, both a :class:`~shapeprog.pointcloud.encoder.PointNet2SSG` in front of the ShapeAssembly
VAE's decoder (:mod:`shapeprog.vae`):

* :class:`LatentRegressionModule` (ShapeAssembly, spec section (d)): the encoder regresses the frozen VAE
  encoder's mean code ``mu`` of each shape's program (MSE summed over the latent dims, averaged over the
  batch); at test time the VAE decoder decodes the regressed code (non-rejecting validity decoding).
* :class:`EndToEndModule` (ShapeMOD): the encoder's code goes straight into the VAE decoder, trained
  together teacher-forced on (cloud, program) pairs with the VAE's program losses
  (:func:`shapeprog.vae.batch.batch_loss`, no KL term). The decoder starts from the shipped VAE's by
  default.

**Macro programs (ShapeMOD's point-cloud experiment).** With ``macros=True`` (or ``vae_weights`` naming a
macro-program VAE, :class:`~shapeprog.vae.macro_model.MacroVAE`) the decoder writes programs that call the
VAE's macro library (the category's shipped ShapeMOD library for the shipped VAE); the data module's
``library`` must be set to the same library (checked at setup), and it serves each cloud's program
from the macro-refactored corpus (:func:`shapeprog.macros.load_refactored`), and the loss is
:func:`~shapeprog.vae.losses.macro_program_loss` without KL. Decoded macro programs are expanded and executed
for the F-score and the pictures. ``configs/pointcloud/e2e_chair_macros.yaml``.

:class:`CloudDataModule` serves the clouds of a :func:`~shapeprog.pointcloud.data.make_clouds` cache: the
``train`` split to train on and the seeded ``val`` carve-out to validate on (both from the corpus's train
split; the cache's ``test`` split, the corpus's val split, is never read here). Each batch carries the
programs' line-vector trees (:class:`~shapeprog.vae.batch.TreeBatch`) beside the clouds.

Every ``recon_every_n_epochs`` epochs the validation logs ``val/fscore`` (decoded programs against the target
programs, :func:`shapeprog.vae.reconstruct.reconstruction_fscores`) and an image grid ``val/clouds`` (each input
cloud drawn as small cubes beside its decoded shape). ``python train.py fit --config
configs/pointcloud/latent_chair.yaml`` runs it; ``--ckpt_path last`` resumes. :func:`export_weights` writes
the small weights file :mod:`shapeprog.pointcloud.infer` loads.
"""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Optional, Sequence

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from shapeio.weights import checkpoint_entry, load_payload, write_weights

from ..picture import render_grid
from ..vae.batch import BatchOutput, TreeBatch, batch_loss, decode_batch, encode_batch
from ..vae.macro_batch import MacroTreeBatch, macro_batch_loss
from ..vae.layout import LineLayout
from ..vae.losses import LOSS_WEIGHTS, MACRO_LOSS_WEIGHTS
from ..vae.macro_model import MacroVAE
from ..vae.model import VAE
from ..vae.pretrained import decoder_fingerprint, load_model, load_pretrained
from ..vae.train import check_data_category
from ..vae.reconstruct import _corners, reconstruction_fscores, target_surfaces
from ..vae.data import _read_macro_programs, load_macro_library, load_macro_trees, load_trees
from ..vae.vectors import VectorNode
from .data import TRAIN_POINTS
from .dataset import CloudDataset, collate_clouds, read_split
from .encoder import NPOINTS, NSAMPLES, RADII, WIDTHS, PointNet2SSG
from .infer import cloud_corners, decode_codes, load_encoder, load_model as load_cloud_model

__all__ = ["CHECKPOINT_FORMAT", "RECIPES", "WEIGHTS_FORMAT", "CloudDataModule", "EndToEndModule",
           "LatentRegressionModule", "export_weights"]

#: Version of what the modules add to their checkpoints (``checkpoint["shapeprog_pointcloud"]``).
CHECKPOINT_FORMAT = 1
#: The ``format`` entry of a weights file written by :func:`export_weights`.
WEIGHTS_FORMAT = "shapeprog-pointcloud"
#: The recipes and the module of each.
RECIPES = ("latent", "e2e")
# ------------------------------------------------------------------------------------------ data


class _CloudTrees(Dataset):
    """The items of a :class:`CloudDataset` whose program could be encoded, each with its tree."""

    def __init__(self, clouds: CloudDataset, trees: dict[str, VectorNode]):
        self.clouds = clouds
        self.rows = [i for i in range(len(clouds)) if clouds.program_name(i) in trees]
        self.trees = trees

    def __len__(self) -> int:
        return len(self.rows)

    def set_epoch(self, epoch: int) -> None:
        self.clouds.set_epoch(epoch)

    def __getitem__(self, i: int) -> dict:
        item = self.clouds[self.rows[i]]
        item["tree"] = self.trees[item["program"]]
        return item


def _collate(items: Sequence[dict]) -> dict:
    """:func:`collate_clouds` plus ``trees``, a :class:`TreeBatch` of the items' programs."""
    out = collate_clouds(items)
    out["trees"] = TreeBatch([it["tree"] for it in items])
    return out


def _collate_macros(items: Sequence[dict]) -> dict:
    """:func:`collate_clouds` plus ``trees``, a :class:`MacroTreeBatch` of the items' macro programs."""
    out = collate_clouds(items)
    out["trees"] = MacroTreeBatch([it["tree"] for it in items])
    return out


class CloudDataModule(L.LightningDataModule):
    """Clouds of a :func:`~shapeprog.pointcloud.data.make_clouds` cache with their programs' trees.

    Args:
        root: the cache folder (``<category>_clouds.npz`` and ``<category>_split.json``).
        category: ``chair``, ``table`` or ``storage``.
        points: points per training cloud (a fresh random subset each epoch), or ``[low, high]`` for a
            random count.
        noise: standard deviation of the Gaussian noise added to training clouds (canonical units).
        val_points: points per validation cloud (a fixed subset, no noise).
        batch_size: clouds per training batch (and validation batch).
        num_workers: DataLoader workers.
        max_train_shapes: the first N training clouds only (smoke runs, overfitting checks).
        max_val_shapes: the first N validation clouds only.
        seed: the subsets' and the noise's draws.
        library: serve macro programs calling this ShapeMOD library (a shipped category's name or a library
            file, :func:`shapeprog.vae.data.load_macro_library`); it must be the decoder's. None: the
            corpus's ShapeAssembly programs.
        programs: with ``library``, the macro-refactored corpus to read (a folder or ``.tar.xz`` of
            :func:`shapeprog.macros.write_refactored`); None: the shipped one of the category.
    """

    def __init__(self, root: str = "clouds", category: str = "chair", points=TRAIN_POINTS, noise: float = 0.0,
                 val_points: int = TRAIN_POINTS, batch_size: int = 16, num_workers: int = 0,
                 max_train_shapes: Optional[int] = None, max_val_shapes: Optional[int] = None, seed: int = 0,
                 library: Optional[str] = None, programs: Optional[str] = None):
        super().__init__()
        if programs is not None and library is None:
            raise ValueError("`programs` (macro programs) needs a `library`")
        self.library, self.programs = library, programs
        self.layout: Optional[LineLayout] = None
        for name, v in (("batch_size", batch_size), ("max_train_shapes", max_train_shapes),
                        ("max_val_shapes", max_val_shapes)):
            if v is not None and int(v) < 1:
                raise ValueError(f"{name} must be >= 1, got {v!r}")
        self.root, self.category = str(root), category
        self.points = tuple(points) if isinstance(points, (list, tuple)) else points
        self.noise, self.val_points, self.batch_size = float(noise), int(val_points), int(batch_size)
        self.num_workers, self.seed = int(num_workers), int(seed)
        self.max_train_shapes, self.max_val_shapes = max_train_shapes, max_val_shapes
        self.train_set: Optional[_CloudTrees] = None
        self.val_set: Optional[_CloudTrees] = None

    def _set(self, split: str, points, noise: float, limit: Optional[int],
             macro_programs: Optional[dict] = None) -> _CloudTrees:
        clouds = CloudDataset(self.root, self.category, split, points=points, noise=noise, seed=self.seed)
        if limit is not None:
            keep = np.arange(min(int(limit), len(clouds)))
            clouds.ids, clouds.clouds = clouds.ids[keep], clouds.clouds[keep]
            clouds.center, clouds.scale = clouds.center[keep], clouds.scale[keep]
        names = [clouds.program_name(i) for i in range(len(clouds))]
        if macro_programs is None:
            keys, trees = load_trees(names)
        else:
            keys, trees = load_macro_trees(names, self.layout, macro_programs)
        return _CloudTrees(clouds, dict(zip(keys, trees)))

    def setup(self, stage: Optional[str] = None) -> None:
        if self.train_set is None:
            programs = None
            if self.library is not None:  # the macro programs of both splits, read from the archive once
                self.layout = LineLayout(load_macro_library(self.library))
                split = read_split(self.root, self.category)
                keys = [f"{self.category}/{i}" for part in ("train", "val") for i in split[part]]
                programs = _read_macro_programs(self.category, keys, self.programs, self.layout.library)
            self.train_set = self._set("train", self.points, self.noise, self.max_train_shapes, programs)
            self.val_set = self._set("val", self.val_points, 0.0, self.max_val_shapes, programs)

    def _collate(self):
        return _collate if self.library is None else _collate_macros

    def train_dataloader(self) -> DataLoader:
        return DataLoader(self.train_set, batch_size=self.batch_size, shuffle=True, collate_fn=self._collate(),
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0, drop_last=False)

    def val_dataloader(self) -> DataLoader:
        return DataLoader(self.val_set, batch_size=self.batch_size, shuffle=False, collate_fn=self._collate(),
                          num_workers=self.num_workers, persistent_workers=self.num_workers > 0)

    def library_text(self) -> Optional[str]:
        """The text of the macro library whose programs are served; None for ShapeAssembly programs."""
        return None if self.library is None else (self.layout.library.to_text() if self.layout is not None
                                                  else load_macro_library(self.library).to_text())

    def state_dict(self) -> dict:
        return {"category": self.category, "library": self.library, "library_text": self.library_text(),
                "val": None if self.val_set is None else [int(i) for i in self.val_set.clouds.ids]}

    def load_state_dict(self, state: dict) -> None:
        """Refuse to resume a run that validated on other shapes."""
        if state.get("library_text", self.library_text()) != self.library_text():  # the same library, by text
            raise ValueError(f"the checkpoint's run trained on programs of library {state.get('library')!r}, this "
                             f"one on {self.library!r}, and the two differ")
        mine = None if self.val_set is None else [int(i) for i in self.val_set.clouds.ids]
        if mine is not None and state.get("val") is not None and state["val"] != mine:
            raise ValueError(f"the checkpoint's run validated on other {state.get('category')} shapes "
                             f"({len(state['val'])}) than this one ({len(mine)}); resume with the same cache "
                             f"and data settings")


# ------------------------------------------------------------------------------------------ modules


class _CloudModule(L.LightningModule):
    """What both recipes share: the encoder, the VAE, checks, validation F-score and image grids."""

    recipe = ""

    def __init__(self, category: str, vae_weights: Optional[str], npoints, radii, nsamples, widths, lr: float,
                 weight_decay: float, recon_every_n_epochs: int, recon_shapes: int, recon_points: int,
                 image_shapes: int, image_size: int, seed: int, macros: bool = False):
        super().__init__()
        if int(recon_every_n_epochs) < 0:
            raise ValueError(f"recon_every_n_epochs must be >= 0, got {recon_every_n_epochs!r}")
        if vae_weights is None:
            self.vae = load_pretrained(category, macros=macros)
        else:
            self.vae = load_model(vae_weights, category=category)
            if macros and not isinstance(self.vae, MacroVAE):
                raise ValueError(f"{vae_weights}: macros=True needs a VAE trained on macro programs; this file holds "
                                 f"a base-language VAE")
        self.vae.train()
        #: the macro library's line layout of a macro-program decoder; None for the base language
        self.layout: Optional[LineLayout] = getattr(self.vae, "layout", None)
        hidden = self.vae.decoder.hidden_dim
        self.encoder = PointNet2SSG(out_dim=hidden, npoints=npoints, radii=radii, nsamples=nsamples, widths=widths)
        self._recon: list[tuple[torch.Tensor, VectorNode]] = []
        self._recon_targets = None

    # ------------------------------------------------------------------ checks and checkpoints
    def setup(self, stage: str) -> None:
        check_data_category(self)
        dm = self.trainer.datamodule if self.trainer is not None else None
        if dm is not None and hasattr(dm, "library_text"):
            if dm.library_text() != self.library_text():
                mine = "a base-language decoder" if self.layout is None else "a macro-program decoder"
                served = ("ShapeAssembly programs" if dm.library is None
                          else f"macro programs of library {dm.library!r}, not the decoder's")
                raise ValueError(f"the model has {mine} and the data module serves {served}; set "
                                 f"data.init_args.library to the decoder's library (None for the base language)")

    def library_text(self) -> Optional[str]:
        """The macro library's text of a macro-program decoder; None for the base language."""
        return None if self.layout is None else self.layout.library.to_text()

    def _info(self) -> dict:
        return {"format": CHECKPOINT_FORMAT, "recipe": self.recipe, "category": self.hparams.category,
                "encoder": self.encoder.config, "hidden_dim": int(self.vae.decoder.hidden_dim),
                "library": self.library_text()}

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["shapeprog_pointcloud"] = self._info()

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        info = checkpoint_entry(checkpoint, "shapeprog_pointcloud", CHECKPOINT_FORMAT,
                                "a shapeprog.pointcloud.train module")
        mine = self._info()
        if {k: info.get(k) for k in mine} != mine:
            short = lambda d: {k: ("<macro library>" if k == "library" and v else v) for k, v in d.items()}
            raise ValueError(f"the checkpoint is of a model with {short(info)}, this run is {short(mine)}")

    def on_train_epoch_start(self) -> None:
        dm = self.trainer.datamodule if self.trainer is not None else None
        if getattr(dm, "train_set", None) is not None:
            dm.train_set.set_epoch(self.current_epoch)

    # ------------------------------------------------------------------ the recipe's parts
    def code(self, points: torch.Tensor) -> torch.Tensor:
        """The latent of each cloud: ``(B, N, 3) -> (B, H)``."""
        return self.encoder(points.to(self.dtype))

    def _batch(self, batch: dict) -> tuple[torch.Tensor, TreeBatch]:
        trees = batch["trees"]
        if trees.dtype != self.dtype or trees.device != self.device:
            trees = trees.to(self.device, self.dtype)
        return batch["points"].to(self.device, self.dtype), trees

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        points, trees = self._batch(batch)
        z = self.code(points)
        loss, terms = self.losses(z, trees)
        self.log("val/loss", loss, prog_bar=True, batch_size=trees.size, sync_dist=True)
        for name, value in terms.items():
            self.log(f"val/{name}", value, batch_size=trees.size, sync_dist=True)
        room = self.hparams.recon_shapes - len(self._recon)
        if room > 0:
            self._recon += [(p.detach().cpu(), t) for p, t in zip(batch["points"][:room], trees.trees[:room])]

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        points, trees = self._batch(batch)
        loss, terms = self.losses(self.code(points), trees)
        self.log("train/loss", loss, prog_bar=True, batch_size=trees.size)
        for name, value in terms.items():
            self.log(f"train/{name}", value, batch_size=trees.size)
        return loss

    def on_validation_epoch_start(self) -> None:
        self._recon = []

    def recon_epoch(self) -> bool:
        n = self.hparams.recon_every_n_epochs
        return bool(n) and not self.trainer.sanity_checking and (self.current_epoch + 1) % n == 0

    def decode(self, z: torch.Tensor) -> list:
        """Programs decoded from latents ``(B, H)`` (:func:`~shapeprog.pointcloud.infer.decode_codes`), None
        where decoding fails."""
        return decode_codes(self.vae, z.detach())

    def on_validation_epoch_end(self) -> None:
        """On :meth:`recon_epoch` epochs: ``val/fscore`` (mean over the kept validation shapes, a failed decode
        scoring 0), ``val/recon_failed`` and, on rank 0, the ``val/clouds`` image grid."""
        kept, self._recon = self._recon, []
        if not kept or not self.recon_epoch():
            return
        points = torch.stack([p for p, _ in kept])
        trees = [t for _, t in kept]
        with torch.no_grad():
            was = self.encoder.training
            self.encoder.eval()
            programs = self.decode(self.code(points.to(self.device)))
            self.encoder.train(was)
        n, seed = self.hparams.recon_points, self.hparams.seed
        if self._recon_targets is None or len(self._recon_targets) != len(trees):
            self._recon_targets = target_surfaces(trees, n, seed, self.layout)
        scores = reconstruction_fscores(trees, programs, n, seed, targets=self._recon_targets)
        self.log("val/fscore", float(np.mean([s or 0.0 for s in scores])), sync_dist=True, prog_bar=True)
        self.log("val/recon_failed", sum(s is None for s in scores) / len(scores), sync_dist=True)
        k = self.hparams.image_shapes
        exp = getattr(self.logger, "experiment", None) if self.logger is not None else None
        if self.trainer.is_global_zero and k and hasattr(exp, "add_image"):
            cells = [c for p, r in zip(points[:k], programs[:k]) for c in (cloud_corners(p), _corners(r))]
            exp.add_image("val/clouds", render_grid(cells, cols=4, size=self.hparams.image_size),
                          self.global_step, dataformats="HWC")

    def losses(self, z: torch.Tensor, trees: TreeBatch) -> tuple[torch.Tensor, dict]:
        raise NotImplementedError

    def configure_optimizers(self):
        params = [p for p in self.parameters() if p.requires_grad]
        return torch.optim.Adam(params, lr=self.hparams.lr, weight_decay=self.hparams.weight_decay)


class LatentRegressionModule(_CloudModule):
    """The ShapeAssembly recipe: the encoder regresses the frozen VAE encoder's ``mu``.

    The loss of a batch is the squared error summed over the latent's dims, averaged over the clouds. The
    VAE stays frozen (its weights are not trained and not changed); validation decodes the regressed codes.

    Args:
        category: the VAE's and the data's category.
        vae_weights: a VAE weights file or checkpoint (default: the shipped model of ``category``).
        npoints, radii, nsamples, widths: the encoder's sizes (:class:`PointNet2SSG`; default the spec's).
        lr: Adam's learning rate.
        weight_decay: Adam's L2 penalty.
        recon_every_n_epochs: compute ``val/fscore`` and the image grid every N epochs (0: never).
        recon_shapes: validation clouds decoded for the F-score.
        recon_points: surface samples per shape for the F-score.
        image_shapes: pairs in the image grid (0: none).
        image_size: pixels per picture.
        seed: the F-score's surface samples.
    """

    recipe = "latent"

    def __init__(self, category: str = "chair", vae_weights: Optional[str] = None,
                 npoints: Sequence[int] = NPOINTS, radii: Sequence[float] = RADII, nsamples: Sequence[int] = NSAMPLES,
                 widths: Sequence[Sequence[int]] = WIDTHS, lr: float = 1e-3, weight_decay: float = 0.0,
                 recon_every_n_epochs: int = 5, recon_shapes: int = 32, recon_points: int = 2048,
                 image_shapes: int = 8, image_size: int = 128, seed: int = 0):
        super().__init__(category, vae_weights, npoints, radii, nsamples, widths, lr, weight_decay,
                         recon_every_n_epochs, recon_shapes, recon_points, image_shapes, image_size, seed)
        if self.layout is not None:
            raise ValueError(f"{vae_weights}: a macro-program VAE; the latent recipe is built for the base "
                             f"language (train macro programs end to end: EndToEndModule with macros=True)")
        self.save_hyperparameters()
        self.vae.eval()
        self.vae.requires_grad_(False)

    def train(self, mode: bool = True):
        super().train(mode)
        self.vae.eval()  # frozen: never in training mode
        return self

    def target(self, trees: TreeBatch) -> torch.Tensor:
        """The frozen VAE encoder's ``mu`` of each tree: ``(B, H)``."""
        with torch.no_grad():
            mu, _ = self.vae.encoder.sampler(encode_batch(self.vae.encoder, trees))
        return mu

    def losses(self, z: torch.Tensor, trees: TreeBatch) -> tuple[torch.Tensor, dict]:
        mu = self.target(trees)
        sq = (z - mu).square().sum(dim=1)
        return sq.mean(), {"mse": sq.mean(), "mu_norm": mu.norm(dim=1).mean()}


class EndToEndModule(_CloudModule):
    """The ShapeMOD recipe: encoder and VAE decoder trained together on the VAE's program losses.

    The encoder's code is the decoder's latent; the loss is :func:`~shapeprog.vae.batch.batch_loss` without
    the KL term (mean over the clouds), or :func:`~shapeprog.vae.losses.macro_program_loss` without KL for a
    macro-program decoder. The VAE's encoder is not used (and not trained).

    Args:
        category, vae_weights, npoints, radii, nsamples, widths, lr, weight_decay, recon_every_n_epochs,
            recon_shapes, recon_points, image_shapes, image_size, seed: as :class:`LatentRegressionModule`.
        init_decoder: start the decoder from the VAE's weights (False: from scratch).
        init_encoder: a point-cloud weights file (:func:`export_weights`, e.g. the shipped latent-regression
            model ``shapeprog/weights/pointcloud_latent_<category>.pt``) to start the encoder from; its
            category, latent size and encoder sizes must equal this run's. None (the paper): from scratch.
        loss_weights: weights by term name that replace those of :data:`~shapeprog.vae.losses.LOSS_WEIGHTS`
            (:data:`~shapeprog.vae.losses.MACRO_LOSS_WEIGHTS` for a macro-program decoder).
        macros: decode macro programs: the decoder is the shipped macro-program VAE's of the category
            (:data:`shapeprog.vae.pretrained.PRETRAINED_MACROS`) unless ``vae_weights`` names one; the data
            module's ``library`` must be its library.
        init: an end-to-end weights file (:func:`export_weights`) to continue from: its encoder and decoder
            replace this run's (after ``init_decoder`` / ``init_encoder``); its category, recipe, sizes and
            macro library must equal this run's. The optimiser starts afresh (``--ckpt_path`` resumes a run).
    """

    recipe = "e2e"

    def __init__(self, category: str = "chair", vae_weights: Optional[str] = None,
                 npoints: Sequence[int] = NPOINTS, radii: Sequence[float] = RADII, nsamples: Sequence[int] = NSAMPLES,
                 widths: Sequence[Sequence[int]] = WIDTHS, lr: float = 1e-4, weight_decay: float = 0.0,
                 init_decoder: bool = True, init_encoder: Optional[str] = None, loss_weights: Optional[dict] = None,
                 recon_every_n_epochs: int = 5, recon_shapes: int = 32, recon_points: int = 2048,
                 image_shapes: int = 8, image_size: int = 128, seed: int = 0, macros: bool = False,
                 init: Optional[str] = None):
        super().__init__(category, vae_weights, npoints, radii, nsamples, widths, lr, weight_decay,
                         recon_every_n_epochs, recon_shapes, recon_points, image_shapes, image_size, seed, macros)
        base = LOSS_WEIGHTS if self.layout is None else MACRO_LOSS_WEIGHTS
        unknown = sorted(set(loss_weights or {}) - set(base))
        if unknown:
            raise ValueError(f"unknown loss term(s) {unknown}; the terms are {', '.join(base)}")
        self.save_hyperparameters()
        if not init_decoder:
            hidden = self.vae.decoder.hidden_dim
            self.vae = VAE(hidden) if self.layout is None else MacroVAE(self.layout, hidden)
        self.vae.encoder.requires_grad_(False)
        if init_encoder is not None:
            self._init_encoder(init_encoder)
        if init is not None:
            self._init_model(init)
        self.weights = {**base, **(loss_weights or {})}

    def _init_model(self, path) -> None:
        start = load_cloud_model(path, category=self.hparams.category)
        if start.recipe != "e2e":
            raise ValueError(f"{path}: a {start.recipe!r} model; --model.init_args.init takes an end-to-end one")
        if start.encoder.config != self.encoder.config:
            raise ValueError(f"{path}: its encoder has sizes {start.encoder.config}, this run's are {self.encoder.config}")
        mine = None if self.layout is None else self.layout.library.to_text()
        theirs = None if start.layout is None else start.layout.library.to_text()
        if mine != theirs:
            what = lambda t: "the base language" if t is None else "a macro library"  # noqa: E731
            raise ValueError(f"{path}: its decoder writes {what(theirs)}{' (another one)' if mine and theirs else ''}, "
                             f"this run's {what(mine)}")
        if start.vae.decoder.hidden_dim != self.vae.decoder.hidden_dim:
            raise ValueError(f"{path}: its decoder has hidden_dim {start.vae.decoder.hidden_dim}, this run's "
                             f"{self.vae.decoder.hidden_dim}")
        self.encoder.load_state_dict(start.encoder.state_dict())
        self.vae.decoder.load_state_dict(start.vae.decoder.state_dict())

    def _init_encoder(self, path) -> None:
        start = load_encoder(path, category=self.hparams.category)
        if start.config != self.encoder.config:
            raise ValueError(f"{path}: its encoder has sizes {start.config}, this run's are {self.encoder.config}")
        self.encoder.load_state_dict(start.state_dict())

    def losses(self, z: torch.Tensor, trees: TreeBatch) -> tuple[torch.Tensor, dict]:
        if self.layout is not None:
            return self._macro_losses(z, trees)
        lines, leaf = decode_batch(self.vae.decoder, trees, z)
        out = BatchOutput(lines, leaf, self.vae.decoder.bbox(z), z, torch.zeros_like(z), z)
        total, terms = batch_loss(out, trees, self.weights, kl=False)
        return total.mean(), {k: v.mean() for k, v in terms.items() if k != "kl"}

    def _macro_losses(self, z: torch.Tensor, trees: MacroTreeBatch) -> tuple[torch.Tensor, dict]:
        """:func:`~shapeprog.vae.macro_batch.macro_batch_loss` (no KL) of the trees decoded teacher-forced from their
        clouds' codes, averaged over the batch (the level-by-level batched pass)."""
        total, terms = macro_batch_loss(self.vae, trees, weights=self.weights, kl=False, codes=z)
        return total.mean(), {k: v.mean() for k, v in terms.items() if k != "kl"}


# ------------------------------------------------------------------------------------------ export


def export_weights(checkpoint, out, half: bool = True, meta: Optional[dict] = None) -> Path:
    """Write the model of a training checkpoint as a small weights file (``torch.load(weights_only=True)``).

    The file holds ``format`` (:data:`WEIGHTS_FORMAT`), ``version``, ``recipe``, ``category``, the encoder's
    ``config`` and ``encoder`` state; an end-to-end model also its ``decoder`` state (a latent-regression
    model decodes with the shipped VAE of its category). ``meta`` records epoch, step and what the caller adds.
    The file is written atomically; an existing ``out`` is replaced (it is the caller's to name).
    """
    payload = load_payload(checkpoint, "readable checkpoint", missing="checkpoint")
    info = payload.get("shapeprog_pointcloud")
    if info is None:
        raise ValueError(f"{checkpoint}: not a checkpoint of a shapeprog.pointcloud.train module")
    state = payload["state_dict"]

    def part(prefix: str) -> dict:
        return {k[len(prefix):]: (v.half() if half and v.is_floating_point() else v)
                for k, v in state.items() if k.startswith(prefix)}

    body = {"recipe": info["recipe"],
            "category": info["category"], "config": info["encoder"], "hidden_dim": info["hidden_dim"],
            "encoder": part("encoder."),
            "meta": {"epoch": int(payload.get("epoch", -1)), "global_step": int(payload.get("global_step", -1)),
                     **(meta or {})}}
    if info["recipe"] == "e2e":
        body["decoder"] = part("vae.decoder.")
    else:  # the VAE whose latent codes the encoder regresses; the file is refused with another
        body["vae_decoder"] = decoder_fingerprint(
            {k[len("vae.decoder."):]: v for k, v in state.items() if k.startswith("vae.decoder.")})
    if info.get("library") is not None:
        body["library"] = info["library"]
    return write_weights(out, WEIGHTS_FORMAT, CHECKPOINT_FORMAT, body)


if __name__ == "__main__":  # pragma: no cover
    warnings.warn("train with: python train.py fit --config configs/pointcloud/latent_chair.yaml", stacklevel=1)
