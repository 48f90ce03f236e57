"""Tests of csgnet.shapes2d: the shipped silhouettes and the paper's cad.h5 format."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from csgnet import shapes2d

import h5py  # noqa: E402  (the dev extra)


def random_images(n: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).random((n, 64, 64)) < 0.3


def write_cad(path, **datasets):
    with h5py.File(path, "w") as f:
        for name, data in datasets.items():
            f.create_dataset(name, data=data)
    return path


def test_cad_h5_round_trip(tmp_path):
    tr, va, te = random_images(5, 0), random_images(3, 1), random_images(4, 2)
    # stored as uint8 0/1 (train), float 0/1 (val) and bool (test): all read back as bool
    path = write_cad(tmp_path / "cad.h5", train_images=tr.astype(np.uint8), val_images=va.astype(np.float32),
                     test_images=te)
    for split, want in (("train", tr), ("val", va), ("test", te)):
        got = shapes2d.load_cad_h5(path, split)
        assert got.dtype == bool and np.array_equal(got, want)
    assert np.array_equal(shapes2d.load_cad_h5(path), te)  # the default split is test


def test_cad_h5_errors(tmp_path):
    path = write_cad(tmp_path / "cad.h5", train_images=random_images(2, 0).astype(np.uint8))
    with pytest.raises(ValueError, match=r"no dataset 'test_images' \(found: train_images\)"):
        shapes2d.load_cad_h5(path, "test")
    bad = write_cad(tmp_path / "bad.h5", test_images=np.zeros((3, 32, 32), np.uint8))
    with pytest.raises(ValueError, match=r"has shape \(3, 32, 32\); expected \(N, 64, 64\)"):
        shapes2d.load_cad_h5(bad, "test")
    with h5py.File(tmp_path / "group.h5", "w") as f:
        f.create_group("val_images")
    with pytest.raises(ValueError, match="is a group, not a dataset"):
        shapes2d.load_cad_h5(tmp_path / "group.h5", "val")
    text = tmp_path / "not.h5"
    text.write_text("hello")
    with pytest.raises(ValueError, match="not a readable HDF5 file"):
        shapes2d.load_cad_h5(text, "test")
    with pytest.raises(FileNotFoundError, match="missing.h5: no such file"):
        shapes2d.load_cad_h5(tmp_path / "missing.h5", "test")
    with pytest.raises(ValueError, match="unknown split 'dev'"):
        shapes2d.load_cad_h5(path, "dev")


def test_cad_h5_without_h5py_names_the_extra(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "h5py", None)  # makes `import h5py` raise ImportError
    with pytest.raises(ImportError, match=r"install the 'cad' extra: pip install -e '\.\[cad\]' in the checkout"):
        shapes2d.load_cad_h5(tmp_path / "cad.h5", "test")


def test_shipped_silhouettes():
    sizes = {}
    for split in shapes2d.SPLITS:
        imgs = shapes2d.load_silhouettes(split)
        assert imgs.dtype == bool and imgs.ndim == 3 and imgs.shape[1:] == (64, 64)
        on = imgs.reshape(len(imgs), -1).sum(axis=1)
        assert (on > 0).all() and (on < 64 * 64).all()  # no empty or full image
        data = shapes2d.load_silhouettes(split, with_ids=True)
        assert np.array_equal(data.images, imgs) and len(data) == len(imgs)
        assert set(data.views) == {"front", "side"}
        assert {i.split("/")[0] for i in data.ids} == {"chair", "table", "storage"}
        sizes[split] = set(data.ids)
    # the splits share no shape
    assert not sizes["train"] & sizes["val"] and not sizes["train"] & sizes["test"] and not sizes["val"] & sizes["test"]
    assert shapes2d.silhouettes_path().name == "silhouettes.npz"


def test_silhouette_file_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="python -m shapeprog assembly silhouettes --out"):
        shapes2d.load_silhouettes("train", path=tmp_path / "none.npz")
    with pytest.raises(ValueError, match="unknown split 'all'"):
        shapes2d.load_silhouettes("all")
    other = tmp_path / "other.npz"
    np.savez(other, images=np.zeros((2, 64, 64), bool))
    with pytest.raises(ValueError, match="not a silhouette set: missing test_ids, test_images, test_views"):
        shapes2d.load_silhouettes("test", path=other)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="not a readable .npz file"):
        shapes2d.load_silhouettes("test", path=junk)
    single = tmp_path / "single.npy"
    np.save(single, np.zeros((2, 64, 64), bool))
    with pytest.raises(ValueError, match="a single array, not an .npz archive"):
        shapes2d.load_silhouettes("test", path=single)
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, test_images=np.zeros((2, 64, 64), np.float32), test_ids=np.array(["a/1", "a/1"]),
             test_views=np.array(["front", "side"]))
    with pytest.raises(ValueError, match="test_images has dtype float32"):
        shapes2d.load_silhouettes("test", path=wrong)


def test_unpacked_silhouette_file(tmp_path):
    imgs = random_images(4, 3)
    path = tmp_path / "plain.npz"
    np.savez(path, val_images=imgs, val_ids=np.array(["chair/1"] * 2 + ["table/2"] * 2),
             val_views=np.array(["front", "side"] * 2))
    assert np.array_equal(shapes2d.load_silhouettes("val", path=path), imgs)
