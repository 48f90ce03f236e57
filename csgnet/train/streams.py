"""Batch streams for training: each item a whole batch, split over distributed ranks and DataLoader workers.

:class:`ShardedBatches` is the base: ``steps`` batches per epoch, each shard (rank × worker) drawing from
its own generator seeded by ``(seed, epoch, shard)``, so a stream is deterministic for a given seed,
epoch, rank and worker count. :class:`MixedLengthBatches` serves supervised training (programs of every
length in equal counts), :class:`ShuffledBatches` the REINFORCE target images. The helpers connect a
stream to a Lightning trainer without importing Lightning.
"""
from __future__ import annotations

import numpy as np
import torch

from ..synth import sample_programs
from ..vocab import vocabulary

__all__ = ["ShardedBatches", "Cycle", "MixedLengthBatches", "ShuffledBatches", "distributed", "stream_loader",
           "set_stream_epoch"]


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

    ``prepare(tokens, lengths)``, when given, runs on each batch where it is made (in a DataLoader worker)
    and its results are appended to the batch (e.g. :func:`csgnet.train.supervised.packed_inputs`).

    Yields:
        ``(tokens (B, T + 1) int64, lengths (B,) int64)``, ``$``-padded, then ``prepare``'s results if any.
    """

    def __init__(self, dim: int, lengths: list[int], batch: int, steps: int, max_len: int,
                 tables: dict[int, torch.Tensor] | None = None, seed: int = 0, rank: int = 0, world: int = 1,
                 prepare=None):
        super().__init__(steps, seed, rank, world)
        self.dim, self.lengths, self.max_len = dim, list(lengths), int(max_len)
        self.per_length = max(1, int(batch) // len(self.lengths))
        self.tables = tables
        self.prepare = prepare

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
            tokens, lens = torch.cat(parts), lengths.clone()
            yield (tokens, lens) if self.prepare is None else (tokens, lens, *self.prepare(tokens, lens))


class ShuffledBatches(ShardedBatches):
    """``steps`` batches of ``batch`` images, reshuffled after each pass over the set (the reference's
    CAD generator). Deterministic for a seed, epoch and rank; DataLoader workers split the steps.

    Yields:
        ``(batch, 64, 64)`` bool tensors.
    """

    def __init__(self, images: torch.Tensor, batch: int, steps: int, seed: int = 0, rank: int = 0, world: int = 1):
        if batch < 1 or steps < 1:
            raise ValueError(f"batch and steps must be positive, got {batch} and {steps}")
        super().__init__(steps, seed, rank, world)
        self.images, self.batch = images, int(batch)

    def _batches(self, steps: int, rng: np.random.Generator):
        cycle = Cycle(len(self.images), rng)
        for _ in range(steps):
            yield self.images[torch.as_tensor(cycle.take(self.batch))]
