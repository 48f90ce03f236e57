"""Every registered fuzz target, a few seconds each: only the project's own errors escape, every input
finishes within its bound, and execution yields finite numbers (docs/fuzzing.md)."""

import math
import time

import pytest

from fuzz import registry
from fuzz.engine import Target, fuzz

SECONDS = 3.0
#: Mutated inputs every target runs at least, however slow the machine (then more until SECONDS have passed).
MIN_MUTATIONS = 10


@pytest.mark.parametrize("target", registry.targets(), ids=lambda t: t.name)
def test_fuzz_target(target):
    stats = fuzz(target, seconds=SECONDS, seed=0, min_inputs=len(target.seeds) + MIN_MUTATIONS)
    assert stats.inputs >= len(target.seeds) + MIN_MUTATIONS
    assert not stats.findings, "\n".join(f"{f.kind}: {f.detail}: {f.data[:200]!r}" for f in stats.findings)


def test_engine_reports_foreign_errors_non_finite_numbers_and_slow_inputs():
    def run(data: bytes):
        if data == b"key":
            raise KeyError("cube9")
        if data == b"own":
            raise ValueError("a located error of the project's own kind")
        if data == b"slow":
            time.sleep(0.05)
        return [math.nan] if data == b"nan" else [1.0]

    target = Target("test/engine", [b"key", b"own", b"slow", b"nan", b"fine"], run, (ValueError,), bound_s=0.02,
                    mutator=lambda data, rng, seeds: b"fine")
    stats = fuzz(target, inputs=8, seed=0)
    assert stats.inputs == 8
    assert fuzz(target, seconds=0.0, seed=0, min_inputs=7).inputs == 7  # the floor holds even with no time
    kinds = sorted((f.kind, f.data) for f in stats.findings)
    assert kinds == [("error", b"key"), ("non-finite", b"nan"), ("slow", b"slow")]
    assert "KeyError" in next(f.detail for f in stats.findings if f.kind == "error")
