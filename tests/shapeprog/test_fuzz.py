"""The ShapeAssembly fuzz target (``tests/fuzz/shapeassembly_targets.py``; the bounded run itself is
``tests/fuzz/test_fuzz.py``, which runs every registered target): its mutations reach the parser's errors,
the executor's errors and successful executions."""
import random
import warnings


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
