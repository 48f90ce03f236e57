"""The ShapeAssembly fuzz target (``tests/fuzz/shapeassembly_targets.py``; the bounded run itself is
``tests/fuzz/test_fuzz.py``, which runs every registered target): its mutations reach the parser's errors,
the executor's errors and successful executions, and its check reports foreign exceptions."""
import random
import warnings

import pytest

from fuzz import shapeassembly_targets as target

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
    with pytest.raises(AssertionError, match="KeyError"):
        target.check("bbox = Cuboid(1.0, 1.0, 1.0, True)\n")
