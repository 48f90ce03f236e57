"""Gymnasium environments over the CSG and ShapeAssembly renderers (registrations only).

Importing this package registers (string entry points; nothing else is imported or computed):

* ``CSG2D-v0``: :class:`envs.csg.CSGEnv` with ``dim=2`` (vectorised: :class:`envs.csg.CSGVectorEnv`).
* ``CSG3D-v0``: the same with ``dim=3``.
* ``ShapeAssembly-v0``: :class:`envs.assembly.ShapeAssemblyEnv`.

Example:
    >>> import gymnasium as gym
    >>> import envs
    >>> env = gym.make("CSG2D-v0")
    >>> env.action_space
    Discrete(400)
    >>> vec = gym.make_vec("CSG2D-v0", num_envs=4)  # one batched stack machine for all four
"""

from gymnasium.envs.registration import register

__all__: list[str] = []

register(
    id="CSG2D-v0",
    entry_point="envs.csg:CSGEnv",
    vector_entry_point="envs.csg:CSGVectorEnv",
    kwargs={"dim": 2},
)
register(
    id="CSG3D-v0",
    entry_point="envs.csg:CSGEnv",
    vector_entry_point="envs.csg:CSGVectorEnv",
    kwargs={"dim": 3},
)
register(
    id="ShapeAssembly-v0",
    entry_point="envs.assembly:ShapeAssemblyEnv",
)
