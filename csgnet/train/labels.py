"""The pseudo-labels of self-training: the best program found so far per target (:class:`PseudoLabels`) and the
training batches that mix them with synthetic programs (:class:`PseudoLabelBatches`).

A label is ranked by a score of its render against its target, named per dimension
(:data:`DEFAULT_METRIC`): the 2D chamfer distance (lower is better) and the 3D IoU ``|A∧B| / (|A∨B| + 1)``
of ``python -m csgnet evaluate --dim 3`` (higher is better). A label is replaced only by a strictly better one.
"""
from __future__ import annotations

import numpy as np
import torch

from ..vocab import vocabulary
from .streams import MixedLengthBatches, ShardedBatches

__all__ = ["METRICS", "DEFAULT_METRIC", "PseudoLabels", "PseudoLabelBatches"]

#: The label scores: name -> whether a higher score is better.
METRICS = {"chamfer": False, "iou": True}
#: The label score of each dimension.
DEFAULT_METRIC = {2: "chamfer", 3: "iou"}


class PseudoLabels:
    """The best program found so far for each of ``n`` targets, with its score.

    The tensors live in shared memory, so DataLoader workers read the labels of the latest round.

    Args:
        n: targets.
        width: tokens per label (the longest label plus its ``$``).
        dim: 2 or 3 (the vocabulary, and the default ``metric``).
        metric: ``"chamfer"`` (lower is better) or ``"iou"`` (higher is better); default by ``dim``
            (:data:`DEFAULT_METRIC`).

    Attributes:
        tokens: ``(n, width) int64`` token indices, ``$``-padded.
        lengths: ``(n,) int64`` program tokens (0: no label yet).
        score: ``(n,) float64`` the label's ``metric`` against its target (no label: ``inf`` for the
            chamfer, ``-inf`` for the IoU, the worst value).
        rounds: relabelling rounds done.
        last_epoch: the training epoch of the latest round (-1: none).
    """

    def __init__(self, n: int, width: int, dim: int = 2, metric: str | None = None):
        if n < 1 or width < 2:
            raise ValueError(f"a label table needs n >= 1 targets and width >= 2 tokens, got {n} and {width}")
        if dim not in DEFAULT_METRIC:
            raise ValueError(f"dim must be 2 or 3, got {dim!r}")
        metric = DEFAULT_METRIC[dim] if metric is None else metric
        if metric not in METRICS:
            raise ValueError(f"unknown label score {metric!r}; expected one of {', '.join(METRICS)}")
        self.dim, self.metric, self.higher_better = int(dim), metric, METRICS[metric]
        self.width, self.stop = int(width), vocabulary(dim).stop
        self.worst = float("-inf") if self.higher_better else float("inf")
        self.tokens = torch.full((n, width), self.stop, dtype=torch.int64).share_memory_()
        self.lengths = torch.zeros(n, dtype=torch.int64).share_memory_()
        self.score = torch.full((n,), self.worst, dtype=torch.float64).share_memory_()
        self.rounds, self.last_epoch = 0, -1

    def __len__(self) -> int:
        return self.lengths.shape[0]

    def labelled(self) -> torch.Tensor:
        """``(K,) int64`` indices of the targets that have a label."""
        return torch.nonzero(torch.isfinite(self.score)).flatten()

    def better(self, new: torch.Tensor, old: torch.Tensor) -> torch.Tensor:
        """Which of the scores ``new`` are strictly better than ``old`` (a non-finite ``new``: never)."""
        return torch.isfinite(new) & ((new > old) if self.higher_better else (new < old))

    def mean_score(self) -> float:
        """The mean score of the labels held (the worst value when there is none)."""
        have = self.labelled()
        return float(self.score[have].mean()) if len(have) else self.worst

    def offer(self, index: torch.Tensor, tokens: torch.Tensor, lengths: torch.Tensor, score) -> torch.Tensor:
        """Replace the labels of ``index`` whose offered program is strictly better.

        Args:
            index: ``(M,) int64`` target indices (distinct).
            tokens: ``(M, T) int64`` programs, ``$``-padded; ``T`` may differ from the table's width as
                long as every program fits in it (``lengths < width``).
            lengths: ``(M,) int64`` program tokens.
            score: ``(M,)`` the programs' scores (NaN or infinite: never taken).

        Returns:
            ``(M,) bool``, which offers replaced the label.
        """
        index, lengths = torch.as_tensor(index).long().cpu(), torch.as_tensor(lengths).long().cpu()
        tokens = torch.as_tensor(tokens).long().cpu()
        new = torch.as_tensor(np.asarray(score, np.float64))
        M = index.shape[0]
        if tokens.dim() != 2 or tokens.shape[0] != M or lengths.shape != (M,) or new.shape != (M,):
            raise ValueError(f"offer needs index (M,), tokens (M, T), lengths (M,) and score (M,); got "
                             f"{tuple(index.shape)}, {tuple(tokens.shape)}, {tuple(lengths.shape)} and {tuple(new.shape)}")
        if M and int(lengths.max()) >= self.width:
            raise ValueError(f"a program of {int(lengths.max())} tokens does not fit the label table's width "
                             f"{self.width} (data.max_len must be at least the decoding horizon model.max_len)")
        better = self.better(new, self.score[index])
        if bool(better.any()):
            rows = index[better]
            padded = torch.full((int(better.sum()), self.width), self.stop, dtype=torch.int64)
            n = min(tokens.shape[1], self.width)
            padded[:, :n] = tokens[better, :n]
            padded[torch.arange(self.width)[None] >= lengths[better, None]] = self.stop
            self.tokens[rows] = padded
            self.lengths[rows] = lengths[better]
            self.score[rows] = new[better]
        return better

    def state_dict(self) -> dict:
        return {"tokens": self.tokens.clone(), "lengths": self.lengths.clone(), "score": self.score.clone(),
                "metric": self.metric, "rounds": self.rounds, "last_epoch": self.last_epoch}

    def load_state_dict(self, state: dict) -> None:
        """Restore a :meth:`state_dict` in place (the tensors stay shared with running workers). A table of
        2D chamfer labels saved with its scores as ``chamfer`` (and no ``metric``) is read too."""
        state = dict(state)
        if "score" not in state and "chamfer" in state:
            state["score"], state["metric"] = state.pop("chamfer"), "chamfer"
        metric = state.get("metric", "missing")
        if metric != self.metric:
            raise ValueError(f"pseudo-label table: its labels are ranked by {metric!r}, this run's by "
                             f"{self.metric!r} (a checkpoint of a {3 if self.dim == 2 else 2}D run?)")
        want = {"tokens": tuple(self.tokens.shape), "lengths": (len(self),), "score": (len(self),)}
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
        ``(tokens (B, W) int64, lengths (B,) int64, targets (B, 64, 64[, 64]) bool, from_target (B,) bool)``:
        the programs and, for the labelled targets, their targets (all False for synthetic rows, which the
        training step renders).
    """

    def __init__(self, images: torch.Tensor, labels: PseudoLabels, pseudo: int, synthetic: MixedLengthBatches | None,
                 steps: int, seed: int = 0, rank: int = 0, world: int = 1):
        super().__init__(steps, seed, rank, world)
        if len(images) != len(labels):
            raise ValueError(f"{len(images)} targets but a label table of {len(labels)}")
        if images.dim() != labels.dim + 1:
            raise ValueError(f"{labels.dim}D labels need (N, {', '.join(['64'] * labels.dim)}) targets, got "
                             f"{tuple(images.shape)}")
        if synthetic is not None and synthetic.max_len + 1 != labels.width:
            raise ValueError(f"synthetic programs of width {synthetic.max_len + 1} against labels of width {labels.width}")
        if synthetic is not None and synthetic.dim != labels.dim:
            raise ValueError(f"{synthetic.dim}D synthetic programs against {labels.dim}D labels")
        self.images, self.labels, self.pseudo, self.synthetic = images, labels, int(pseudo), synthetic

    def _batches(self, steps: int, rng: np.random.Generator):
        synth = self.synthetic._batches(steps, rng) if self.synthetic is not None else None
        canvas = tuple(self.images.shape[1:])
        for _ in range(steps):
            parts = []
            have = self.labels.labelled().numpy()
            if self.pseudo and len(have):
                idx = torch.as_tensor(rng.choice(have, self.pseudo, replace=len(have) < self.pseudo))
                parts.append((self.labels.tokens[idx], self.labels.lengths[idx], self.images[idx].bool(),
                              torch.ones(len(idx), dtype=torch.bool)))
            if synth is not None:
                toks, lengths = next(synth)
                parts.append((toks, lengths, torch.zeros((len(toks), *canvas), dtype=torch.bool),
                              torch.zeros(len(toks), dtype=torch.bool)))
            if not parts:
                raise RuntimeError("no training pairs: no target has a pseudo-label yet (every beam was invalid) and "
                                   "data.synthetic_fraction is 0; start from supervised weights or mix in synthetic "
                                   "programs")
            yield tuple(torch.cat(cols) for cols in zip(*parts))
