"""Tests of shapeio.silhouettes: the silhouette set's file layout and version."""
import numpy as np
import pytest

from shapeio.silhouettes import FORMAT_VERSION, SilhouetteSplit, read_silhouettes, write_silhouettes


def split(n, size=16, seed=0):
    images = np.random.default_rng(seed).random((n, size, size)) < 0.4
    return SilhouetteSplit(images, np.array([f"chair/{i}" for i in range(n)]), np.array(["front", "side"] * (n // 2)))


def test_round_trip_packed(tmp_path):
    data = {"train": split(4), "test": split(2, seed=1)}
    path = write_silhouettes(tmp_path / "s.npz", data, margin=2)
    with np.load(path) as z:
        assert z["train_images"].shape == (4, 16, 2) and z["train_images"].dtype == np.uint8
        assert int(z["version"]) == FORMAT_VERSION and int(z["size"]) == 16 and int(z["margin"]) == 2
    for name, want in data.items():
        got = read_silhouettes(path, name)
        assert np.array_equal(got.images, want.images) and list(got.ids) == list(want.ids)
        assert list(got.views) == list(want.views) and len(got) == len(want)


def test_version_check(tmp_path):
    path = write_silhouettes(tmp_path / "s.npz", {"val": split(2)}, margin=0)
    with np.load(path) as z:
        arrays = dict(z)
    arrays["version"] = np.int64(FORMAT_VERSION + 1)
    np.savez(tmp_path / "new.npz", **arrays)
    with pytest.raises(ValueError, match=rf"new\.npz: silhouette file version {FORMAT_VERSION + 1}; this reader reads version {FORMAT_VERSION}"):
        read_silhouettes(tmp_path / "new.npz", "val")
    del arrays["version"]  # no version entry: read as version 1
    np.savez(tmp_path / "old.npz", **arrays)
    assert len(read_silhouettes(tmp_path / "old.npz", "val")) == 2


def test_bad_files_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"none\.npz: no such file"):
        read_silhouettes(tmp_path / "none.npz", "test")
    with pytest.raises(ValueError, match="unknown split 'dev'"):
        read_silhouettes(tmp_path / "none.npz", "dev")
    path = write_silhouettes(tmp_path / "s.npz", {"val": split(2)}, margin=0)
    with pytest.raises(ValueError, match=r"s\.npz: not a silhouette set: missing test_ids, test_images, test_views"):
        read_silhouettes(path, "test")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"junk\.npz: not a readable \.npz file"):
        read_silhouettes(tmp_path / "junk.npz", "val")
    (tmp_path / "zip.npz").write_bytes(b"PK\x03\x04")  # the start of a zip, nothing more
    with pytest.raises(ValueError, match=r"zip\.npz: not a readable \.npz file \(BadZipFile"):
        read_silhouettes(tmp_path / "zip.npz", "val")
    # entries of the wrong type or range are refused by name
    with np.load(path, allow_pickle=False) as z:
        good = {k: z[k] for k in z.files}
    for change, match in (({"version": np.array([1, 2])}, "'version' is not an integer"),
                          ({"version": np.array("x")}, "'version' is not an integer"),
                          ({"size": np.array(np.nan)}, r"'size' is not an integer in \[1, 1024\]"),
                          ({"size": np.array(-8)}, r"'size' is not an integer in \[1, 1024\]")):
        np.savez(tmp_path / "e.npz", **{**good, **change})
        with pytest.raises(ValueError, match=r"e\.npz: the entry " + match):
            read_silhouettes(tmp_path / "e.npz", "val")
    # a damaged member (its bytes flipped inside the archive) is reported as a corrupt file naming it
    raw = bytearray((tmp_path / "s.npz").read_bytes())
    at = raw.find(b"val_images") + 200
    raw[at:at + 16] = bytes(16)
    (tmp_path / "d.npz").write_bytes(bytes(raw))
    with pytest.raises(ValueError, match=r"d\.npz: "):
        read_silhouettes(tmp_path / "d.npz", "val")
    bad = SilhouetteSplit(np.zeros((2, 16, 16), bool), np.array(["a/1"]), np.array(["front", "side"]))
    with pytest.raises(ValueError, match=r"w\.npz: val has 2 images but 1 ids"):
        write_silhouettes(tmp_path / "w.npz", {"val": bad}, margin=0)
    with pytest.raises(ValueError, match=r"w\.npz: val images must be \(N, 16, 16\) bool"):
        write_silhouettes(tmp_path / "w.npz", {"val": SilhouetteSplit(np.zeros((2, 16, 16), np.uint8), bad.views, bad.views)},
                          margin=0)
    assert not (tmp_path / "w.npz").exists()


def test_a_side_beyond_the_reader_limit_is_not_written(tmp_path, monkeypatch):
    import shapeio.silhouettes as sil

    monkeypatch.setattr(sil, "MAX_SIZE", 8)
    with pytest.raises(ValueError, match=r"s\.npz: images of side 16; at most MAX_SIZE = 8"):
        write_silhouettes(tmp_path / "s.npz", {"val": split(2)}, margin=0)
    assert not (tmp_path / "s.npz").exists()
