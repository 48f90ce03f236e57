"""Targets without programs for the fine-tuning methods (REINFORCE, self-training): 2D images or 3D volumes.

:func:`load_targets` reads one split of a named source; :class:`TargetDataModule` serves it (training in
shuffled batches, validation in order). 2D sources: the shipped PartNet silhouettes, the paper's
``cad.h5``, a folder of images, an ``.npz`` or the renders of a generated dataset; 3D sources: the
ShapeAssembly volumes (:func:`csgnet.shapes3d.load_volumes`), an ``.npz`` or the renders of a generated
3D dataset. ``docs/csgnet.md`` ("REINFORCE", "Self-training") describes them.
"""
from __future__ import annotations

from pathlib import Path

import lightning as L
import numpy as np
import torch

from shapeio.image import read_image_folder

from ..data import load_dataset
from ..primitives import SIZE
from ..renderer import render_programs
from ..shapes2d import load_cad_h5, load_silhouettes
from ..shapes3d import load_volumes
from .streams import ShuffledBatches, distributed, stream_loader

__all__ = ["SOURCES", "SOURCES_BY_DIM", "DEFAULT_SOURCE", "check_targets", "load_targets", "target_batch",
           "TargetDataModule"]

#: The sources of each dimension.
SOURCES_BY_DIM = {2: ("silhouettes", "cad", "folder", "npz", "synthetic"), 3: ("volumes", "npz", "synthetic")}
SOURCES = ("silhouettes", "cad", "folder", "npz", "synthetic", "volumes")
#: The source of each dimension when none is named.
DEFAULT_SOURCE = {2: "silhouettes", 3: "volumes"}


def _check_dim(dim) -> int:
    if dim not in SOURCES_BY_DIM:
        raise ValueError(f"dim must be 2 (images) or 3 (volumes), got {dim!r}")
    return int(dim)


def _check_source(source: str, dim: int) -> None:
    if source not in SOURCES:
        raise ValueError(f"unknown target source {source!r}; expected one of {', '.join(SOURCES)}")
    if source not in SOURCES_BY_DIM[dim]:
        raise ValueError(f"the target source {source!r} holds {5 - dim}D shapes; {dim}D targets come from "
                         f"{', '.join(SOURCES_BY_DIM[dim])}")


def check_targets(targets, name: str, dim: int = 2) -> np.ndarray:
    """``targets`` as ``(N, 64, 64)`` (2D) or ``(N, 64, 64, 64)`` (3D) bool, non-zero = inside; a
    ``ValueError`` naming ``name`` for another shape, no target, or an empty one."""
    a = np.asarray(targets)
    want = (SIZE,) * _check_dim(dim)
    what = "images" if dim == 2 else "volumes"
    if a.ndim != dim + 1 or a.shape[1:] != want:
        raise ValueError(f"{name}: {dim}D target {what} must be (N, {', '.join(map(str, want))}), got shape {a.shape}")
    a = a != 0
    if len(a) == 0:
        raise ValueError(f"{name}: no {what}")
    empty = np.flatnonzero(~a.reshape(len(a), -1).any(1))
    if len(empty):
        raise ValueError(f"{name}: {len(empty)} empty target {what[:-1]}(s), e.g. index {int(empty[0])}; "
                         f"the reward and the label scores are undefined for an empty target")
    return a


def target_batch(batch, dim: int = 2) -> torch.Tensor:
    """The targets of a DataLoader batch (a tensor or a one-tuple) as bool, checked to be ``(B, 64, 64)``
    (2D) or ``(B, 64, 64, 64)`` (3D)."""
    x = batch[0] if isinstance(batch, (list, tuple)) else batch
    want = (SIZE,) * dim
    if x.dim() != dim + 1 or tuple(x.shape[1:]) != want:
        raise ValueError(f"{dim}D target batches must be (B, {', '.join(map(str, want))}), got {tuple(x.shape)}")
    return x.bool()


def load_targets(source: str, split: str, path=None, dim: int = 2, limit: int | None = None) -> np.ndarray:
    """One split of a set of targets as ``(N, 64, 64)`` (2D) or ``(N, 64, 64, 64)`` (3D) bool.

    Sources:
        * ``"silhouettes"`` (2D): the shipped PartNet silhouettes (or a file written by
          ``python -m shapeprog assembly silhouettes`` at ``path``);
        * ``"cad"`` (2D): the paper's ``cad.h5`` at ``path`` (needs h5py, the ``cad`` extra);
        * ``"folder"`` (2D): image files under ``path/<split>/`` (PNG, JPG, ...; each binarised by Otsu's rule
          and fitted into 64x64, :func:`shapeio.image.read_image_folder`), in sorted name order;
        * ``"volumes"`` (3D): the ShapeAssembly chairs and tables voxelised to 64³, a file written by
          ``python -m shapeprog assembly volumes`` (default ``data/assembly_volumes.npz``,
          :func:`csgnet.shapes3d.load_volumes`);
        * ``"npz"``: a NumPy ``.npz`` at ``path`` holding ``<split>`` or ``<split>_images`` arrays
          ``(N, 64, 64)`` (2D) or ``(N, 64, 64, 64)`` (3D);
        * ``"synthetic"``: the renders of the programs of a dataset written by ``python -m csgnet generate``
          at ``path`` (all lengths).

    Args:
        limit: only the first ``limit`` targets of the split.
    """
    dim = _check_dim(dim)
    _check_source(source, dim)
    if split not in ("train", "val", "test"):
        raise ValueError(f"unknown split {split!r}; expected train, val or test")
    if limit is not None and limit < 1:
        raise ValueError(f"limit must be positive, got {limit}")
    if source == "silhouettes":
        return check_targets(load_silhouettes(split, path)[:limit], f"silhouettes {split}")
    if source == "volumes":
        return check_targets(load_volumes(split, path, limit), f"volumes {split}", 3)
    if path is None:
        raise ValueError(f"the {source!r} target source needs a path")
    p = Path(path)
    if source == "cad":
        return check_targets(load_cad_h5(p, split)[:limit], f"{p}:{split}_images")
    if source == "folder":
        d = p / split
        if not d.is_dir():
            raise FileNotFoundError(f"{d}: no such folder; the 'folder' source reads images from "
                                    f"{p}/train/, {p}/val/ and {p}/test/")
        return check_targets(read_image_folder(d)[:limit], str(d))
    if source == "npz":
        if not p.is_file():
            raise FileNotFoundError(f"{p}: no such file")
        with np.load(p, allow_pickle=False) as f:
            for key in (split, f"{split}_images"):
                if key in f.files:
                    return check_targets(f[key][:limit], f"{p}:{key}", dim)
            raise ValueError(f"{p}: no array {split!r} or {split + '_images'!r} (found: {', '.join(f.files) or 'none'})")
    progs = [q for _, ps in sorted(load_dataset(p, dim, split).items()) for q in ps][:limit]
    if not progs:
        raise ValueError(f"{p}: the {dim}D {split} split holds no programs")
    return check_targets(render_programs(progs, dim).numpy(), f"{p} {dim}D {split}", dim)


class TargetDataModule(L.LightningDataModule):
    """Targets without programs (training with shuffled batches; validation in order).

    Args:
        source: the source (:func:`load_targets`); default by ``dim``: ``"silhouettes"`` (2D), ``"volumes"``
            (3D).
        path: the file or folder of the source (optional for the silhouettes and the volumes).
        batch_size: targets per batch (REINFORCE, as the paper: 300).
        steps_per_epoch: training batches per epoch (default: one pass, ``N // batch_size``); with the
            paper's accumulation of 10 batches, 330 batches make the reference's 33 updates per epoch.
        val_size: validation targets (the first ones of the split; default: all).
        train_size: training targets (the first ones; default: all).
        val_split: the split validated on (``"val"``; ``"test"`` for a final check).
        num_workers: DataLoader workers.
        seed: shuffling seed.
        dim: 2 (images) or 3 (volumes, 256 KiB each in memory).
    """

    def __init__(self, source: str | None = None, path: str | None = None, batch_size: int = 300,
                 steps_per_epoch: int | None = None, val_size: int | None = None, train_size: int | None = None,
                 val_split: str = "val", num_workers: int = 0, seed: int = 0, dim: int = 2):
        super().__init__()
        self.dim = _check_dim(dim)
        source = DEFAULT_SOURCE[self.dim] if source is None else source
        _check_source(source, self.dim)
        if batch_size < 1:
            raise ValueError(f"batch_size must be positive, got {batch_size}")
        self.source, self.path = source, path
        self.batch_size, self.steps_per_epoch = int(batch_size), steps_per_epoch
        self.val_size, self.train_size, self.val_split = val_size, train_size, val_split
        self.num_workers, self.seed = int(num_workers), int(seed)
        self._arrays: dict[str, np.ndarray] | None = None
        self.train_images: torch.Tensor | None = None
        self.val_images: torch.Tensor | None = None

    @classmethod
    def from_arrays(cls, train, val=None, **kwargs) -> "TargetDataModule":
        """Targets given in code: ``train`` (and ``val``, default: ``train``) as ``(N, 64, 64)`` arrays, or
        ``(N, 64, 64, 64)`` with ``dim=3``."""
        dm = cls(**kwargs)
        dm._arrays = {"train": check_targets(train, "train", dm.dim),
                      "val": check_targets(train if val is None else val, "val", dm.dim)}
        return dm

    def _load(self, split: str) -> torch.Tensor:
        size = self.train_size if split == "train" else self.val_size
        if self._arrays is not None:
            a = self._arrays["val" if split != "train" else "train"][:size or None]
        else:
            a = load_targets(self.source, split, self.path, self.dim, size or None)
        return torch.from_numpy(np.ascontiguousarray(a))

    def setup(self, stage: str | None = None) -> None:
        if stage in (None, "fit") and self.train_images is None:
            self.train_images = self._load("train")
        if self.val_images is None:
            self.val_images = self._load(self.val_split)

    def train_dataloader(self):
        rank, world = distributed(self.trainer)
        steps = self.steps_per_epoch or max(1, len(self.train_images) // self.batch_size)
        ds = ShuffledBatches(self.train_images, self.batch_size, steps, self.seed, rank, world)
        return stream_loader(ds, self.trainer, self.num_workers)

    def val_dataloader(self):
        return torch.utils.data.DataLoader(torch.utils.data.TensorDataset(self.val_images), batch_size=self.batch_size,
                                           shuffle=False)
