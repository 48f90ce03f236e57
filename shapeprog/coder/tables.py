"""ShapeCoder's Tables 2 and 3 for a discovered library, beside the paper's rows.

Table 2 (discovery): the "Input Prims" row (the naive programs of the library's discovery shapes) and the
library's row (F, |L|, Num Struct, Num Param of its discovered programs), with optional structure-only
baseline rows (:func:`baseline`, :data:`BASELINE_ROWS`: discovery runs with the abstraction rules only,
``discover-abstractions --no-semantic-rewrites``, from the naive programs or from the programs of one wake
with the semantic rewrites; ours, the nearest this implementation has to the paper's ShapeMOD+Input and
ShapeMOD+Wake rows, which ran ShapeMOD on those programs and are printed beside them). Table 3: F of the
discovered programs ("train"), and of post hoc inference (:func:`shapeprog.coder.infer.infer`, the library fixed) on
the first discovery shapes ("train-PHI") and the first held-out shapes ("validation-PHI"), with the number of
abstractions the programs use.

A library comes either from the package (:func:`shipped`: ``shapeprog/data/coder_libraries/<category>.txt``
with its ``<category>_programs.txt``) or from a ``discover-abstractions`` output folder (:func:`from_run`:
``library.txt`` and ``programs.txt``). The per-shape inference goes through the caller's
``concurrent.futures.Executor`` (None: in this process); the result does not depend on the executor.

Example (``python -m shapeprog table2-coder --categories chair --train 20 --heldout 20``):
    >>> from shapeprog.coder import tables
    >>> run = tables.shipped("chair")
    >>> t2 = tables.table2(run)
    >>> round(t2.naive.F, 1), round(t2.ours.F, 1), t2.ours.library_size
    (146.5, 62.2, 27)
"""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Callable, Sequence

from shapeio.files import parse_json

from ..errors import ParseError
from ..limits import decode
from . import data
from .discover import Summary, summarize
from .wake import evaluate, network_payload
from .infer import PASSES, check_search_budget, infer, load_network, shipped_libraries
from .lang import LANG_3D, Call, Library, parse, walk
from .objective import naive_summary, omega
from .refactor import MAX_ENODES, MAX_ITERATIONS, TIME_LIMIT, VALUES
from .search import WAKE_BATCH, WAKE_BATCHES, WAKE_SECONDS, WAKE_STEP_BUDGET
from .recnet import load_checkpoint

__all__ = ["BASELINE_ROWS", "PAPER_TABLE2", "PAPER_TABLE3", "Phi", "Run", "Table2", "baseline", "format_tables", "from_run", "phi",
           "shipped", "table2", "table3"]

#: The paper's Table 2 rows per category: (row, F, |L|, Num Struct, Num Param), 400 discovery shapes.
PAPER_TABLE2 = {"chair": [("Input Prims", 146.0, 6, 29, 61), ("ShapeMOD+Input", 109.0, 21, 16, 46),
                          ("ShapeMOD+Wake", 83.0, 21, 12, 36), ("ShapeCoder", 63.6, 33, 10, 27)],
                "table": [("Input Prims", 125.0, 6, 25, 51), ("ShapeMOD+Input", 84.2, 25, 11, 34),
                          ("ShapeMOD+Wake", 69.1, 17, 10, 30), ("ShapeCoder", 40.9, 37, 8, 18)],
                "storage": [("Input Prims", 154.0, 6, 30, 62), ("ShapeMOD+Input", 119.0, 16, 20, 48),
                            ("ShapeMOD+Wake", 103.0, 10, 19, 45), ("ShapeCoder", 71.3, 31, 11, 33)]}
#: Table 2's structure-only rows (ours, not ShapeMOD): discovery with the abstraction rules only, from the naive
#: programs or from one wake's programs (``discover-abstractions --no-semantic-rewrites``).
BASELINE_ROWS = {"input": "Structure only, from the naive programs (ours; not ShapeMOD)",
                 "wake": "Structure only, from one wake's programs (ours; not ShapeMOD)"}
#: The paper's post hoc inference F (chairs only are reported): train shapes and validation shapes.
PAPER_TABLE3 = {"chair": {"train": 63.6, "train-PHI": 67.5, "validation-PHI": 70.6}}


@dataclass(frozen=True)
class Run:
    """A library with the programs discovery wrote for its shapes.

    Attributes:
        category: 'chair', 'table' or 'storage'.
        library: the abstractions.
        keys: the shape keys of the programs (``<id>_0_<index>``), in file order.
        programs: the discovered programs, parsed with ``library``.
        source: where they were read from (for the table's header).
    """

    category: str
    library: Library
    keys: tuple
    programs: tuple
    source: str


def _read_run(category: str, lib_text: str, lib_name: str, prog_text: str, prog_name: str, source: str) -> Run:
    lib = Library.from_text(lib_text, LANG_3D, file=lib_name)
    keys, progs = [], []
    for i, line in enumerate(prog_text.splitlines()):
        if not line.strip():
            continue
        key, sep, text = line.partition(":")
        if not sep:
            raise ParseError(f"expected '<key>:<program>', got {line[:40]!r}", prog_name, i + 1, 1, line[:40])
        keys.append(key)
        progs.append(parse(text, lib, file=prog_name, line=i + 1, column=len(key) + 2))
    if not progs:
        raise ParseError("no programs", prog_name, 1, 1, "")
    return Run(category, lib, tuple(keys), tuple(progs), source)


def shipped(category: str) -> Run:
    """The shipped library of ``category`` with its discovered programs.

    Raises:
        ValueError: no library is shipped for ``category``.
    """
    if category not in shipped_libraries():
        raise ValueError(f"no shipped library for {category!r}; shipped: {', '.join(shipped_libraries()) or 'none'}")
    folder = resources.files("shapeprog").joinpath("data", "coder_libraries")
    return _read_run(category, folder.joinpath(f"{category}.txt").read_text(encoding="utf-8"), f"{category}.txt",
                     folder.joinpath(f"{category}_programs.txt").read_text(encoding="utf-8"),
                     f"{category}_programs.txt", f"shapeprog/data/coder_libraries/{category}.txt")


def log_of(run: Run) -> list:
    """The F log per phase of a run (``<category>_log.json`` of a shipped library, ``log.json`` of a run
    folder); empty when the file is missing.

    Raises:
        ParseError: the file is not JSON (at its line and column) or holds no ``log`` list.
    """
    if run.source.startswith("shapeprog/data/"):
        f = resources.files("shapeprog").joinpath("data", "coder_libraries", f"{run.category}_log.json")
    else:
        f = Path(run.source) / "log.json"
    if not f.is_file():
        return []
    name = str(f)
    record = parse_json(decode(f.read_bytes(), name), name, ParseError.in_file(name))
    try:
        log = record["log"]
    except (KeyError, TypeError):
        raise ParseError("not a discovery log (no 'log' list)", name, 1, 1, "") from None
    if not isinstance(log, list) or not all(isinstance(h, dict) for h in log):
        raise ParseError("not a discovery log ('log' is not a list of phases)", name, 1, 1, "")
    return log


def network_of(run: Run) -> tuple:
    """``(model, vocab)``: the recognition network of a run: the shipped one of its category for a shipped
    run, else the last ``recnet_round<k>.pt`` in its folder.

    Raises:
        ValueError: the run has no network.
    """
    if run.source.startswith("shapeprog/data/"):
        return load_network(run.category)
    files = sorted(Path(run.source).glob("recnet_round*.pt"), key=lambda p: int(p.stem[len("recnet_round"):]))
    if not files:
        raise ValueError(f"{run.source}: no recnet_round<k>.pt (the run used the refactor-only wake)")
    model, vocab, _ = load_checkpoint(files[-1], run.library)
    return model.eval(), vocab


def from_run(folder, category: str) -> Run:
    """The library and programs of a ``discover-abstractions`` output folder.

    Raises:
        OSError: ``library.txt`` or ``programs.txt`` is missing (the message names it).
        ParseError: a malformed line (file, line, column); a file whose SHA-256 is not the one the folder's
            ``log.json`` records (a write interrupted between the files; folders written before the digests
            were recorded are not checked).
    """
    folder = Path(folder)
    lib_path, prog_path = folder / "library.txt", folder / "programs.txt"
    for p in (lib_path, prog_path):
        if not p.is_file():
            raise FileNotFoundError(f"{p}: not found (a discover-abstractions output folder has library.txt and "
                                    "programs.txt)")
    log_path = folder / "log.json"
    if log_path.is_file():
        name = str(log_path)
        record = parse_json(decode(log_path.read_bytes(), name), name,
                            ParseError.in_file(name))
        files = record.get("files") if isinstance(record, dict) else None
        for p in (lib_path, prog_path) if isinstance(files, dict) else ():
            if files.get(p.name) != hashlib.sha256(p.read_bytes()).hexdigest():
                raise ParseError(f"not the {p.name} that log.json records (a write interrupted between the "
                                 "files?); rerun or resume the discovery into this folder", str(p), 1, 1, "")
    return _read_run(category, decode(lib_path.read_bytes(), str(lib_path)), str(lib_path),
                     decode(prog_path.read_bytes(), str(prog_path)), str(prog_path), str(folder))


def _used(programs, library: Library) -> int:
    names = {ab.name for ab in library.abstractions}
    return len({node.fn for p in programs for node in walk(p) if isinstance(node, Call) and node.fn in names})


@dataclass(frozen=True)
class Table2:
    """Table 2 of one run: ``naive`` (Input Prims) and ``ours`` (the run's programs) as
    :class:`~shapeprog.coder.discover.Summary`, and ``used``, the abstractions the programs call."""

    naive: Summary
    ours: Summary
    used: int


def table2(run: Run) -> Table2:
    """Input Prims and the run's row, on the run's own shapes (each program checked against its shape).

    Raises:
        ValueError: a key not among the category's shapes, or a program that does not re-cover its shape.
    """
    recs = {r.key: r for r in data.load(run.category, "all")}
    errors = []
    for key, prog in zip(run.keys, run.programs):
        if key not in recs:
            raise ValueError(f"{run.source}: {key!r} is not a {run.category} shape")
        got = evaluate(prog, run.library, recs[key].prims)
        if got is None:
            raise ValueError(f"{run.source}: the program of {key} does not re-cover its primitives")
        errors.append(got[1])
    naive = naive_summary(recs[k].prims for k in run.keys)
    return Table2(naive, summarize(run.programs, run.library, errors), _used(run.programs, run.library))


def baseline(base: Run, run: Run) -> Table2:
    """Table 2 of a structure-only baseline run (``discover-abstractions --no-semantic-rewrites``) on the
    same shapes as ``run``, for the baseline row beside it.

    Raises:
        ValueError: the two runs' shapes differ, or :func:`table2`'s errors.
    """
    if base.keys != run.keys:
        raise ValueError(f"{base.source}: the baseline's {len(base.keys)} shapes are not the {len(run.keys)} shapes of "
                         f"{run.source}")
    return table2(base)


@dataclass(frozen=True)
class Phi:
    """One post hoc inference row.

    Attributes:
        split: 'train-PHI' or 'validation-PHI'.
        shapes: shapes inferred; ``skipped`` the shapes of the slice left out for having more primitives than
            the language allows (16).
        F: mean program cost (tokens + 10 x error) plus the library's preference cost, as Table 2's F.
        used: abstractions called by the inferred programs.
        cpu: mean CPU seconds per shape (in the process that inferred it); ``wall`` the row's wall time.
    """

    split: str
    shapes: int
    skipped: int
    F: float
    used: int
    cpu: float
    wall: float


def _infer_one(task):
    prims, lib_text, limits, payload, seed, budget = task
    lib = Library.from_text(lib_text, LANG_3D)
    t0 = time.process_time()
    r = infer(prims, lib, **limits, network=payload, seed=seed, **budget)
    return r.cost, time.process_time() - t0, r.text


def phi(split: str, records: Sequence, library: Library, *, executor=None, iterations: int = MAX_ITERATIONS,
        max_nodes: int = MAX_ENODES, time_limit: float = TIME_LIMIT, network=None,
        search_seconds: float = WAKE_SECONDS, search_batches: int = WAKE_BATCHES,
        search_step_budget: int = WAKE_STEP_BUDGET, values: str = VALUES, passes: int = PASSES) -> Phi:
    """Post hoc inference of ``records`` (:class:`~shapeprog.coder.data.ShapeRecord`) with ``library`` fixed;
    with ``network`` (a ``(model, vocab)`` pair) as :func:`~shapeprog.coder.infer.infer` with the network,
    shape k's search seeded with k and budgeted by ``search_batches`` / ``search_step_budget`` (counts) with
    ``search_seconds`` as a safety cap (as :func:`~shapeprog.coder.infer.infer`; ``values``: the e-graph's
    value schedule, and ``passes``, the refactor calls per shape, as there)."""
    check_search_budget(search_seconds, search_batches, search_step_budget)
    limits = {"iterations": iterations, "max_nodes": max_nodes, "time_limit": time_limit, "values": values,
              "passes": passes}
    budget = {"search_seconds": float(search_seconds), "search_batches": int(search_batches),
              "search_step_budget": int(search_step_budget)}
    kept = [r for r in records if len(r.prims) <= library.lang.max_prims]
    if not kept:
        raise ValueError(f"{split}: no shape with at most {library.lang.max_prims} primitives")
    payload = None
    if network is not None:
        payload = network_payload(*network)
    tasks = [(r.prims, library.to_text(), limits, payload, k, budget) for k, r in enumerate(kept)]
    t0 = time.time()
    out = list(executor.map(_infer_one, tasks)) if executor is not None else [_infer_one(t) for t in tasks]
    wall = time.time() - t0
    lib_cost = sum(omega(ab, library) for ab in library.abstractions)
    progs = [parse(text, library) for _, _, text in out]
    return Phi(split, len(kept), len(records) - len(kept), sum(c for c, _, _ in out) / len(out) + lib_cost,
               _used(progs, library), sum(c for _, c, _ in out) / len(out), wall)


def table3(run: Run, *, train: int = 100, heldout: int = 100, executor=None,
           progress: Callable[[str], None] | None = None, network=None, **limits) -> list:
    """The two post hoc inference rows: the first ``train`` discovery shapes and the first ``heldout``
    held-out shapes (``limits``: ``iterations``, ``max_nodes``, ``time_limit``, ``values``, ``passes``, and
    ``network``, ``search_seconds``, ``search_batches``, ``search_step_budget`` as :func:`phi`)."""
    rows = []
    for split, recs in (("train-PHI", data.load(run.category)[:train]),
                        ("validation-PHI", data.load(run.category, "heldout")[:heldout])):
        if progress is not None:
            progress(f"{run.category} {split}: {len(recs)} shapes")
        rows.append(phi(split, recs, run.library, executor=executor, network=network, **limits))
    return rows


def format_tables(run: Run, t2: Table2, t3: Sequence[Phi], *, iterations: int = MAX_ITERATIONS,
                  max_nodes: int = MAX_ENODES, time_limit: float = TIME_LIMIT, values: str = VALUES,
                  network: bool = False, search_seconds: float = WAKE_SECONDS, search_batches: int = WAKE_BATCHES,
                  search_step_budget: int = WAKE_STEP_BUDGET, baselines: Sequence[tuple] = (),
                  passes: int = PASSES) -> str:
    """Markdown of Tables 2 and 3 for one run, the paper's rows beside ours; ``baselines``, ``[(kind,
    Table2)]`` with kind ``"input"`` or ``"wake"`` (:func:`baseline`), add the structure-only rows to Table 2."""
    cat = run.category
    out = [f"## Table 2 ({cat}, {t2.ours.shapes} discovery shapes; library {run.source})", "",
           "| row | F | \\|L\\| | Num Struct | Num Param |", "| --- | --- | --- | --- | --- |",
           f"| Input Prims (ours) | {t2.naive.F:.1f} | 6 | {t2.naive.num_struct:.1f} | {t2.naive.num_param:.1f} |"]
    for kind, t in baselines:
        if kind not in BASELINE_ROWS:
            raise ValueError(f"a baseline is 'input' or 'wake', got {kind!r}")
        b = t.ours
        out.append(f"| {BASELINE_ROWS[kind]} | {b.F:.1f} | {b.library_size} | {b.num_struct:.1f} | {b.num_param:.1f} |")
    out.append(f"| ShapeCoder (ours) | {t2.ours.F:.1f} | {t2.ours.library_size} | {t2.ours.num_struct:.1f} | "
               f"{t2.ours.num_param:.1f} |")
    out += [f"| {name} (paper, 400 shapes) | {f} | {size} | {ns} | {npar} |" for name, f, size, ns, npar in PAPER_TABLE2[cat]]
    paper_limits = (iterations, max_nodes) == (MAX_ITERATIONS, MAX_ENODES)
    which = "the paper's" if paper_limits else "ours, not the paper's"
    how = "the recognition network's search and refactoring" if network else "refactoring only"
    if network:
        paper_budget = (search_batches, search_step_budget) == (WAKE_BATCHES, WAKE_STEP_BUDGET)
        how += (f", the search's budget {search_step_budget} units / at most {search_batches} batches of {WAKE_BATCH} "
                "per step: " + ("the wake's, standing for the paper's 1 s" if paper_budget
                                else "ours, not the wake's"))
        if search_seconds != WAKE_SECONDS:
            how += f", safety cap {search_seconds:g} s per step"
    cap = "" if time_limit == TIME_LIMIT else f", safety cap {time_limit:g} s per call"
    out += ["", f"## Table 3 ({cat}, post hoc inference with the {len(run.library)} abstractions by {how}; e-graph limits "
            f"{iterations} iterations / {max_nodes} e-nodes: {which}{cap}"
            + ("" if values == VALUES else f"; e-graph values {values}")
            + ("" if passes == PASSES else f"; {passes} refactor call{'s' if passes > 1 else ''} per shape, not {PASSES}")
            + ")", "",
            "| split | shapes | F | abstractions used | CPU s / shape | wall s | paper F |",
            "| --- | --- | --- | --- | --- | --- | --- |"]
    paper = PAPER_TABLE3.get(cat, {})
    out.append(f"| train (discovery programs) | {t2.ours.shapes} | {t2.ours.F:.1f} | {t2.used} | - | - | "
               f"{paper.get('train', '-')} |")
    for r in t3:
        shapes = f"{r.shapes}" + (f" ({r.skipped} over 16 primitives left out)" if r.skipped else "")
        out.append(f"| {r.split} | {shapes} | {r.F:.1f} | {r.used} | {r.cpu:.2f} | {r.wall:.0f} | "
                   f"{paper.get(r.split, '-')} |")
    return "\n".join(out)
