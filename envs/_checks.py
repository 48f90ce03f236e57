"""Argument checks and the render guard shared by the environments."""

from __future__ import annotations

import gymnasium as gym
import numpy as np


def check_dim(dim) -> int:
    """``dim`` as an int, or a ``ValueError`` if it is not 2 or 3."""
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    return int(dim)


def check_int(name: str, value, minimum: int = 1) -> int:
    """``value`` as an int, or a ``ValueError`` naming ``name`` if it is not an int >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        what = "a positive int" if minimum == 1 else f"an int >= {minimum}"
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return int(value)


def check_render_mode(render_mode, metadata: dict):
    """``render_mode`` if it is None or one of ``metadata["render_modes"]``, else a ``ValueError``."""
    modes = metadata["render_modes"]
    if render_mode is not None and render_mode not in modes:
        raise ValueError(f"render_mode must be None or one of {modes}, got {render_mode!r}")
    return render_mode


def can_render(env) -> bool:
    """Whether ``env.render()`` has a frame to draw: False (with a warning) without
    ``render_mode="rgb_array"``; a ``RuntimeError`` before the first ``reset()`` (``env._started``)."""
    if env.render_mode != "rgb_array":
        gym.logger.warn("render() needs render_mode='rgb_array' (e.g. gymnasium.make(..., render_mode='rgb_array'))")
        return False
    if not env._started:
        raise RuntimeError("call reset() before render()")
    return True
