"""An on-disk cache of expensive reference arrays (retrieval indexes, ground-truth metric rows, classifier
features), keyed by what they depend on.

The folder is ``$SHAPE_PROGRAMS_CACHE`` when set, else ``$XDG_CACHE_HOME/shape-programs``, else
``~/.cache/shape-programs``; ``SHAPE_PROGRAMS_CACHE=off`` turns caching off. An entry is one ``.npz`` file
(no pickles) named ``<name>-<digest>.npz``, the digest a SHA-256 of the key; it stores the key itself, and an
entry whose stored key differs from the one asked for, or that does not read, is recomputed and replaced.
Entries are written atomically (:func:`shapeio.files.atomic_write`), so a concurrent reader sees a whole
entry or none.

Example:
    >>> import numpy as np, tempfile, os
    >>> os.environ["SHAPE_PROGRAMS_CACHE"] = tempfile.mkdtemp()
    >>> calls = []
    >>> f = lambda: calls.append(1) or {"x": np.arange(3)}
    >>> cached("demo", {"n": 3}, f)["x"].tolist(), cached("demo", {"n": 3}, f)["x"].tolist(), len(calls)
    ([0, 1, 2], [0, 1, 2], 1)
    >>> del os.environ["SHAPE_PROGRAMS_CACHE"]
"""
from __future__ import annotations

import hashlib
import io
import json
import os
from functools import lru_cache
from pathlib import Path
from typing import Callable, Mapping, Optional

import numpy as np

from .files import atomic_write

__all__ = ["CACHE_ENV", "cache_dir", "cached", "entry_path", "file_digest", "key_digest", "load", "store"]

#: The environment variable naming the cache folder (``off``: no caching).
CACHE_ENV = "SHAPE_PROGRAMS_CACHE"
_KEY = "__cache_key__"


def cache_dir() -> Optional[Path]:
    """The cache folder (see the module docstring); None when caching is off."""
    env = os.environ.get(CACHE_ENV)
    if env is not None and env.strip().lower() in ("off", "0", "none", ""):
        return None
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "shape-programs"


def _canonical(key: Mapping) -> str:
    return json.dumps(key, sort_keys=True, separators=(",", ":"), default=str)


def key_digest(key: Mapping) -> str:
    """SHA-256 of the key's canonical JSON (sorted keys)."""
    return hashlib.sha256(_canonical(key).encode("utf-8")).hexdigest()


@lru_cache(maxsize=64)
def _file_digest(path: str, size: int, mtime_ns: int) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_digest(path) -> str:
    """SHA-256 of a file's bytes (remembered per path, size and modification time within the process)."""
    st = os.stat(path)
    return _file_digest(str(path), st.st_size, st.st_mtime_ns)


def entry_path(name: str, key: Mapping) -> Optional[Path]:
    """Where the entry of ``name`` and ``key`` lives; None when caching is off."""
    root = cache_dir()
    return None if root is None else root / f"{name}-{key_digest(key)[:32]}.npz"


def load(name: str, key: Mapping) -> Optional[dict]:
    """The arrays stored for ``name`` and ``key``, or None (no entry, caching off, an unreadable entry, or one
    stored under another key)."""
    path = entry_path(name, key)
    if path is None or not path.is_file():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            if _KEY not in data.files or str(data[_KEY]) != _canonical(key):
                return None
            return {k: data[k] for k in data.files if k != _KEY}
    except (OSError, ValueError, KeyError, EOFError):
        return None


def store(name: str, key: Mapping, arrays: Mapping[str, np.ndarray]) -> Optional[Path]:
    """Write the entry of ``name`` and ``key`` atomically; None when caching is off or the folder cannot be
    written (the caller still has its arrays)."""
    path = entry_path(name, key)
    if path is None:
        return None
    buf = io.BytesIO()
    np.savez(buf, **{_KEY: np.array(_canonical(key))}, **{k: np.asarray(v) for k, v in arrays.items()})
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        return atomic_write(path, buf.getvalue())
    except OSError:
        return None


def cached(name: str, key: Mapping, compute: Callable[[], Mapping[str, np.ndarray]]) -> dict:
    """The arrays of ``name`` under ``key``: read from the cache, or ``compute()`` d and stored."""
    hit = load(name, key)
    if hit is not None:
        return hit
    arrays = {k: np.asarray(v) for k, v in compute().items()}
    store(name, key, arrays)
    return arrays
