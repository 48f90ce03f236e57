"""The refactored corpus (write, read back, executor, failures, the command, the shipped archive) and the
perturbed execution of macro programs."""
import hashlib
import json
import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest
import torch

from shapeprog import corpus, parse
from shapeprog.__main__ import main
from shapeio import InputError
from shapeprog.errors import ParseError
from shapeprog.execute import execute as sa_execute
from shapeprog.macros import Library, hierarchy, load_library
from shapeprog.macros.execute import compile_hierarchy, execute_hierarchy, hierarchy_parameters
from shapeprog.macros.perturb import MIN_DIM, PerturbablePrograms, continuous_mask
from shapeprog.macros.refactored import (CHECK_TOL, SUMMARY, _leaf_error, load_refactored, read_refactored,
                                         refactor_corpus, refactor_texts, write_refactored)

IDS = [173, 44017, 36880]


@pytest.fixture(scope="module")
def lib():
    return load_library("chair")


@pytest.fixture(scope="module")
def three(lib):
    return refactor_corpus("chair", lib, "chair", ids=IDS)


def _corners(h):
    with torch.no_grad():
        return execute_hierarchy(h).corners


def test_written_programs_parse_expand_and_execute_to_the_originals(three, tmp_path):
    out = write_refactored(three, tmp_path / "chair_macros", command="test")
    assert sorted(p.name for p in out.iterdir()) == sorted([f"{i}.txt" for i in IDS] + [SUMMARY])
    programs, summary = read_refactored(out)
    assert list(programs) == sorted(IDS)
    assert summary["command"] == "test" and summary["refactored"] == 3 and summary["failures"] == []
    per = {s["id"]: s for s in summary["per_shape"]}
    for s in three.shapes:
        h = programs[s.shape_id]
        assert hierarchy.to_text(h) == s.text  # the file is the canonical text
        want = sa_execute(parse(corpus.read("chair", s.shape_id))).corners
        got = _corners(h)
        err = _leaf_error(got, want)
        assert len(got) == len(want) == per[s.shape_id]["leaves"]
        assert err == pytest.approx(per[s.shape_id]["max_corner_error"], abs=1e-6)
        assert err <= CHECK_TOL
        # fewer parameters with the macros, never more calls
        assert per[s.shape_id]["float_after"] < per[s.shape_id]["float_before"]
        assert per[s.shape_id]["lines_after"] <= per[s.shape_id]["lines_before"]
    # the archive holds the same files
    arc = write_refactored(three, tmp_path / "chair.tar.xz", command="test")
    again, summary2 = read_refactored(arc)
    assert again == programs and summary2 == summary
    assert read_refactored(arc, ids=[173])[0].keys() == {173}


def test_executor_path_equals_serial_path(lib):
    items = [(i, corpus.read("chair", i)) for i in IDS[:2]] + [(7, "Assembly Program_0 {\n  bbox = Cuboid(1.0\n}\n")]
    serial = refactor_texts("chair", items, lib)
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        pooled = refactor_texts("chair", items, lib, executor=pool, chunk=1)
    assert pooled == serial
    assert [s.shape_id for s in serial] == [173, 44017, 7]


def test_a_bad_shape_is_reported_and_the_rest_kept(lib, tmp_path):
    items = [(1, "Assembly Program_0 {\n  bbox = Cubiod(1.0, 1.0, 1.0, True)\n}\n"),
             (173, corpus.read("chair", 173)),
             (48522, corpus.read("chair", 48522))]  # a block with two reflect/translate of one cuboid
    from shapeprog.macros.refactored import RefactoredCorpus

    rc = RefactoredCorpus("chair", "chair", refactor_texts("chair", items, lib))
    assert [s.error is None for s in rc.shapes] == [False, True, False]
    assert "does not parse" in rc.shapes[0].error and "chair/1.txt:2" in rc.shapes[0].error
    assert "Program_3 has more than one reflect/translate" in rc.shapes[2].error
    out = write_refactored(rc, tmp_path / "out")
    programs, summary = read_refactored(out)
    assert list(programs) == [173]
    assert summary["shapes"] == 3 and summary["refactored"] == 1 and summary["failed"] == 2
    assert [f["id"] for f in summary["failures"]] == [1, 48522]
    assert [s["id"] for s in summary["per_shape"]] == [1, 173, 48522]
    assert summary["per_shape"][0] == {"id": 1, "error": rc.shapes[0].error}
    # without the check the counts are the same and nothing is executed
    unchecked = RefactoredCorpus("chair", "chair", refactor_texts("chair", items, lib, check=False)).summary()
    assert unchecked["per_shape"][1] == {**summary["per_shape"][1], "leaves": None, "max_corner_error": None}
    assert unchecked["mean_per_shape"]["leaves"] is None and unchecked["max_corner_error"] is None


def test_outputs_are_never_overwritten(three, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    write_refactored(three, empty)  # an empty folder may be filled
    with pytest.raises(FileExistsError, match="not an empty folder"):
        write_refactored(three, empty)
    before = {p.name: p.read_bytes() for p in empty.iterdir()}
    arc = write_refactored(three, tmp_path / "a.tar.xz")
    data = arc.read_bytes()
    with pytest.raises(FileExistsError):
        write_refactored(three, arc)
    assert arc.read_bytes() == data and {p.name: p.read_bytes() for p in empty.iterdir()} == before
    with pytest.raises(FileNotFoundError):
        write_refactored(three, tmp_path / "missing" / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.tar.xz", "empty"]  # no temporary left


def test_read_refactored_names_a_bad_file(tmp_path, monkeypatch):
    (tmp_path / "5.txt").write_text("# Program_0\nbbox = Cuboid(1.0, 1.0, 1.0, True)\nc = nope(1.0)\n\n")
    with pytest.raises(ParseError, match=r"5\.txt:3:"):
        read_refactored(tmp_path)
    (tmp_path / "5.txt").write_bytes(b"# Program_0\nbbox = Cuboid(1.0, 1.0, 1.0, True)\xff\n\n")
    with pytest.raises(ParseError, match=r"5\.txt:2:.*not UTF-8"):
        read_refactored(tmp_path)
    (tmp_path / "5.txt").unlink()
    (tmp_path / SUMMARY).write_text("{")
    with pytest.raises(InputError, match="summary.json:1:2: not JSON"):
        read_refactored(tmp_path)
    for text, match in (("[1, 2]", "not a summary JSON"), ("[" * 5000, "nested more than 64"), ("1" * 5000, "not JSON")):
        (tmp_path / SUMMARY).write_text(text)
        with pytest.raises(InputError, match=match):
            read_refactored(tmp_path)
    (tmp_path / SUMMARY).unlink()
    bad = tmp_path / "x.tar.xz"
    bad.write_bytes(b"not xz")
    with pytest.raises(InputError, match=r"x\.tar\.xz: not a \.tar\.xz archive"):
        read_refactored(bad)
    with pytest.raises(FileNotFoundError):
        read_refactored(tmp_path / "none")
    # an archive that decompresses past the limit is refused before it is unpacked; a truncated one too
    import lzma

    from shapeprog.macros import refactored
    bomb = tmp_path / "bomb.tar.xz"
    bomb.write_bytes(lzma.compress(bytes(4096)))
    monkeypatch.setattr(refactored, "MAX_ARCHIVE_BYTES", 1024)
    with pytest.raises(InputError, match=r"bomb\.tar\.xz: decompresses to more than MAX_ARCHIVE_BYTES = 1024"):
        read_refactored(bomb)
    bomb.write_bytes(lzma.compress(bytes(512))[:-8])
    with pytest.raises(InputError, match=r"bomb\.tar\.xz: a truncated \.xz file"):
        read_refactored(bomb)


def test_refactor_corpus_command(tmp_path, capsys):
    out = tmp_path / "c"
    argv = ["macros", "refactor-corpus", "--category", "chair", "--library", "chair", "--limit", "3", "--split", "val",
            "--workers", "1", "--out", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert "3 of 3 shapes refactored" in printed and f"wrote {out}" in printed
    summary = json.loads((out / SUMMARY).read_text())
    assert summary["command"] == "python -m shapeprog " + " ".join(argv)
    assert summary["split"] == "val" and summary["shapes"] == 3
    assert all(i in corpus.ids("chair", "val") for i in read_refactored(out)[0])
    with pytest.raises(SystemExit, match="not an empty folder"):
        main(argv)


def test_shipped_refactored_chairs_match_the_shipped_library(lib, three):
    programs, summary = load_refactored("chair", ids=IDS)
    assert summary["library_sha256"] == hashlib.sha256(lib.to_text().encode()).hexdigest(), (
        "the shipped library changed: regenerate shapeprog/data/shapemod_chair_refactored.tar.xz with the "
        "summary's command")
    assert summary["refactored"] + summary["failed"] == summary["shapes"] == len(corpus.ids("chair", "all"))
    assert [hierarchy.to_text(programs[i]) for i in IDS] == [s.text for s in three.shapes]
    with pytest.raises(ValueError, match="no shipped refactored corpus for 'bench'"):
        load_refactored("bench")


@pytest.mark.parametrize("category", ["table", "storage"])
def test_shipped_refactored_corpora_match_their_shipped_library(category):
    lib = load_library(category)
    ids = corpus.ids(category, "all")[:2]
    programs, summary = load_refactored(category, ids=ids)
    assert summary["library_sha256"] == hashlib.sha256(lib.to_text().encode()).hexdigest(), (
        f"the shipped {category} library changed: regenerate its refactored corpus with the summary's command")
    assert summary["refactored"] + summary["failed"] == summary["shapes"] == len(corpus.ids(category, "all"))
    assert sorted(programs) == sorted(ids)


# --------------------------------------------------------------------------------------------------
# perturbation

LEG = ("# Program_0\ndef leg(s: float, b: bool, t: float):\n    c = Cuboid(s, bb_y, s, b)\n"
       "    squeeze(bbox, bbox, top, 0.6 * s, t)\n    reflect(X)\n\n"
       "bbox = Cuboid(1.0, 0.8, 1.0, True)\nl0 = leg(0.1, True, 0.2)\nc1 = Cuboid(0.5, 0.1, 0.5, True)\n"
       "attach(bbox, 0.5, 0.9, 0.5, 0.5, 0.9, 0.5)\ntranslate(X, 2, 0.3)\n\n")


def test_continuous_parameters_exclude_the_bbox_and_translate_counts():
    h = hierarchy.parse(LEG)
    # parameters: bbox 3 | leg s, t | Cuboid 3 | attach 6 | translate n, d
    assert continuous_mask(h).tolist() == [False] * 3 + [True] * 2 + [True] * 9 + [False, True]
    base = hierarchy.parse(hierarchy.to_text(h.replace([Library().with_program(h.programs[0]).inline(h.programs[0])])))
    # the inlined program exposes every float of its lines: Cuboid 3, squeeze 2, Cuboid 3, attach 6, d
    assert PerturbablePrograms([base]).n_continuous == [3 + 2 + 3 + 6 + 1]


def test_perturbation_moves_only_continuous_numbers_through_the_macros():
    h = hierarchy.parse(LEG)
    pp = PerturbablePrograms([h])
    x = hierarchy_parameters(h, torch.float64)
    c = compile_hierarchy(h)
    # sigma 0: exactly the program's own execution
    assert torch.equal(pp.perturb(0.0, np.random.default_rng(0))[0], _corners(h))
    rng = np.random.default_rng(3)
    nums = pp.numbers(0.01, rng)[0]
    noise = torch.from_numpy(np.random.default_rng(3).standard_normal(pp.n_continuous[0]))
    y = x.clone()
    y[pp.masks[0]] += 0.01 * noise
    assert torch.allclose(nums, c.numbers(y), atol=1e-12)  # small noise: nothing clamped
    # numbers: bbox 0-2, the leg's Cuboid 3-5, c1 6-8 (declarations first), squeeze 9-10, attach 11-16,
    # translate's distance 17. The leg's width s moves its length, its depth and the squeeze's u (0.6 * s).
    delta = nums - c.numbers(x)
    ds = 0.01 * float(noise[0])
    assert delta[[3, 5]].tolist() == pytest.approx([ds, ds], abs=1e-12)
    assert float(delta[9]) == pytest.approx(0.6 * ds, abs=1e-12)
    assert float(delta[10]) == pytest.approx(0.01 * float(noise[1]), abs=1e-12)
    assert delta[[0, 1, 2, 4]].tolist() == [0.0] * 4  # the bbox and bb_y never move
    assert int((delta != 0).sum()) == 2 + 3 + 2 + 6 + 1


def test_large_noise_is_clamped_to_the_language_ranges():
    h = hierarchy.parse(LEG)
    pp = PerturbablePrograms([h])
    nums = pp.numbers(5.0, np.random.default_rng(1))[0]
    assert bool((nums >= pp.low[0]).all() and (nums <= pp.high[0]).all())
    assert nums[:3].tolist() == [1.0, 0.8, 1.0]  # the bbox never moves
    assert (pp.low[0] == MIN_DIM).sum() == 3 * 3  # bbox, the leg's cuboid, c1
    with pytest.raises(ValueError, match="sigma"):
        pp.numbers(-1.0, np.random.default_rng(0))
