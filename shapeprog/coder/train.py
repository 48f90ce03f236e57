"""Training ShapeCoder's recognition network on dreams: a plain PyTorch loop (it runs inside a discovery
round, on a wall-clock budget, so it has no Lightning trainer around it).

:func:`tensorize` turns :class:`~shapeprog.coder.dream.DreamPair` s into padded tensors;
:func:`train` fits a :class:`~shapeprog.coder.recnet.RecognitionNet` with Adam: token cross-entropy over
the target tokens plus the variable cross-entropy (against the referenced value's rank) at ``<var>``
tokens, averaged over the batch's tokens. A share of the pairs (:attr:`TrainConfig.holdout`) is held out;
after every epoch the held-out loss is measured, the best weights are kept, and training stops early
when it has not improved by :attr:`TrainConfig.min_delta` for :attr:`TrainConfig.patience` epochs, after
:attr:`TrainConfig.epochs` epochs, or after :attr:`TrainConfig.max_seconds`.

:data:`PAPER` holds the paper's settings (Adam 1e-4, batch 64, ≤ 300 epochs, patience 30 / 0.025, 10%
held out, 12,000 s); :data:`CPU` a budget for a small CPU (lr 1e-3, dropout 0.1, 3 minutes).

Example:
    >>> from shapeprog.coder.dream import dream
    >>> from shapeprog.coder.lang import Library
    >>> from shapeprog.coder.recnet import NetConfig, RecognitionNet, Vocab
    >>> pairs = dream(Library(), n=8, seed=0).pairs
    >>> vocab = Vocab.of(Library())
    >>> model = RecognitionNet(NetConfig(len(vocab), token_dim=32, value_dim=16, heads=4, dropout=0.0))
    >>> log = train(model, pairs, vocab, TrainConfig(epochs=2, holdout=0.25), torch.Generator().manual_seed(0))
    >>> len(log.train_loss)
    2
"""
from __future__ import annotations

import copy
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Callable, Sequence

import torch

from .recnet import RecognitionNet
from .vocab import MAX_TOKENS, TargetError, Vocab, encode_scene, encode_target

__all__ = ["BUCKET_GROUP", "CPU", "PAPER", "Batch", "TrainConfig", "TrainLog", "batch_loss", "batches", "device_of",
           "tensorize", "train"]


@dataclass(frozen=True)
class TrainConfig:
    """Settings of :func:`train`.

    Attributes:
        lr: Adam learning rate. batch: pairs per step. epochs: at most. patience: epochs without an
        improvement of ``min_delta`` in the held-out loss before stopping. holdout: share of the pairs held
        out (at least one pair when there are two or more). max_seconds: wall-clock budget (None: none).
        dropout: the network's dropout (used by :func:`shapeprog.coder.discover` when it builds one).
        bucket: batches of scenes of similar length (each epoch: the shuffled pairs are cut into groups of
            :data:`BUCKET_GROUP` batches, each group sorted by scene length and cut into batches, the batches
            shuffled); False: plain shuffled batches. The loss of a batch is computed on its longest
            scene's conditioning tokens only, so bucketing makes an epoch several times cheaper.
    """

    lr: float = 1e-4
    batch: int = 64
    epochs: int = 300
    patience: int = 30
    min_delta: float = 0.025
    holdout: float = 0.1
    max_seconds: float | None = 12_000.0
    dropout: float = 0.5
    bucket: bool = True

    def __post_init__(self):
        if not self.lr > 0 or self.batch < 1 or self.epochs < 0 or self.patience < 1 or not 0 <= self.holdout < 1:
            raise ValueError(f"bad TrainConfig: {self}")


#: Batches per group sorted by scene length when :attr:`TrainConfig.bucket` is set.
BUCKET_GROUP = 16


def batches(lengths: torch.Tensor, batch: int, generator: torch.Generator, bucket: bool = True) -> list:
    """Index tensors of one epoch's batches over ``len(lengths)`` pairs (see :attr:`TrainConfig.bucket`);
    every pair is in exactly one batch.

    >>> bs = batches(torch.tensor([5, 1, 9, 2, 7, 3]), 2, torch.Generator().manual_seed(0))
    >>> sorted(int(i) for b in bs for i in b)
    [0, 1, 2, 3, 4, 5]
    """
    order = torch.randperm(len(lengths), generator=generator)
    if not bucket:
        return [order[s:s + batch] for s in range(0, len(order), batch)]
    out = []
    group = batch * BUCKET_GROUP
    for g in range(0, len(order), group):
        idx = order[g:g + group]
        idx = idx[torch.sort(lengths[idx], stable=True).indices]
        out.extend(idx[s:s + batch] for s in range(0, len(idx), batch))
    perm = torch.randperm(len(out), generator=generator)
    return [out[k] for k in perm.tolist()]


#: The paper's settings.
PAPER = TrainConfig()
#: A budget for a small shared CPU.
CPU = TrainConfig(lr=1e-3, epochs=300, patience=10, min_delta=0.005, max_seconds=180.0, dropout=0.1)


@dataclass
class Batch:
    """Padded tensors of pairs.

    Attributes:
        ranks, fields: (N, I) int64; cmask: (N, I) bool (real slots).
        tokens: (N, T) int64, ``<start>`` then the target but its last token (input); tok_ranks: (N, T) int64.
        targets: (N, T) int64, the target tokens, -100 on padding; target_ranks: (N, T) int64, the rank
        at ``<var>`` targets, else -100. n_values: (N,) int64.
    """

    ranks: torch.Tensor
    fields: torch.Tensor
    cmask: torch.Tensor
    tokens: torch.Tensor
    tok_ranks: torch.Tensor
    targets: torch.Tensor
    target_ranks: torch.Tensor
    n_values: torch.Tensor

    def __len__(self) -> int:
        return self.ranks.shape[0]

    def take(self, idx) -> "Batch":
        return Batch(*(getattr(self, f)[idx] for f in self.__dataclass_fields__))

    def to(self, device) -> "Batch":
        return Batch(*(getattr(self, f).to(device) for f in self.__dataclass_fields__))


def tensorize(pairs: Sequence, vocab: Vocab, inputs: int, library=None, skipped: Counter | None = None) -> Batch:
    """The :class:`Batch` of ``pairs`` (:class:`~shapeprog.coder.dream.DreamPair`, or ``(scene, target)``
    tuples); ``inputs`` is the network's conditioning length (fields × max primitives). Pairs whose
    scene is longer than ``inputs``, or whose target does not fit the vocabulary or
    :data:`~shapeprog.coder.vocab.MAX_TOKENS`, are skipped and counted in ``skipped`` (per reason).
    ``library``: the targets' library (see :func:`~shapeprog.coder.vocab.encode_target`)."""
    skipped = Counter() if skipped is None else skipped
    rows = []
    for p in pairs:
        scene, target = (p.scene, p.target) if hasattr(p, "scene") else p
        sc = encode_scene(scene)
        if len(sc.ranks) > inputs:
            skipped[f"scene longer than the network's {inputs} inputs"] += 1
            continue
        try:
            toks, rks = encode_target(target, sc, vocab, library)
        except TargetError as e:  # a token outside the vocabulary, a target over MAX_TOKENS
            skipped[e.reason] += 1
            continue
        rows.append((sc, toks, rks))
    n, t = len(rows), MAX_TOKENS
    b = Batch(torch.zeros(n, inputs, dtype=torch.long), torch.zeros(n, inputs, dtype=torch.long),
              torch.zeros(n, inputs, dtype=torch.bool), torch.zeros(n, t, dtype=torch.long),
              torch.zeros(n, t, dtype=torch.long), torch.full((n, t), -100, dtype=torch.long),
              torch.full((n, t), -100, dtype=torch.long), torch.zeros(n, dtype=torch.long))
    for i, (sc, toks, rks) in enumerate(rows):
        k = len(sc.ranks)
        b.ranks[i, :k] = torch.as_tensor(sc.ranks)
        b.fields[i, :k] = torch.as_tensor(sc.fields)
        b.cmask[i, :k] = True
        m = len(toks)
        b.tokens[i, 1:m] = torch.as_tensor(toks[:-1])
        b.tok_ranks[i, 1:m] = torch.as_tensor([max(r, 0) for r in rks[:-1]])
        b.targets[i, :m] = torch.as_tensor(toks)
        b.target_ranks[i, :m] = torch.as_tensor([r if r >= 0 else -100 for r in rks])
        b.n_values[i] = len(sc.values)
    return b


def batch_loss(model: RecognitionNet, b: Batch) -> torch.Tensor:
    """Mean token cross-entropy plus mean variable cross-entropy of a batch (scalar). The padding after the
    batch's longest scene and longest target is cut off first (the masks make this exact)."""
    t = int((b.targets != -100).sum(1).max().item()) if len(b) else 1
    i = max(int(b.cmask.sum(1).max().item()), 1) if len(b) else 1
    tl, vl = model(b.ranks[:, :i], b.fields[:, :i], b.cmask[:, :i], b.tokens[:, :t], b.tok_ranks[:, :t])
    vmask = torch.arange(vl.shape[-1], device=vl.device)[None] < b.n_values[:, None]
    vl = vl.masked_fill(~vmask[:, None, :], -1e9)
    loss = torch.nn.functional.cross_entropy(tl.reshape(-1, tl.shape[-1]), b.targets[:, :t].reshape(-1),
                                             ignore_index=-100)
    vt = b.target_ranks[:, :t].reshape(-1)
    if (vt != -100).any():
        loss = loss + torch.nn.functional.cross_entropy(vl.reshape(-1, vl.shape[-1]), vt, ignore_index=-100)
    return loss


@dataclass
class TrainLog:
    """What :func:`train` did: the mean training and held-out loss per epoch, the best held-out loss,
    why it stopped (``"epochs"``, ``"patience"``, ``"time"``) and the seconds."""

    train_loss: list = field(default_factory=list)
    val_loss: list = field(default_factory=list)
    best: float = float("inf")
    stop: str = "epochs"
    seconds: float = 0.0
    pairs: int = 0
    skipped: dict = field(default_factory=dict)  # pairs left out of training, per reason (tensorize)


def device_of(name: str = "auto") -> torch.device:
    """``"auto"``: CUDA when available, else the CPU; otherwise the named device."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def train(model: RecognitionNet, pairs, vocab: Vocab, cfg: TrainConfig = PAPER,
          generator: torch.Generator | None = None, device: str | torch.device = "cpu",
          log: Callable | None = None, library=None) -> TrainLog:
    """Fit ``model`` on ``pairs`` (:class:`~shapeprog.coder.dream.DreamPair` s or a :class:`Batch`); the
    model ends with the weights of the best held-out epoch (the last epoch's without a held-out set)
    and in eval mode.

    Args:
        generator: shuffles the pairs and splits off the held-out share (a CPU generator).
        device: where to train.
        log: called with one line per epoch.
        library: the targets' library (for :func:`tensorize`).
    """
    t0 = time.perf_counter()
    generator = generator or torch.Generator().manual_seed(0)
    dev = torch.device(device)
    skipped: Counter = Counter()
    data = pairs if isinstance(pairs, Batch) else tensorize(pairs, vocab, model.cfg.inputs, library, skipped)
    n = len(data)
    out = TrainLog(pairs=n, skipped=dict(skipped))
    if skipped and log is not None:
        log(f"{sum(skipped.values())} pairs left out: " + "; ".join(f"{k}: {v}" for k, v in sorted(skipped.items())))
    if n == 0:
        raise ValueError("no training pairs")
    perm = torch.randperm(n, generator=generator)
    n_val = int(round(cfg.holdout * n))
    if cfg.holdout > 0 and n >= 2:
        n_val = max(1, n_val)
    val, tr = data.take(perm[:n_val]), data.take(perm[n_val:])
    val = val.take(torch.sort(val.cmask.sum(1), stable=True).indices).to(dev)  # short scenes batch together
    tr_len = tr.cmask.sum(1)
    tr = tr.to(dev)
    model.to(dev)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    best_state, since = None, 0
    for epoch in range(cfg.epochs):
        model.train()
        total, count = 0.0, 0
        for idx in batches(tr_len, cfg.batch, generator, cfg.bucket):
            b = tr.take(idx.to(dev))
            loss = batch_loss(model, b)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(b)
            count += len(b)
        out.train_loss.append(total / max(count, 1))
        if n_val:
            model.eval()
            with torch.no_grad():
                vl = sum(float(batch_loss(model, val.take(slice(s, s + 256)))) * len(val.take(slice(s, s + 256)))
                         for s in range(0, n_val, 256)) / n_val
            out.val_loss.append(vl)
            if vl < out.best - cfg.min_delta:
                out.best, since = vl, 0
                best_state = copy.deepcopy(model.state_dict())
            else:
                since += 1
                if vl < out.best:
                    out.best = vl
                    best_state = copy.deepcopy(model.state_dict())
        if log:
            log(f"epoch {epoch}: train {out.train_loss[-1]:.4f}" + (f" held-out {out.val_loss[-1]:.4f}" if n_val else ""))
        if n_val and since >= cfg.patience:
            out.stop = "patience"
            break
        if cfg.max_seconds is not None and time.perf_counter() - t0 > cfg.max_seconds:
            out.stop = "time"
            break
    if best_state is not None:
        model.load_state_dict(best_state)
    model.eval()
    out.seconds = time.perf_counter() - t0
    return out

