"""Atomic writes, the guard that keeps outputs off inputs, the error for unreadable user files, and the one
rule for an argument that is a shipped name or a file (:func:`resolve_shipped`: an existing file wins).

The permissions and temporary-file names of :func:`atomic_write` are described in ``docs/shapeio.md``.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import json
import os
import re
import stat
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import BinaryIO, Callable, Iterable, Mapping, Union

__all__ = ["InputError", "MAX_JSON_DEPTH", "NotShippedError", "resolve_shipped", "atomic_write", "c_output_silenced", "existing_outputs", "output_problem", "parse_json", "refuse_overwrite",
           "remove_stale_temps", "write_new",
           "write_new_set", "STALE_TEMP_SECONDS"]

PathLike = Union[str, os.PathLike]

STALE_TEMP_SECONDS = 24 * 3600
"""A temporary file of :func:`atomic_write` older than this is stale even if its writer's process id is
in use again."""
_TEMP_RE = re.compile(r"\.(?P<name>.+)\.atomic-(?P<pid>\d+)-[^.]+\.tmp")
_UMASK_LOCK = threading.Lock()


class InputError(ValueError):
    """A user's file that cannot be read as asked; the message starts with the file's path."""


class NotShippedError(FileNotFoundError, ValueError):
    """An argument that is neither an existing file nor a shipped name (:func:`resolve_shipped`); caught as
    either a missing file or a bad value."""


MAX_JSON_DEPTH = 64
"""The deepest nesting of arrays and objects :func:`parse_json` reads (the project's own JSON files nest a few
levels)."""


def _outside_strings(text: str):
    """``(offset, char)`` of each character of JSON ``text`` that is not inside a string literal."""
    in_str = esc = False
    for i, ch in enumerate(text):
        if in_str:
            if esc:
                esc = False
            elif ch == "\\":
                esc = True
            elif ch == '"':
                in_str = False
        elif ch == '"':
            in_str = True
        else:
            yield i, ch


def _too_deep(text: str, limit: int) -> int | None:
    """The offset of the first ``[`` / ``{`` (outside strings) that opens level ``limit + 1``, or None."""
    depth = 0
    for i, ch in _outside_strings(text):
        if ch in "[{":
            depth += 1
            if depth > limit:
                return i
        elif ch in "]}":
            depth -= 1
    return None


def _token_at(text: str, pattern: str) -> int:
    """The offset of the first match of ``pattern`` that starts outside strings (0 when none does)."""
    outside = {i for i, _ in _outside_strings(text)}
    for m in re.finditer(pattern, text):
        if m.start() in outside:
            return m.start()
    return 0


def parse_json(text: str, file: str, error: Callable[[str, int, int], Exception] | None = None):
    """``text`` as JSON, strictly: no ``NaN`` / ``Infinity``, at most :data:`MAX_JSON_DEPTH` levels of nesting.

    ``error(reason, line, column)`` makes the exception raised for bad text (default an :class:`InputError`
    ``"<file>:<line>:<column>: <reason>"``), so that each format raises its own error type.

    Raises:
        what ``error`` makes: not JSON, too deep, a non-finite constant or a float out of range, an integer too
        long to convert.
    """
    def fail(reason: str, line: int = 1, column: int = 1) -> Exception:
        if error is not None:
            return error(reason, line, column)
        return InputError(f"{file}:{line}:{column}: {reason}")

    def line_col(offset: int) -> tuple[int, int]:
        return text.count("\n", 0, offset) + 1, offset - (text.rfind("\n", 0, offset) + 1) + 1

    where = _too_deep(text, MAX_JSON_DEPTH)
    if where is not None:
        raise fail(f"nested more than {MAX_JSON_DEPTH} levels deep (MAX_JSON_DEPTH)", *line_col(where))

    bad: list[str] = []  # the regular expression of the token that failed, to locate it

    def constant(name: str):
        bad.append(r"-?" + name if name != "-Infinity" else r"-Infinity")
        raise ValueError(f"{name} is not a JSON number")

    def finite(token: str) -> float:
        value = float(token)
        if value in (float("inf"), float("-inf")):
            bad.append(re.escape(token) + r"(?![0-9.eE+-])")
            raise ValueError(f"{token} is out of the range of a float")
        return value

    try:
        return json.loads(text, parse_constant=constant, parse_float=finite)
    except json.JSONDecodeError as e:
        raise fail(f"not JSON: {e.msg}", e.lineno, e.colno) from None
    except (ValueError, RecursionError) as e:  # a non-finite constant or float, an integer of too many digits
        pattern = bad[0] if bad else r"[0-9]{%d,}" % (sys.get_int_max_str_digits() + 1)
        raise fail(f"not JSON: {e}", *line_col(_token_at(text, pattern))) from None


def _umask() -> int:
    """The process's umask, read without changing it where the system allows (Linux ``/proc``)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _UMASK_LOCK:  # elsewhere the only way to read it is to set it and put it back
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # a process of another user, or a system that cannot say: keep its file
    return True


_CLEANED: set[str] = set()  # folders already cleaned of stale temporary files by this process


def remove_stale_temps(folder: PathLike, name: str | None = None) -> list[Path]:
    """Remove the temporary files that killed :func:`atomic_write` calls left in ``folder``.

    A temporary file is named ``.<target>.atomic-<pid>-<random>.tmp``; it is stale when the process
    ``<pid>`` no longer exists or when it is older than :data:`STALE_TEMP_SECONDS`. Files being written
    by a live process are kept. :func:`atomic_write` calls this at its first write into a folder.

    Args:
        folder: the folder to clean.
        name: only the temporary files of this target file name (default: every target).

    Returns:
        The files removed.
    """
    pattern = f".{glob.escape(name)}.atomic-*.tmp" if name is not None else ".*.atomic-*.tmp"
    removed = []
    now = time.time()
    for tmp in glob.glob(os.path.join(glob.escape(str(folder)), pattern)):
        m = _TEMP_RE.fullmatch(os.path.basename(tmp))
        if m is None:
            continue
        try:
            old = now - os.stat(tmp).st_mtime > STALE_TEMP_SECONDS
            if old or not _alive(int(m.group("pid"))):
                os.unlink(tmp)
                removed.append(Path(tmp))
        except FileNotFoundError:  # removed by another cleanup meanwhile
            pass
    return removed


def _write_synced(f: BinaryIO, data) -> None:
    """Write ``data`` (bytes, a str as UTF-8, or a function given the open file) to ``f``, flushed and synced."""
    if callable(data):
        data(f)
    else:
        f.write(data.encode("utf-8") if isinstance(data, str) else data)
    f.flush()
    os.fsync(f.fileno())


def atomic_write(path: PathLike, data: Union[bytes, str, Callable[[BinaryIO], object]],
                 mkdir: bool = False) -> Path:
    """Write a file so that a reader never sees it half-written.

    The content goes to a temporary file ``.<name>.atomic-<pid>-<random>.tmp`` in the target's
    directory, is flushed to disk, then ``os.replace``-d onto ``path``; on any error the temporary file
    is removed and ``path`` is untouched. The file gets the usual permissions: those of the file it
    replaces, else ``0o666`` less the umask. The first write into a folder in a process removes the
    temporary files that killed writes left there (:func:`remove_stale_temps`), so a folder is listed
    once per process, not once per write.

    Args:
        path: the target file.
        data: bytes, text (written as UTF-8, ``\\n`` line ends kept), or a function that writes to the
            open binary file.
        mkdir: create the target's directory first.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        FileNotFoundError: the target's directory does not exist (and ``mkdir`` is false).
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if mkdir:
        folder.mkdir(parents=True, exist_ok=True)
    elif not folder.is_dir():
        raise FileNotFoundError(f"{path}: directory {str(folder)!r} does not exist")
    key = os.path.realpath(folder)
    if key not in _CLEANED:
        remove_stale_temps(folder)
        _CLEANED.add(key)
    try:
        mode = stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        mode = 0o666 & ~_umask()
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.atomic-{os.getpid()}-", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), mode)
            _write_synced(f, data)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


def write_new(path: PathLike, data: Union[bytes, str, Callable[[BinaryIO], object]]) -> Path:
    """Write a file that must not exist yet, atomically: it never replaces a file.

    The content is written and flushed as by :func:`atomic_write` to a temporary file beside ``path``,
    which is then hard-linked to ``path`` (the link fails if ``path`` exists, so a file made meanwhile
    by someone else is never replaced) and removed. On a file system without hard links the file is
    created with ``O_EXCL`` instead (still never replacing, but readable while being written).

    Args:
        path: the new file.
        data: bytes, text (UTF-8) or a function that writes to the open binary file.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        FileExistsError: ``path`` exists.
        FileNotFoundError: its directory does not exist.
    """
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise FileNotFoundError(f"{path}: directory {str(folder)!r} does not exist")
    if os.path.lexists(path):
        raise FileExistsError(f"{path}: the file exists; it is not replaced")

    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.atomic-{os.getpid()}-", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            os.fchmod(f.fileno(), 0o666 & ~_umask())
            _write_synced(f, data)
        try:
            os.link(tmp, path)
        except FileExistsError:
            raise FileExistsError(f"{path}: the file exists; it is not replaced") from None
        except OSError:  # no hard links here: an exclusive create
            with open(path, "xb") as f:
                _write_synced(f, data)
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
    return path


def write_new_set(items: Iterable[tuple[PathLike, Union[bytes, str, Callable[[BinaryIO], object]]]]) -> list[Path]:
    """Write several new files as one: each with :func:`write_new`, in order; if one fails (it exists, the
    disk is full), the files this call already wrote are removed again before the error propagates, so no
    partial set is left.

    Returns:
        The paths, in order.
    """
    written: list[Path] = []
    try:
        for path, data in items:
            written.append(write_new(path, data))
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        raise
    return written


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


def existing_outputs(paths: Iterable[PathLike | None], overwrite: bool = False,
                     hint: str | None = None) -> str | None:
    """Why a command must not write ``paths`` (None if it may): one of them exists and ``overwrite`` (the
    command's ``--overwrite``) is not given, so that a second run never silently replaces a first run's files.
    ``hint`` replaces the advice at the end (for outputs that ``--overwrite`` does not replace)."""
    taken = [p for p in paths if p and Path(p).exists()]
    if not taken or overwrite:
        return None
    one = len(taken) == 1
    hint = hint or f"give --overwrite to replace {'it' if one else 'them'}, or choose another output"
    return f"{taken[0]}: exists ({len(taken)} of the outputs {'does' if one else 'do'}); {hint}"


def output_problem(path: PathLike, folder: bool = False, create: bool = True) -> str | None:
    """Why ``path`` cannot be written as an output, checked before a command's work starts; None if it can.

    The problems, each one line naming the real path (never a temporary file): a folder where a file goes
    (or a file where a folder goes), a path component that is a file, a missing folder (only with
    ``create`` false), a folder this process cannot create files in (probed by creating and removing an
    empty temporary file in it, so that permissions, read-only file systems and root alike are judged).

    Args:
        path: the output file, or with ``folder`` the output folder.
        folder: ``path`` is a folder (created with its missing parents by the command).
        create: the command creates a missing folder for a file output as well.
    """
    p = Path(path)
    if folder and os.path.lexists(p) and not p.is_dir():
        return f"{str(p)!r} is a file, not a folder"
    if not folder and p.is_dir():
        return f"{str(p)!r} is a folder, not a file"
    here = p if folder else (p.parent if str(p.parent) else Path("."))
    probe = here
    while not os.path.lexists(probe) and probe.parent != probe:
        probe = probe.parent
    if os.path.lexists(probe) and not probe.is_dir():
        return f"{str(probe)!r} is a file, not a folder"
    if probe != here and not create:
        return f"folder {str(here)!r} does not exist"
    try:
        fd, tmp = tempfile.mkstemp(prefix=".write-probe-", suffix=".tmp", dir=probe)
    except OSError as e:
        return f"cannot write in folder {str(probe)!r} ({e.strerror or e})"
    os.close(fd)
    os.unlink(tmp)
    return None


@contextlib.contextmanager
def c_output_silenced():
    """Send what C code writes to the process's stdout and stderr (file descriptors 1 and 2) to the null device
    for the duration, e.g. a compiled library's build banner; Python's own streams are flushed first and C's
    stdio buffers before the descriptors are restored, so nothing written inside comes out later."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (AttributeError, ValueError, OSError):
            pass
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no such descriptors (an embedded interpreter): nothing to silence
        yield
        return
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        yield
    finally:
        try:
            ctypes.CDLL(None).fflush(None)  # C stdio buffers go to the null device, not to the restored stdout
        except (OSError, AttributeError):
            pass
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved + [null]:
            os.close(fd)


def resolve_shipped(name: Union[str, PathLike], shipped: Mapping[str, PathLike], what: str) -> Path:
    """The file an argument names, by the one rule for "a shipped name or a file": ``name`` itself when a
    file of that path exists (an existing file wins), else the shipped file of that name.

    Args:
        name: a path or a shipped name (``"chair"``).
        shipped: shipped name -> its file.
        what: what is looked for, for the error (``"ShapeMOD library"``).

    Raises:
        NotShippedError: neither a file nor a shipped name (a ``FileNotFoundError`` and a ``ValueError``);
            the message names both readings and the shipped names.
    """
    path = Path(name)
    if path.is_file():
        return path
    if str(name) in shipped:
        return Path(shipped[str(name)])
    names = ", ".join(sorted(shipped)) or "none"
    raise NotShippedError(f"{name}: neither a {what} file nor a shipped {what} (shipped: {names})")
