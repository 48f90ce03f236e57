"""What every command of ``python -m shapeprog`` shares, written once.

- :func:`add_command` makes a command's parser from the command function and its docstring (summary line,
  description, example): its help shows each option's default and the example in its epilog; the outputs it
  lists are checked by the dispatcher before the command's work starts. The options several commands share are
  added by one function each (:func:`add_seed`, :func:`add_workers`, :func:`add_result_options`,
  :func:`add_export_weights`).
- The category is always ``--category`` (:func:`add_category`): one of :data:`CATEGORIES`, by default
  :data:`DEFAULT_CATEGORY`, or, for commands whose input names one (a corpus id, a weights file), the input's.
- A corpus id (``chair/173``) names a program of the ShapeAssembly corpus, everywhere (:class:`Program`).
- Outputs go to ``--out``; an existing output file is refused unless ``--overwrite``
  (:func:`refuse_existing`), and an output that is one of the inputs is always refused (:func:`refuse_inputs`).
- ``--quiet`` silences progress output (:func:`add_quiet`, :func:`progress_log`).
- Per-item work runs in a process pool of ``--workers`` (:func:`worker_pool`).
- A command that scores something writes its figures with ``--json FILE`` as a result file of
  :mod:`shapeio.results` (:func:`add_json`, :func:`write_json`, :func:`command_result`, :func:`report`,
  :func:`markdown_result`).
"""
from __future__ import annotations

import argparse
import inspect
import math
import multiprocessing
import re
import shlex
import sys
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from pathlib import Path

from shapeio import atomic_write, refuse_overwrite
from shapeio.mesh import WRITE_SUFFIXES
from shapeio.files import NotShippedError, existing_outputs
from shapeio.options import HelpFormatter, float_in, int_in

from . import corpus
from . import io
from .errors import ExecutionError
from .execute import execute
from .lang import parse
from .limits import decode

__all__ = ["PROG", "CATEGORIES", "DEFAULT_CATEGORY", "MAX_COUNT_OPTION", "MAX_WORKERS", "MAX_SEED",
           "MAX_SECONDS_OPTION", "HelpFormatter", "add_command", "add_category", "category_of", "add_quiet",
           "add_overwrite", "add_json", "add_result_options", "add_seed", "add_workers", "add_export_weights",
           "worker_pool", "progress_log", "write_json", "command_result", "report", "markdown_result",
           "int_at_least", "seed", "float_in", "positive_float", "Program", "check_outputs", "refuse_inputs",
           "refuse_existing", "write_mesh", "emit_text", "command_line", "category_pairs", "macro_library"]

#: How the commands are started, for examples and the command lines recorded in written files.
PROG = "python -m shapeprog"
#: The corpus categories every ``--category`` takes.
CATEGORIES = corpus.CATEGORIES
#: The category of a command whose input does not name one.
DEFAULT_CATEGORY = "chair"
#: The largest value of a count, step or size option that has no maximum of its own.
MAX_COUNT_OPTION = 10_000_000
#: The most worker processes of an option ``--workers``.
MAX_WORKERS = 256
#: The largest seed (NumPy and torch both take 0 to 2**63 - 1).
MAX_SEED = 2 ** 63 - 1
#: The largest time option, in seconds (``--stop-after``, ``--wake-seconds``; minutes options: this / 60).
MAX_SECONDS_OPTION = 366 * 24 * 3600.0


def add_command(sub, name: str, func, *, outputs: dict | None = None, help: str | None = None,
                description: str | None = None, example: str | None = None) -> argparse.ArgumentParser:
    """A command's parser in ``sub`` (a system's sub-parsers) that runs ``func(args)``.

    The command's texts are ``func``'s docstring unless given: its first line is ``help``, the paragraphs after it
    are ``description``, and its last paragraph, ``Example: ...``, is ``example``.

    Args:
        outputs: each output option's attribute and what it names: ``"folder"`` (created with its parents),
            ``"file"`` (in an existing folder) or ``"file+"`` (its folder created); the dispatcher checks
            them with :func:`shapeio.files.output_problem` before the command's work starts.
        help: the one line of the system's command list.
        description: the text of the command's ``--help``.
        example: one command line after ``python -m shapeprog`` (``vae sample --category chair``); the
            epilog shows it and a test parses it.
    """
    summary, *paragraphs = [" ".join(p.split()) for p in (inspect.getdoc(func) or "").split("\n\n")]
    if paragraphs and paragraphs[-1].startswith("Example: "):
        example = example or paragraphs.pop().removeprefix("Example: ")
    help, description = help or summary, description or "\n\n".join(paragraphs)
    if not (help and description and example):
        raise ValueError(f"command {name!r}: {func.__qualname__} needs a docstring of a summary line, a description "
                         "and an 'Example: ...' paragraph, or help, description and example given")
    p = sub.add_parser(name, help=help, description=description, epilog=f"example:\n  {PROG} {example}",
                       formatter_class=HelpFormatter)
    p.set_defaults(func=func, outputs=dict(outputs or {}), example=example, parser=p)
    return p


def add_category(parser, *, from_input: str | None = None, multiple: bool = False, help: str | None = None) -> None:
    """``--category``, one of :data:`CATEGORIES` (several with ``multiple``): by default
    :data:`DEFAULT_CATEGORY`, or with ``from_input`` (what names it: "the corpus id") the input's category,
    resolved by :func:`category_of`."""
    what = help or ("the categories" if multiple else "the category")
    if from_input:
        parser.add_argument("--category", choices=CATEGORIES, default=None,
                            help=f"{what} (default: {from_input}'s, else {DEFAULT_CATEGORY})")
    elif multiple:
        parser.add_argument("--category", nargs="+", choices=CATEGORIES, default=[DEFAULT_CATEGORY],
                            metavar="CATEGORY", help=f"{what}: one or more of {', '.join(CATEGORIES)}")
    else:
        parser.add_argument("--category", choices=CATEGORIES, default=DEFAULT_CATEGORY, help=what)


def category_of(spec: str | None) -> str | None:
    """The category of a corpus id (``chair/173`` -> ``chair``); None for a file or anything else."""
    if not spec:
        return None
    cat = spec.partition("/")[0]
    return cat if cat in CATEGORIES and not Path(spec).is_file() else None


def add_quiet(parser, what: str = "progress output") -> None:
    parser.add_argument("--quiet", action="store_true", help=f"no {what}")


def add_overwrite(parser) -> None:
    parser.add_argument("--overwrite", action="store_true",
                        help="replace existing output files (an output that is one of the inputs is always refused)")


def add_json(parser, what: str = "the figures") -> None:
    parser.add_argument("--json", metavar="FILE",
                        help=f"also write {what} to this JSON file (a result file of shapeio.results)")


def add_result_options(parser, what: str = "the rows", quiet: str | None = "progress lines") -> None:
    """The output options of a command that scores something: ``--json FILE`` (:func:`add_json`), ``--quiet``
    (unless ``quiet`` is None) and ``--overwrite``."""
    add_json(parser, what)
    if quiet is not None:
        add_quiet(parser, quiet)
    add_overwrite(parser)


def write_json(args, result: dict) -> None:
    """Write ``result`` (:func:`shapeio.results.make_result`) to ``args.json`` when given."""
    if getattr(args, "json", None):
        from shapeio.results import write_result  # lazy: loaded when the command runs

        print(f"wrote {write_result(args.json, result)}")


def command_result(args, title: str, columns: list, rows: list, notes: list) -> dict:
    """A command's figures as a result (:func:`shapeio.results.make_result`) that records its command line."""
    from shapeio.results import make_result  # lazy: loaded when the command runs

    return make_result(title, columns, rows, notes, command_line(args))


def report(args, result: dict, out: str | None = None) -> int:
    """The end of a command that scores something: print ``result`` as markdown, also write that markdown to
    ``out`` when given and the result to ``--json`` when given; the exit status 0."""
    from shapeio.results import markdown  # lazy: loaded when the command runs

    text = markdown(result)
    print(text)
    if out:
        atomic_write(out, text)
        print(f"wrote {out}")
    write_json(args, result)
    return 0


def add_seed(parser, help: str, default: int = 0, flag: str = "--seed") -> None:
    """A seed option (:func:`seed`: 0 to :data:`MAX_SEED`)."""
    parser.add_argument(flag, type=seed, default=default, help=help)


def add_workers(parser, help: str = "processes (1: none)", default: int | None = 1) -> None:
    """``--workers``: the processes of the command's pool (:func:`worker_pool`), 1 to :data:`MAX_WORKERS`."""
    parser.add_argument("--workers", type=int_at_least(1, MAX_WORKERS), default=default, help=help)


@contextmanager
def worker_pool(workers: int, start: str | None = None):
    """A process pool of ``workers`` processes, shut down on leaving; None for one worker (the work runs in this
    process). ``start``: the pool's start method (``"spawn"``, ``"forkserver"``; None: the platform's)."""
    if workers <= 1:
        yield None
        return
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context(start) if start else None)
    try:
        yield pool
    finally:
        pool.shutdown()


def progress_log(args):
    """The ``log`` of a command's long work: None with ``--quiet``, else a function that prints each line on
    stderr at once."""
    return None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))


def add_export_weights(sub, export, *, help: str, example: str, checkpoint_help: str, average: bool = False) -> None:
    """The ``export-weights`` command of a model family: ``export(checkpoint, out, half=...)`` writes the weights
    file of a training checkpoint and returns its path (a usage error raises SystemExit; an unreadable or
    foreign checkpoint FileNotFoundError or ValueError, naming the file); its docstring is the command's
    description. With ``average`` the command takes several checkpoints and ``export`` gets their list."""

    def run(args) -> int:
        inputs = args.checkpoint if average else [args.checkpoint]
        check_outputs(others=[args.out])
        refuse_inputs([args.out], inputs)
        refuse_existing([args.out], args.overwrite)
        try:
            path = export(inputs if average else args.checkpoint, args.out, half=not args.float32)
        except (FileNotFoundError, ValueError) as e:
            raise SystemExit(f"error: {e}") from None
        print(f"wrote {path} ({path.stat().st_size / 2**20:.2f} MiB)")
        return 0

    x = add_command(sub, "export-weights", run, help=help, description=inspect.getdoc(export), example=example,
                    outputs={"out": "file"})
    if average:
        x.add_argument("checkpoint", nargs="+", help=checkpoint_help + "; several: their weights averaged")
    else:
        x.add_argument("checkpoint", help=checkpoint_help)
    x.add_argument("--out", required=True, help="the weights file to write (.pt)")
    x.add_argument("--float32", action="store_true", help="keep float32 (float16 storage otherwise)")
    add_overwrite(x)


def _number(cell: str):
    """A table cell as a number when it is one (``81.2``, ``1,024``, ``12 %``), else its text."""
    text = cell.strip().replace(",", "").removesuffix("%").strip()
    try:
        value = float(text)
    except ValueError:
        return cell.strip()
    return int(value) if re.fullmatch(r"[+-]?\d+", text) else value if math.isfinite(value) else None


def markdown_result(text: str, title: str, command: str) -> dict:
    """The markdown tables of ``text`` as one result (:func:`shapeio.results.make_result`): a column ``table``
    (the heading or bold line above each table) and every table's columns; a row has None where its table has
    no such column. The text's other lines become the notes."""
    from shapeio.results import column, make_result  # lazy: loaded when the command runs

    columns, keys, rows, notes = [column("table", "table")], {}, [], []
    heading, header = title, None
    for line in text.splitlines():
        s = line.strip()
        if s.startswith("|") and s.endswith("|"):
            cells = [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", s[1:-1])]
            if header is None:
                header = cells
                for label in cells:
                    if label not in keys:
                        keys[label] = re.sub(r"\W+", "_", label.lower()).strip("_") or f"column{len(keys)}"
                        while keys[label] in [c["key"] for c in columns]:
                            keys[label] += "_"
                        columns.append(column(keys[label], label))
            elif not all(set(c) <= set(":- ") for c in cells):
                rows.append({"table": heading, **{keys[h]: _number(c) for h, c in zip(header, cells)}})
            continue
        header = None
        if s.startswith("#") or (s.startswith("**") and s.endswith("**")):
            heading = s.lstrip("#").strip().strip("*").strip()
        elif s:
            notes.append(s)
    full = [{c["key"]: r.get(c["key"]) for c in columns} for r in rows]
    return make_result(title, columns, full, notes, command)


def int_at_least(low: int, high: int = MAX_COUNT_OPTION):
    """An argparse type: an int from ``low`` to ``high`` (:func:`shapeio.options.int_in`)."""
    return int_in(low, high)


def seed(text: str) -> int:
    """An argparse type: a seed, 0 to :data:`MAX_SEED`."""
    return int_at_least(0, MAX_SEED)(text)


def positive_float(text: str) -> float:
    """An argparse type: a positive finite float."""
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


class Program:
    """A loaded program, the name printed for it and the file name its errors carry."""

    def __init__(self, spec: str):
        path = Path(spec)
        cat, _, ident = spec.partition("/")
        if path.is_file():
            self.name = self.file = str(path)
            text = decode(path.read_bytes(), self.file)
        elif cat in corpus.CATEGORIES and ident.isascii() and ident.isdigit():
            self.name, self.file = spec, f"{cat}/{int(ident)}.txt"
            try:
                text = corpus.read(cat, int(ident))
            except KeyError:
                raise SystemExit(f"error: no program {cat}/{int(ident)} in the corpus") from None
        else:
            raise SystemExit(f"error: {spec!r} is neither a file nor a corpus id like 'chair/173'")
        self.program = parse(text, file=self.file)

    def execute(self, program=None, **kwargs):
        """Execute this program (or ``program``, e.g. a fitted version); errors carry the file name."""
        try:
            return execute(self.program if program is None else program, **kwargs)
        except ExecutionError as e:
            raise ExecutionError(e.reason, e.line, file=self.file) from None


def check_outputs(meshes=(), others=()) -> None:
    """Stop before any work when an output's folder is missing or a mesh suffix is unknown."""
    for path in [p for p in (*meshes, *others) if p]:
        folder = Path(path).parent
        if not folder.is_dir():
            raise SystemExit(f"error: {path}: folder {str(folder)!r} does not exist")
    for path in [p for p in meshes if p]:
        if Path(path).suffix.lower() not in WRITE_SUFFIXES:
            raise SystemExit(f"error: {path}: unknown mesh format {Path(path).suffix!r} "
                             f"(use {', '.join(WRITE_SUFFIXES)})")


def refuse_inputs(outputs, inputs) -> None:
    """Stop before writing an output over an input file (a corpus id is no file: never matches)."""
    try:
        refuse_overwrite(outputs, [p for p in inputs if p is not None and Path(p).is_file()])
    except FileExistsError as e:
        raise SystemExit(f"error: {e}") from None


def refuse_existing(paths, overwrite: bool = False, hint: str | None = None) -> None:
    """Stop before any work when one of ``paths`` exists, unless ``overwrite``
    (:func:`shapeio.files.existing_outputs`; ``hint``: other advice than ``--overwrite``)."""
    problem = existing_outputs(paths, overwrite, hint)
    if problem:
        raise SystemExit(f"error: {problem}")


def write_mesh(path: str, shape) -> None:
    suffix = Path(path).suffix.lower()
    if suffix == ".obj":
        io.write_obj(path, shape.corners, lines=shape.line)
    elif suffix == ".ply":
        io.write_ply(path, shape.corners, labels=shape.line.numpy())
    else:
        io.write_glb(path, shape.corners, labels=shape.line.numpy())


def emit_text(path: str | None, text: str) -> None:
    """Write a program to ``path`` (atomically) or, without one, print it."""
    if path:
        atomic_write(path, text)
        print(f"wrote {path}")
    else:
        sys.stdout.write(text)


def command_line(args) -> str:
    """The command line that ran, for the files that record it."""
    return f"{PROG} " + shlex.join(sys.argv[1:] if getattr(args, "argv", None) is None else args.argv)


def category_pairs(values, form: str, flag: str = "--library") -> dict:
    """``--library CATEGORY=PATH`` values as a dict; a value without '=' stops with the expected form."""
    bad = [x for x in values or () if "=" not in x]
    if bad:
        raise SystemExit(f"error: {flag} {bad[0]!r}: expected {form}")
    return dict(x.split("=", 1) for x in values or ())


def macro_library(name: str, option: str = "", text: bool = False):
    """The ShapeMOD library ``name`` (:func:`shapeprog.macros.api.read_library`: a library file when one exists
    at that path, else a shipped category); SystemExit with the reason otherwise. ``text``: (library, its
    file's text)."""
    # the macro library code is imported when a command reads a library, not for --help
    from .macros.api import read_library  # lazy: loaded when the command runs

    try:
        lib, src = read_library(name)
    except NotShippedError as e:
        raise SystemExit(f"error: {option}{e}") from None
    return (lib, src) if text else lib
