"""The macro-refactored corpus: every program of a category rewritten with a library, as files.

:func:`refactor_corpus` refactors a category's corpus programs (:func:`shapeprog.macros.refactor` per
shape) through a caller's ``concurrent.futures.Executor`` (one task per chunk of shapes; none: in this
process) and checks every result: the macro text is parsed back and executed, and its leaf cuboids are
matched one to one with the original program's (the largest corner distance is recorded). A shape that
does not parse, convert, refactor or execute is a :class:`ShapeRefactor` with an ``error``: reported, the
others kept. :func:`write_refactored` writes the result as a folder, ``<id>.txt`` per shape (the
hierarchical macro program of :mod:`shapeprog.macros.hierarchy`, the text ``refactor -o`` writes and
``python -m shapeprog edit`` reads) plus ``summary.json``, atomically (a temporary folder renamed into
place) and never over existing files, or the same files as a reproducible ``.tar.xz``.
:func:`read_refactored` reads either back; :func:`load_refactored` reads the shipped one
(``shapeprog/data/shapemod_<category>_refactored.tar.xz``: chair, table, storage).

Example:
    >>> from shapeprog.macros import Library
    >>> lib = Library.from_text("def slab(h: float):\\n    c = Cuboid(bb_x, h, bb_z, True)\\n"
    ...                         "    attach(bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\\n")
    >>> rc = refactor_corpus("chair", lib, ids=[173])
    >>> s = rc.shapes[0]
    >>> s.error, s.summary["blocks"], s.summary["f_after"] <= s.summary["f_before"] + 2
    (None, 2, True)
"""
from __future__ import annotations

import hashlib
import io
import json
import lzma
import os
import shutil
import tarfile
import tempfile
from concurrent.futures import Executor
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from shapeio import write_new, InputError
from shapeio.files import parse_json

from .. import corpus
from ..errors import ExecutionError, ParseError
from ..execute import execute as sa_execute
from ..lang import parse
from ..limits import decode
from . import hierarchy
from .api import program_stats, refactor
from .data import convert_program
from .execute import execute_hierarchy
from .lang import MacroError, from_lines
from .library import Library

__all__ = ["CHUNK", "CHECK_TOL", "MAX_ARCHIVE_BYTES", "SHIPPED", "SUMMARY", "RefactoredCorpus", "ShapeRefactor", "check_target", "library_sha256",
           "load_refactored", "read_refactored", "refactor_corpus", "refactor_texts", "write_refactored"]

#: Shapes per executor task.
CHUNK = 25
#: A refactored shape whose leaf corners are farther than this from the original's is flagged in the
#: summary (``over_tolerance``): four times the fit tolerance ``ABS_MAX_ERROR`` (0.06), the lever arm of
#: a fitted attach point on a unit cuboid, as the API tests allow.
CHECK_TOL = 0.24
#: The summary file's name in a refactored-corpus folder.
SUMMARY = "summary.json"
#: The most bytes a ``.tar.xz`` refactored corpus may decompress to (the shipped chair corpus: 11 MB).
MAX_ARCHIVE_BYTES = 256 * 2**20

_COUNTS = ("lines", "float", "cube", "categorical", "bool")


@dataclass(frozen=True)
class ShapeRefactor:
    """One shape of a refactored corpus.

    Attributes:
        shape_id: the corpus id.
        text: the hierarchical macro program (None when the shape failed).
        summary: ``id``, ``blocks``, ``f_before`` / ``f_after`` (sums over sub-programs of f without and
            with the library, the library's |L| term in every sub-program's f), ``<count>_before`` /
            ``<count>_after`` for the calls after the bbox lines (``lines``) and their ``float``,
            ``cube``, ``categorical`` and ``bool`` parameters, ``leaves`` and ``max_corner_error`` (the
            check; None without it). A failed shape's summary holds ``id`` and ``error``.
        error: why the shape failed, or None.
    """

    shape_id: int
    text: str | None
    summary: dict
    error: str | None = None


@dataclass
class RefactoredCorpus:
    """The refactored shapes of a category, in the order asked for, and how they were made."""

    category: str
    library: str
    shapes: list[ShapeRefactor]
    meta: dict = field(default_factory=dict)

    @property
    def failures(self) -> list[ShapeRefactor]:
        return [s for s in self.shapes if s.error is not None]

    def summary(self) -> dict:
        """The summary JSON's content: ``meta``, totals and means over the refactored shapes, the
        failures with their reasons, and one entry per shape."""
        ok = [s.summary for s in self.shapes if s.error is None]
        totals = {}
        for key in ("f_before", "f_after", "blocks", "leaves") + tuple(f"{c}_{w}" for c in _COUNTS
                                                                      for w in ("before", "after")):
            vals = [s[key] for s in ok if s[key] is not None]  # leaves: None without the check
            totals[key] = round(float(np.mean(vals)), 4) if vals else None
        errs = [s["max_corner_error"] for s in ok if s.get("max_corner_error") is not None]
        return {
            "category": self.category,
            "library": self.library,
            **self.meta,
            "shapes": len(self.shapes),
            "refactored": len(ok),
            "failed": len(self.shapes) - len(ok),
            "mean_per_shape": totals,
            "max_corner_error": max(errs) if errs else None,
            "over_tolerance": [s["id"] for s in ok if (s.get("max_corner_error") or 0.0) > CHECK_TOL],
            "check_tolerance": CHECK_TOL,
            "failures": [{"id": s.shape_id, "reason": s.error} for s in self.failures],
            "per_shape": [s.summary for s in self.shapes],
        }


def _leaf_error(got, want) -> float:
    """The corner distance between two sets of leaf cuboids ``(L, 8, 3)``: the largest coordinate
    difference of corresponding corners (L-infinity), over the cuboids matched one to one by the assignment
    minimising the summed per-cuboid distances; inf when the counts differ."""
    from scipy.optimize import linear_sum_assignment  # lazy: scipy only when a refactor is checked

    a, b = got.detach().double().numpy(), want.detach().double().numpy()
    if a.shape != b.shape:
        return float("inf")
    if len(a) == 0:
        return 0.0
    cost = np.abs(a[:, None] - b[None, :]).max(axis=(2, 3))
    rows, cols = linear_sum_assignment(cost)
    return float(cost[rows, cols].max())


def _counts(programs, library) -> dict:
    out = dict.fromkeys(_COUNTS, 0)
    for p in programs:
        st = program_stats(p, library)
        for k in _COUNTS:
            out[k] += st[k]
    return out


def _one(category: str, shape_id: int, text: str, library, mode: str, max_orders: int,
         check: bool) -> ShapeRefactor:
    file = f"{category}/{shape_id}.txt"

    def failed(reason: str) -> ShapeRefactor:
        return ShapeRefactor(shape_id, None, {"id": shape_id, "error": reason}, reason)

    try:
        prog = parse(text, file=file)
    except ParseError as e:
        return failed(f"does not parse: {e}")
    conv = convert_program(prog, category, shape_id)
    if conv.failures:
        return failed("; ".join(str(f) for f in conv.failures))
    try:
        r = refactor(conv.subprograms, library, mode=mode, max_orders=max_orders)
    except (ValueError, MacroError) as e:
        return failed(f"refactor: {e}")
    before = _counts([from_lines(b.lines) for b in r.blocks], Library())
    summary = {"id": shape_id, "blocks": r.stats["blocks"], "f_before": round(float(r.stats["f_base"]), 4),
               "f_after": round(float(r.stats["f"]), 4)}
    for k in _COUNTS:
        summary[f"{k}_before"] = before[k]
        summary[f"{k}_after"] = int(r.stats[k])
    summary["leaves"] = None
    summary["max_corner_error"] = None
    if check:
        try:
            h = hierarchy.parse(r.text, file=f"{shape_id}.txt")
            with torch.no_grad():
                got = execute_hierarchy(h).corners
                want = sa_execute(prog).corners
        except (ParseError, ExecutionError, MacroError, ValueError) as e:
            return failed(f"the macro program does not read back or execute: {e}")
        err = _leaf_error(got, want)
        if not np.isfinite(err):
            return failed(f"the macro program has {len(got)} leaf cuboids, the original {len(want)}")
        summary["leaves"] = int(len(want))
        summary["max_corner_error"] = round(err, 6)
    return ShapeRefactor(shape_id, r.text, summary)


def _chunk(job) -> list[ShapeRefactor]:
    category, items, library, mode, max_orders, check = job
    return [_one(category, i, t, library, mode, max_orders, check) for i, t in items]


def refactor_texts(category: str, items: Sequence[tuple[int, str]], library, executor: Executor | None = None,
                   chunk: int = CHUNK, mode: str = "beam", max_orders: int = 1000,
                   check: bool = True) -> list[ShapeRefactor]:
    """Refactor program texts ``(id, text)`` of ``category`` with ``library``, in order.

    Args:
        executor: runs chunks of ``chunk`` shapes (a process pool, Dask's or Ray's executor); None: here.
        mode, max_orders: the best-program search (:func:`shapeprog.macros.refactor`).
        check: parse every macro text back, execute it and match its leaf cuboids with the original's.

    Returns:
        One :class:`ShapeRefactor` per item (failures included), the same with or without an executor.
    """
    if chunk < 1:
        raise ValueError(f"`chunk` must be at least 1, got {chunk}")
    items = [(int(i), t) for i, t in items]
    jobs = [(category, items[s:s + chunk], library, mode, max_orders, check) for s in range(0, len(items), chunk)]
    if executor is None:
        parts = [_chunk(j) for j in jobs]
    else:
        parts = [f.result() for f in [executor.submit(_chunk, j) for j in jobs]]
    return [s for p in parts for s in p]


def library_sha256(library) -> str:
    """The hash a refactored corpus's summary records of the library it was made with (``library_sha256``): of
    its definitions as :meth:`Library.to_text` prints them (no header)."""
    return hashlib.sha256(library.to_text().encode("utf-8")).hexdigest()


def refactor_corpus(category: str, library, library_name: str = "", split: str = "all",
                    limit: int | None = None, seed: int = 0, ids: Sequence[int] | None = None,
                    executor: Executor | None = None, chunk: int = CHUNK, mode: str = "beam",
                    max_orders: int = 1000, check: bool = True) -> RefactoredCorpus:
    """Refactor the corpus programs of ``category`` (``split``; ``ids`` instead, when given) with ``library``.

    Args:
        library: a :class:`~shapeprog.macros.Library`.
        library_name: how the summary names it (a shipped category or a file).
        limit: a random subset of this many shapes of the split, drawn with ``seed`` (as
            :func:`shapeprog.macros.collection` draws it), in split order.
        executor, chunk, mode, max_orders, check: as :func:`refactor_texts`.

    Raises:
        ValueError: an unknown category or split, or an id that is not in the corpus.
    """
    given = ids is not None
    if not given:
        ids = corpus.ids(category, split)
        if limit is not None and limit < len(ids):
            pick = set(int(i) for i in np.random.default_rng(seed).choice(ids, size=limit, replace=False))
            ids = [i for i in ids if i in pick]
    items = []
    for i in ids:
        try:
            items.append((int(i), corpus.read(category, int(i))))
        except KeyError:
            raise ValueError(f"no program {category}/{i} in the corpus") from None
    shapes = refactor_texts(category, items, library, executor, chunk, mode, max_orders, check)

    meta = {"library_sha256": library_sha256(library),
            "split": None if given else split, "ids": len(ids) if given else None, "limit": limit, "seed": seed,
            "search": mode, "max_orders": max_orders, "library_macros": len(library.macros),
            "library_size": len(library)}
    return RefactoredCorpus(category, library_name, shapes, meta)


def check_target(out) -> None:
    """Refuse an output :func:`write_refactored` would not write: an existing archive, an existing folder
    that is not empty, a missing parent folder (``FileExistsError`` / ``FileNotFoundError``)."""
    out = Path(out)
    if _is_archive(out):
        if os.path.lexists(out):
            raise FileExistsError(f"{out}: the file exists; it is not replaced")
    elif out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise FileExistsError(f"{out}: exists and is not an empty folder; refactored corpora are never written "
                              "over existing files")
    if not out.parent.is_dir():
        raise FileNotFoundError(f"{out}: folder {str(out.parent)!r} does not exist")


def _is_archive(path: Path) -> bool:
    return path.name.endswith(".tar.xz")


def _files(result: RefactoredCorpus, command: str | None) -> list[tuple[str, bytes]]:
    summary = result.summary()
    if command is not None:
        summary = {"command": command, **summary}
    files = [(f"{s.shape_id}.txt", s.text.encode("utf-8")) for s in result.shapes if s.text is not None]
    return files + [(SUMMARY, (json.dumps(summary, indent=1) + "\n").encode("utf-8"))]


def _archive_bytes(files: list[tuple[str, bytes]]) -> bytes:
    """A reproducible ``.tar.xz``: members in the given order, no owners, times or modes of this machine."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:", format=tarfile.PAX_FORMAT) as tar:
        for name, data in files:
            info = tarfile.TarInfo(name)
            info.size, info.mode, info.mtime = len(data), 0o644, 0
            tar.addfile(info, io.BytesIO(data))
    return lzma.compress(buf.getvalue(), preset=9 | lzma.PRESET_EXTREME)


def write_refactored(result: RefactoredCorpus, out, command: str | None = None) -> Path:
    """Write ``<id>.txt`` per refactored shape and :data:`SUMMARY` into the new folder ``out``, or into
    the new archive ``out`` when its name ends in ``.tar.xz`` (members ``<id>.txt`` and the summary).

    A folder is written as a temporary folder beside ``out`` and then renamed to ``out``; an archive is
    written with :func:`shapeio.write_new`: a reader sees all the files or none. A folder ``out`` must not
    exist or be empty; an archive must not exist.

    Args:
        command: the command line that made it, recorded in the summary.

    Raises:
        FileExistsError: ``out`` exists (a folder: is not empty; checked before and at the rename).
        FileNotFoundError: ``out``'s parent folder does not exist.
    """
    out = Path(out)
    check_target(out)
    if _is_archive(out):
        return write_new(out, _archive_bytes(_files(result, command)))
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-{os.getpid()}-", dir=out.parent))
    try:
        for name, data in _files(result, command):
            (tmp / name).write_bytes(data)
        os.chmod(tmp, 0o777 & ~_umask())
        try:
            os.rename(tmp, out)
        except OSError as e:
            if out.exists():
                raise FileExistsError(f"{out}: appeared meanwhile and is not empty; not replaced") from e
            raise
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: The shipped refactored corpora (in ``shapeprog/data``), by category.
SHIPPED = {"chair": "shapemod_chair_refactored.tar.xz", "table": "shapemod_table_refactored.tar.xz",
           "storage": "shapemod_storage_refactored.tar.xz"}


def load_refactored(category: str, ids: Sequence[int] | None = None) -> tuple[dict, dict]:
    """The shipped refactored corpus of ``category`` (:func:`read_refactored` of its archive; how it was
    made: its summary's ``command``).

    Raises:
        ValueError: none is shipped for ``category``.
    """
    if category not in SHIPPED:
        raise ValueError(f"no shipped refactored corpus for {category!r} (shipped: {', '.join(SHIPPED)})")
    ref = resources.files("shapeprog").joinpath("data", SHIPPED[category])
    with resources.as_file(ref) as path:
        return read_refactored(path, ids=ids)


def _decompress(path: Path) -> bytes:
    """The ``.xz`` file at ``path``, decompressed, at most :data:`MAX_ARCHIVE_BYTES`.

    Raises:
        shapeio.InputError: larger than the limit, truncated, or not xz.
    """
    d = lzma.LZMADecompressor()
    out = d.decompress(path.read_bytes(), max_length=MAX_ARCHIVE_BYTES + 1)
    if len(out) > MAX_ARCHIVE_BYTES:
        raise InputError(f"{path}: decompresses to more than MAX_ARCHIVE_BYTES = {MAX_ARCHIVE_BYTES} bytes")
    if not d.eof:
        raise InputError(f"{path}: a truncated .xz file")
    return out


def read_refactored(path, library=None, ids: Sequence[int] | None = None) -> tuple[dict, dict]:
    """Read a refactored corpus: a folder :func:`write_refactored` wrote, or a ``.tar.xz`` of one.

    Args:
        library: functions the programs call without defining them (the written ones define theirs).
        ids: read only these shapes (default: all).

    Returns:
        ``(programs, summary)``: ``{shape id: MacroHierarchy}`` in id order, and the summary (``{}`` when
        the folder has none).

    Raises:
        ParseError: a program file that does not parse (named, with line and column).
        shapeio.InputError: a file that is not such an archive (or one that decompresses to more than
            :data:`MAX_ARCHIVE_BYTES`), a summary that is not a JSON object.
        FileNotFoundError: no such folder or archive.
    """
    path = Path(path)
    files: dict[str, bytes] = {}
    if path.is_dir():
        for f in path.iterdir():
            if f.name.endswith(".txt") or f.name == SUMMARY:
                files[f.name] = f.read_bytes()
    elif path.is_file():
        try:
            with tarfile.open(fileobj=io.BytesIO(_decompress(path)), mode="r:") as tar:
                for m in tar.getmembers():
                    name = m.name.rsplit("/", 1)[-1]
                    if m.isfile() and (name.endswith(".txt") or name == SUMMARY):
                        files[name] = tar.extractfile(m).read()
        except (lzma.LZMAError, tarfile.TarError, EOFError) as e:
            raise InputError(f"{path}: not a .tar.xz archive of a refactored corpus ({e})") from None
    else:
        raise FileNotFoundError(f"{path}: no such folder or archive")
    summary = {}
    if SUMMARY in files:
        where = f"{path}/{SUMMARY}"
        try:
            summary = parse_json(files.pop(SUMMARY).decode("utf-8"), where)
        except UnicodeDecodeError as e:
            raise InputError(f"{where}: not a summary JSON ({e})") from None
        if not isinstance(summary, dict):
            raise InputError(f"{where}: not a summary JSON (a JSON object is expected)")
    wanted = set() if ids is None else {int(i) for i in ids}
    programs = {}
    for name in sorted(files, key=lambda n: (len(n), n)):
        stem = name[:-4]
        if not (stem.isascii() and stem.isdigit()) or (ids is not None and int(stem) not in wanted):
            continue
        where = f"{path}/{name}"
        programs[int(stem)] = hierarchy.parse(decode(files[name], where), file=where, library=library)
    return dict(sorted(programs.items())), summary
