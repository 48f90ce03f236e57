"""Tests for shapeprog.vae.structure and shapeprog.vae.smoothness: structural novelty, editability, the token edit
distance and interpolation smoothness."""
import random

import pytest

from shapeprog import corpus, parse
from shapeprog.lang import numbers, replace_numbers, to_text
from shapeprog.vae import load_pretrained, structural_novelty, structure_key
from shapeprog.vae.smoothness import interpolation_smoothness, step_distances
from shapeprog.vae.structure import (EDITABILITY_KEYS, edit_distance, editability, mean_editability, program_tokens,
                                     training_structures)
from sa_testutil import FLAT



def perturbed(program, rng, sigma=0.1):
    return replace_numbers(program, [v + rng.gauss(0.0, sigma) for v in numbers(program)])


# ---------------------------------------------------------------- structure and novelty

def test_structure_key_abstracts_numbers_only():
    p = parse(FLAT)
    q = perturbed(p, random.Random(0))
    assert to_text(q) != to_text(p) and structure_key(q) == structure_key(p) == structure_key(FLAT)
    assert "cube0 = Cuboid(0.0, 0.0, 0.0, True)" in structure_key(p)
    for old, new in (("True)\ncube1", "False)\ncube1"), ("reflect(cube0, X)", "reflect(cube0, Z)"),
                     ("translate(cube0, Z, 2", "translate(cube0, Z, 3"), ("attach(cube1, cube0", "attach(cube1, bbox")):
        assert structure_key(FLAT.replace(old, new)) != structure_key(p), new
    with pytest.raises(TypeError, match="Program or program text"):
        structure_key(3)


def test_structural_novelty_of_perturbed_training_programs_is_zero():
    train = [p for _, p in corpus.load("storage", "train")]
    rng = random.Random(1)
    moved = [perturbed(p, rng) for p in train[::10]]
    assert all(to_text(m) != to_text(p) for m, p in zip(moved, train[::10]))
    assert structural_novelty(moved, "storage") == 0.0
    assert structural_novelty([to_text(m) for m in moved[:5]], "storage") == 0.0  # texts as well as programs
    assert len(training_structures("storage")) < len(train)  # some training programs share a structure


def test_structural_novelty_of_the_val_split_is_strictly_between():
    val = [p for _, p in corpus.load("storage", "val")]
    novel = structural_novelty(val, "storage")
    assert 0.0 < novel < 1.0
    known = training_structures("storage")
    assert novel == sum(structure_key(p) not in known for p in val) / len(val)


def test_structural_novelty_against_given_programs_and_errors():
    p = parse(FLAT)
    other = parse(FLAT.replace("reflect(cube0, X)", "reflect(cube0, Z)"))
    assert structural_novelty([perturbed(p, random.Random(2)), other], training=[p]) == 0.5
    with pytest.raises(ValueError, match="either category or training"):
        structural_novelty([p])
    with pytest.raises(ValueError, match="either category or training"):
        structural_novelty([p], "chair", training=[p])
    with pytest.raises(ValueError, match="no program"):
        structural_novelty([], training=[p])
    with pytest.raises(ValueError, match="unknown category 'sofa'"):
        structural_novelty([p], "sofa")


# ---------------------------------------------------------------- edit distance

def slow_levenshtein(a, b):
    rows = list(range(len(b) + 1))
    for i, x in enumerate(a, 1):
        cur = [i]
        for j, y in enumerate(b, 1):
            cur.append(min(rows[j] + 1, cur[j - 1] + 1, rows[j - 1] + (x != y)))
        rows = cur
    return rows[-1]


def test_edit_distance_known_values():
    assert edit_distance("kitten", "sitting") == 3
    assert edit_distance("flaw", "lawn") == 2
    assert edit_distance("", "abc") == edit_distance("abc", "") == 3
    assert edit_distance("abc", "abc") == 0 and edit_distance("", "") == 0
    assert edit_distance(["attach", "(", "a"], ["attach", "(", "b", ")"]) == 2
    rng = random.Random(3)
    for _ in range(200):
        a = [rng.choice("abc") for _ in range(rng.randrange(12))]
        b = [rng.choice("abc") for _ in range(rng.randrange(12))]
        assert edit_distance(a, b) == edit_distance(b, a) == slow_levenshtein(a, b)


def test_program_tokens():
    text = "bbox = Cuboid(1.0, 1.0, 1.0, True)\ncube0 = Cuboid(0.5, 0.25, 0.5, False)\nreflect(cube0, X)\n"
    assert program_tokens(text)[:12] == ["bbox", "=", "Cuboid", "(", "1.0", ",", "1.0", ",", "1.0", ",", "True", ")"]
    assert program_tokens(text)[12:] == ["cube0", "=", "Cuboid", "(", "0.5", ",", "0.25", ",", "0.5", ",", "False",
                                         ")", "reflect", "(", "cube0", ",", "X", ")"]
    p = parse(FLAT)
    noisy = replace_numbers(p, [v + 1e-5 for v in numbers(p)])  # below the corpus's 3 decimals
    assert program_tokens(noisy) == program_tokens(p)
    one = replace_numbers(p, [v + (0.25 if i == 0 else 0.0) for i, v in enumerate(numbers(p))])
    assert edit_distance(program_tokens(one), program_tokens(p)) == 1


# ---------------------------------------------------------------- editability

def test_editability_counts():
    e = editability(FLAT)
    assert {k: e[k] for k in EDITABILITY_KEYS if k not in ("macro_lines",)} == {
        "lines": 7, "blocks": 1, "cuboid_lines": 3, "attach_lines": 2, "squeeze_lines": 0, "reflect_lines": 1,
        "translate_lines": 1, "macro_parts": 60.0}  # 2 declared parts, 1 + 2 copies
    assert e["macro_lines"] == pytest.approx(100 * 2 / 7)
    storage = corpus.read("storage", corpus.ids("storage", "val")[0])
    e = editability(storage)
    assert (e["lines"], e["blocks"], e["squeeze_lines"], e["reflect_lines"], e["translate_lines"]) == (27, 3, 4, 2, 1)
    assert e["macro_parts"] == 100 * 7 / 16
    m = mean_editability([FLAT, storage])
    assert m["programs"] == 2 and m["lines"] == 17.0
    with pytest.raises(ValueError, match="no program"):
        mean_editability([])


# ---------------------------------------------------------------- smoothness

def test_step_distances_of_equal_and_changed_programs():
    p = parse(FLAT)
    q = parse(FLAT.replace("reflect(cube0, X)\n", ""))
    geometric, program, structure = step_distances([p, p, q])
    assert geometric[0] == 0.0 and program[0] == 0 and structure[0] == 0  # same shape, same sampling seed
    assert geometric[1] > 0 and program[1] == 6 and structure[1] == 6  # the six tokens of the reflect line
    assert (geometric[2], program[2]) == (geometric[1], 6)  # the ends: p and q


def test_interpolation_smoothness_small():
    vae = load_pretrained("storage")
    r = interpolation_smoothness(vae, sequences=2, steps=4, seed=0)
    assert (r["sequences"], r["steps"]) == (2, 4) and r["pairs"] <= 6
    assert 0 <= r["geometric"] and 0 <= r["structure"] <= r["program"] and 0 <= r["unchanged"] <= 100
    assert r == {**interpolation_smoothness(vae, sequences=2, steps=4, seed=0), "seconds": r["seconds"]}
    with pytest.raises(ValueError, match="steps"):
        interpolation_smoothness(vae, sequences=1, steps=1)
    with pytest.raises(ValueError, match="sequences"):
        interpolation_smoothness(vae, sequences=0)


# ---------------------------------------------------------------- commands

def test_novelty_editability_and_smoothness_commands(tmp_path, capsys):
    from shapeio.results import read_result
    from shapeprog.__main__ import main

    assert main(["vae", "novelty", "--category", "storage", "-n", "5", "--json", str(tmp_path / "n.json")]) == 0
    rows = read_result(tmp_path / "n.json")["rows"]
    assert [(r["category"], r["programs"]) for r in rows] == [("storage", 5), ("storage", 116)]
    val = [p for _, p in corpus.load("storage", "val")]
    assert rows[1]["structure"] == 100 * structural_novelty(val, "storage") and rows[1]["text"] == 100.0
    assert main(["vae", "editability", "--category", "storage", "-n", "5", "--json", str(tmp_path / "e.json")]) == 0
    rows = read_result(tmp_path / "e.json")["rows"]
    assert rows[0] == {"category": "storage", "row": "corpus val split", **mean_editability(val)}
    assert rows[1]["programs"] == 5
    assert main(["vae", "smoothness", "--category", "storage", "--sequences", "1", "--steps", "3", "--quiet",
                 "--json", str(tmp_path / "s.json")]) == 0
    (row,) = read_result(tmp_path / "s.json")["rows"]
    assert (row["sequences"], row["steps"], row["category"]) == (1, 3, "storage") and row["geometric"] >= 0
    assert "1 sequences x 3 steps" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="exists"):
        main(["vae", "novelty", "--category", "storage", "-n", "5", "--json", str(tmp_path / "n.json")])
