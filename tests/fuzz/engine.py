"""A seeded byte mutator and the loop that runs one fuzz target (docs/fuzzing.md).

A target is a :class:`Target`: real inputs to start from (``seeds``), a function that feeds one input
to a parser or loader and returns the numbers its execution produced, and the error types the project
allows to escape. :func:`fuzz` mutates the seeds with a ``random.Random`` and records a finding for an
input that raises any other error, takes longer than the target's bound, or yields a non-finite number.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable, Sequence

__all__ = ["Target", "Finding", "Stats", "mutate", "fuzz"]

_INTERESTING = [b"0", b"-1", b"99999999999999999999", b"nan", b"inf", b"\xff", b"\x00", b"(", b")", b",",
                b"+", b"-", b"*", b"$", b"\xd9\xa3", b" ", b"\n", b"1e308"]


@dataclass(frozen=True)
class Target:
    """One parser or loader under fuzzing.

    Attributes:
        name: ``family/what``, e.g. ``csg/text-2d``.
        seeds: real inputs the mutator starts from.
        run: feeds one input; returns the numbers the execution produced (checked to be finite).
        allowed: the error types that may escape ``run`` (the project's own).
        bound_s: the longest one input may take.
        mutator: ``(data, rng, seeds) -> bytes``, a structured mutator of the target's own (default: the
            byte mutator :func:`mutate`).
    """

    name: str
    seeds: Sequence[bytes]
    run: Callable[[bytes], Iterable[float]]
    allowed: tuple[type[BaseException], ...]
    bound_s: float = 2.0
    mutator: Callable[[bytes, random.Random, Sequence[bytes]], bytes] | None = None


@dataclass(frozen=True)
class Finding:
    """An input that broke a rule: ``kind`` is ``"error"``, ``"slow"`` or ``"non-finite"``."""

    target: str
    kind: str
    detail: str
    data: bytes


@dataclass
class Stats:
    """What one :func:`fuzz` run did."""

    target: str
    inputs: int = 0
    seconds: float = 0.0
    findings: list[Finding] = field(default_factory=list)

    @property
    def rate(self) -> float:
        return self.inputs / self.seconds if self.seconds else 0.0


def mutate(data: bytes, rng: random.Random, seeds: Sequence[bytes] = ()) -> bytes:
    """One to four random edits of ``data``: flip, insert, delete, duplicate, splice, or an interesting token."""
    buf = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        op = rng.randrange(7)
        i = rng.randrange(len(buf) + 1)
        if op == 0 and buf:
            buf[min(i, len(buf) - 1)] ^= 1 << rng.randrange(8)
        elif op == 1:
            buf[i:i] = bytes([rng.randrange(256)])
        elif op == 2 and buf:
            del buf[i:i + rng.randint(1, 8)]
        elif op == 3 and buf:
            j = rng.randrange(len(buf))
            buf[i:i] = buf[j:j + rng.randint(1, 16)]
        elif op == 4 and seeds:
            other = rng.choice(seeds)
            j = rng.randrange(len(other) + 1)
            buf = buf[:i] + bytearray(other[j:])
        elif op == 5:
            buf[i:i] = rng.choice(_INTERESTING)
        elif op == 6 and buf:
            buf[i:i + 1] = rng.choice(_INTERESTING)
    return bytes(buf)


def fuzz(target: Target, seconds: float | None = None, inputs: int | None = None, seed: int = 0,
         min_inputs: int = 0) -> Stats:
    """Run ``target`` on its seeds, then on mutations, for ``seconds`` or ``inputs`` (whichever ends first),
    but never fewer than ``min_inputs`` inputs (however long they take)."""
    rng = random.Random(seed)
    stats = Stats(target.name)
    start = time.perf_counter()
    queue = list(target.seeds)
    while True:
        elapsed = time.perf_counter() - start
        if stats.inputs >= min_inputs and ((seconds is not None and elapsed >= seconds)
                                           or (inputs is not None and stats.inputs >= inputs)):
            break
        data = queue.pop() if queue else (target.mutator or mutate)(rng.choice(target.seeds), rng, target.seeds)
        t0 = time.perf_counter()
        try:
            values = list(target.run(data))
            bad = [v for v in values if not math.isfinite(v)]
            if bad:
                stats.findings.append(Finding(target.name, "non-finite", repr(bad[:3]), data))
        except target.allowed:
            pass
        except Exception as e:  # noqa: BLE001 - every other escape is a finding
            stats.findings.append(Finding(target.name, "error", f"{type(e).__name__}: {e}"[:300], data))
        took = time.perf_counter() - t0
        if took > target.bound_s:
            stats.findings.append(Finding(target.name, "slow", f"{took:.2f} s", data))
        stats.inputs += 1
    stats.seconds = time.perf_counter() - start
    return stats
