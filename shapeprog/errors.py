"""The errors of the ShapeAssembly layer: a text that is not a valid program, an execution that
cannot give finite cuboids, and a point cloud that a point-cloud operation cannot take. Standard
library only.

Example:
    >>> str(ParseError("unknown command 'cubiod'", "chair_12.txt", 2, 9, "cubiod"))
    "chair_12.txt:2:9: unknown command 'cubiod'"
    >>> str(ExecutionError("a corner is not finite", line=4))
    'line 4: a corner is not finite'
    >>> str(PointCloudError("a coordinate is NaN", "clouds", index=3))
    '`clouds`: cloud 3: a coordinate is NaN'
    >>> str(EditError("value 1.5 is outside [0.0, 1.0]", "chair/173.txt", 5, 30, "0.5", control="Program_0:4:attach.y2"))
    "chair/173.txt:5:30: control 'Program_0:4:attach.y2': value 1.5 is outside [0.0, 1.0]"
"""
from __future__ import annotations

__all__ = ["EditError", "ExecutionError", "ParseError", "ParseWarning", "PointCloudError", "RefactorError"]


class ParseError(ValueError):
    """A program text that is not ShapeAssembly (or exceeds one of the language's limits).

    Attributes:
        file: the file name given to :func:`shapeprog.lang.parse` (or ``"<string>"``).
        line: 1-based line number.
        column: 1-based column of the offending token (a TAB counts as one column).
        token: the offending token text ('' at the end of a line).
        reason: the message without the location.
    """

    def __init__(self, reason: str, file: str, line: int, column: int, token: str):
        self.reason, self.file, self.line, self.column, self.token = reason, file, line, column, token
        super().__init__(f"{file}:{line}:{column}: {reason}")

    @classmethod
    def in_file(cls, file: str):
        """``(reason, line, column) -> ParseError`` in ``file`` (no token): the ``error`` argument of
        :func:`shapeio.files.parse_json`."""
        return lambda reason, line, column: cls(reason, file, line, column, "")


class EditError(ParseError):
    """An edit of a program that cannot be made: an unknown control, a value of the wrong type or outside
    the control's range, or an edited program that the language refuses (e.g. beyond a limit).

    It is a :class:`ParseError` located in the printed program at the token the control changes.

    Attributes:
        control: the control's name (None when the edit names no single control).
        value: the value asked for (None when not one value's fault).
    """

    def __init__(self, reason: str, file: str, line: int, column: int, token: str, control: str | None = None,
                 value=None):
        self.control, self.value = control, value
        super().__init__(reason if control is None else f"control {control!r}: {reason}", file, line, column, token)
        self.reason = reason


class ParseWarning(UserWarning):
    """A tolerated irregularity in a program text (e.g. a stray trailing comma)."""


class ExecutionError(ValueError):
    """A program (or parameter vector) whose execution gives a non-finite value.

    Attributes:
        reason: the message without the location.
        line: 1-based file line of the statement that created the first affected cuboid.
        index: position of the program in the executed batch (None for a single program).
        file: the program's file name when the caller knows it (None otherwise).
    """

    def __init__(self, reason: str, line: int, index: int | None = None, file: str | None = None):
        self.reason, self.line, self.index, self.file = reason, line, index, file
        where = f"line {line}" if index is None else f"program {index}, line {line}"
        if file is not None:
            where = f"{file}:{line}"
        super().__init__(f"{where}: {reason}")


class PointCloudError(ValueError):
    """A point cloud (or the indices or features that go with it) that a point-cloud operation cannot
    take: a wrong shape or dtype, a coordinate that is not finite, fewer points than asked for.

    Attributes:
        reason: the message without the location.
        name: the argument at fault (None when the message is about several).
        index: position of the offending cloud in the batch (None when not one cloud's fault).
    """

    def __init__(self, reason: str, name: str | None = None, index: int | None = None):
        self.reason, self.name, self.index = reason, name, index
        where = "" if name is None else f"`{name}`: "
        if index is not None:
            where += f"cloud {index}: "
        super().__init__(where + reason)


class RefactorError(ValueError):
    """A ShapeCoder program the e-graph refactor cannot take (not a closed, well-typed Shape expression),
    an e-graph limit out of range, or a failure inside the e-graph engine. The message names the program
    (shortened)."""
