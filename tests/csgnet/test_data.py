"""Dataset files (csgnet.data): generation to disk, split sizes, determinism over workers, loading with
located errors and warnings, and the padded token dataset."""
import re
import shutil
import warnings

import pytest
import torch

from csg_testutil import rules_hold
from csgnet.data import TABLE2, ProgramDataset, generate_dataset, load_dataset, split_sizes
from csgnet.vocab import vocabulary

SCALE = 0.001
LENGTHS_2D = [3, 5, 13]


@pytest.fixture(scope="module")
def ds2(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds")
    counts = generate_dataset(out, dim=2, scale=SCALE, seed=3, workers=1, lengths=LENGTHS_2D, progress=False)
    return out, counts


@pytest.fixture(scope="module")
def ds3(tmp_path_factory):
    out = tmp_path_factory.mktemp("ds3")
    counts = generate_dataset(out, dim=3, scale=0.0001, seed=0, workers=1, lengths=[3, 7], progress=False,
                              chunk_size=16)
    return out, counts


# --- an independent check of the rules on the NumPy renderer --------------------------------------


# --- sizes, lengths, duplicates, vocabulary ----------------------------------------------------------

def test_split_sizes_are_table2_times_scale():
    assert split_sizes(2, 0.001)[3] == {"train": 25, "val": 5, "test": 5}
    assert split_sizes(2, 0.001)[13] == {"train": 350, "val": 20, "test": 100}
    assert split_sizes(3, 0.0002)[7] == {"train": 80, "val": 8, "test": 16}
    assert split_sizes(3, 1e-9)[3] == {"train": 1, "val": 1, "test": 1}  # at least one
    with pytest.raises(ValueError, match="lengths"):
        split_sizes(3, 0.1, [9])


def test_files_sizes_lengths_vocabulary_and_no_duplicates(ds2):
    out, counts = ds2
    vocab = vocabulary(2)
    assert counts == {L: dict(zip(("train", "val", "test"), (round(n * SCALE) for n in TABLE2[2][L])))
                      for L in LENGTHS_2D}
    for L in LENGTHS_2D:
        texts = []
        for split in ("train", "val", "test"):
            progs = load_dataset(out, 2, split, [L])[L]
            assert len(progs) == counts[L][split]
            lines = (out / "2d" / f"len_{L:02d}" / f"{split}.txt").read_text().splitlines()
            assert len(lines) == counts[L][split]
            for p, line in zip(progs, lines):
                assert len(p) == L and p.is_valid and p.text() == line
                assert len(vocab.encode(p)) == L  # every primitive is in the vocabulary
            texts += lines
        assert len(set(texts)) == len(texts)  # no duplicates within or across the splits
    meta = (out / "2d" / "meta.json").read_text()
    assert '"seed": 3' in meta and '"min_pixels": 100' in meta


def test_every_operation_passes_the_change_rule_and_min_pixels(ds2, ds3):
    out, _ = ds2
    progs = load_dataset(out, 2, "train")
    sample = progs[3][:10] + progs[5][:10] + progs[13][:15]
    assert all(rules_hold(p, 100) for p in sample)
    out3, _ = ds3
    progs3 = load_dataset(out3, 3, "val")
    assert len(progs3[3]) == 1 and len(progs3[7]) == 4
    assert all(len(p) == 3 for p in progs3[3]) and all(len(p) == 7 for p in progs3[7])
    assert all(rules_hold(p, 1000) for p in progs3[3] + progs3[7][:2])
    assert all(p.text().startswith(("sp(", "cu(", "cy(")) for p in progs3[7])


# --- determinism ------------------------------------------------------------------------------------

def test_same_files_for_any_number_of_workers(tmp_path):
    kw = dict(dim=2, scale=SCALE, seed=11, lengths=[3, 9], progress=False, chunk_size=64)
    generate_dataset(tmp_path / "a", workers=1, **kw)
    generate_dataset(tmp_path / "b", workers=2, **kw)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert len(files) == 7  # 2 lengths x 3 splits + meta.json
    for f in files:
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f
    generate_dataset(tmp_path / "c", workers=1, **{**kw, "seed": 12})
    assert (tmp_path / "c/2d/len_09/train.txt").read_text() != (tmp_path / "a/2d/len_09/train.txt").read_text()


def test_unknown_rule_is_rejected(tmp_path):
    with pytest.raises(TypeError, match="min_pixel"):
        generate_dataset(tmp_path, min_pixel=5)


# --- distributions ----------------------------------------------------------------------------------


# --- loading ----------------------------------------------------------------------------------------

def test_load_reports_file_and_line_of_bad_lines(ds2, tmp_path):
    src, counts = ds2
    shutil.copytree(src / "2d", tmp_path / "2d")
    f = tmp_path / "2d" / "len_03" / "train.txt"
    lines = f.read_text().splitlines()
    lines[2] = "c(1,2)s(8,8,8)+"  # line 3: wrong parameter count
    lines[4] = "c(32,32,8)"  # line 5: a program of the wrong length
    f.write_text("\n".join(lines) + "\n")
    with pytest.warns(UserWarning) as rec:
        progs = load_dataset(tmp_path, 2, "train", [3, 5])
    msg = str(rec[0].message)
    assert f"{f}:3:" in msg and f"{f}:5:" in msg and "2 bad line(s)" in msg
    assert len(progs[3]) == counts[3]["train"] - 2 and len(progs[5]) == counts[5]["train"]
    with pytest.raises(ValueError) as e:
        load_dataset(tmp_path, 2, "train", errors="raise")
    assert f"{f}:3:" in str(e.value) and f"{f}:5:" in str(e.value)
    with pytest.raises(FileNotFoundError, match="len_07"):
        load_dataset(tmp_path, 2, "train", [7])


# --- torch dataset and jitter -----------------------------------------------------------------------

def test_program_dataset_pads_with_stop():
    vocab = vocabulary(2)
    ds = ProgramDataset(["c(32,32,8)s(32,32,8)+", "c(32,32,8)"], dim=2)
    assert len(ds) == 2 and ds.max_len == 3
    tok, n = ds[1]
    assert tok.shape == (4,) and tok.dtype == torch.int64 and int(n) == 1
    assert tok.tolist() == [vocab.index("c(32,32,8)"), vocab.stop, vocab.stop, vocab.stop]
    assert vocab.text(ds[0][0].tolist()) == "c(32,32,8)s(32,32,8)+"
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=2)))
    assert batch[0].shape == (2, 4) and batch[1].tolist() == [3, 1]
    with pytest.raises(ValueError, match="max_len"):
        ProgramDataset(["c(32,32,8)s(32,32,8)+"], dim=2, max_len=1)


def test_defect7_interrupted_or_mixed_generate_warns(tmp_path, monkeypatch):
    import json

    from csgnet import data
    from csgnet.data import DatasetWarning

    generate_dataset(tmp_path, dim=2, scale=0.0002, seed=0, lengths=[3, 5], progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_dataset(tmp_path, 2, "test")  # a complete run: no warning

    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(data, "sample_chunk", killed)
    with pytest.raises(KeyboardInterrupt):
        generate_dataset(tmp_path, dim=2, scale=0.0002, seed=1, lengths=[3, 5], progress=False)
    assert json.loads((tmp_path / "2d" / "meta.json").read_text())["complete"] is False
    with pytest.warns(DatasetWarning, match="did not finish"):
        load_dataset(tmp_path, 2, "test")
    meta = tmp_path / "2d" / "meta.json"
    for text, match in (('{"lengths": [1e999]}', "out of the range of a float"), ('{"lengths": [null]}', "'lengths'"),
                        ('{"lengths": "3"}', "'lengths'"), ('{"lengths": [1e308]}', "'lengths'"),
                        ('{"lengths": [3], "complete": "yes"}', "'complete'"), ("[" * 200, "nested more than 64")):
        meta.write_text(text)
        with pytest.raises(ValueError, match="meta.json.*" + match):
            load_dataset(tmp_path, 2, "test")
    meta.unlink()
    with pytest.warns(DatasetWarning, match="meta.json is missing"):
        load_dataset(tmp_path, 2, "test")


def test_defect7_lengths_left_by_another_run_warn(tmp_path):
    from csgnet.data import DatasetWarning

    generate_dataset(tmp_path, dim=2, scale=0.0002, seed=0, lengths=[3, 5], progress=False)
    generate_dataset(tmp_path, dim=2, scale=0.0002, seed=1, lengths=[3], progress=False)
    with pytest.warns(DatasetWarning, match=r"does not list lengths \[5\]"):
        load_dataset(tmp_path, 2, "test", lengths=[3, 5])


def test_defect8_non_utf8_line_is_located_and_the_rest_loads(tmp_path):
    generate_dataset(tmp_path, dim=2, scale=0.0002, seed=0, lengths=[3], progress=False)
    f = tmp_path / "2d" / "len_03" / "test.txt"
    lines = f.read_bytes().splitlines(keepends=True)
    f.write_bytes(b"c(32,32,8)\xffs(8,8,8)+\n" + b"".join(lines))
    with pytest.warns(UserWarning, match=re.escape(f"{f}:1:11: not UTF-8 text (byte 0xff)")):
        progs = load_dataset(tmp_path, 2, "test")
    assert len(progs[3]) == len(lines)
    with pytest.raises(ValueError, match="not UTF-8"):
        load_dataset(tmp_path, 2, "test", errors="raise")
