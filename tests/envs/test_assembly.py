"""The ShapeAssembly environment: line encoding, rewards and invalid actions (the Gymnasium API checks of
every registered id are in tests/envs/test_registered.py)."""

import numpy as np
import pytest
import torch

from envs.assembly import CloudTargets, CorpusTargets, ShapeAssemblyEnv
from shapeprog import corpus, execute, parse, to_text
from shapeprog import metrics as sa_metrics
from shapeprog.lang import AXES, FACES, Attach, Cuboid, Reflect, Squeeze, Translate

EX0 = corpus.example_text("ex-0.txt").replace("),\n", ")\n")  # without the file's stray comma
BOX = "bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.5, 0.2, 0.5, True)\n" \
      "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"


def _action(command=0, cuboids=(0, 0, 0), params=(), aligned=1, face=0, axis=0, copies=0):
    p = np.zeros(6, np.float32)
    p[: len(params)] = params
    return {"command": command, "cuboids": np.array(cuboids, dtype=np.int64), "params": p,
            "aligned": aligned, "face": face, "axis": axis, "copies": copies}


def _actions_of(text, bbox):
    """The actions that write the flat program ``text`` line by line (cuboid names in creation order)."""
    prog = parse(text)
    index = {"bbox": 0}
    out = []
    for s in prog.root.statements[1:]:
        if isinstance(s, Cuboid):
            out.append(_action(1, params=np.array([s.l, s.h, s.w]) / bbox, aligned=int(s.aligned)))
            index[s.name] = len(index)
        elif isinstance(s, Attach):
            out.append(_action(2, (index[s.a], index[s.b], 0), (s.x1, s.y1, s.z1, s.x2, s.y2, s.z2)))
        elif isinstance(s, Squeeze):
            out.append(_action(3, (index[s.a], index[s.b], index[s.c]), (s.u, s.v), face=FACES.index(s.face)))
        else:
            n = 1 if isinstance(s, Reflect) else s.n
            cmd = 4 if isinstance(s, Reflect) else 5
            d = (s.d,) if isinstance(s, Translate) else ()
            out.append(_action(cmd, (index[s.a], 0, 0), d, axis=AXES.index(s.axis), copies=n - 1))
            for _ in range(n):
                index[f"cube{len(index) - 1}"] = len(index)
    return out


def test_replaying_a_program_rebuilds_its_cuboids():
    env = ShapeAssemblyEnv(targets=[EX0], n_points=512)
    obs, info = env.reset(seed=0)
    assert info["score"] == 0.0
    expected = execute(parse(EX0)).corners.numpy()
    np.testing.assert_allclose(obs["bbox"], [1.845, 0.132, 0.944], rtol=1e-6)
    total, score = 0.0, 0.0
    for a in _actions_of(EX0, obs["bbox"].astype(np.float64)):
        obs, reward, terminated, truncated, info = env.step(a)
        assert not info["invalid"] and not terminated and not truncated
        assert reward == pytest.approx(info["score"] - score, abs=1e-12)
        score = info["score"]
        total += reward
    n = expected.shape[0]
    assert obs["mask"].sum() == n and not obs["cuboids"][n:].any()
    np.testing.assert_allclose(obs["cuboids"][:n], expected, atol=2e-6)
    obs, reward, terminated, _, info = env.step(_action(0))
    assert terminated and reward == 0.0
    assert total == pytest.approx(info["score"]) and 0.8 < info["score"] < 1.0  # 1 only without sampling noise
    # the same program, up to the float32 precision of the action's numbers
    assert to_text(parse(info["program"]), decimals=5) == to_text(parse(EX0), decimals=5)
    # the target cloud lies on the target's surface: every point is inside (or on) a cuboid
    from shapeprog.sampling import inside_cuboids

    corners = torch.from_numpy(expected)
    centre = corners.mean(dim=1, keepdim=True)
    grown = centre + (corners - centre) * (1 + 1e-4)  # each cuboid grown a little about its centre
    assert inside_cuboids(torch.from_numpy(obs["target"]), grown).all()


def test_invalid_lines_are_ignored_with_a_penalty():
    env = ShapeAssemblyEnv(targets=[BOX], n_points=128, max_cuboids=2, invalid_penalty=0.25)
    obs0, _ = env.reset(seed=0)
    cases = [
        (_action(2, (1, 0, 0)), "names no cuboid"),  # no cuboid yet
        (_action(1, params=(0.5, 0.2, 0.5)), None),
        (_action(2, (0, 1, 0)), "bbox is never moved"),
        (_action(2, (1, 1, 0)), "attached to itself"),
        (_action(3, (1, 0, 1)), "squeezed against itself"),
        (_action(5, (1, 0, 0), copies=1), "exceed max_cuboids=2"),
        (_action(4, (1, 0, 0)), None),
        (_action(1, params=(0.1, 0.1, 0.1)), "no cuboid slot left"),
    ]
    obs = obs0
    for action, error in cases:
        new, reward, terminated, _, info = env.step(action)
        assert not terminated
        if error is None:
            assert not info["invalid"]
        else:
            assert info["invalid"] and error in info["error"] and reward == -0.25
            for k in ("cuboids", "mask", "target", "bbox"):
                np.testing.assert_array_equal(new[k], obs[k])
        obs = new
    assert obs["mask"].sum() == 2 and obs["steps"] == len(cases)


def test_invalid_line_errors_name_the_line_and_command():
    env = ShapeAssemblyEnv(targets=[BOX], n_points=64)
    env.reset(seed=0)
    env.step(_action(1, params=(0.5, 0.2, 0.5)))  # line 2: cube0
    info = env.step(_action(3, (1, 1, 0)))[4]  # would be line 3
    assert info["error"] == "line 3 (squeeze): cube0 cannot be squeezed against itself"
    info = env.step(_action(2, (0, 1, 0)))[4]
    assert info["error"].startswith("line 3 (attach): the attached cuboid cannot be bbox")


def test_every_accepted_line_is_a_line_of_the_language():
    """The statements the environment builds directly obey the language: the program parses, prints
    back unchanged and has one statement per accepted line."""
    env = ShapeAssemblyEnv(targets=[BOX], n_points=64, max_cuboids=4, max_lines=40, max_copies=2)
    env.action_space.seed(0)
    rng = np.random.default_rng(0)
    accepted = 0
    for episode in range(8):
        env.reset(seed=episode)
        lines, terminated = 1, False
        while not terminated:
            action = env.action_space.sample()
            action["command"] = int(rng.integers(1, 6)) if rng.random() < 0.97 else 0
            _, _, terminated, _, info = env.step(action)
            if action["command"] and not info["invalid"]:
                lines += 1
            program = parse(env.program)
            assert to_text(program) == env.program and len(program.root.statements) == lines
        accepted += lines - 1
    assert accepted >= 10


def test_corner_outside_the_world_is_invalid():
    env = ShapeAssemblyEnv(targets=[EX0], n_points=128, invalid_action="terminate")
    env.reset(seed=0)
    env.step(_action(1, params=(1.0, 1.0, 1.0)))
    # put the bbox-sized cuboid's min corner on the bbox's max corner: it reaches x = 0.92 + 1.85 > 2
    _, reward, terminated, _, info = env.step(_action(2, (1, 0, 0), (0, 0, 0, 1, 1, 1)))
    assert info["invalid"] and "world cube" in info["error"] and terminated and reward == -0.1
    with pytest.raises(RuntimeError, match="ended"):
        env.step(_action(0))


def test_chamfer_reward_is_the_chamfer_improvement():
    env = ShapeAssemblyEnv(targets=[BOX], n_points=256, reward="chamfer")
    obs, info = env.reset(seed=3)
    target = torch.from_numpy(obs["target"])
    assert info["score"] == pytest.approx(-float(sa_metrics.chamfer(torch.zeros(1, 3), target)))
    actions = _actions_of(BOX, obs["bbox"].astype(np.float64))
    _, r1, *_, i1 = env.step(actions[0])
    _, r2, *_, i2 = env.step(actions[1])
    assert r1 == pytest.approx(i1["score"] - info["score"]) and r2 == pytest.approx(i2["score"] - i1["score"])
    assert i2["score"] > info["score"]  # the right box beats a single point at the centre
    # two samples of the same box are close; the centre point is far from the box's surface
    assert -0.1 < i2["score"] < 0 and info["score"] < -0.3


def test_episode_ends_at_max_lines():
    env = ShapeAssemblyEnv(targets=[BOX], n_points=64, max_lines=3)
    env.reset(seed=0)
    ends = [env.step(_action(1, params=(0.3, 0.3, 0.3)))[2] for _ in range(3)]
    assert ends == [False, False, True]


def test_cloud_targets():
    rng = np.random.default_rng(0)
    clouds = rng.uniform([1, 2, 3], [1.5, 2.2, 3.9], size=(2, 100, 3)).astype(np.float32)
    env = ShapeAssemblyEnv(targets=clouds, n_points=100)
    obs, info = env.reset(seed=1)
    k = int(info["target"].split()[-1])
    lo, hi = clouds[k].min(0), clouds[k].max(0)
    np.testing.assert_allclose(obs["bbox"], hi - lo, rtol=1e-6)
    np.testing.assert_allclose(obs["target"], clouds[k] - (lo + hi) / 2, atol=1e-6)
    with pytest.raises(ValueError, match=r"\(64, 3\), got \(100, 3\)"):
        ShapeAssemblyEnv(targets=clouds, n_points=64).reset(seed=0)
    with pytest.raises(ValueError, match=r"\(N, P, 3\)"):
        CloudTargets(np.zeros((5, 3)))


def test_render_frame():
    env = ShapeAssemblyEnv(targets=[BOX], n_points=256, render_mode="rgb_array", render_size=128)
    obs, _ = env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (128, 258, 3) and frame.dtype == np.uint8
    assert (frame[:, :128] != 255).any() and (frame[:, 130:] == 255).all()  # no cuboid yet
    for a in _actions_of(BOX, obs["bbox"].astype(np.float64)):
        env.step(a)
    assert (env.render()[:, 130:] != 255).any()


def test_bad_arguments():
    with pytest.raises(ValueError, match="reward must be"):
        ShapeAssemblyEnv(targets=[BOX], reward="iou")
    with pytest.raises(ValueError, match="max_cuboids must be a positive int, got 0"):
        ShapeAssemblyEnv(targets=[BOX], max_cuboids=0)
    with pytest.raises(ValueError, match="n_points must be an int >= 2, got 1"):
        ShapeAssemblyEnv(targets=[BOX], n_points=1)
    with pytest.raises(ValueError, match="render_mode must be None or one of"):
        ShapeAssemblyEnv(targets=[BOX], render_mode="human")
    with pytest.raises(RuntimeError, match="reset"):
        ShapeAssemblyEnv(targets=[BOX], render_mode="rgb_array").render()
    with pytest.raises(ValueError, match="unknown category"):
        CorpusTargets("lamp")
    env = ShapeAssemblyEnv(targets=[BOX])
    with pytest.raises(RuntimeError, match="reset"):
        env.step(_action(0))
    env.reset(seed=0)
    with pytest.raises(ValueError, match="not in the action space"):
        env.step({"command": 9})
