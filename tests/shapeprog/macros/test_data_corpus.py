"""The whole corpus as sub-programs: counts, failures, and orderings that execute as the original programs.

Executing every ordering of every sub-program (1,046,374 orderings) takes too long for the test suite on
a 2-core machine; ``python bench/shapemod_data.py --check all`` does it (docs/shapemod.md, "Data"). Here:
the first ordering of every storage sub-program, and every ordering (up to 40: the first and the last
20 enumerated) of the sub-programs of a seeded random sample of programs of every category.
"""
import dataclasses
import random

import pytest

from shapeprog import corpus
from shapeprog.lang import parse
from shapeprog.macros.data import convert_corpus, convert_program, order_errors
from shapeprog.macros.subprogram import ORDER_TOL

# sub-programs and |O_P| before the MAX_ORDERS limit, per category (docs/shapemod.md)
EXPECTED = {"chair": (3835, 11911, 50404), "table": (6536, 16758, 983914), "storage": (1551, 3549, 547816)}


@pytest.fixture(scope="module")
def data():
    """Every corpus program converted, one ordering enumerated per sub-program."""
    return convert_corpus(max_orders=1)


def test_counts_and_the_one_failure(data):
    for cat, (programs, subs, n_orders) in EXPECTED.items():
        got = data.by_category(cat)
        assert data.programs[cat] == programs and len(got) == subs, cat
        assert sum(s.n_orders for s in got) == n_orders, cat
        assert all(len(s.orders) == 1 for s in got)
    assert [str(f) for f in data.failures] == [
        "chair/48522/Program_2: Program_3 has more than one reflect/translate (the grammar allows one)"]
    assert data.counts == {"close second attach dropped": 177, "close second attach kept": 65,
                           "text order differs, same cuboids": 123}
    # the grammar's shape: 1-9 cubes, each moved by 1-2 attaches or one squeeze
    assert max(len(s.cubes) for s in data.subprograms) == 9
    assert all(1 <= len(c.moves) <= 2 for s in data.subprograms for c in s.cubes)


def test_first_ordering_of_every_storage_subprogram_executes_as_the_original(data):
    progs = {}
    items = []
    for s in data.by_category("storage"):
        if s.shape_id not in progs:
            progs[s.shape_id] = parse(corpus.read("storage", s.shape_id))
        items.append((s, progs[s.shape_id]))
    errors = order_errors(items)
    assert len(errors) == 3549 and max(errors) <= ORDER_TOL


def test_every_ordering_of_a_random_sample_executes_as_the_original():
    rng = random.Random(0)
    items = []
    for cat in corpus.CATEGORIES:
        for i in rng.sample(corpus.ids(cat, "all"), 12):
            prog = parse(corpus.read(cat, i))
            for s in convert_program(prog, cat, i).subprograms:
                orders = s.orders if len(s.orders) <= 40 else s.orders[:20] + s.orders[-20:]
                items.append((dataclasses.replace(s, orders=orders), prog))
    assert sum(len(s.orders) for s, _ in items) > 300
    errors = order_errors(items)
    worst = max(range(len(items)), key=errors.__getitem__)
    assert errors[worst] <= ORDER_TOL, items[worst][0].key
