"""Refactoring ShapeCoder programs with e-graphs (the ``egglog`` package).

:func:`refactor` puts one program into an e-graph, grows it with the semantic rewrites of the paper
(:func:`~shapeprog.coder.rules.semantic_rules`) plus one conditional rewrite per abstraction of the library
(:func:`~shapeprog.coder.rules.abstraction_rule`), and extracts the cheapest equivalent program.

* **Leaves.** Every float of the program becomes ``(Num v)`` (its value, so equal values share one
  e-class: the reference's ``do_dedup``), except the constants 0, 1 and 2, which become ``(K v)``; axes
  are the nullary ``AX AY AZ`` and counts ``(N k)``.
* **Value table.** ``(function val (Flt) f64 :merge old)``, filled by rules: a leaf's value is its
  literal, and ``Add Sub Mul Div Inv`` nodes get the value computed from their children's (the
  reference's ``er_add`` / ``er_inv`` bookkeeping, as ordinary rules).
* **Conditional rewrites** are rules whose queries compare values: ``(<= (abs (- va vb)) tol)``
  (tolerance :data:`~shapeprog.coder.rules.SEMANTIC_TOL` for the semantic rules, :data:`~shapeprog.coder.rules.ABSTRACTION_TOL` for abstractions).
* **Limits.** The e-graph is run one iteration at a time; before each iteration the e-node count (all
  constructors, the value table excluded) is checked against ``max_nodes`` and the elapsed time against
  ``time_limit`` (a safety cap, :data:`TIME_LIMIT`); at most ``iterations`` iterations. Inside an iteration, a rule with more than
  ``max_matches`` matches (by default :data:`MATCHES_PER_ENODE` × ``max_nodes``) is skipped for that
  iteration (egglog's back-off scheduler, a fresh one per iteration), so that the e-nodes one iteration adds
  are bounded by a count, not only by the time it takes. A run that stops on a limit still extracts the
  best program found so far (:attr:`Refactored.stop` names the reason).
* **Extraction** uses the constructors' integer costs, the paper's costs ×10 (:data:`~shapeprog.coder.rules.COSTS`): shape
  function 10, float operator 1, free float 20, constant 0/1/2 5, categorical 5. The program returned is
  re-costed with :func:`shapeprog.coder.objective.program_cost`.

The program text egglog runs (declarations, rules, terms) is built in :mod:`shapeprog.coder.rules`.
See docs/shapecoder.md ("Refactor") for the rules and the decisions where this differs from the paper
and the reference code.

Example:
    >>> from shapeprog.coder.lang import parse, to_text
    >>> p = parse("Union(Move(Cuboid(0.1,0.5,0.1),-0.4,0.2,0.1),Move(Cuboid(0.1,0.5,0.1),0.4,0.2,0.1))")
    >>> r = refactor(p)
    >>> to_text(r.expr), r.cost < r.input_cost
    ('SymRef(Move(Cuboid(0.1,0.5,0.1),-0.4,0.2,0.1),AX)', True)
"""
from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Mapping

from ..errors import RefactorError
from .lang import (
    as_expr, Expr, Lang, Library, Num, ProgramError, Type, Var, _library, _short, check, substitute, walk,
)
from .objective import program_cost
from .rules import (
    SCHEMES, _from_term, _term, egglog_program, naive_egglog_program, naive_relations, relations_command,
)

__all__ = [
    "MATCHES_PER_ENODE",
    "RefactorError",
    "check_limits",
    "Refactored",
    "refactor",
]


@dataclass(frozen=True)
class Refactored:
    """The result of :func:`refactor`.

    Attributes:
        expr: the extracted program (floats as literals; abstractions of the library may be called).
        cost: its :func:`~shapeprog.coder.objective.program_cost` (no geometric error).
        input_cost: the same for the input program.
        stop: why the e-graph stopped: ``"saturated"``, ``"iterations"``, ``"nodes"`` or ``"time"``.
        iterations: iterations run.
        nodes: e-nodes at the end (constructors only).
        seconds: wall time of the whole call.
    """

    expr: Expr
    cost: float
    input_cost: float
    stop: str
    iterations: int
    nodes: int
    seconds: float


# ----------------------------------------------------------------------------- the refactor call

_LOG = logging.getLogger(__name__)

#: Default limits, the budget of a refactor call: the reference's egg settings, 5 iterations and 10,000 e-nodes.
MAX_ITERATIONS, MAX_ENODES = 5, 10_000
#: A safety cap in seconds per refactor call, not a budget (the reference's 5 s made a refactor depend on the
#: machine's load). Post hoc inference of 200 chairs with the shipped library took 0.44 s of CPU at most per
#: call (docs/shapecoder.md, "Budgets"), so the cap does not bind on a loaded machine and a refactor's result
#: depends only on the counts.
TIME_LIMIT = 120.0
#: The default ``max_matches`` of :func:`refactor` per e-node of ``max_nodes``: a rule with more matches
#: than ``MATCHES_PER_ENODE * max_nodes`` in one iteration is skipped for that iteration (the corpus's largest
#: is 61,481 matches of associativity on a 16-part chair, under the default 100,000).
MATCHES_PER_ENODE = 10
#: Largest ``max_matches`` :func:`refactor` takes.
MAX_MATCHES = 100_000_000
#: How the value table and ``norot`` follow the e-graph (:func:`refactor`'s ``values``).
VALUE_SCHEDULES = ("eager", "lagged")
#: The default: the reference's (values of every e-node there is, before each iteration).
VALUES = "eager"


def check_limits(iterations, max_nodes, time_limit, max_matches=None):
    """Raise :class:`RefactorError` naming the first e-graph limit out of range (shared by refactor and
    discovery's Config, which checks before any work); ``max_matches`` None is the default."""
    if isinstance(iterations, bool) or not isinstance(iterations, int) or not 0 <= iterations <= 1000:
        raise RefactorError(f"iterations must be an int from 0 to 1000, got {iterations!r}")
    if isinstance(max_nodes, bool) or not isinstance(max_nodes, int) or not 1 <= max_nodes <= 10_000_000:
        raise RefactorError(f"max_nodes must be an int from 1 to 10,000,000, got {max_nodes!r}")
    if not isinstance(time_limit, (int, float)) or not 0 < time_limit <= 3600 or not math.isfinite(time_limit):
        raise RefactorError(f"time_limit must be seconds in (0, 3600], got {time_limit!r}")
    if max_matches is not None and (isinstance(max_matches, bool) or not isinstance(max_matches, int)
                                    or not 1 <= max_matches <= MAX_MATCHES):
        raise RefactorError(f"max_matches must be an int from 1 to {MAX_MATCHES:,} (MAX_MATCHES), got {max_matches!r}")


def _node_count(eg, bindings) -> int:
    out = eg.run_program(*eg.parse_program("(print-size)"))
    return sum(n for name, n in out[0].sizes if name not in ("val", "norot"))


def refactor(expr: Expr, library: Library | Lang | None = None, env: Mapping | None = None, *,
             iterations: int = MAX_ITERATIONS, max_nodes: int = MAX_ENODES, time_limit: float = TIME_LIMIT,
             rules: str | None = None, scheme: str = "conditional", values: str = VALUES,
             max_matches: int | None = None) -> Refactored:
    """Refactor one program with the semantic rewrites and the library's abstractions.

    Args:
        expr: a Shape expression of ``library`` or its text (abstraction calls are kept as e-nodes).
        library: a :class:`~shapeprog.coder.lang.Library` (or a bare domain); :data:`LANG_3D` by default.
        env: values of the program's Float variables (e.g. a naive program's ``S_i_j_``); Axis and Int
            variables are not allowed.
        iterations, max_nodes: the e-graph's budget (checked before each iteration); time_limit: a safety
            cap in seconds (:data:`TIME_LIMIT`, which does not bind on a loaded machine).
        max_matches: the matches one rule may apply in one iteration; a rule with more is skipped for that
            iteration. None: :data:`MATCHES_PER_ENODE` × ``max_nodes`` (at most :data:`MAX_MATCHES`).
        rules: the text of :func:`egglog_program` for ``library`` (of :func:`naive_egglog_program` with the naive
            scheme), when the caller has it already.
        scheme: one of :data:`SCHEMES`; ``"naive"`` is the paper's Table 1 ablation, for benchmarks.
        values: one of :data:`VALUE_SCHEDULES`: ``"eager"`` brings the value table and
            ``norot`` up to date before every iteration, so that a guarded rule sees the values of the
            e-nodes there are (the reference keeps them as e-class data); ``"lagged"`` keeps them with
            the rewrites, one iteration behind (the guarded rules cannot fire in the first iteration): the
            behaviour of runs made before 2026-11-29, to reproduce them.

    Returns:
        :class:`Refactored`; the input program itself when extraction finds nothing cheaper.

    Raises:
        RefactorError: a program that is not a closed Shape expression, a limit out of range, or an
            egglog failure.
    """
    from egglog import bindings  # lazy: egglog only when a program is refactored


    t0 = time.perf_counter()
    lib = _library(library)
    expr = as_expr(expr, lib, "shapeprog.coder.refactor")
    check_limits(iterations, max_nodes, time_limit, max_matches)
    if max_matches is None:
        max_matches = min(MATCHES_PER_ENODE * max_nodes, MAX_MATCHES)
    # one iteration of rw in which a rule with more than max_matches matches applies none of them
    step = f"(run-schedule (let-scheduler bo (back-off :match-limit {max_matches})) (run-with bo rw))"
    if values not in VALUE_SCHEDULES:
        raise RefactorError(f"values must be one of {', '.join(VALUE_SCHEDULES)}, got {values!r}")
    if scheme not in SCHEMES:
        raise RefactorError(f"scheme must be one of {SCHEMES}, got {scheme!r}")
    try:
        check(expr, lib, Type.SHAPE)
    except ProgramError as e:
        raise RefactorError(str(e)) from None
    if env:
        expr = substitute(expr, {k: Num(float(v)) for k, v in env.items()
                                 if isinstance(v, (int, float)) and not isinstance(v, bool)})
    free = [n for n in walk(expr) if isinstance(n, Var)]
    if free:
        raise RefactorError(f"variable {free[0].name!r} has no value in {_short(expr)}")
    input_cost = program_cost(expr, lib)
    eg = bindings.EGraph()
    try:
        if rules is None:
            rules = egglog_program(lib) if scheme == "conditional" else naive_egglog_program(lib)
        eg.run_program(*eg.parse_program(rules))
        eg.run_program(*eg.parse_program(f"(let $root {_term(expr, lib)})"))
        if scheme == "naive":
            leaves = [n.value for n in walk(expr) if isinstance(n, Num)]
            eg.run_program(*eg.parse_program(relations_command(naive_relations(leaves))))
        stop, done = "iterations", 0
        nodes = _node_count(eg, bindings)
        for _ in range(iterations):
            if nodes > max_nodes:
                stop = "nodes"
                break
            if time.perf_counter() - t0 > time_limit:
                stop = "time"
                break
            if values == "eager":
                eg.run_program(*eg.parse_program("(run-schedule (saturate (run facts)))"))
            rep = eg.run_program(*eg.parse_program(step))
            done += 1
            nodes = _node_count(eg, bindings)
            if not rep[0].report.updated:
                stop = "saturated"
                break
        out = eg.run_program(*eg.parse_program("(extract $root)"))[0]
        best = _from_term(out.termdag.to_string(out.term), lib)
    except RefactorError:
        raise
    except Exception as e:  # egglog reports its own errors (EggSmolError and others)
        raise RefactorError(f"egglog failed on {_short(expr)}: {e}") from None
    if stop in ("nodes", "time"):
        _LOG.info("e-graph stopped early (%s limit) after %d iteration(s), %d e-nodes: %s", stop, done, nodes,
                  _short(expr))
    cost = program_cost(best, lib)
    if cost >= input_cost:
        best, cost = expr, input_cost
    return Refactored(best, cost, input_cost, stop, done, nodes, time.perf_counter() - t0)
