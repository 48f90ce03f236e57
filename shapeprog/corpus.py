"""The ShapeAssembly PartNet program corpus (vendored in ``shapeprog/data``).

11,922 hierarchical programs: chair (3,835), table (6,536), storage (1,551), with the paper's
train/val splits. Provenance and licence (non-commercial): ``shapeprog/data/NOTICE.md``.

The archive is read once per process, on first use, and kept in memory (about 5 MB of text);
importing this module reads nothing.

Example:
    >>> from shapeprog import corpus
    >>> len(corpus.ids("chair", "val"))
    496
    >>> corpus.read("table", 33075).splitlines()[0]
    'Assembly Program_0 {'
"""
from __future__ import annotations

import functools
import io
import lzma
import tarfile
import warnings
from importlib import resources

from shapeio.cache import file_digest
from shapeio.points import obj_vertices

from .errors import ParseError
from .lang import Program, parse
from .limits import decode

__all__ = ["CATEGORIES", "SPLITS", "CorpusWarning", "example_points", "example_text", "ids", "load", "read"]

CATEGORIES = ("chair", "table", "storage")
SPLITS = ("train", "val", "all")


class CorpusWarning(UserWarning):
    """Some corpus files could not be parsed (they are named in the message)."""


def _data(name: str) -> bytes:
    return resources.files("shapeprog").joinpath("data", name).read_bytes()


@functools.lru_cache(maxsize=None)
def data_digest() -> str:
    """SHA-256 of the corpus archive: the key under which results derived from the corpus are cached."""
    return file_digest(str(resources.files("shapeprog").joinpath("data", "shapeassembly_partnet.tar.xz")))


@functools.lru_cache(maxsize=None)
def _archive(name: str) -> dict[str, bytes]:
    with tarfile.open(fileobj=io.BytesIO(lzma.decompress(_data(name))), mode="r:") as tar:
        return {m.name.lstrip("./"): tar.extractfile(m).read() for m in tar.getmembers() if m.isfile()}


def _check_category(category: str) -> None:
    if category not in CATEGORIES:
        raise ValueError(f"unknown category {category!r}; expected one of {', '.join(CATEGORIES)}")


def ids(category: str, split: str = "train") -> list[int]:
    """Program ids of ``category`` in ``split`` ('train', 'val' or 'all'), in file order."""
    _check_category(category)
    if split not in SPLITS:
        raise ValueError(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")
    arc = _archive("shapeassembly_partnet.tar.xz")
    if split == "all":
        return ids(category, "train") + ids(category, "val")
    name = f"data_splits/{category}/{split}.txt"
    out = []
    for n, line in enumerate(decode(arc[name], name).splitlines(), 1):
        for x in line.split():
            if not (x.isascii() and x.isdigit()):
                raise ParseError(f"not a program id: {x[:20]!r}", name, n, line.index(x) + 1, x)
            out.append(int(x))
    return out


def read(category: str, id: int | str) -> str:
    """The text of program ``category/id`` (e.g. ``read("chair", 173)``).

    Raises:
        KeyError: no such program.
        ParseError: the stored file is not UTF-8 (at the bad byte's line and column).
    """
    _check_category(category)
    key = f"data/{category}/{int(id)}.txt"
    arc = _archive("shapeassembly_partnet.tar.xz")
    if key not in arc:
        raise KeyError(f"no program {category}/{id} in the corpus")
    return decode(arc[key], f"{category}/{int(id)}.txt")


def load(category: str, split: str = "train", strict: bool = False) -> list[tuple[int, Program]]:
    """Parse every program of ``category`` in ``split``.

    A file that does not parse is skipped and reported by name (a :class:`CorpusWarning`
    listing ``category/id: error`` for each), and the rest still loads; with ``strict=True``
    the first error is raised instead.

    Returns:
        ``[(id, Program), ...]`` in split-file order.
    """
    out, errors = [], []
    for i in ids(category, split):
        name = f"{category}/{i}.txt"
        try:
            out.append((i, parse(read(category, i), file=name)))
        except (ParseError, KeyError) as e:
            if strict:
                raise
            errors.append(f"{name}: {e}")
    if errors:
        warnings.warn(f"{len(errors)} corpus file(s) skipped: " + "; ".join(errors), CorpusWarning, stacklevel=2)
    return out


def example_text(name: str = "ex-0.txt") -> str:
    """A vendored example file: ``'ex-0.txt'`` (flat program), ``'comp_pc.obj'`` or ``'simp_pc.obj'`` (point
    clouds of a real PartNet table and chair)."""
    arc = _archive("examples.tar.xz")
    if name not in arc:
        raise KeyError(f"no example {name!r}; available: {', '.join(sorted(arc))}")
    return decode(arc[name], name)


def example_points(name: str = "comp_pc.obj"):
    """An example point cloud (``'comp_pc.obj'`` or ``'simp_pc.obj'``) as a (N, 3) float32 numpy array (10,000
    points of a real PartNet table, or chair for ``simp_pc``)."""
    return obj_vertices(example_text(name).splitlines(), name)
