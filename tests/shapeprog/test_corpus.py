"""Corpus access: ids, splits, text, loading with per-file errors."""
import random
import warnings
from importlib.resources import files

import numpy as np
import pytest
import torch

from shapeprog import corpus
from shapeprog.errors import ParseError
from shapeprog.execute import execute_batch
from shapeprog.lang import Program, parse


@pytest.mark.parametrize("cat,train,val", [("chair", 3339, 496), ("table", 5762, 774), ("storage", 1435, 116)])
def test_split_sizes_disjoint(cat, train, val):
    tr, va = corpus.ids(cat, "train"), corpus.ids(cat, "val")
    assert (len(tr), len(va)) == (train, val) and not set(tr) & set(va)
    assert len(corpus.ids(cat, "all")) == train + val


def test_read_and_errors():
    assert corpus.read("chair", 173).startswith("Assembly Program_0 {\n\tbbox = Cuboid(0.893, 1.558, 1.019, True)")
    with pytest.raises(KeyError, match="chair/1"):
        corpus.read("chair", 1)
    with pytest.raises(ValueError, match="unknown category 'sofa'"):
        corpus.ids("sofa")
    with pytest.raises(ValueError, match="unknown split"):
        corpus.ids("chair", "test")


def test_load_reports_bad_files_by_name_and_keeps_the_rest(monkeypatch):
    real = corpus.read
    bad = corpus.ids("storage", "val")[3]

    def fake(cat, i):
        text = real(cat, i)
        return text.replace("Cuboid(", "Cubiod(", 1) if int(i) == bad else text

    monkeypatch.setattr(corpus, "read", fake)
    with pytest.warns(corpus.CorpusWarning, match=rf"storage/{bad}\.txt:2:\d+: unknown command 'Cubiod'"):
        progs = corpus.load("storage", "val")
    assert len(progs) == 115 and bad not in [i for i, _ in progs]
    with pytest.raises(ParseError, match=rf"storage/{bad}\.txt:2:\d+: unknown command 'Cubiod'"):
        corpus.load("storage", "val", strict=True)


def test_defect8_non_utf8_entry_is_reported_by_name_and_skipped(monkeypatch):
    arc = dict(corpus._archive("shapeassembly_partnet.tar.xz"))
    bad = corpus.ids("storage", "val")[5]
    arc[f"data/storage/{bad}.txt"] = arc[f"data/storage/{bad}.txt"].replace(b"Cuboid", b"Cub\xffid", 1)
    monkeypatch.setattr(corpus, "_archive", lambda name: arc)
    with pytest.raises(ParseError, match=rf"^storage/{bad}\.txt:2:\d+: not UTF-8 text"):
        corpus.read("storage", bad)
    with pytest.warns(corpus.CorpusWarning, match=rf"storage/{bad}\.txt:2:\d+: not UTF-8"):
        progs = corpus.load("storage", "val")
    assert len(progs) == 115 and bad not in [i for i, _ in progs]
    with pytest.raises(ValueError, match="not UTF-8"):
        corpus.load("storage", "val", strict=True)
    arc["data_splits/storage/val.txt"] = b"46436\n12x\n"
    with pytest.raises(ParseError, match=r"^data_splits/storage/val\.txt:2:1: not a program id: '12x'"):
        corpus.ids("storage", "val")


def test_load_parses_programs():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        progs = corpus.load("storage", "val")
    assert len(progs) == 116 and all(isinstance(p, Program) for _, p in progs)


def test_licence_notice_ships_with_the_data():
    """The vendored archives sit next to a notice carrying the licence text verbatim."""
    data = files("shapeprog") / "data"
    assert (data / "shapeassembly_partnet.tar.xz").is_file() and (data / "examples.tar.xz").is_file()
    notice = (data / "NOTICE.md").read_text(encoding="utf-8")
    for line in (
        "Copyright 2020, Brown University, Providence, RI.",
        "its documentation for any purpose other than its incorporation into a",
        "commercial product or service is hereby granted without fee, provided",
        "BROWN UNIVERSITY DISCLAIMS ALL WARRANTIES WITH REGARD TO THIS SOFTWARE,",
        "OR IN CONNECTION WITH THE USE OR PERFORMANCE OF THIS SOFTWARE.",
    ):
        assert "\n" + line + "\n" in notice, line


def test_example_points():
    pts = corpus.example_points()
    assert pts.shape == (10000, 3) and abs(float(pts.max())) < 2
    # the second real cloud (a chair): a shape of its own, not a copy of the first
    simp = corpus.example_points("simp_pc.obj")
    assert simp.shape == (10000, 3) and np.isfinite(simp).all()
    assert not np.allclose(np.sort(simp, axis=0), np.sort(pts, axis=0), atol=1e-3)
    with pytest.raises(KeyError, match="available: comp_pc.obj, ex-0.txt, simp_pc.obj"):
        corpus.example_points("nope.obj")


def test_corpus_sample_executes_without_nan():
    rng = random.Random(0)
    sample = [(c, i) for c in corpus.CATEGORIES for i in rng.sample(corpus.ids(c, "all"), 40)]
    progs = [parse(corpus.read(c, i), f"{c}/{i}.txt") for c, i in sample]
    with torch.no_grad():
        shapes = execute_batch(progs)
    for (c, i), s in zip(sample, shapes):
        assert len(s) >= 3 and torch.isfinite(s.corners).all(), f"{c}/{i}"
        # leaves stay near their root bbox (clean_data's extent check holds to 1.5x except chair/42350)
        assert float((s.corners.abs() / (s.root_dims / 2)).max()) < 1.5, f"{c}/{i}"


def test_full_corpus_executes_and_matches_reference_statistics():
    """All 11,922 programs run without NaN, and the leaf counts and extent statistics equal the
    figures the specification reports for the reference executor (section (b))."""
    progs = [parse(corpus.read(c, i), f"{c}/{i}.txt") for c in corpus.CATEGORIES for i in corpus.ids(c, "all")]
    leaves, ext = [], []
    with torch.no_grad():
        for k in range(0, len(progs), 400):
            for s in execute_batch(progs[k:k + 400]):
                assert torch.isfinite(s.corners).all()
                leaves.append(len(s))
                ext.append(float((s.corners.abs() / (s.root_dims / 2)).max()))
    assert len(leaves) == 11922
    assert (min(leaves), max(leaves), round(sum(leaves) / len(leaves), 2)) == (3, 51, 9.13)
    counts = [sum(e > t for e in ext) for t in (1.0001, 1.01, 1.05, 1.5)]
    assert counts == [6201, 937, 7, 1]
