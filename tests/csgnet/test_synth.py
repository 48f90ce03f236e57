"""The synthetic program sampler (csgnet.synth): its rules against an independent NumPy check, and the
distributions of primitive types and operators."""
import collections
import math

import numpy as np

from csg_testutil import rules_hold
from csgnet.synth import Rules, _draw_candidates, check_programs, sample_programs
from csgnet.vocab import vocabulary


def test_batched_check_equals_numpy_check_on_random_candidates():
    rules = Rules().resolved(2)
    cand = _draw_candidates(2, 5, rules, 150, np.random.default_rng(7))
    got = check_programs(cand, 2, rules)
    vocab = vocabulary(2)
    want = np.array([rules_hold(vocab.decode(row), 100) for row in cand])
    assert 0 < want.sum() < len(want)  # both outcomes occur
    assert (got == want).all()


def test_literal_sum_rule_is_available():
    vocab = vocabulary(2)
    # two disjoint circles: their union changes nothing on the stack total, so "sum" rejects it
    disjoint = np.array([vocab.encode("c(16,16,8)c(48,48,8)+")])
    assert check_programs(disjoint, 2, Rules(change_rule="sum"))[0] == False  # noqa: E712
    assert check_programs(disjoint, 2, Rules())[0] == True  # noqa: E712
    inside = np.array([vocab.encode("c(32,32,28)c(32,32,8)+")])  # the union adds nothing
    assert check_programs(inside, 2, Rules())[0] == False  # noqa: E712


def _frequencies(rows: np.ndarray, dim: int) -> collections.Counter:
    vocab = vocabulary(dim)
    return collections.Counter(vocab.tokens[i][0] for i in rows.ravel())


def test_primitive_types_uniform_when_nothing_is_rejected():
    rules = Rules(min_change=0.0, min_pixels=0)
    rows = sample_programs(2, 5, 2000, np.random.default_rng(0), rules)
    c = _frequencies(rows, 2)
    n = sum(c[k] for k in "cst")
    sd = math.sqrt(n / 3 * 2 / 3)
    for k in "cst":  # binomial, 5 standard deviations
        assert abs(c[k] - n / 3) < 5 * sd, c


def test_primitive_types_roughly_uniform_under_the_rules():
    rows = sample_programs(2, 9, 600, np.random.default_rng(1))
    c = _frequencies(rows, 2)
    n = sum(c[k] for k in "cst")
    for k in "cst":  # rule (b) favours larger shapes (triangles are the smallest): a documented bias
        assert 0.25 < c[k] / n < 0.42, c


def test_subtract_and_intersect_boosted():
    rng_a, rng_b = np.random.default_rng(2), np.random.default_rng(2)
    plain = _frequencies(sample_programs(2, 7, 800, rng_a, Rules(op_weights=(1, 1, 1))), 2)
    boosted = _frequencies(sample_programs(2, 7, 800, rng_b), 2)
    n = 800 * 3
    assert boosted["*"] / n > plain["*"] / n + 0.05
    assert boosted["-"] / n > plain["-"] / n + 0.02
    assert plain["+"] > plain["*"]  # rule (b) favours unions, which is why the boost exists
