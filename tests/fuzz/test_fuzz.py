"""Every registered fuzz target, a few seconds each: only the project's own errors escape, every input
finishes within its bound, and execution yields finite numbers (docs/fuzzing.md)."""

import pytest

from fuzz import registry
from fuzz.engine import fuzz

SECONDS = 3.0


@pytest.mark.parametrize("target", registry.targets(), ids=lambda t: t.name)
def test_fuzz_target(target):
    stats = fuzz(target, seconds=SECONDS, seed=0)
    assert stats.inputs >= len(target.seeds)
    assert not stats.findings, "\n".join(f"{f.kind}: {f.detail}: {f.data[:200]!r}" for f in stats.findings)
