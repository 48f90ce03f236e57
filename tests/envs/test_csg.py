"""The CSG environments: Gymnasium API, rewards, stack observations, masks, the batched vector env."""

import math
import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import SyncVectorEnv

import csgnet
import envs  # noqa: F401  (registers the environments)
from csgnet import metrics
from csgnet.renderer import stack_trace
from envs.csg import CSGEnv, CSGVectorEnv
from envs.targets import ArrayTargets, SyntheticTargets

PROGRAMS_2D = [
    "c(32,32,16)",
    "c(32,32,24)s(32,32,16)-",
    "s(24,24,12)t(40,40,16)+c(32,32,8)-",
    "c(16,16,12)c(48,48,12)+s(32,32,20)*",
]
PROGRAMS_3D = [
    "sp(32,32,32,16)",
    "cu(32,32,32,24)sp(32,32,32,16)-",
    "cy(24,24,32,12,24)sp(40,40,32,12)+",
]
V2, V3 = csgnet.vocabulary(2), csgnet.vocabulary(3)


def _array_targets(programs, dim):
    return ArrayTargets(csgnet.render(programs, dim), programs=programs)


def _play(env, tokens):
    """Step ``tokens`` (indices); returns the list of step results."""
    return [env.step(int(a)) for a in tokens]


@pytest.fixture(scope="module")
def small_2d():
    return SyntheticTargets(2, size=6)


@pytest.fixture(scope="module")
def small_3d():
    return SyntheticTargets(3, lengths=[3, 5], size=3)


# ------------------------------------------------------------------------------------------------
# spaces and seeding (tests/envs/test_registered.py runs check_env on every registered id)

def test_registered_ids_and_spaces():
    env = gym.make("CSG2D-v0", targets=_array_targets(PROGRAMS_2D, 2))
    assert env.action_space.n == 400 and V2.stop == 399
    obs = env.observation_space
    assert obs["target"].shape == (64, 64) and obs["target"].dtype == np.bool_
    assert obs["stack"].shape == (7, 64, 64)  # (13 + 1) // 2
    assert obs["steps"].n == 14
    env3 = gym.make("CSG3D-v0", targets=_array_targets(PROGRAMS_3D, 3))
    assert env3.observation_space["stack"].shape == (4, 64, 64, 64)
    assert env3.observation_space["steps"].n == 8
    assert env3.action_space.n == 6635 and V3.stop == 6634
    assert "steps" not in gym.make("CSG2D-v0", targets=_array_targets(PROGRAMS_2D, 2),
                                   observe_steps=False).observation_space.spaces


def test_seeding_chooses_the_target():
    env = CSGEnv(targets=_array_targets(PROGRAMS_2D, 2))
    seen = []
    for seed in range(12):
        o1, i1 = env.reset(seed=seed)
        o2, i2 = env.reset(seed=seed)
        assert i1["target_index"] == i2["target_index"]
        np.testing.assert_array_equal(o1["target"], o2["target"])
        np.testing.assert_array_equal(o1["target"], csgnet.render(PROGRAMS_2D[i1["target_index"]])[0])
        seen.append(i1["target_index"])
    assert len(set(seen)) > 1


# ------------------------------------------------------------------------------------------------
# rewards

@pytest.mark.parametrize("dim", [2, 3])
def test_perfect_program_scores_one(dim):
    programs = PROGRAMS_2D if dim == 2 else PROGRAMS_3D
    vocab = csgnet.vocabulary(dim)
    env = CSGEnv(dim=dim, targets=_array_targets(programs, dim))
    for seed in range(6):
        _, info = env.reset(seed=seed)
        tokens = vocab.encode(info["target_program"])
        results = _play(env, tokens + [vocab.stop])
        assert [r[1] for r in results[:-1]] == [0.0] * len(tokens)
        assert not any(r[2] for r in results[:-1])
        _, reward, terminated, truncated, info = results[-1]
        assert (reward, terminated, truncated) == (1.0, True, False)
        assert info["valid"] and info["iou"] == 1.0
        assert info["program"] == csgnet.parse(info["program"], dim).text()


def test_perfect_program_at_max_length_ends_without_stop():
    prog = "c(32,32,24)s(32,32,16)-"
    env = CSGEnv(targets=_array_targets([prog], 2), max_length=3)
    env.reset(seed=0)
    results = _play(env, V2.encode(prog))
    assert [r[2] for r in results] == [False, False, True]
    assert results[-1][1] == 1.0 and results[-1][4]["valid"]


@pytest.mark.parametrize("invalid_action", ["terminate", "continue"])
def test_invalid_program_scores_zero(invalid_action):
    env = CSGEnv(targets=_array_targets(PROGRAMS_2D, 2), invalid_action=invalid_action)
    env.reset(seed=0)
    # an operator on an empty stack: the program can never be valid
    _, reward, terminated, _, info = env.step(V2.op_index("+"))
    if invalid_action == "terminate":
        assert (reward, terminated) == (0.0, True) and info["valid"] is False
    else:
        assert (reward, terminated) == (0.0, False)
        _, reward, terminated, _, info = env.step(V2.index("c(32,32,16)"))
        assert not terminated
        _, reward, terminated, _, info = env.step(V2.stop)
        assert (reward, terminated) == (0.0, True) and info["valid"] is False
    # two shapes left on the stack at the stop token
    env.reset(seed=0)
    _play(env, [V2.index("c(32,32,16)"), V2.index("s(32,32,16)")])
    _, reward, terminated, _, info = env.step(V2.stop)
    assert (reward, terminated, info["valid"]) == (0.0, True, False)
    # a stop token on the empty program
    env.reset(seed=0)
    _, reward, terminated, _, info = env.step(V2.stop)
    assert (reward, terminated, info["valid"]) == (0.0, True, False)
    assert info["program"] == ""


def test_reference_invalid_reward():
    env = CSGEnv(targets=_array_targets(PROGRAMS_2D, 2), invalid_reward="reference")
    env.reset(seed=0)
    _, reward, terminated, _, _ = env.step(V2.stop)
    assert terminated
    assert reward == pytest.approx((1 - 16 / (64 * math.sqrt(2))) ** 20) and 0.0204 < reward < 0.0205
    env3 = CSGEnv(dim=3, targets=_array_targets(PROGRAMS_3D, 3), invalid_reward="reference")
    env3.reset(seed=0)
    assert env3.step(V3.stop)[1] == 0.0  # the IoU reward of an empty prediction is 0 in the reference too


def test_imperfect_program_reward_matches_metrics():
    target = "c(32,32,24)s(32,32,16)-"
    env = CSGEnv(targets=_array_targets([target], 2))
    iou_env = CSGEnv(targets=_array_targets([target], 2), reward="iou", gamma=3)
    guess = "c(32,32,24)s(32,32,12)-"
    pred, tgt = csgnet.render(guess)[0], csgnet.render(target)[0]
    expected = metrics.reward(pred, tgt, gamma=20)
    iou = (pred & tgt).sum() / (pred | tgt).sum()
    assert 0.0 < expected < 1.0
    for e, want in ((env, expected), (iou_env, iou ** 3)):
        e.reset(seed=0)
        *_, last = _play(e, V2.encode(guess) + [V2.stop])
        assert last[1] == pytest.approx(want, rel=1e-12)
        assert last[4]["iou"] == pytest.approx(iou, rel=1e-12)


def test_empty_valid_program_scores_zero():
    # a valid program whose result is empty: the chamfer reward of an empty rendering is 0
    env = CSGEnv(targets=_array_targets(PROGRAMS_2D, 2))
    env.reset(seed=0)
    *_, last = _play(env, V2.encode("c(32,32,8)c(32,32,16)-") + [V2.stop])
    assert last[4]["valid"] and last[1] == 0.0


def test_bad_arguments():
    with pytest.raises(ValueError, match="2D images only"):
        CSGEnv(dim=3, reward="chamfer", targets=_array_targets(PROGRAMS_3D, 3))
    with pytest.raises(ValueError, match="dim must be 2 or 3"):
        CSGEnv(dim=4)
    with pytest.raises(ValueError, match="invalid_action"):
        CSGEnv(invalid_action="ignore", targets=_array_targets(PROGRAMS_2D, 2))
    with pytest.raises(ValueError, match="holds 3D shapes"):
        CSGEnv(dim=2, targets=_array_targets(PROGRAMS_3D, 3))
    env = CSGEnv(targets=_array_targets(PROGRAMS_2D, 2))
    with pytest.raises(RuntimeError, match="reset"):
        env.step(0)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"\[0, 400\)"):
        env.step(400)
    env.step(V2.stop)
    with pytest.raises(RuntimeError, match="ended"):
        env.step(0)
    with pytest.raises(ValueError, match="max_length must be a positive int, got 0"):
        CSGEnv(max_length=0)
    with pytest.raises(ValueError, match="num_envs must be a positive int"):
        CSGVectorEnv(0)
    with pytest.raises(ValueError, match="render_mode must be None or one of"):
        CSGVectorEnv(2, render_mode="human")
    with pytest.warns(UserWarning, match="render_mode='rgb_array'"):
        assert env.render() is None
    with pytest.raises(RuntimeError, match="reset"):
        CSGVectorEnv(2, targets=_array_targets(PROGRAMS_2D, 2), render_mode="rgb_array").render()


# ------------------------------------------------------------------------------------------------
# observations and masks

def _random_tokens(rng, vocab, n, legal_only):
    """Random token sequences from the mask automaton (or anything with ``legal_only=False``)."""
    out = []
    for _ in range(n):
        depth, toks = 0, []
        for t in range(13):
            if legal_only:
                choices = []
                if depth <= 13 - t - 1:
                    choices.append("d")
                if depth >= 2:
                    choices.append("o")
                kind = rng.choice(choices)
            else:
                kind = rng.choice(["d", "o"])
            if kind == "d":
                toks.append(int(rng.integers(vocab.stop - 3)))
                depth += 1
            else:
                toks.append(int(rng.integers(vocab.stop - 3, vocab.stop)))
                depth -= 1
        out.append(toks)
    return out


@pytest.mark.parametrize("invalid_action", ["terminate", "continue"])
def test_stack_observation_equals_stack_trace(invalid_action):
    rng = np.random.default_rng(1)
    env = CSGEnv(targets=_array_targets(PROGRAMS_2D, 2), invalid_action=invalid_action)
    K = env.config.stack_size
    for legal_only in (True, False):
        for toks in _random_tokens(rng, V2, 6, legal_only):
            obs, _ = env.reset(seed=0)
            trace = stack_trace(torch.tensor([toks]), 2, k=K).numpy()[:, 0]  # (T+1, K, 64, 64)
            np.testing.assert_array_equal(obs["stack"], trace[0])
            for t, a in enumerate(toks, start=1):
                obs, _, terminated, _, info = env.step(a)
                np.testing.assert_array_equal(obs["stack"], trace[t])
                assert obs["steps"] == t
                if terminated:
                    break
            # the verdict is the language's (an early end is an illegal token)
            valid = t == len(toks) and csgnet.is_valid(V2.decode(toks))
            assert terminated and info["valid"] == valid
            result = csgnet.render(V2.decode(toks[:t]))[0]  # empty unless valid
            want_iou = (result & obs["target"]).sum() / (result | obs["target"]).sum()
            assert info["iou"] == pytest.approx(want_iou, abs=0) and (valid or info["iou"] == 0.0)


def test_stack_observation_3d():
    env = CSGEnv(dim=3, targets=_array_targets(PROGRAMS_3D, 3))
    toks = V3.encode("cu(32,32,32,24)sp(32,32,32,16)-cy(24,24,32,12,24)+")
    trace = stack_trace(torch.tensor([toks]), 3, k=4).numpy()[:, 0]
    env.reset(seed=0)
    for t, a in enumerate(toks, start=1):
        obs = env.step(a)[0]
        np.testing.assert_array_equal(obs["stack"], trace[t])
    assert obs["stack"][0].any() and not obs["stack"][1:].any()


def test_action_mask_keeps_programs_completable():
    rng = np.random.default_rng(2)
    for max_length in (1, 2, 5, 13):
        env = CSGEnv(targets=_array_targets(PROGRAMS_2D, 2), max_length=max_length)
        for _ in range(20):
            _, info = env.reset(seed=int(rng.integers(1000)))
            steps, terminated = 0, False
            while not terminated:
                mask = info["action_mask"].astype(bool)
                np.testing.assert_array_equal(mask, env.action_masks())
                assert mask.any()
                _, reward, terminated, _, info = env.step(int(rng.choice(np.flatnonzero(mask))))
                steps += 1
            assert info["valid"] and steps <= max_length + 1 and not info["action_mask"].any()


def test_masked_out_action_terminates_with_zero():
    env = CSGEnv(targets=_array_targets(PROGRAMS_2D, 2), max_length=3)
    env.reset(seed=0)
    _play(env, [V2.index("c(32,32,16)"), V2.index("c(32,32,8)")])
    assert not env.action_masks()[:396].any()  # a third draw cannot be combined any more
    _, reward, terminated, _, info = env.step(V2.index("s(32,32,8)"))
    assert (reward, terminated, info["valid"]) == (0.0, True, False)


def test_render_shows_target_and_current_shape():
    env = CSGEnv(targets=_array_targets(["c(32,32,24)s(32,32,16)-"], 2), render_mode="rgb_array", render_scale=2)
    obs, _ = env.reset(seed=0)
    env.step(V2.index("s(24,24,8)"))
    frame = env.render()
    assert frame.shape == (128, 260, 3) and frame.dtype == np.uint8
    left, right = frame[::2, 0:128:2], frame[::2, 132::2]
    white = (left == 255).all(axis=-1)
    np.testing.assert_array_equal(~white, obs["target"])
    np.testing.assert_array_equal(~(right == 255).all(axis=-1), csgnet.render("s(24,24,8)")[0])
    env.step(V2.op_index("+"))  # invalid: ends, and the current shape is the (empty) result
    assert (env.render()[:, 132:] == 255).all()
    env.reset(seed=0)
    _play(env, [V2.index("s(24,24,8)"), V2.index("c(32,32,8)")])
    assert not (env.render()[:, 132:] == 255).all()  # the top of the stack while the episode runs
    env.step(V2.stop)  # two shapes left: invalid, the result is empty although the stack is not
    assert (env.render()[:, 132:] == 255).all()


# ------------------------------------------------------------------------------------------------
# the batched vector environment

@pytest.mark.parametrize("dim, invalid_action", [(2, "terminate"), (2, "continue"), (3, "terminate")])
def test_vector_env_equals_single_envs(dim, invalid_action, small_2d, small_3d):
    n = 5
    kwargs = dict(targets=small_2d if dim == 2 else small_3d, invalid_action=invalid_action,
                  max_length=7 if dim == 2 else 5, render_mode="rgb_array", render_scale=1)
    env_id = f"CSG{dim}D-v0"
    vec = gym.make_vec(env_id, num_envs=n, **kwargs)
    assert isinstance(vec.unwrapped, CSGVectorEnv)
    sync = SyncVectorEnv([lambda: gym.make(env_id, **kwargs) for _ in range(n)])
    assert vec.single_observation_space == sync.single_observation_space
    assert vec.observation_space == sync.observation_space
    r1, r2 = vec.reset(seed=11), sync.reset(seed=11)
    assert data_equivalence(r1, r2)
    rng = np.random.default_rng(3)
    vocab = csgnet.vocabulary(dim)
    ends = 0
    for t in range(25 if dim == 2 else 12):
        masks = vec.unwrapped.action_masks()
        actions = np.array([rng.choice(np.flatnonzero(m)) if m.any() and rng.random() < 0.85
                            else rng.integers(vocab.size) for m in masks])
        s1, s2 = vec.step(actions), sync.step(actions)
        for name, a, b in zip(("obs", "reward", "terminated", "truncated", "info"), s1, s2):
            assert data_equivalence(a, b), (t, name)
        assert data_equivalence(vec.render(), sync.render()), t  # running and ended episodes alike
        ends += int(s1[2].sum())
    assert ends >= n  # episodes ended and were reset along the way
    vec.close()
    sync.close()


def test_vector_env_seed_list_and_render(small_2d):
    vec = CSGVectorEnv(3, targets=small_2d, render_mode="rgb_array")
    obs, info = vec.reset(seed=[4, 4, 9])
    np.testing.assert_array_equal(obs["target"][0], obs["target"][1])
    assert info["_target_program"].all()
    frames = vec.render()
    assert len(frames) == 3 and frames[0].shape == (256, 520, 3)
    with pytest.raises(ValueError, match="shape \\(3,\\)"):
        vec.step(np.zeros(2, dtype=np.int64))
