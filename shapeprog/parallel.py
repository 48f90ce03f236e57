"""Per-item work on a ``concurrent.futures.Executor`` (a process pool by default in the commands; Dask or Ray
executors work too), or here when there is none."""
from __future__ import annotations

from typing import Callable, Iterable, Iterator

__all__ = ["ordered_map"]


def ordered_map(executor, fn: Callable, jobs: Iterable, window: int = 4) -> Iterator:
    """``fn`` over ``jobs`` (an iterable, consumed lazily), results in order; here, or on ``executor`` with at
    most ``window`` jobs in flight (so that a long stream of large jobs is not all submitted at once)."""
    if executor is None:
        yield from map(fn, jobs)
        return
    pending = []
    for job in jobs:
        pending.append(executor.submit(fn, job))
        if len(pending) >= window:
            yield pending.pop(0).result()
    for f in pending:
        yield f.result()
