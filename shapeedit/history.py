"""The undo / redo history the program editors share: a line of immutable states with a cursor
(:class:`History`) and the session moves over it (:class:`UndoableSession`). Standard library only.

Example:
    >>> h = History("a")
    >>> h.push("b"); h.push("c")
    >>> h.undo(), h.undo(), h.can_undo
    ('b', 'a', False)
    >>> h.redo(), h.current
    ('b', 'b')
    >>> h.push("d"); h.can_redo   # a new state drops the redo branch
    False
"""
from __future__ import annotations

from typing import Generic, TypeVar

__all__ = ["History", "MAX_HISTORY", "UndoableSession"]

T = TypeVar("T")


#: States kept; the oldest are dropped beyond it (a slider drag pushes one state per move).
MAX_HISTORY = 2000


class History(Generic[T]):
    """A line of states with a cursor: :meth:`push` adds a state after the cursor (dropping the states
    that :meth:`redo` could have brought back), :meth:`undo` and :meth:`redo` move the cursor.

    Invariants: ``current`` is always a pushed state (or the initial one); ``undo`` then ``redo`` returns
    to the same state; at most ``limit`` states are kept.

    Args:
        initial: the first state.
        limit: states kept (at least 1).
    """

    def __init__(self, initial: T, limit: int = MAX_HISTORY):
        if isinstance(limit, bool) or not isinstance(limit, int) or limit < 1:
            raise ValueError(f"`limit` must be an int >= 1, got {limit!r}")
        self._states: list[T] = [initial]
        self._i = 0
        self.limit = limit

    @property
    def current(self) -> T:
        return self._states[self._i]

    @property
    def initial(self) -> T:
        """The oldest state kept (the first one unless ``limit`` dropped it)."""
        return self._states[0]

    @property
    def can_undo(self) -> bool:
        return self._i > 0

    @property
    def can_redo(self) -> bool:
        return self._i < len(self._states) - 1

    def __len__(self) -> int:
        return len(self._states)

    def push(self, state: T) -> None:
        """Make ``state`` the current state; the redo branch is dropped."""
        del self._states[self._i + 1:]
        self._states.append(state)
        if len(self._states) > self.limit:
            del self._states[: len(self._states) - self.limit]
        self._i = len(self._states) - 1

    def undo(self) -> T:
        """Step back; returns the new current state. IndexError when there is nothing to undo."""
        if not self.can_undo:
            raise IndexError("nothing to undo")
        self._i -= 1
        return self.current

    def redo(self) -> T:
        """Step forward again; returns the new current state. IndexError when there is nothing to redo."""
        if not self.can_redo:
            raise IndexError("nothing to redo")
        self._i += 1
        return self.current


class UndoableSession:
    """Undo / redo / reset of an edit session over a :class:`History` of states.

    A subclass keeps ``self.history`` (None while nothing valid was loaded) and ``self.error``, and defines
    ``_sync()``, which sets its attributes from ``self.history.current``. Each move returns False when it
    cannot be made; a move that is made clears ``error`` (the last operation succeeded).
    """

    history: "History | None"
    error: "Exception | None"

    def _sync(self) -> None:  # pragma: no cover - every subclass defines it
        raise NotImplementedError

    def _record(self, state) -> None:
        """Make ``state`` current: the first state of a new history, or pushed onto the existing one."""
        if self.history is None:
            self.history = History(state)
        else:
            self.history.push(state)
        self._sync()

    def _moved(self) -> bool:
        self._sync()
        self.error = None
        return True

    def undo(self) -> bool:
        """Step back (False when there is nothing to undo)."""
        if self.history is None or not self.history.can_undo:
            return False
        self.history.undo()
        return self._moved()

    def redo(self) -> bool:
        """Step forward again (False when there is nothing to redo)."""
        if self.history is None or not self.history.can_redo:
            return False
        self.history.redo()
        return self._moved()

    def reset(self) -> bool:
        """Back to the first state (an undoable step). False when already there."""
        if self.history is None or self.history.current is self.history.initial:
            return False
        self.history.push(self.history.initial)
        return self._moved()
