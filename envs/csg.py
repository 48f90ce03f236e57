"""CSG program synthesis as a Gymnasium environment, one postfix token per step.

``CSG2D-v0`` / ``CSG3D-v0`` are :class:`CSGEnv`; ``gymnasium.make_vec`` builds their batched twin
:class:`CSGVectorEnv`, which steps every episode through one :class:`csgnet.renderer.StackMachine`.
Both run on :class:`_Episodes`. ``docs/envs.md`` explains the episode end, the rewards and the masks.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import VectorEnv
from gymnasium.vector.utils import batch_space
from gymnasium.vector.vector_env import AutoresetMode

from csgnet import metrics
from csgnet.lang import completable
from csgnet.primitives import SIZE
from csgnet.renderer import StackMachine, pack, popcount, primitive_cache, unpack
from csgnet.vocab import codes, vocabulary

from ._checks import can_render, check_dim, check_int, check_render_mode
from .targets import Target, as_target_source

__all__ = ["CSGEnv", "CSGVectorEnv", "CSGConfig"]

REWARDS = ("chamfer", "iou")
INVALID_REWARDS = ("zero", "reference")
INVALID_ACTIONS = ("terminate", "continue")

_TARGET_GREY = np.array([70, 70, 70], dtype=np.float64)
_SHAPE_BLUE = np.array([31, 119, 180], dtype=np.float64)


@dataclass(frozen=True)
class CSGConfig:
    """The validated settings of a CSG environment (the arguments of :class:`CSGEnv`)."""

    dim: int
    max_length: int
    stack_size: int
    reward: str
    gamma: float
    invalid_reward: str
    invalid_action: str
    observe_steps: bool
    render_scale: int

    @classmethod
    def build(cls, dim=2, max_length=None, stack_size=None, reward=None, gamma=None, invalid_reward="zero",
              invalid_action="terminate", observe_steps=True, render_scale=4) -> "CSGConfig":
        dim = check_dim(dim)
        if max_length is None:
            max_length = 13 if dim == 2 else 7
        max_length = check_int("max_length", max_length)
        stack_size = check_int("stack_size", (max_length + 1) // 2 if stack_size is None else stack_size)
        if reward is None:
            reward = "chamfer" if dim == 2 else "iou"
        if reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
        if reward == "chamfer" and dim == 3:
            raise ValueError("the chamfer reward is defined on 2D images only; use reward='iou' in 3D")
        if gamma is None:
            gamma = 20.0 if reward == "chamfer" else 1.0
        if not (isinstance(gamma, (int, float, np.number)) and np.isfinite(gamma) and gamma > 0):
            raise ValueError(f"gamma must be a positive number, got {gamma!r}")
        if invalid_reward not in INVALID_REWARDS:
            raise ValueError(f"invalid_reward must be one of {INVALID_REWARDS}, got {invalid_reward!r}")
        if invalid_action not in INVALID_ACTIONS:
            raise ValueError(f"invalid_action must be one of {INVALID_ACTIONS}, got {invalid_action!r}")
        render_scale = check_int("render_scale", render_scale)
        return cls(dim, max_length, stack_size, reward, float(gamma), invalid_reward, invalid_action,
                   bool(observe_steps), render_scale)

    @property
    def canvas(self) -> tuple[int, ...]:
        return (SIZE,) * self.dim

    def observation_space(self) -> spaces.Dict:
        obs = {
            "target": spaces.Box(0, 1, self.canvas, dtype=np.bool_),
            "stack": spaces.Box(0, 1, (self.stack_size,) + self.canvas, dtype=np.bool_),
        }
        if self.observe_steps:
            obs["steps"] = spaces.Discrete(self.max_length + 1)
        return spaces.Dict(obs)


class _Episodes:
    """A batch of ``n`` CSG episodes in lock step; the one implementation behind both environments.

    The program state lives in one :class:`StackMachine` (``n`` programs); the validity automaton
    (stack depth, tokens written) in NumPy arrays.
    """

    def __init__(self, n: int, cfg: CSGConfig, device=None):
        self.n, self.cfg = n, cfg
        self.device = torch.device("cpu" if device is None else device)
        vocab = vocabulary(cfg.dim)
        self.vocab = vocab
        self.V = len(vocab)
        self.stop = vocab.stop
        self.first_op = vocab.num_primitives  # + * - then $
        self.kind_of = primitive_cache(cfg.dim, self.device).kinds  # (V,) int64 on the device
        self.machine = StackMachine(n, cfg.dim, cfg.max_length, self.device)
        self.tokens = np.full((n, cfg.max_length), self.stop, dtype=np.int64)
        self.steps = np.zeros(n, dtype=np.int64)
        self.depth = np.zeros(n, dtype=np.int64)
        self.invalid = np.zeros(n, dtype=bool)  # an illegal token was written (continue mode)
        self.done = np.zeros(n, dtype=bool)
        self.target = np.zeros((n,) + cfg.canvas, dtype=bool)
        self.target_words = torch.zeros((n,) + cfg.canvas[:-1], dtype=torch.int64, device=self.device)

    # -------------------------------------------------------------------------------------------
    def begin(self, rows: np.ndarray, targets: list[Target]) -> None:
        """Start new episodes in ``rows`` (int indices) with the given targets."""
        if len(rows) == 0:
            return
        shapes = np.stack([t.shape for t in targets])
        if shapes.shape[1:] != self.cfg.canvas or shapes.dtype != np.bool_:
            raise ValueError(f"the target source returned shapes {shapes.shape[1:]} {shapes.dtype}, "
                             f"expected {self.cfg.canvas} bool")
        self.target[rows] = shapes
        idx = torch.as_tensor(rows, dtype=torch.int64, device=self.device)
        self.target_words[idx] = pack(shapes).to(self.device)
        self.tokens[rows] = self.stop
        self.steps[rows] = 0
        self.depth[rows] = 0
        self.invalid[rows] = False
        self.done[rows] = False
        self.machine.reset(idx)

    def _allowed(self, rows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per episode in ``rows``: may it write a draw, an operator, the stop token (each bool) and
        still complete a valid program within ``max_length`` tokens? All False once it has ended or
        written an illegal token."""
        live = ~self.done[rows] & ~self.invalid[rows]
        draw, op, stop = completable(self.depth[rows], self.cfg.max_length - self.steps[rows])
        return live & draw, live & op, live & stop

    def masks(self) -> np.ndarray:
        """``(n, V) bool``: tokens after which a valid program can still be completed."""
        draw, op, stop = self._allowed(slice(None))
        out = np.empty((self.n, self.V), dtype=bool)
        out[:, : self.first_op] = draw[:, None]
        out[:, self.first_op: self.stop] = op[:, None]
        out[:, self.stop] = stop
        return out

    def act(self, rows: np.ndarray, actions: np.ndarray):
        """Apply ``actions[i]`` to episode ``rows[i]``.

        Rows not listed get a stop code in the stack machine and must be restarted with :meth:`begin`
        before they act again (the vector environment restarts exactly those rows).

        Returns:
            ended ``(len(rows),) bool``, rewards ``(len(rows),) float64`` and, for the ended rows (in
            order), ``valid (m,) bool``, ``iou (m,) float64``.
        """
        cfg = self.cfg
        L = cfg.max_length
        a = np.asarray(actions, dtype=np.int64).reshape(-1)
        if a.shape[0] != len(rows):
            raise ValueError(f"expected {len(rows)} actions, got {a.shape[0]}")
        bad = (a < 0) | (a >= self.V)
        if bad.any():
            raise ValueError(f"actions must be token indices in [0, {self.V}) of the {cfg.dim}D vocabulary, "
                             f"got {a[bad][:5].tolist()}")
        if self.done[rows].any():
            raise RuntimeError("step() called on an episode that has ended; call reset() first")
        is_stop = a == self.stop
        is_op = (a >= self.first_op) & ~is_stop
        is_draw = a < self.first_op
        draw_ok, op_ok, stop_ok = self._allowed(rows)
        legal = np.where(is_stop, stop_ok, np.where(is_op, op_ok, draw_ok))
        write = ~is_stop
        wr = rows[write]
        self.tokens[wr, self.steps[wr]] = a[write]
        self.steps[wr] += 1
        self.depth[rows] += is_draw.astype(np.int64) - is_op
        self.invalid[rows] |= ~legal

        kinds = torch.full((self.n,), codes().stop, dtype=torch.int64, device=self.device)
        ids = torch.zeros(self.n, dtype=torch.int64, device=self.device)
        if len(wr):
            wr_t = torch.as_tensor(wr, device=self.device)
            ids[wr_t] = torch.as_tensor(a[write], device=self.device)
            kinds[wr_t] = self.kind_of[ids[wr_t]]
        self.machine.step(kinds, token_ids=ids)

        ended = is_stop | (self.steps[rows] >= L)
        if cfg.invalid_action == "terminate":
            ended |= ~legal
        self.done[rows] = ended
        rewards = np.zeros(len(rows), dtype=np.float64)
        er = rows[ended]
        valid = ~self.invalid[er] & (self.depth[er] == 1)
        iou = np.zeros(len(er), dtype=np.float64)
        if len(er):
            rewards[ended], iou = self._score(er, valid)
        return ended, rewards, valid, iou

    def _score(self, rows: np.ndarray, valid: np.ndarray):
        """Batched end-of-episode rewards and IoU of the programs in ``rows``."""
        cfg = self.cfg
        idx = torch.as_tensor(rows, device=self.device)
        pred = self.machine.result().index_select(0, idx)  # empty for an invalid program
        tgt = self.target_words.index_select(0, idx)
        inter = popcount(pred & tgt).astype(np.float64)
        union = popcount(pred | tgt).astype(np.float64)
        iou = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
        if cfg.reward == "iou":
            reward = np.where(valid, iou ** cfg.gamma, 0.0)
        else:
            images = unpack(pred, cfg.dim).cpu().numpy()
            reward = np.atleast_1d(metrics.reward(images, self.target[rows], gamma=cfg.gamma,
                                                  invalid=cfg.invalid_reward, valid=valid, workers=1))
        return reward, iou

    # -------------------------------------------------------------------------------------------
    def observe(self) -> dict[str, np.ndarray]:
        """The batched observation (fresh arrays)."""
        stack = unpack(self.machine.top(self.cfg.stack_size), self.cfg.dim).cpu().numpy()
        obs = {"target": self.target.copy(), "stack": stack}
        if self.cfg.observe_steps:
            obs["steps"] = self.steps.copy()
        return obs

    def program(self, row: int) -> str:
        """The text of episode ``row``'s tokens (:meth:`csgnet.Vocabulary.text`)."""
        return self.vocab.text(self.tokens[row, : self.steps[row]])

    def frames(self) -> tuple[np.ndarray, ...]:
        """Per episode, ``(64 s, 130 s, 3) uint8``: target beside the current shape (``s = render_scale``):
        the top of the stack while the episode runs, its program's result (empty if invalid) once ended."""
        done = torch.as_tensor(self.done, device=self.device).view((-1,) + (1,) * (self.cfg.dim - 1))
        words = torch.where(done, self.machine.result(), self.machine.top(1)[:, 0])
        current = unpack(words, self.cfg.dim).cpu().numpy()
        return tuple(_side_by_side(t, c, self.cfg.render_scale) for t, c in zip(self.target, current))


def _panel(shape: np.ndarray, color: np.ndarray) -> np.ndarray:
    """(64, 64, 3) float RGB of a bool image, or of a volume seen along its third axis (depth-shaded)."""
    if shape.ndim == 2:
        on, shade = shape, np.ones(shape.shape)
    else:
        on = shape.any(axis=2)
        first = np.argmax(shape, axis=2)  # nearest occupied voxel along the view axis
        shade = 1.0 - 0.6 * first / (SIZE - 1)
    img = np.full(on.shape + (3,), 255.0)
    img[on] = 255.0 - (255.0 - color) * shade[on][:, None]
    return img


def _side_by_side(target: np.ndarray, current: np.ndarray, scale: int) -> np.ndarray:
    gap = np.full((SIZE, 2, 3), 200.0)
    img = np.concatenate([_panel(target, _TARGET_GREY), gap, _panel(current, _SHAPE_BLUE)], axis=1)
    img = np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _reset_info(target: Target, mask: np.ndarray) -> dict[str, Any]:
    info: dict[str, Any] = {"action_mask": mask.astype(np.int8), "target_index": int(target.index)}
    if target.program is not None:
        info["target_program"] = target.program
    return info


class CSGEnv(gym.Env):
    """Write a postfix CSG program, one token per step, to match a target shape (``CSG2D-v0``, ``CSG3D-v0``).

    Each episode's target is drawn from ``targets`` with ``np_random``; each token is executed on the
    stack at once.

    Action space:
        ``Discrete(400)`` (2D) or ``Discrete(6635)`` (3D): a :func:`csgnet.vocabulary` index; ``$``
        (the last index) stops. ``info["action_mask"]`` ``(V,) int8`` and :meth:`action_masks` mark the
        tokens after which a valid program can still be completed.
    Observation space:
        ``Dict``: ``target`` ``(64, 64[, 64]) bool``; ``stack`` ``(K, 64, 64[, 64]) bool``, the top
        ``K = stack_size`` stack slots (top first; :func:`csgnet.renderer.stack_trace` of the tokens);
        ``steps`` ``Discrete(max_length + 1)`` (omitted with ``observe_steps=False``).
    Reward:
        0 until the end; then ``clip(1 - CD / (64 sqrt 2), 0, 1) ** gamma`` (``"chamfer"``, 2D) or
        ``IoU ** gamma`` (``"iou"``), 1 for a perfect program; 0 for an invalid one (0.0204 with the
        chamfer reward and ``invalid_reward="reference"``). The final info holds ``"program"``,
        ``"valid"`` and ``"iou"``.
    Episode end:
        Terminated at ``$``, at ``max_length`` tokens, or (``invalid_action="terminate"``) at the first
        token after which no valid program can be completed; never truncated.

    Args:
        dim: 2 or 3.
        targets: the target source (:func:`envs.targets.as_target_source`): None for synthetic programs,
            a folder of PNGs, an array of shapes, or a source object.
        max_length: most tokens per program (13 in 2D, 7 in 3D).
        stack_size: stack slots observed (default ``(max_length + 1) // 2``).
        reward: ``"chamfer"`` (2D default) or ``"iou"`` (3D default).
        gamma: the reward exponent (20 for chamfer, 1 for IoU).
        invalid_reward: ``"zero"`` or ``"reference"`` (0.0204 with the chamfer reward).
        invalid_action: ``"terminate"`` or ``"continue"``.
        observe_steps: include ``"steps"`` in the observation.
        render_mode: None or ``"rgb_array"``.
        render_scale: pixels per canvas pixel in rendered frames.
        device: torch device of the stack machine.

    Example:
        >>> import csgnet
        >>> env = CSGEnv(targets=csgnet.render(["c(32,32,16)"]))
        >>> obs, info = env.reset(seed=0)
        >>> obs["stack"].shape
        (7, 64, 64)
        >>> for token in csgnet.vocabulary(2).encode("c(32,32,16)") + [399]:
        ...     obs, reward, terminated, truncated, info = env.step(token)
        >>> reward, terminated, info["program"]
        (1.0, True, 'c(32,32,16)')
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}

    def __init__(self, dim: int = 2, targets=None, max_length: int | None = None, stack_size: int | None = None,
                 reward: str | None = None, gamma: float | None = None, invalid_reward: str = "zero",
                 invalid_action: str = "terminate", observe_steps: bool = True, render_mode: str | None = None,
                 render_scale: int = 4, device=None):
        self.config = CSGConfig.build(dim, max_length, stack_size, reward, gamma, invalid_reward, invalid_action,
                                      observe_steps, render_scale)
        self.render_mode = check_render_mode(render_mode, self.metadata)
        self.targets = as_target_source(targets, self.config.dim, self.config.max_length)
        self._episodes = _Episodes(1, self.config, device)
        self.action_space = spaces.Discrete(self._episodes.V)
        self.observation_space = self.config.observation_space()
        self._started = False

    def _obs(self) -> dict:
        obs = self._episodes.observe()
        out = {"target": obs["target"][0], "stack": obs["stack"][0]}
        if "steps" in obs:
            out["steps"] = np.int64(obs["steps"][0])
        return out

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        target = self.targets.sample(self.np_random)
        self._episodes.begin(np.zeros(1, dtype=np.int64), [target])
        self._started = True
        return self._obs(), _reset_info(target, self._episodes.masks()[0])

    def step(self, action):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        if not self.action_space.contains(action):
            raise ValueError(f"action must be a token index in [0, {self.action_space.n}), got {action!r}")
        ep = self._episodes
        ended, reward, valid, iou = ep.act(np.zeros(1, dtype=np.int64), np.array([int(action)]))
        info: dict[str, Any] = {"action_mask": ep.masks()[0].astype(np.int8)}
        if ended[0]:
            info.update(program=ep.program(0), valid=bool(valid[0]), iou=float(iou[0]))
        return self._obs(), float(reward[0]), bool(ended[0]), False, info

    def action_masks(self) -> np.ndarray:
        """``(V,) bool``: the tokens after which a valid program can still be completed."""
        return self._episodes.masks()[0]

    def render(self):
        return self._episodes.frames()[0] if can_render(self) else None

    @property
    def program(self) -> str:
        """The program written so far (text)."""
        return self._episodes.program(0)


class CSGVectorEnv(VectorEnv):
    """``num_envs`` CSG episodes stepped as one batch (``gymnasium.make_vec("CSG2D-v0", num_envs=N)``).

    Equivalent, step for step, to ``gymnasium.vector.SyncVectorEnv`` over ``num_envs`` :class:`CSGEnv`
    with the same arguments: the same autoreset (next step), the same seeding (sub-environment ``i``
    of ``reset(seed=s)`` uses seed ``s + i`` and keeps its own generator across autoresets), the same
    observations, rewards and infos. The difference is speed: one stack machine executes the tokens of
    all episodes and one reward call scores all episodes that end at a step.

    Args:
        num_envs: the batch size.
        **kwargs: as :class:`CSGEnv`.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, dim: int = 2, targets=None, max_length: int | None = None,
                 stack_size: int | None = None, reward: str | None = None, gamma: float | None = None,
                 invalid_reward: str = "zero", invalid_action: str = "terminate", observe_steps: bool = True,
                 render_mode: str | None = None, render_scale: int = 4, device=None):
        self.num_envs = check_int("num_envs", num_envs)
        self.config = CSGConfig.build(dim, max_length, stack_size, reward, gamma, invalid_reward, invalid_action,
                                      observe_steps, render_scale)
        self.render_mode = check_render_mode(render_mode, self.metadata)
        self.targets = as_target_source(targets, self.config.dim, self.config.max_length)
        self._episodes = _Episodes(self.num_envs, self.config, device)
        self.single_action_space = spaces.Discrete(self._episodes.V)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.single_observation_space = self.config.observation_space()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._prev_done = np.zeros(self.num_envs, dtype=bool)
        self._started = False

    def _seeds(self, seed) -> list:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (int, np.integer)):
            return [int(seed) + i for i in range(self.num_envs)]
        seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(f"seed must be an int or {self.num_envs} seeds, got {len(seeds)}")
        return seeds

    def _begin(self, rows: np.ndarray) -> list[Target]:
        targets = [self.targets.sample(self._rngs[i]) for i in rows]
        self._episodes.begin(rows, targets)
        return targets

    def reset(self, *, seed=None, options: dict | None = None):
        seeds = self._seeds(seed)
        super().reset(seed=seed if isinstance(seed, (int, np.integer)) else None)
        for i, s in enumerate(seeds):
            if s is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(s)
        rows = np.arange(self.num_envs)
        targets = self._begin(rows)
        self._prev_done[:] = False
        self._started = True
        infos: dict = {}
        self._reset_infos(infos, rows, targets, self._episodes.masks())
        return self._episodes.observe(), infos

    def step(self, actions):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs,):
            raise ValueError(f"actions must have shape ({self.num_envs},), got {actions.shape}")
        ep = self._episodes
        restart = np.flatnonzero(self._prev_done)
        act = np.flatnonzero(~self._prev_done)
        rewards = np.zeros(self.num_envs, dtype=np.float64)
        terminated = np.zeros(self.num_envs, dtype=bool)
        ended, r, valid, iou = ep.act(act, actions[act])
        rewards[act] = r
        terminated[act] = ended
        targets = self._begin(restart)
        masks = ep.masks()
        infos: dict = {}
        # the infos SyncVectorEnv would assemble from the sub-environments (same keys, dtypes and masks)
        if len(act):
            _put(infos, "action_mask", act, masks[act].astype(np.int8), self.num_envs)
        fin = act[ended]
        if len(fin):
            _put(infos, "program", fin, np.array([ep.program(i) for i in fin], dtype=object), self.num_envs)
            _put(infos, "valid", fin, valid, self.num_envs)
            _put(infos, "iou", fin, iou, self.num_envs)
        self._reset_infos(infos, restart, targets, masks)
        self._prev_done = terminated.copy()
        return ep.observe(), rewards, terminated, np.zeros(self.num_envs, dtype=bool), infos

    def _reset_infos(self, infos: dict, rows: np.ndarray, targets: list[Target], masks: np.ndarray) -> None:
        if len(rows) == 0:
            return
        _put(infos, "action_mask", rows, masks[rows].astype(np.int8), self.num_envs)
        _put(infos, "target_index", rows, np.array([t.index for t in targets], dtype=np.int64), self.num_envs)
        have = [k for k, t in enumerate(targets) if t.program is not None]
        if have:
            _put(infos, "target_program", rows[have], np.array([targets[k].program for k in have], dtype=object),
                 self.num_envs)

    def action_masks(self) -> np.ndarray:
        """``(num_envs, V) bool``: per episode, the tokens that keep its program completable."""
        return self._episodes.masks()

    def render(self):
        return self._episodes.frames() if can_render(self) else None


def _put(infos: dict, key: str, rows: np.ndarray, values: np.ndarray, n: int) -> None:
    """Set ``infos[key][rows] = values`` and the mask ``infos['_' + key]``, creating both as
    ``VectorEnv._add_info`` does (zeros of the values' dtype, or an object array of None)."""
    if key not in infos:
        if values.dtype == object:
            infos[key] = np.full(n, None, dtype=object)
        else:
            infos[key] = np.zeros((n,) + values.shape[1:], dtype=values.dtype)
        infos["_" + key] = np.zeros(n, dtype=bool)
    infos[key][rows] = values
    infos["_" + key][rows] = True
