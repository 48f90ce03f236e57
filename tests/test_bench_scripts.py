"""The benchmark scripts under bench/ are run by hand, not by the test suite: each must at least compile on the
Python the project supports, so that a syntax only a newer Python accepts is caught here."""
from pathlib import Path

import pytest

BENCH = sorted((Path(__file__).resolve().parents[1] / "bench").glob("*.py"))


def test_there_are_bench_scripts():
    assert len(BENCH) > 10


@pytest.mark.parametrize("path", BENCH, ids=lambda p: p.name)
def test_bench_script_compiles(path):
    compile(path.read_text(encoding="utf-8"), str(path), "exec")
