"""The paper's Table 4 (left): discovery with one feature switched off at a time, on the same shapes.

Each row is a :class:`~shapeprog.coder.config.Config` derived from one base configuration (:data:`ROWS`):

* **ShapeCoder (dream + wake)**: the base with the network wake (dreams, a recognition network, its search);
* **no dream + wake**: the base itself, whose wake refactors only;
* **no abstraction**: no proposal round (``rounds=0``): the wake alone, the naive programs refactored with
  the semantic rewrites;
* **single iteration**: one proposal round (``rounds=1``);
* **no semantic rewrites**: the abstraction rules only (``semantic_rewrites=False``);
* **no conditional rewrites**: the naive rewrite scheme (``scheme="naive"``: plain rewrites over relations
  put in as e-nodes);
* **no preferences**: every abstraction's ω constant and proposals ranked without the preference score
  (``preferences=False``).

The ablations other than the first are taken from the refactor-only base, so that each costs minutes on a
CPU (the paper ablates from its full method, which dreams and trains a network every round). Every row's F
is the paper's objective (:func:`~shapeprog.coder.discover.summarize`: ω from the preferences, also for the
"no preferences" row, whose discovery ran with the constant ω).

Example (seconds)::

    >>> from shapeprog.coder.config import Config
    >>> cfgs = row_configs(Config(rounds=2, n_proposals=100))
    >>> cfgs["single iteration"].rounds, cfgs["no conditional rewrites"].scheme, cfgs["no abstraction"].rounds
    (1, 'naive', 0)
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Callable, Sequence

from .config import Config
from .discover import Summary, discover

__all__ = ["DEFAULT_ROWS", "PAPER_TABLE4_LEFT", "ROWS", "AblationRow", "ablation", "row_configs"]

#: The rows, in the paper's order, and what each changes in the base configuration.
ROWS = {
    "ShapeCoder (dream + wake)": {"wake": "network"},
    "no dream + wake": {},
    "no abstraction": {"rounds": 0},
    "single iteration": {"rounds": 1},
    "no semantic rewrites": {"semantic_rewrites": False},
    "no conditional rewrites": {"scheme": "naive"},
    "no preferences": {"preferences": False},
}
#: The rows run unless others are asked for: all but the naive rewrite scheme, whose e-graphs outgrow the memory
#: (about 3 GB for one refactor of an 11-primitive chair, more than 4 GB at 16 primitives; the paper's did not
#: finish one abstraction phase in 3 days).
DEFAULT_ROWS = tuple(r for r in ROWS if r != "no conditional rewrites")
#: The paper's Table 4 (left), chair F (400 shapes, 4 rounds, ablated from the full method).
PAPER_TABLE4_LEFT = {"chair": {"no abstraction": 104.9, "single iteration": 81.6, "no dream + wake": 99.0,
                               "no semantic rewrites": 75.2, "no conditional rewrites": 100.0,
                               "no preferences": 70.7, "ShapeCoder (dream + wake)": 63.6}}


def row_configs(base: Config, network: dict | None = None) -> dict:
    """``{row: Config}`` of :data:`ROWS` from ``base`` (its wake replaced by the refactor-only wake); the
    network row also takes the settings of ``network`` (e.g. ``n_dreams``, ``train_epochs``)."""
    base = dataclasses.replace(base, wake="refactor")
    out = {}
    for name, change in ROWS.items():
        extra = dict(network or {}) if change.get("wake") == "network" else {}
        out[name] = dataclasses.replace(base, **change, **extra)
    return out


@dataclass(frozen=True)
class AblationRow:
    """One row: its name, the :class:`~shapeprog.coder.discover.Summary` of its programs (F with the paper's
    ω), the abstractions the final library holds, and the wall seconds."""

    name: str
    summary: Summary
    abstractions: int
    seconds: float


def ablation(shapes: Sequence, base: Config, rows: Sequence[str] | None = None, *, network: dict | None = None,
             executor=None, progress: Callable[[str], None] | None = None) -> list:
    """Discovery once per row of ``rows`` (default :data:`DEFAULT_ROWS`) on the same ``shapes``.

    Raises:
        ValueError: an unknown row name.
    """
    cfgs = row_configs(base, network)
    rows = list(DEFAULT_ROWS) if rows is None else list(rows)
    unknown = [r for r in rows if r not in cfgs]
    if unknown:
        raise ValueError(f"unknown ablation row {unknown[0]!r}; rows: {', '.join(ROWS)}")
    out = []
    for name in rows:
        t0 = time.time()
        res = discover(shapes, cfgs[name], executor=executor, log=None)
        out.append(AblationRow(name, res.summary(), len(res.library), time.time() - t0))
        if progress is not None:
            s = out[-1].summary
            progress(f"{name}: F {s.F:.2f}, |L| {s.library_size} ({out[-1].seconds:.0f} s)")
    return out
