"""The settings of a ShapeCoder discovery run (:class:`Config`) and the wake searches it names."""
from __future__ import annotations

from dataclasses import dataclass

from .dream import DREAM_TIMEOUT, N_DREAMS
from .rules import SCHEMES
from .refactor import MAX_ENODES, MAX_ITERATIONS, TIME_LIMIT, VALUE_SCHEDULES, VALUES, check_limits
from .search import WAKE_BATCH, WAKE_BATCHES, WAKE_SECONDS, WAKE_STEP_BUDGET
from .train import TrainConfig

__all__ = [
    "Config",
    "CONSTANT_OMEGA",
    "WAKES",
]


#: The wake searches: by refactoring only, or with the recognition network.
WAKES = ("refactor", "network")
#: ω of every abstraction when ``Config.preferences`` is off (the preference score 0: 0.25 · (1 − 0)).
CONSTANT_OMEGA = 0.25


@dataclass(frozen=True)
class Config:
    """Settings of a discovery run (the paper's values where it has them).

    Attributes:
        rounds: proposal/integration rounds (``max_sc_rounds`` 4), then one final wake.
        n_proposals: proposals per round (10,000).
        n_abstractions: candidates tried per round (N_A, 20).
        seed: random seed of the proposals (42).
        iterations, max_nodes: the e-graph limits of each refactor (5, 10,000, the paper's); time_limit: a
            safety cap in seconds, not a budget (:data:`~shapeprog.coder.refactor.TIME_LIMIT`; the paper's 5 s
            made results depend on the machine's load).
        egraph_values: how the e-graph's value table follows its e-nodes (:data:`~shapeprog.coder.refactor.VALUES`;
            ``"lagged"`` reproduces runs made before 2026-11-29; :func:`~shapeprog.coder.refactor.refactor`).
        refactor_all: integration refactors every program (the paper) rather than only those a candidate
            covers.
        semantic_rewrites: use the semantic rewrites (False: only the abstraction rules, the paper's
            "no semantic rewrites" ablation).
        scheme: how the e-graph's rewrites are guarded (:data:`~shapeprog.coder.rules.SCHEMES`):
            ``"conditional"`` (value-guarded rules, the paper's) or ``"naive"`` (plain rewrites over relations
            put in as e-nodes: the paper's "no conditional rewrites" ablation; needs the semantic rewrites).
        preferences: ω of each abstraction from its preference score, which also ranks the proposals (the
            paper's); False: ω = :data:`CONSTANT_OMEGA` for every abstraction and the ranking without the
            preference term (the paper's "no preferences" ablation; abstractions ω rejects stay rejected).
        wake: ``"refactor"`` (search by refactoring) or ``"network"`` (dreams, a recognition network, the
            network search; see the module docstring).
        n_dreams, dream_timeout: valid dreams per function (N_D, 10,000) and seconds per function (1,800).
        train_lr, train_batch, train_epochs, train_patience, train_min_delta, train_holdout,
            train_seconds, dropout, train_bucket: the network's training (:class:`shapeprog.coder.train.TrainConfig`;
            its defaults, the paper's values, are theirs; ``train_seconds`` per round).
        wake_batch, wake_batches, wake_step_budget: samples per batch (64), batches per search step at
            most, and the step's budget in batch-primitives (:func:`~shapeprog.coder.search.step_batches`;
            the paper's 1 s per step as a count). wake_seconds: a safety cap per search step, not the budget
            (:data:`~shapeprog.coder.search.WAKE_SECONDS`; None: none).
        device: where the network trains (``"auto"``: CUDA when available).
        network_from: with ``wake="network"``, the first round whose wake uses the network; the rounds
            before it use the refactor-only wake (cheap early rounds, then the network; ours, not the paper's).
        wake_repeats: network wakes per round with the round's network, each from the programs of the one
            before and with other sampling seeds (a shape keeps its program unless a candidate is cheaper,
            so F never rises); 1 is the paper's one wake per round.
    """

    rounds: int = 4
    n_proposals: int = 10_000
    n_abstractions: int = 20
    seed: int = 42
    iterations: int = MAX_ITERATIONS
    max_nodes: int = MAX_ENODES
    time_limit: float = TIME_LIMIT
    egraph_values: str = VALUES
    refactor_all: bool = False
    semantic_rewrites: bool = True
    scheme: str = "conditional"
    preferences: bool = True
    wake: str = "refactor"
    n_dreams: int = N_DREAMS
    dream_timeout: float = DREAM_TIMEOUT
    train_lr: float = TrainConfig.lr
    train_batch: int = TrainConfig.batch
    train_epochs: int = TrainConfig.epochs
    train_patience: int = TrainConfig.patience
    train_min_delta: float = TrainConfig.min_delta
    train_holdout: float = TrainConfig.holdout
    train_seconds: float | None = TrainConfig.max_seconds
    dropout: float = TrainConfig.dropout
    train_bucket: bool = TrainConfig.bucket
    wake_batch: int = WAKE_BATCH
    wake_batches: int = WAKE_BATCHES
    wake_step_budget: int | None = WAKE_STEP_BUDGET
    wake_seconds: float | None = WAKE_SECONDS
    device: str = "auto"
    network_from: int = 0
    wake_repeats: int = 1

    def __post_init__(self):
        for name in ("rounds", "n_proposals", "n_abstractions", "iterations", "max_nodes", "train_epochs",
                     "network_from"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"Config.{name} must be an int >= 0, got {v!r}")
        for name in ("n_dreams", "train_batch", "train_patience", "wake_batch", "wake_batches", "wake_repeats"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"Config.{name} must be an int >= 1, got {v!r}")
        if self.wake_step_budget is not None and (isinstance(self.wake_step_budget, bool)
                                                  or not isinstance(self.wake_step_budget, int)
                                                  or self.wake_step_budget < 1):
            raise ValueError(f"Config.wake_step_budget must be None or an int >= 1, got {self.wake_step_budget!r}")
        if self.scheme not in SCHEMES:
            raise ValueError(f"Config.scheme must be one of {', '.join(SCHEMES)}, got {self.scheme!r}")
        if self.scheme == "naive" and not self.semantic_rewrites:
            raise ValueError("Config.scheme 'naive' needs the semantic rewrites (it replaces their guards)")
        if self.wake not in WAKES:
            raise ValueError(f"Config.wake must be one of {', '.join(WAKES)}, got {self.wake!r}")
        check_limits(self.iterations, self.max_nodes, self.time_limit)  # before any work, not in a worker
        if self.egraph_values not in VALUE_SCHEDULES:
            raise ValueError(f"Config.egraph_values must be one of {', '.join(VALUE_SCHEDULES)}, "
                             f"got {self.egraph_values!r}")

    def train_config(self):
        """The :class:`shapeprog.coder.train.TrainConfig` of these settings."""
        return TrainConfig(lr=self.train_lr, batch=self.train_batch, epochs=self.train_epochs,
                           patience=self.train_patience, min_delta=self.train_min_delta, holdout=self.train_holdout,
                           max_seconds=self.train_seconds, dropout=self.dropout,
                           bucket=self.train_bucket)
