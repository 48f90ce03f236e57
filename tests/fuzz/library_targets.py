"""Fuzz target for ShapeCoder abstraction library files (``shapeprog.coder.lang.Library.from_text``, what
``abstract-infer --library FILE`` reads), mutated from the shipped libraries by the byte mutator. Only the
project's ParseError may escape (an exponential library is refused when it loads, ``MAX_NODES``).
"""
from __future__ import annotations

from importlib import resources

from shapeprog.coder.lang import LANG_3D, Library, size
from shapeprog.errors import ParseError

from fuzz.engine import Target

__all__ = ["BOUND_S", "TARGETS", "run_library"]

#: The longest one input may take (on a loaded 2-core machine).
BOUND_S = 3.0

def _library_seeds() -> list[bytes]:
    folder = resources.files("shapeprog").joinpath("data", "coder_libraries")
    return [folder.joinpath(n).read_bytes() for n in ("chair.txt", "table.txt", "storage.txt")]


def run_library(data: bytes):
    """Load a library from the bytes (as UTF-8 text; undecodable bytes are the reader's error too)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ParseError(f"not UTF-8 text (byte offset {e.start})", "<fuzz>", 1, 1, "") from None
    lib = Library.from_text(text, LANG_3D, file="<fuzz>")
    return [float(size(a.body)) for a in lib.abstractions]


TARGETS = [Target("shapecoder/library-file", _library_seeds(), run_library, (ParseError,), BOUND_S)]
