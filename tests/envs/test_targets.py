"""Target sources of the CSG environments."""

import cv2
import numpy as np
import pytest

import csgnet
from envs.csg import CSGEnv
from envs.targets import ArrayTargets, ImageFolderTargets, SyntheticTargets, Target, TargetSource, as_target_source
from envs.targets import _synthetic_pool


def test_synthetic_targets_are_rendered_pool_programs():
    src = SyntheticTargets(2, lengths=[3, 7], size=5, seed=3)
    assert len(src) == 10
    drawn = _synthetic_pool.cache_info().misses
    assert src.prepare() is src
    assert _synthetic_pool.cache_info().misses == drawn + 2  # both pools drawn now, ...
    rng = np.random.default_rng(0)
    lengths = set()
    for _ in range(20):
        t = src.sample(rng)
        assert _synthetic_pool.cache_info().misses == drawn + 2  # ... none on sampling
        prog = csgnet.parse(t.program, 2)  # strict: a valid program
        lengths.add(len(prog))
        np.testing.assert_array_equal(t.shape, csgnet.render(prog)[0])
        np.testing.assert_array_equal(src.tokens(t.index), csgnet.vocabulary(2).encode(prog))
        assert t.shape.sum() >= 100  # the sampler's minimum size rule
    assert lengths == {3, 7}
    # the pool depends on the source's seed only; the episode generator picks from it
    again = SyntheticTargets(2, lengths=[3, 7], size=5, seed=3)
    np.testing.assert_array_equal(again.tokens(7), src.tokens(7))
    other = SyntheticTargets(2, lengths=[3, 7], size=5, seed=4)
    assert any(not np.array_equal(other.tokens(i), src.tokens(i)) for i in range(10))
    with pytest.raises(IndexError):
        src.tokens(10)


def test_synthetic_default_lengths_fit_max_length():
    src = as_target_source(None, 2, max_length=7)
    assert src.lengths == (3, 5, 7)
    with pytest.raises(ValueError, match="no synthetic program length"):
        as_target_source("synthetic", 3, max_length=2)
    with pytest.raises(ValueError, match="odd"):
        SyntheticTargets(2, lengths=[4])


def test_array_targets_accept_bool_and_binary_numbers():
    imgs = csgnet.render(["c(32,32,16)", "s(32,32,16)"])
    for arr in (imgs, imgs.astype(np.uint8), imgs.astype(np.float32), list(imgs)):
        src = ArrayTargets(arr)
        assert src.dim == 2 and len(src) == 2
        t = src.sample(np.random.default_rng(0))
        assert isinstance(t, Target) and t.shape.dtype == np.bool_
        np.testing.assert_array_equal(t.shape, imgs[t.index])
    imgs[0, 0, 0] = True
    src = ArrayTargets(imgs)
    imgs[0, 0, 0] = False  # the source keeps its own copy
    assert src.shapes[0, 0, 0]


def test_array_targets_errors():
    with pytest.raises(ValueError, match=r"\(N, 64, 64\) or \(N, 64, 64, 64\), got \(2, 32, 32\)"):
        ArrayTargets(np.zeros((2, 32, 32), bool))
    bad = np.zeros((3, 64, 64), np.uint8)
    bad[2, 5, 5] = 255
    with pytest.raises(ValueError, match=r"target\(s\) \[2\] hold values other than 0 and 1"):
        ArrayTargets(bad)
    with pytest.raises(ValueError, match="no target"):
        ArrayTargets(np.zeros((0, 64, 64), bool))
    with pytest.raises(ValueError, match="programs has 1 entries for 2 targets"):
        ArrayTargets(np.zeros((2, 64, 64), bool), programs=["c(32,32,8)"])


def test_silhouette_array_plugs_into_the_environment():
    # a silhouette set is an (N, 64, 64) bool array: it is a target source as it stands
    sil = np.zeros((3, 64, 64), bool)
    sil[0, 10:50, 20:40] = True
    sil[1, 5:60, 5:15] = True
    sil[2, 30:34, :] = True
    env = CSGEnv(targets=sil)
    for seed in range(5):
        obs, info = env.reset(seed=seed)
        np.testing.assert_array_equal(obs["target"], sil[info["target_index"]])
        assert "target_program" not in info


def test_image_folder_targets(tmp_path):
    imgs = csgnet.render(["c(32,32,16)", "t(32,32,20)", "s(24,24,12)"])
    for i, img in enumerate(imgs):
        cv2.imwrite(str(tmp_path / f"{i:02d}.png"), img.astype(np.uint8) * 255)
    (tmp_path / "notes.txt").write_text("not an image")
    src = ImageFolderTargets(tmp_path)
    assert len(src) == 3 and [f.name for f in src.files] == ["00.png", "01.png", "02.png"]
    np.testing.assert_array_equal(src.shapes, imgs)
    inv = ImageFolderTargets(tmp_path, invert=True)
    np.testing.assert_array_equal(inv.shapes, ~imgs)
    env = CSGEnv(targets=str(tmp_path))
    obs, info = env.reset(seed=0)
    np.testing.assert_array_equal(obs["target"], imgs[info["target_index"]])


def test_image_folder_errors_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such directory"):
        ImageFolderTargets(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match="no .png file"):
        ImageFolderTargets(tmp_path)
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((64, 64), np.uint8))
    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((32, 64), np.uint8))
    src = ImageFolderTargets(tmp_path)
    with pytest.raises(ValueError, match=r"b\.png: target images must be 64x64, got 64x32"):
        src.sample(np.random.default_rng(0))
    (tmp_path / "b.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match=r"b\.png: not a readable PNG"):
        ImageFolderTargets(tmp_path).shapes


def test_custom_source_protocol():
    class Fixed:
        dim = 2

        def sample(self, rng):
            return Target(csgnet.render("c(32,32,20)")[0], 0, "c(32,32,20)")

    assert isinstance(Fixed(), TargetSource)
    env = CSGEnv(targets=Fixed())
    _, info = env.reset(seed=0)
    assert info["target_program"] == "c(32,32,20)"
    with pytest.raises(TypeError, match="targets must be"):
        CSGEnv(targets=3.5)
