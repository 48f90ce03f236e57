"""Tests of shapeio.volumes: the volume set's file layout, version and errors."""
import numpy as np
import pytest

from shapeio.volumes import FORMAT_VERSION, VolumeSplit, pack_volumes, read_volumes, unpack_volumes, write_volumes


def split(n, size=16, seed=0):
    vols = np.random.default_rng(seed).random((n, size, size, size)) < 0.4
    return vols, VolumeSplit(pack_volumes(vols), np.array([f"chair/{i}" for i in range(n)]), size)


def test_round_trip_packed(tmp_path):
    (v1, s1), (v2, s2) = split(3), split(2, seed=1)
    path = write_volumes(tmp_path / "v.npz", {"train": s1, "test": s2}, margin=2)
    with np.load(path) as z:
        assert z["train_volumes"].shape == (3, 16, 16, 2) and z["train_volumes"].dtype == np.uint8
        assert int(z["version"]) == FORMAT_VERSION and int(z["size"]) == 16 and int(z["margin"]) == 2
    got = read_volumes(path, "train")
    assert np.array_equal(got.volumes(), v1) and list(got.ids) == list(s1.ids) and len(got) == 3
    assert np.array_equal(got.volumes(2), v1[:2]) and np.array_equal(read_volumes(path, "test").volumes(), v2)
    odd = np.random.default_rng(2).random((2, 5, 5, 5)) < 0.5  # a side that is no multiple of 8
    assert np.array_equal(unpack_volumes(pack_volumes(odd), 5), odd)


def test_bad_files_and_data_name_the_file(tmp_path):
    _, s = split(2)
    with pytest.raises(FileNotFoundError, match=r"none\.npz: no such file"):
        read_volumes(tmp_path / "none.npz", "train")
    with pytest.raises(ValueError, match="unknown split 'dev'"):
        read_volumes(tmp_path / "none.npz", "dev")
    path = write_volumes(tmp_path / "v.npz", {"val": s}, margin=0)
    with pytest.raises(ValueError, match=r"v\.npz: not a volume set with a test split: missing test_ids, test_volumes"):
        read_volumes(path, "test")
    with np.load(path) as z:
        arrays = dict(z)
    arrays["version"] = np.int64(FORMAT_VERSION + 1)
    np.savez(tmp_path / "new.npz", **arrays)
    with pytest.raises(ValueError, match=rf"new\.npz: volume file version {FORMAT_VERSION + 1}; this reader reads"):
        read_volumes(tmp_path / "new.npz", "val")
    arrays["version"] = np.int64(FORMAT_VERSION)
    arrays["val_volumes"] = arrays["val_volumes"][..., :1]
    np.savez(tmp_path / "cut.npz", **arrays)
    with pytest.raises(ValueError, match=r"cut\.npz: val_volumes has dtype uint8 and shape \(2, 16, 16, 1\); expected "
                                         r"\(N, 16, 16, 2\) uint8"):
        read_volumes(tmp_path / "cut.npz", "val")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"junk\.npz: not a readable \.npz file"):
        read_volumes(tmp_path / "junk.npz", "val")
    with pytest.raises(ValueError, match=r"w\.npz: no split to write"):
        write_volumes(tmp_path / "w.npz", {}, margin=0)
    with pytest.raises(ValueError, match=r"w\.npz: val has 2 volumes but 1 ids"):
        write_volumes(tmp_path / "w.npz", {"val": VolumeSplit(s.packed, s.ids[:1], 16)}, margin=0)
    with pytest.raises(ValueError, match=r"w\.npz: val volumes must be packed as \(N, 16, 16, 2\) uint8"):
        write_volumes(tmp_path / "w.npz", {"val": VolumeSplit(s.packed.astype(bool), s.ids, 16)}, margin=0)
    assert not (tmp_path / "w.npz").exists()
