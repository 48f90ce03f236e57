"""ShapeCoder: abstraction discovery over unstructured primitives (Jones et al., SIGGRAPH 2023).

Discovery: :mod:`shapeprog.coder.refactor` (e-graph refactoring with egglog),
:mod:`shapeprog.coder.proposal` (structure signatures, clusters, greedy abstraction),
:mod:`shapeprog.coder.discover` (wake by refactoring or with the recognition network, integration, the
rounds) and :mod:`shapeprog.coder.infer` (post hoc inference, shipped libraries). The network wake's parts,
imported on demand (the network needs torch): :mod:`shapeprog.coder.dream` (the dream phase),
:mod:`shapeprog.coder.recnet` (the recognition network), :mod:`shapeprog.coder.train` (its training loop)
and :mod:`shapeprog.coder.search` (the network's search per shape, the store of covering expressions).

The foundation: the language (:mod:`shapeprog.coder.lang`: typed expression trees,
text form, abstractions, libraries, the 3D domain and the 2D toy domain), the executor
(:mod:`shapeprog.coder.execute`: programs to primitives), the objective F
(:mod:`shapeprog.coder.objective`) and the vendored PartNet primitive data (:mod:`shapeprog.coder.data`).
See docs/shapecoder.md.

Example:
    >>> from shapeprog import coder
    >>> shapes = coder.data.load("table")
    >>> round(coder.naive_summary(s.prims for s in shapes).F, 2)
    125.8
    >>> expr, env = coder.naive_program(shapes[0].prims)
    >>> coder.execute(expr, env=env) == shapes[0].prims
    True
"""
from __future__ import annotations

from . import data, limits  # cheap: data reads nothing until asked
from .execute import Execution, ExecutionError, execute, run  # the function shadows the module name
from .lang import (LANG_2D, LANG_3D, Abstraction, Library, ParseError, Param, ProgramError, Type, check, expand,
                   parse, parse_abstraction, to_text)
from . import objective  # the module, callable: objective(programs, library) is F (objective.objective)
from .objective import WEIGHTS, match, naive_cost, naive_program, naive_summary, omega, preference, program_cost
from ..errors import RefactorError
from .refactor import Refactored, refactor
from .discover import DiscoveryResult, Summary, discover, summarize
from .config import Config
from .infer import Inferred, infer, load_library

__all__ = [  # by the module each name comes from, in the order of the imports above
    "data", "limits",
    "Execution", "ExecutionError", "execute", "run",
    "LANG_2D", "LANG_3D", "Abstraction", "Library", "ParseError", "Param", "ProgramError", "Type", "check", "expand",
    "parse", "parse_abstraction", "to_text",
    "objective", "WEIGHTS", "match", "naive_cost", "naive_program", "naive_summary", "omega", "preference",
    "program_cost",
    "RefactorError",
    "Refactored", "refactor",
    "DiscoveryResult", "Summary", "discover", "summarize",
    "Config",
    "Inferred", "infer", "load_library",
]
