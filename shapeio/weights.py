"""Weights files of every model family: one versioned payload, written atomically and read with
``torch.load(weights_only=True)``.

A weights file holds one dict ``{"format": family, "version": n, ...}``. :func:`write_weights` writes it (a
temporary file, then ``os.replace``); :func:`read_weights` reads it and checks its family and version, and
its errors name the file: a missing file is a ``FileNotFoundError``; a file that torch cannot read, a file
of another family, and a file of another version are ``ValueError`` s. :func:`load_payload` is the reading
step alone, for files that are not weights files (a Lightning training checkpoint); :func:`checkpoint_entry`
checks the entry a model family's LightningModule adds to its checkpoints.

Files written before the payload carried ``format`` (the shipped csgnet models and the PointNet
classifier, whose SHA-256 the generation metrics pin) are read as version 0 of their family: a family
names the keys of its old layout (``legacy=("config", "state_dict")``), and a payload without ``format``
that holds them is accepted as that version.

torch is imported when a file is read or written (``import shapeio`` stays NumPy-level).

Example:
    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "m.pt"
    >>> _ = write_weights(path, "demo", 1, {"state_dict": {}})
    >>> read_weights(path, "demo", 1)["version"]
    1
    >>> try:
    ...     read_weights(path, "csgnet", 1)
    ... except ValueError as e:
    ...     print(str(e).split(": ", 1)[1])
    a 'demo' weights file, not a 'csgnet' one
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Iterable, Mapping, Optional

from .files import PathLike, atomic_write

__all__ = ["LEGACY_VERSION", "check_weights", "checkpoint_entry", "load_payload", "read_weights", "write_weights"]

#: The version a payload of a family's old layout (no ``format`` field) is read as.
LEGACY_VERSION = 0


def load_payload(path: PathLike, what: str = "weights file", missing: str = "weights file") -> dict:
    """The dict stored in ``path`` by ``torch.save``, read on the CPU with ``weights_only=True``.

    Args:
        path: the file.
        what: what the file should be, for the error of an unreadable file (``"csgnet weights file"``).
        missing: the same for the error of a missing file.

    Raises:
        FileNotFoundError: ``<path>: no such <missing>``.
        ValueError: naming the file, when torch cannot read it (the failure's type, not torch's advice to
            load unsafely) or it holds something other than a dict.
    """
    import torch  # torch only where a weights file is read: shapeio is NumPy-level

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such {missing}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise ValueError(f"{path}: not a {what} (unreadable: {type(e).__name__})") from None
    if not isinstance(payload, dict):
        raise ValueError(f"{path}: not a {what} (a {type(payload).__name__})")
    return payload


def check_weights(payload: dict, path: PathLike, family: str, version: int,
                  legacy: Optional[Iterable[str]] = None) -> dict:
    """``payload`` (read from ``path``) checked as a weights file of ``family`` at ``version``; a payload of
    the family's old layout (no ``format``, every key of ``legacy``) comes back with ``format`` and
    ``version`` (:data:`LEGACY_VERSION`) added.

    Raises:
        ValueError: naming the file, for a payload of another family or version, or of no family.
    """
    fmt = payload.get("format")
    if fmt is None:
        if legacy is not None and all(k in payload for k in legacy):
            return {**payload, "format": family, "version": LEGACY_VERSION}
        raise ValueError(f"{path}: not a {family!r} weights file (no 'format' field; keys {sorted(payload)[:6]})")
    if fmt != family:
        raise ValueError(f"{path}: a {fmt!r} weights file, not a {family!r} one")
    found = payload.get("version")
    if found != version:
        raise ValueError(f"{path}: {family!r} weights file version {found!r}; this version of the software reads "
                         f"version {version}")
    return payload


def read_weights(path: PathLike, family: str, version: int, legacy: Optional[Iterable[str]] = None,
                 what: Optional[str] = None) -> dict:
    """The payload of a weights file of ``family`` at ``version`` (:func:`load_payload`, then the checks of
    :func:`check_weights`); ``what`` names the file's kind in the error of an unreadable file (default
    ``'<family>' weights file``).

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file: unreadable, another family, another version.
    """
    return check_weights(load_payload(path, what or f"{family!r} weights file"), path, family, version, legacy)


def write_weights(path: PathLike, family: str, version: int, fields: Mapping) -> Path:
    """Write ``{"format": family, "version": version, **fields}`` with ``torch.save``, atomically (parent
    folders made). ``fields`` must not hold ``format`` or ``version``.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.
    """
    import torch  # torch only where a weights file is written: shapeio is NumPy-level

    clash = {"format", "version"} & set(fields)
    if clash:
        raise ValueError(f"fields must not hold {sorted(clash)}: write_weights sets them")
    payload = {"format": family, "version": int(version), **fields}
    buf = io.BytesIO()
    torch.save(payload, buf)
    return Path(atomic_write(path, buf.getvalue(), mkdir=True))


def checkpoint_entry(checkpoint: Mapping, key: str, version: int, what: str) -> dict:
    """The entry ``key`` that a model family's LightningModule adds to its training checkpoints, checked:
    present, and its ``format`` is ``version``.

    Args:
        checkpoint: the checkpoint dict (as ``on_load_checkpoint`` gets it).
        key: the family's entry (``"shapeprog_vae"``).
        version: the entry's format this version writes.
        what: the module that writes it, for the error (``"shapeprog.vae.train.VAEModule"``).

    Raises:
        ValueError: no such entry, or another format.
    """
    info = checkpoint.get(key)
    if info is None:
        raise ValueError(f"not a checkpoint of {what} (no {key!r} entry)")
    if info.get("format") != version:
        raise ValueError(f"the checkpoint has format {info.get('format')!r}; this version reads {version}")
    return info
