"""shapeprog.pointcloud.data: clouds of corpus shapes, the cache, the splits and the Dataset."""
import json
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch

from shapeio.files import InputError
from shapeprog import corpus
from shapeprog.__main__ import main
from shapeprog.lang import parse
from shapeprog.pointcloud import normalize
from shapeprog.pointcloud.data import (
    cache_paths, carve_validation, cloud_seed, corpus_cloud, corpus_splits, make_clouds, program_cloud,
    sample_clouds,
)
from shapeprog.pointcloud.dataset import CloudDataset, collate_clouds, load_cache, read_split

SPLITS = corpus_splits("chair")
# a handful of chairs from each split: 3 train, 2 carved-out val, 2 test (= corpus val)
IDS = SPLITS["train"][:3] + SPLITS["val"][:2] + SPLITS["test"][:2]
BOX = ("bbox = Cuboid(2.0, 1.0, 0.5, True)\ncube0 = Cuboid(2.0, 1.0, 0.5, True)\n"
       "attach(cube0, bbox, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)\n")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    root = tmp_path_factory.mktemp("clouds")
    rep = make_clouds("chair", root, n_points=300, workers=1, ids=IDS)
    return root, rep


def test_a_cloud_depends_only_on_category_id_and_seed():
    a = corpus_cloud("chair", IDS[0], n_points=200)
    assert a.shape == (200, 3) and a.dtype == np.float32
    assert np.array_equal(a, corpus_cloud("chair", IDS[0], n_points=200))
    assert not np.array_equal(a, corpus_cloud("chair", IDS[0], n_points=200, seed=1))
    # pinned: the same in every process and Python version (a salted hash would change between runs)
    assert (cloud_seed("chair", 173, 0), cloud_seed("table", 173, 0)) == (2054223066050137686, 3659894705287828627)
    # order and executor do not matter
    ids = IDS[:4]
    fwd = sample_clouds("chair", ids, n_points=200)
    with ThreadPoolExecutor(2) as ex:
        back = sample_clouds("chair", ids[::-1], n_points=200, executor=ex)
    assert fwd.ids.tolist() == ids and back.ids.tolist() == ids[::-1]
    assert np.array_equal(fwd.points, back.points[::-1])
    assert np.array_equal(fwd.points[0], a)


def test_points_are_spread_by_face_area():
    # one 2 x 1 x 0.5 box centred at the origin: faces of area 0.5 (x), 1 (y), 2 (z), twice each
    pts = program_cloud(BOX, n_points=20000, seed=3)
    half = np.array([1.0, 0.5, 0.25])
    on = np.isclose(np.abs(pts), half, atol=1e-5)
    assert on.any(axis=1).all() and (np.abs(pts) <= half + 1e-5).all()
    for axis, area in enumerate([0.5, 1.0, 2.0]):
        for sign in (1, -1):
            share = float((on[:, axis] & (np.sign(pts[:, axis]) == sign)).mean())
            assert abs(share - area / 7.0) < 0.015, (axis, sign, share)


def test_a_failing_shape_is_reported_and_the_rest_kept():
    bad = "bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.5, 0.5, 0.5, True)\nattach(cube9, bbox, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)\n"
    res = sample_clouds("chair", [IDS[0], IDS[1], 999999], n_points=50, texts={IDS[1]: bad})
    assert res.ids.tolist() == [IDS[0]] and res.points.shape == (1, 50, 3)
    (i1, r1), (i2, r2) = res.failures
    assert i1 == IDS[1] and r1.startswith(f"chair/{IDS[1]}.txt:3:") and "cube9" in r1
    assert i2 == 999999 and "no program chair/999999" in r2
    with pytest.raises(ValueError, match="no leaf cuboid"):
        program_cloud("bbox = Cuboid(1.0, 1.0, 1.0, True)\n", 10)
    with pytest.raises(ValueError, match="MAX_CLOUD_POINTS"):
        program_cloud(BOX, 0)


def test_splits_are_disjoint_reproducible_and_keep_the_test_split_apart():
    train_ids, val_ids = set(SPLITS["train"]), set(SPLITS["val"])
    assert not train_ids & val_ids and train_ids | val_ids == set(corpus.ids("chair", "train"))
    assert SPLITS["test"] == sorted(corpus.ids("chair", "val")) and not set(SPLITS["test"]) & (train_ids | val_ids)
    assert len(val_ids) == round(0.05 * 3339)
    assert corpus_splits("chair") == SPLITS and corpus_splits("chair", seed=1)["val"] != SPLITS["val"]
    ids = list(range(100, 140))
    assert carve_validation(ids, 0.25, 7) == carve_validation(ids[::-1], 0.25, 7)
    assert [len(x) for x in carve_validation(ids, 0.25, 7)] == [30, 10]
    with pytest.raises(ValueError, match="fraction"):
        carve_validation(ids, 1.0)


def test_cache_round_trip(cache):
    root, rep = cache
    assert (rep.cache, rep.split) == cache_paths(root, "chair") and rep.count == len(IDS) and not rep.failures
    c = load_cache(root, "chair")
    assert c.ids.tolist() == sorted(IDS) and c.points.dtype == np.float16 and c.points.shape == (len(IDS), 300, 3)
    fresh = sample_clouds("chair", sorted(IDS), n_points=300).points
    assert np.abs(c.points.astype(np.float32) - fresh).max() <= 5e-4
    # the stored transform is normalize() of the stored points
    t = normalize(c.points[2].astype(np.float32))[1]
    assert np.allclose(c.center[2], t.center, atol=0, rtol=1e-12) and c.scale[2] == pytest.approx(t.scale, rel=1e-12)
    split = read_split(root, "chair")
    assert split == {"train": sorted(IDS[:3]), "val": sorted(IDS[3:5]), "test": sorted(IDS[5:])}
    record = json.loads(rep.split.read_text())
    assert record["cache"] == "chair_clouds.npz" and record["failed"] == {}


def test_cache_errors_name_the_file(cache, tmp_path):
    root, _ = cache
    with pytest.raises(FileNotFoundError, match="make-clouds --category table"):
        load_cache(root, "table")
    (tmp_path / "chair_clouds.npz").write_bytes(b"junk")
    with pytest.raises(InputError, match="chair_clouds.npz: cannot read the cloud cache"):
        load_cache(tmp_path, "chair")
    # damaged entries of a real cache: each refused by name, none read as something else
    with np.load(root / "chair_clouds.npz", allow_pickle=False) as z:
        good = {k: z[k] for k in z.files}
    damaged = [({"version": np.array([1, 2])}, "'version' is not an integer >= 0"),
               ({"n_points": np.array([])}, "'n_points' is not an integer >= 0"),
               ({"points": np.where(np.arange(3) == 0, np.nan, good["points"])}, "'points' holds a non-finite"),
               ({"scale": np.zeros_like(good["scale"])}, "a scale <= 0"),
               ({"scale": np.full_like(good["scale"], -np.inf)}, "'scale' holds a non-finite"),
               ({"failed_ids": np.array([1, 2]), "failed_reasons": np.array(["x"])}, "2 failed ids but 1 reasons")]
    for change, match in damaged:
        np.savez(tmp_path / "chair_clouds.npz", **{**good, **change})
        with pytest.raises(InputError, match=match):
            load_cache(tmp_path, "chair")
    split = tmp_path / "chair_split.json"
    for text, match in (('{"train": [1e999], "val": [], "test": []}', "out of the range of a float"),
                        ("[" * 100, "nested more than 64"),
                        ('{"train": [1.5], "val": [], "test": []}', "'train' is not a list of shape ids"),
                        ('{"train": "12", "val": [], "test": []}', "'train' is not a list of shape ids"),
                        ('{"train": [], "val": []}', "'test' is not a list of shape ids"), ("[]", "a JSON object")):
        split.write_text(text)
        with pytest.raises(InputError, match=match):
            read_split(tmp_path, "chair")


def test_dataset_items(cache):
    root, _ = cache
    ds = CloudDataset(root, "chair", "train", points=64, seed=5)
    assert len(ds) == 3 and len(CloudDataset(root, "chair", "test", points=8)) == 2
    item = ds[0]
    assert item["points"].shape == (64, 3) and item["points"].dtype == torch.float32
    assert item["id"] == sorted(IDS[:3])[0] and item["program"] == f"chair/{item['id']}"
    assert ds.program(0) == parse(corpus.read("chair", item["id"]))
    assert torch.equal(ds[0]["points"], item["points"])  # the same draw for the same (seed, epoch, item)
    ds.set_epoch(1)
    assert not torch.equal(ds[0]["points"], item["points"])
    # all points, no noise: exactly the normalised stored cloud
    full = CloudDataset(root, "chair", "train", points=None)[0]["points"].numpy()
    c = load_cache(root, "chair")
    expect = normalize(c.points[c.index([item["id"]])[0]].astype(np.float32))[0]
    assert np.allclose(full, expect, atol=1e-6)
    lo, hi = full.min(0), full.max(0)
    assert np.allclose((lo + hi) / 2, 0, atol=1e-6) and np.linalg.norm(hi - lo) == pytest.approx(2.0, abs=1e-5)
    # noise and random counts; batches cut to the smallest count
    noisy = CloudDataset(root, "chair", "train", points=(20, 40), noise=0.01, seed=5)
    batch = collate_clouds([noisy[i] for i in range(3)])
    n = min(noisy[i]["points"].shape[0] for i in range(3))
    assert batch["points"].shape == (3, n, 3) and 20 <= n <= 40 and batch["id"].dtype == torch.int64
    assert batch["program"] == [noisy.program_name(i) for i in range(3)]
    with pytest.raises(ValueError, match="points"):
        CloudDataset(root, "chair", "train", points=301)


def test_make_clouds_command(tmp_path, capsys):
    assert main(["pointcloud", "make-clouds", "--category", "storage", "--limit", "1", "--points", "32", "--workers", "1",
                 "--quiet", "--out", str(tmp_path / "c")]) == 0
    out = capsys.readouterr().out
    assert "2 clouds of 32 points" in out and "storage_split.json" in out
    c = load_cache(tmp_path / "c", "storage")
    assert c.points.shape == (2, 32, 3)
    assert read_split(tmp_path / "c", "storage", c) == read_split(tmp_path / "c", "storage")
    # a second run into the folder never replaces the cache
    before = (tmp_path / "c" / "storage_clouds.npz").read_bytes()
    with pytest.raises(SystemExit, match=r"storage_clouds\.npz: exists"):
        main(["pointcloud", "make-clouds", "--category", "storage", "--limit", "2", "--points", "32", "--workers", "1", "--quiet",
              "--out", str(tmp_path / "c")])
    assert (tmp_path / "c" / "storage_clouds.npz").read_bytes() == before
    # a split file of another run beside the cache is refused where both are read
    record = json.loads((tmp_path / "c" / "storage_split.json").read_text())
    (tmp_path / "c" / "storage_split.json").write_text(json.dumps(dict(record, n_points=64)))
    with pytest.raises(InputError, match=r"storage_split\.json: not the split of storage_clouds\.npz \(n_points 64"):
        CloudDataset(tmp_path / "c", "storage", "train")
    (tmp_path / "c" / "storage_split.json").write_text(json.dumps(dict(record, test=record["test"] + [99999999])))
    with pytest.raises(InputError, match="shape 99999999 is not in the cache"):
        read_split(tmp_path / "c", "storage", c)


def test_a_cache_of_any_integer_seed_reads_back(tmp_path):
    make_clouds("storage", tmp_path, n_points=16, workers=1, seed=-1, ids=corpus_splits("storage")["train"][:1])
    c = load_cache(tmp_path, "storage")
    assert c.seed == -1 and read_split(tmp_path, "storage", c)["train"] == c.ids.tolist()


def test_defect_unbounded_reads_cloud_cache_bomb_is_refused_before_decompressing(tmp_path):
    from shapeio import InputError
    from shapeprog.pointcloud.dataset import load_cache

    bomb = tmp_path / "chair_clouds.npz"
    np.savez_compressed(bomb, points=np.zeros((2, 200_000, 3), np.float32), ids=np.zeros(2, np.int64))
    with pytest.raises(InputError, match=r"'points' of shape \(2, 200000, 3\); a chair cache holds at most "
                                         r"\(\d+, 100000, 3\) \(MAX_CLOUD_POINTS\)"):
        load_cache(tmp_path, "chair")
    np.savez_compressed(bomb, points=np.zeros((2, 10, 3), np.float32), ids=np.zeros(80 << 20 >> 3, np.int64))
    assert bomb.stat().st_size < 1 << 20
    with pytest.raises(InputError, match=r"array 'ids' would take 83886080 bytes; at most 67108864 "
                                         r"\(MAX_CACHE_TABLE_BYTES\)"):
        load_cache(tmp_path, "chair")


def test_defect_unbounded_reads_xyz_line_is_refused(tmp_path):
    from shapeio import InputError
    from shapeio.points import read_points

    path = tmp_path / "long.xyz"
    path.write_text("0 0 0\n" + "1" * 10_000)
    with pytest.raises(InputError) as e:
        read_points(path)
    assert str(e.value) == f"{path}:2: a line longer than MAX_LINE_CHARS = 4096 characters"
    folder = tmp_path / "cloud.xyz"
    folder.mkdir()
    with pytest.raises(InputError) as e:
        read_points(folder)
    assert str(e.value) == f"{folder}: a folder, not a point-cloud or mesh file"
