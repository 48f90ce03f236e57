"""ShapeAssembly program synthesis as a Gymnasium environment, one program line per step.

``ShapeAssembly-v0`` is :class:`ShapeAssemblyEnv`; its targets come from :class:`CorpusTargets`,
:class:`ProgramTargets` or :class:`CloudTargets`. ``docs/envs.md`` explains the action encoding, the
reward and the treatment of invalid lines.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Sequence

import cv2
import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces

from shapeprog import ParseError, corpus, execute, metrics, parse
from shapeprog.lang import AXES, FACES, Attach, Block, Cuboid, Program, Reflect, Squeeze, Translate, to_text
from shapeprog.picture import camera  # the view of shapeprog.picture.render_png
from shapeprog.sampling import sample_surface

from ._checks import can_render, check_int, check_render_mode

__all__ = [
    "COMMANDS",
    "AssemblyTarget",
    "CorpusTargets",
    "ProgramTargets",
    "CloudTargets",
    "ShapeAssemblyEnv",
]

COMMANDS = ("stop", "cuboid", "attach", "squeeze", "reflect", "translate")
STOP, CUBOID, ATTACH, SQUEEZE, REFLECT, TRANSLATE = range(6)
REWARDS = ("fscore", "chamfer")
INVALID_ACTIONS = ("ignore", "terminate")


# ---------------------------------------------------------------------------------------------
# target sources


@dataclass(frozen=True)
class AssemblyTarget:
    """One episode's target: cuboids to sample, or a point cloud, and the root bounding box.

    Attributes:
        bbox: ``(3,) float`` root bounding box extents; the shape is centred at the origin.
        corners: ``(L, 8, 3) float`` tensor of the target's cuboids (sampled by the environment), or None.
        points: ``(P, 3) float32`` array of surface points (used as they are), or None.
        index: the target's index in its source.
        name: a readable name (``"chair/173"``).
    """

    bbox: np.ndarray
    corners: torch.Tensor | None = None
    points: np.ndarray | None = None
    index: int = 0
    name: str = ""


def _program_target(program, index: int, name: str) -> AssemblyTarget:
    shape = execute(program)
    if len(shape) == 0:
        raise ValueError(f"{name}: the program has no leaf cuboid")
    return AssemblyTarget(bbox=shape.root_dims.detach().numpy().astype(np.float64),
                          corners=shape.corners.detach(), index=index, name=name)


class CorpusTargets:
    """Programs of the vendored PartNet corpus (:mod:`shapeprog.corpus`), one drawn uniformly per episode.

    Args:
        categories: corpus categories (chair, table, storage).
        split: ``"train"``, ``"val"`` or ``"all"``.

    A program that fails to parse is reported in a ``UserWarning`` and another one is drawn.
    """

    def __init__(self, categories: Sequence[str] = ("chair", "table", "storage"), split: str = "train"):
        if isinstance(categories, str):
            categories = (categories,)
        for c in categories:
            if c not in corpus.CATEGORIES:
                raise ValueError(f"unknown category {c!r}; expected some of {', '.join(corpus.CATEGORIES)}")
        if split not in corpus.SPLITS:
            raise ValueError(f"unknown split {split!r}; expected one of {', '.join(corpus.SPLITS)}")
        self.categories, self.split = tuple(categories), split
        self._ids: list[tuple[str, int]] | None = None

    @property
    def ids(self) -> list[tuple[str, int]]:
        """``[(category, id), ...]`` of the split (read on first use)."""
        if self._ids is None:
            self._ids = [(c, i) for c in self.categories for i in corpus.ids(c, self.split)]
        return self._ids

    def __len__(self) -> int:
        return len(self.ids)

    def sample(self, rng: np.random.Generator) -> AssemblyTarget:
        for _ in range(100):
            k = int(rng.integers(len(self.ids)))
            cat, i = self.ids[k]
            name = f"{cat}/{i}"
            try:
                return _program_target(parse(corpus.read(cat, i), f"{name}.txt"), k, name)
            except (ParseError, ValueError) as e:
                warnings.warn(f"skipping corpus program {name}: {e}", UserWarning, stacklevel=2)
        raise RuntimeError("100 corpus programs in a row could not be used as targets")


class ProgramTargets:
    """Targets from given ShapeAssembly programs (texts or :class:`shapeprog.lang.Program`), executed once.

    Raises:
        shapeprog.ParseError: a text does not parse (named ``program <k>``).
        ValueError: a program has no leaf cuboid.
    """

    def __init__(self, programs: Sequence):
        progs = [parse(p, f"program {k}") if isinstance(p, str) else p for k, p in enumerate(programs)]
        if not progs:
            raise ValueError("ProgramTargets needs at least one program")
        self.targets = [_program_target(p, k, f"program {k}") for k, p in enumerate(progs)]

    def __len__(self) -> int:
        return len(self.targets)

    def sample(self, rng: np.random.Generator) -> AssemblyTarget:
        return self.targets[int(rng.integers(len(self.targets)))]


class CloudTargets:
    """Targets from point clouds ``(N, P, 3)``: each cloud is centred at its axis-aligned bounding box
    centre, whose extents become the root bounding box (the spec's F-score convention). Each cloud
    must have exactly the environment's ``n_points`` points."""

    def __init__(self, clouds):
        arr = np.asarray(clouds, dtype=np.float32)
        if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] < 2:
            raise ValueError(f"clouds must have shape (N, P, 3) with N >= 1 and P >= 2, got {arr.shape}")
        if not np.isfinite(arr).all():
            bad = np.flatnonzero(~np.isfinite(arr).reshape(arr.shape[0], -1).all(axis=1))
            raise ValueError(f"clouds {bad[:10].tolist()} contain NaN or infinite values")
        lo, hi = arr.min(axis=1, keepdims=True), arr.max(axis=1, keepdims=True)
        self.clouds = arr - (lo + hi) / 2
        self.extents = (hi - lo)[:, 0].astype(np.float64)
        if (self.extents <= 0).any(axis=1).any():
            bad = np.flatnonzero((self.extents <= 0).any(axis=1))
            raise ValueError(f"clouds {bad[:10].tolist()} are flat (zero extent along an axis)")

    def __len__(self) -> int:
        return self.clouds.shape[0]

    def sample(self, rng: np.random.Generator) -> AssemblyTarget:
        k = int(rng.integers(len(self)))
        return AssemblyTarget(bbox=self.extents[k].copy(), points=self.clouds[k].copy(), index=k, name=f"cloud {k}")


def _as_source(targets):
    if targets is None:
        return CorpusTargets()
    if hasattr(targets, "sample"):
        return targets
    if isinstance(targets, str):
        if targets in corpus.CATEGORIES:
            return CorpusTargets((targets,))
        return ProgramTargets([targets])
    if isinstance(targets, np.ndarray):
        return CloudTargets(targets)
    if isinstance(targets, (list, tuple)):
        return ProgramTargets(targets)
    raise TypeError(f"targets must be None, a corpus category, programs, clouds (N, P, 3) or a source, "
                    f"got {type(targets).__name__}")


# ---------------------------------------------------------------------------------------------
# the environment


def _short(v) -> float:
    """``v`` at float32 precision, as the float of its shortest decimal form (0.505, not 0.50499999523)."""
    return float(str(np.float32(v)))


class _Invalid(Exception):
    """An action that cannot become a program line (the message says why)."""


class ShapeAssemblyEnv(gym.Env):
    """Write a flat ShapeAssembly program, line by line, to match a target point cloud (``ShapeAssembly-v0``).

    Each episode's target is drawn from ``targets`` with ``np_random`` and sampled as ``n_points`` surface
    points; the program's first line, ``bbox = Cuboid(l, h, w, True)``, is given (the target's box).

    Action space:
        ``Dict`` encoding one line: ``command`` ``Discrete(6)`` (stop, Cuboid, attach, squeeze, reflect,
        translate), ``cuboids`` ``MultiDiscrete([M + 1] * 3)`` (0 = bbox, ``i`` = ``cube{i-1}``),
        ``params`` ``Box(0, 1, (6,), float32)``, ``aligned`` ``Discrete(2)``, ``face`` ``Discrete(6)``,
        ``axis`` ``Discrete(3)``, ``copies`` ``Discrete(max_copies)``; ``M = max_cuboids``.
    Observation space:
        ``Dict``: ``target`` ``(n_points, 3) float32`` cloud, ``bbox`` ``(3,) float32`` extents,
        ``cuboids`` ``(M, 8, 3) float32`` corners of the cuboids so far with their ``mask`` ``(M,) bool``,
        ``steps`` ``Discrete(max_lines + 1)``.
    Reward:
        The change of the current shape's score (F-score / 100, or minus the chamfer distance) after
        each valid line; ``-invalid_penalty`` for an invalid line, which is dropped (``info["error"]``
        names its line, command and fault).
    Episode end:
        Terminated by the stop command, after ``max_lines`` lines, or (``invalid_action="terminate"``)
        at an invalid line; never truncated. The final info holds ``"program"``.

    Args:
        targets: None (the corpus train split), a corpus category name, ShapeAssembly programs (texts or
            parsed), point clouds ``(N, n_points, 3)``, or a source with ``sample(rng)``.
        n_points: surface samples of the target and of the current shape.
        max_cuboids: M, the most cuboids (copies included) a program may create.
        max_lines: the most lines per episode (the stop command included).
        max_copies: the most copies one translate line may make.
        reward: ``"fscore"`` or ``"chamfer"``.
        invalid_action: ``"ignore"`` or ``"terminate"``.
        invalid_penalty: the (non-negative) cost of an invalid line.
        min_size: smallest cuboid extent, as a fraction of the bounding box.
        bound: half-width of the world cube that holds every target point and cuboid corner.
        render_mode: None or ``"rgb_array"``.
        render_size: the height of rendered frames (each panel is square).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, targets=None, n_points: int = 1024, max_cuboids: int = 16, max_lines: int = 24,
                 max_copies: int = 4, reward: str = "fscore", invalid_action: str = "ignore",
                 invalid_penalty: float = 0.1, min_size: float = 0.01, bound: float = 2.0,
                 render_mode: str | None = None, render_size: int = 256):
        self.n_points, self.max_cuboids = check_int("n_points", n_points, 2), check_int("max_cuboids", max_cuboids)
        self.max_lines, self.max_copies = check_int("max_lines", max_lines), check_int("max_copies", max_copies)
        self.render_size = check_int("render_size", render_size, 16)
        if reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
        if invalid_action not in INVALID_ACTIONS:
            raise ValueError(f"invalid_action must be one of {INVALID_ACTIONS}, got {invalid_action!r}")
        if not (np.isfinite(invalid_penalty) and invalid_penalty >= 0):
            raise ValueError(f"invalid_penalty must be a non-negative number, got {invalid_penalty!r}")
        if not 0 < min_size <= 1:
            raise ValueError(f"min_size must lie in (0, 1], got {min_size!r}")
        if not (np.isfinite(bound) and bound > 0):
            raise ValueError(f"bound must be a positive number, got {bound!r}")
        self.render_mode = check_render_mode(render_mode, self.metadata)
        self.reward_kind, self.invalid_action = reward, invalid_action
        self.invalid_penalty, self.min_size, self.bound = float(invalid_penalty), float(min_size), float(bound)
        self.targets = _as_source(targets)
        M = self.max_cuboids
        self.action_space = spaces.Dict({
            "command": spaces.Discrete(len(COMMANDS)),
            "cuboids": spaces.MultiDiscrete([M + 1] * 3),
            "params": spaces.Box(0.0, 1.0, (6,), dtype=np.float32),
            "aligned": spaces.Discrete(2),
            "face": spaces.Discrete(6),
            "axis": spaces.Discrete(3),
            "copies": spaces.Discrete(self.max_copies),
        })
        b = self.bound
        self.observation_space = spaces.Dict({
            "target": spaces.Box(-b, b, (self.n_points, 3), dtype=np.float32),
            "bbox": spaces.Box(0.0, 2 * b, (3,), dtype=np.float32),
            "cuboids": spaces.Box(-b, b, (M, 8, 3), dtype=np.float32),
            "mask": spaces.Box(0, 1, (M,), dtype=np.bool_),
            "steps": spaces.Discrete(self.max_lines + 1),
        })
        self._started = False

    # -------------------------------------------------------------------------------------------
    # state

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._gen = torch.Generator().manual_seed(int(self.np_random.integers(2**63 - 1)))
        target = self.targets.sample(self.np_random)
        bbox = np.asarray(target.bbox, dtype=np.float64).reshape(-1)
        if bbox.shape != (3,) or not np.isfinite(bbox).all() or (bbox <= 0).any() or (bbox > 2 * self.bound).any():
            raise ValueError(f"target {target.name}: the bounding box {bbox.tolist()} must be 3 extents in "
                             f"(0, {2 * self.bound}]")
        if target.points is not None:
            pts = torch.as_tensor(np.asarray(target.points, dtype=np.float32))
            if pts.shape != (self.n_points, 3):
                raise ValueError(f"target {target.name}: the cloud must have shape ({self.n_points}, 3), "
                                 f"got {tuple(pts.shape)}")
        else:
            pts, _ = sample_surface(target.corners.to(torch.float32), self.n_points, generator=self._gen)
        if not torch.isfinite(pts).all() or float(pts.abs().max()) > self.bound:
            raise ValueError(f"target {target.name}: points must lie in [-{self.bound}, {self.bound}]^3")
        self._target = target
        self._target_points = pts.contiguous()
        self._bbox = bbox
        self._bbox_line = Cuboid("bbox", *(_short(v) for v in bbox), True)
        self._lines: list = []
        self._count = 0  # cuboids created (copies included)
        self._corners = np.zeros((0, 8, 3), dtype=np.float32)
        self._points: torch.Tensor | None = None
        self._steps = 0
        self._done = False
        if self.reward_kind == "fscore":
            self._threshold = float(metrics.adaptive_threshold(self._target_points))
        self._score = self._score_of(None)
        self._started = True
        return self._obs(), {"target": target.name, "score": self._score}

    def _obs(self) -> dict:
        M = self.max_cuboids
        cub = np.zeros((M, 8, 3), dtype=np.float32)
        n = self._corners.shape[0]
        cub[:n] = self._corners
        mask = np.zeros(M, dtype=bool)
        mask[:n] = True
        return {
            "target": self._target_points.numpy().copy(),
            "bbox": self._bbox.astype(np.float32),
            "cuboids": cub,
            "mask": mask,
            "steps": np.int64(self._steps),
        }

    def _score_of(self, points: torch.Tensor | None) -> float:
        if self.reward_kind == "fscore":
            if points is None:
                return 0.0
            return metrics.fscore(points, self._target_points, self._threshold) / 100.0
        if points is None:
            points = torch.zeros(1, 3, dtype=torch.float32)
        return -float(metrics.chamfer(points, self._target_points))

    def _flat_program(self, lines: list):
        """The flat :class:`shapeprog.lang.Program` of the bbox line followed by ``lines``."""
        return Program((Block("Program_0", (self._bbox_line, *lines)),), flat=True)

    @property
    def program(self) -> str:
        """The program written so far (flat ShapeAssembly text, bbox line included)."""
        return to_text(self._flat_program(self._lines)) if self._started else ""

    # -------------------------------------------------------------------------------------------
    # actions

    def _name(self, index: int, what: str, allow_bbox: bool) -> str:
        index = int(index)
        if index == 0:
            if not allow_bbox:
                raise _Invalid(f"{what} cannot be bbox (index 0): bbox is never moved")
            return "bbox"
        if index > self._count:
            raise _Invalid(f"{what} index {index} names no cuboid ({self._count} exist)")
        return f"cube{index - 1}"

    def _line(self, action: dict):
        """The statement an action encodes and the cuboids it creates.

        The statement is built directly and held to the language's rules for a line of a block (the
        cuboids it names exist, bbox is never moved, nothing is attached or squeezed to itself; see
        :func:`shapeprog.lang.parse`) plus the environment's cuboid budget. Raises :class:`_Invalid`
        naming the action field at fault.
        """
        cmd = int(action["command"])
        c = [int(v) for v in np.asarray(action["cuboids"]).reshape(-1)]
        p = [_short(v) for v in np.asarray(action["params"]).reshape(-1)]
        if cmd == CUBOID:
            if self._count + 1 > self.max_cuboids:
                raise _Invalid(f"no cuboid slot left (max_cuboids={self.max_cuboids})")
            dims = [_short(b * max(v, self.min_size)) for b, v in zip(self._bbox, p[:3])]
            return Cuboid(f"cube{self._count}", *dims, bool(int(action["aligned"]))), 1
        if cmd == ATTACH:
            a = self._name(c[0], "the attached cuboid", False)
            b = self._name(c[1], "the target cuboid", True)
            if a == b:
                raise _Invalid(f"{a} cannot be attached to itself")
            return Attach(a, b, *p[:6]), 0
        if cmd == SQUEEZE:
            a = self._name(c[0], "the squeezed cuboid", False)
            b = self._name(c[1], "the first squeezing cuboid", True)
            cc = self._name(c[2], "the second squeezing cuboid", True)
            if a in (b, cc):
                raise _Invalid(f"{a} cannot be squeezed against itself")
            return Squeeze(a, b, cc, FACES[int(action["face"])], p[0], p[1]), 0
        if cmd in (REFLECT, TRANSLATE):
            a = self._name(c[0], "the copied cuboid", False)
            n = 1 if cmd == REFLECT else int(action["copies"]) + 1
            if self._count + n > self.max_cuboids:
                raise _Invalid(f"{n} more cuboid(s) exceed max_cuboids={self.max_cuboids}")
            axis = AXES[int(action["axis"])]
            return (Reflect(a, axis), 1) if cmd == REFLECT else (Translate(a, axis, n, p[0]), n)
        raise _Invalid(f"unknown command {cmd}")

    def _execute(self, lines: list) -> np.ndarray:
        """``(L, 8, 3) float32`` corners of the flat program of ``lines``; raises :class:`_Invalid`."""
        try:
            with torch.no_grad():
                shape = execute(self._flat_program(lines))
        except (ValueError, RuntimeError, IndexError, ZeroDivisionError) as e:
            raise _Invalid(f"the program does not execute: {e}") from None
        corners = shape.corners.numpy()
        if not np.isfinite(corners).all():
            raise _Invalid("the program's cuboids have non-finite corners")
        if corners.size and np.abs(corners).max() > self.bound:
            raise _Invalid(f"a cuboid corner leaves the world cube [-{self.bound}, {self.bound}]^3")
        return corners.astype(np.float32)

    def step(self, action):
        if not self._started:
            raise RuntimeError("call reset() before step()")
        if self._done:
            raise RuntimeError("step() called on an episode that has ended; call reset() first")
        if not self.action_space.contains(action):
            raise ValueError(f"action is not in the action space {self.action_space}: {action!r}")
        self._steps += 1
        info: dict[str, Any] = {"invalid": False}
        reward = 0.0
        terminated = int(action["command"]) == STOP
        if not terminated:
            try:
                line, created = self._line(action)
                corners = self._execute(self._lines + [line])
                if corners.shape[0] != self._count + created:
                    raise _Invalid(f"the program has {corners.shape[0]} cuboids, expected {self._count + created}")
                points = None
                if corners.shape[0]:
                    try:
                        points, _ = sample_surface(torch.from_numpy(corners), self.n_points, generator=self._gen)
                    except ValueError as e:
                        raise _Invalid(f"the cuboids cannot be sampled: {e}") from None
            except _Invalid as e:
                where = f"line {len(self._lines) + 2} ({COMMANDS[int(action['command'])]})"
                info.update(invalid=True, error=f"{where}: {e}")
                reward = -self.invalid_penalty
                terminated = self.invalid_action == "terminate"
            else:
                self._lines.append(line)
                self._count += created
                self._corners, self._points = corners, points
                score = self._score_of(points)
                reward = score - self._score
                self._score = score
        terminated = terminated or self._steps >= self.max_lines
        self._done = terminated
        info["score"] = self._score
        if terminated:
            info["program"] = self.program
        return self._obs(), float(reward), bool(terminated), False, info

    # -------------------------------------------------------------------------------------------
    # rendering

    def render(self):
        if not can_render(self):
            return None

        S = self.render_size
        right, up, _ = camera()
        scale = 0.9 * S / max(float(np.linalg.norm(self._bbox)), 1e-9)

        def project(p):  # (..., 3) -> (..., 2) integer pixel coordinates (x right, y down)
            p = np.asarray(p, dtype=np.float64)
            return np.stack([S / 2 + (p @ right) * scale, S / 2 - (p @ up) * scale], axis=-1).round().astype(np.int32)

        def dots(img, pts, color):
            xy = project(pts)
            ok = (xy >= 0).all(axis=1) & (xy < S).all(axis=1)
            img[xy[ok, 1], xy[ok, 0]] = color

        left = np.full((S, S, 3), 255, np.uint8)
        dots(left, self._target_points.numpy(), (90, 90, 90))
        right_img = np.full((S, S, 3), 255, np.uint8)
        if self._points is not None:
            dots(right_img, self._points.numpy(), (150, 190, 225))
        for box in project(self._corners):
            for i in range(8):
                for bit in (1, 2, 4):
                    if not i & bit:
                        cv2.line(right_img, tuple(int(v) for v in box[i]), tuple(int(v) for v in box[i | bit]),
                                 (31, 119, 180), 1, cv2.LINE_AA)
        gap = np.full((S, max(2, S // 128), 3), 200, np.uint8)
        return np.concatenate([left, gap, right_img], axis=1)
