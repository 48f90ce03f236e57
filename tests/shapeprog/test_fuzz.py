"""A bounded fuzz run of the ShapeAssembly parser and executor (``tests/fuzz/shapeassembly_targets.py``).

Seeded, so a failure reproduces: only ParseError and ExecutionError escape, parsing and execution stay
within their time bounds, and no executed shape holds a non-finite number. Longer runs use the same
target with other seeds.
"""
import random
import time
import warnings

import pytest

from fuzz import shapeassembly_targets as target

INPUTS = 300  # about 2 s on a 2-core machine


def test_fuzz_parser_and_executor_only_raise_own_errors_in_bounded_time():
    seeds = target.seeds()
    rng = random.Random(20240611)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a stray-comma ParseWarning is allowed
        for n in range(INPUTS):
            text = target.mutate(rng, rng.choice(seeds))
            try:
                target.check(text)
            except AssertionError as e:
                raise AssertionError(f"input {n} (seed 20240611): {e}\n--- input ---\n{text}") from None
    assert time.perf_counter() - t0 < 30


def test_mutations_reach_the_executor_and_both_error_types():
    seeds = target.seeds(n=12)
    rng = random.Random(1)
    outcomes = set()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(200):
            text = target.mutate(rng, rng.choice(seeds))
            try:
                program = target.parse(text, "fuzz.txt")
            except target.ParseError:
                outcomes.add("parse error")
                continue
            try:
                target.execute(program)
                outcomes.add("executed")
            except target.ExecutionError:
                outcomes.add("execution error")
    assert outcomes == {"parse error", "executed", "execution error"}


def test_check_reports_foreign_exceptions(monkeypatch):
    def broken(text, file):
        raise KeyError("cube9")

    monkeypatch.setattr(target, "parse", broken)
    with pytest.raises(AssertionError, match="parse raised KeyError"):
        target.check("bbox = Cuboid(1.0, 1.0, 1.0, True)\n")
