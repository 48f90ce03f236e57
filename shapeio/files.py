"""Atomic writes, the guard that keeps outputs off inputs, and the error for unreadable user files."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import BinaryIO, Callable, Iterable, Union

__all__ = ["InputError", "atomic_write", "refuse_overwrite"]

PathLike = Union[str, os.PathLike]


class InputError(ValueError):
    """A user's file that cannot be read as asked; the message starts with the file's path."""


def atomic_write(path: PathLike, data: Union[bytes, str, Callable[[BinaryIO], object]],
                 mkdir: bool = False) -> Path:
    """Write a file so that a reader never sees it half-written.

    The content goes to a temporary file in the target's directory, is flushed to disk, then
    ``os.replace``-d onto ``path``; on any error the temporary file is removed and ``path`` is untouched.

    Args:
        path: the target file.
        data: bytes, text (written as UTF-8, ``\\n`` line ends kept), or a function that writes to the
            open binary file.
        mkdir: create the target's directory first.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if mkdir:
        folder.mkdir(parents=True, exist_ok=True)
    elif not folder.is_dir():
        raise FileNotFoundError(f"{path}: directory {str(folder)!r} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            if callable(data):
                data(f)
            else:
                f.write(data.encode("utf-8") if isinstance(data, str) else data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


def refuse_overwrite(outputs: Iterable[PathLike | None], inputs: Iterable[PathLike | None]) -> None:
    """Refuse a command whose output files include one of its input files.

    Paths are compared after resolving (``./a.png`` and ``a.png`` are the same file); ``None`` entries
    (options not given) are skipped.

    Args:
        outputs: the files a command is about to write.
        inputs: the files it reads.

    Raises:
        FileExistsError: naming the first output that is also an input.
    """
    protected = {Path(p).resolve() for p in inputs if p is not None}
    for out in outputs:
        if out is not None and Path(out).resolve() in protected:
            raise FileExistsError(f"{out}: this output would overwrite an input file; choose another name or folder")
