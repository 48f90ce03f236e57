"""Every environment this package registers, checked the same way.

The ids are read from ``gymnasium.registry`` (every entry point in ``envs.``), so a new environment
is checked here as soon as it is registered in ``envs/__init__.py``:

* :func:`gymnasium.utils.env_checker.check_env` without warnings, with and without ``render_mode``;
* seeding: two instances reset with the same seed and given the same actions match step for step
  (:func:`gymnasium.utils.env_match.check_environments_match`, renders included);
* the package's boundary: making and stepping them imports no model, training or Lightning code;
* the vector environment (``gymnasium.make_vec``): its observations lie in its spaces, runs with the
  same seeds are identical, and an id with a ``vector_entry_point`` behaves exactly like
  ``SyncVectorEnv`` over the single environment.
"""

import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence
from gymnasium.utils.env_match import check_environments_match
from gymnasium.vector import SyncVectorEnv

import envs  # noqa: F401  (registers the environments)

ENV_IDS = sorted(env_id for env_id, spec in gym.registry.items()
                 if isinstance(spec.entry_point, str) and spec.entry_point.startswith("envs."))
VECTOR_IDS = [env_id for env_id in ENV_IDS if gym.spec(env_id).vector_entry_point is not None]
NUM_ENVS = 3
ROOT = Path(__file__).resolve().parents[2]


def test_the_package_registers_its_environments():
    assert {"CSG2D-v0", "CSG3D-v0", "ShapeAssembly-v0"} <= set(ENV_IDS)
    assert "CSG2D-v0" in VECTOR_IDS and "CSG3D-v0" in VECTOR_IDS


def test_environments_import_no_models_training_or_lightning():
    code = (
        "import sys, gymnasium as gym, envs\n"
        f"for env_id in {ENV_IDS!r}:\n"
        "    env = gym.make(env_id)\n"
        "    env.reset(seed=0)\n"
        "    env.step(env.action_space.sample())\n"
        "bad = sorted(m for m in sys.modules if m.startswith(('csgnet.models', 'csgnet.train', 'lightning',\n"
        "                                                   'pytorch_lightning')) or '.lit' in m)\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True, timeout=300)


@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_without_warnings(env_id, render_mode):
    env = gym.make(env_id, render_mode=render_mode)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    env.close()


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_same_seed_same_episodes(env_id):
    for seed in (0, 7):
        a = gym.make(env_id, render_mode="rgb_array")
        b = gym.make(env_id, render_mode="rgb_array")
        check_environments_match(a, b, num_steps=20, seed=seed)
        a.close()
        b.close()


def _rollout(env_id, steps=8, seed=5, **kwargs):
    """Reset and step a vector environment with seeded random actions; every result, in order."""
    vec = gym.make_vec(env_id, num_envs=NUM_ENVS, **kwargs)
    vec.action_space.seed(seed)
    out = [vec.reset(seed=seed)]
    assert vec.observation_space.contains(out[0][0])
    for _ in range(steps):
        actions = vec.action_space.sample()
        out.append(vec.step(actions))
        obs, rewards, terminated, truncated, _ = out[-1]
        assert vec.observation_space.contains(obs)
        assert rewards.shape == terminated.shape == truncated.shape == (NUM_ENVS,)
    vec.close()
    return out


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_vector_env_is_deterministic(env_id):
    assert data_equivalence(_rollout(env_id), _rollout(env_id))


@pytest.mark.parametrize("env_id", VECTOR_IDS)
def test_vector_entry_point_equals_sync_vector_env(env_id):
    vec = gym.make_vec(env_id, num_envs=NUM_ENVS, vectorization_mode="vector_entry_point")
    sync = SyncVectorEnv([lambda: gym.make(env_id) for _ in range(NUM_ENVS)])
    assert vec.single_observation_space == sync.single_observation_space
    assert vec.single_action_space == sync.single_action_space
    assert data_equivalence(vec.reset(seed=3), sync.reset(seed=3))
    vec.action_space.seed(3)
    for t in range(12):
        actions = vec.action_space.sample()
        assert data_equivalence(vec.step(actions), sync.step(actions)), t
    vec.close()
    sync.close()
