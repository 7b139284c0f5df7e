"""What a reader thread saw, in order, for other threads to wait on: `Record` is fed by one
thread and waited on by others through a condition it notifies (no polling); the reader's
failure is raised to every waiter.
"""

from __future__ import annotations

import bisect
import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")

KEEP = 1 << 16
"""Items kept (the oldest go): a minute of replies or frames at 1 kHz."""


class Record(Generic[T]):
    """An append-only list that forgets its oldest items beyond `keep`. Indices are absolute
    (the first item ever added is 0), so an index taken before stays valid."""

    def __init__(self, keep: int = KEEP) -> None:
        self._items: list[T] = []
        self._first = 0
        """The absolute index of `_items[0]`."""
        self._keep = keep
        self._error: BaseException | None = None
        self.changed = threading.Condition()
        """Notified on every item and on failure; hold it to read consistently."""

    def add(self, item: T) -> None:
        with self.changed:
            self._items.append(item)
            if len(self._items) > 2 * self._keep:
                drop = len(self._items) - self._keep
                del self._items[:drop]
                self._first += drop
            self.changed.notify_all()

    def fail(self, error: BaseException) -> None:
        """The reader stopped: every wait (now and later) raises `error`."""
        with self.changed:
            self._error = error
            self.changed.notify_all()

    def check(self) -> None:
        """Raise the reader's failure, if any."""
        if self._error is not None:
            raise self._error

    @property
    def end(self) -> int:
        """The index the next item will have."""
        with self.changed:
            return self._first + len(self._items)

    def latest(self) -> T | None:
        with self.changed:
            return self._items[-1] if self._items else None

    def since(self, index: int) -> list[T]:
        """The items from absolute `index` on (those still kept)."""
        with self.changed:
            return self._items[max(0, index - self._first) :]

    def index_after(self, value: float, key: Callable[[T], float]) -> int:
        """The index of the first kept item whose `key` (ascending with the index) exceeds
        `value`."""
        with self.changed:
            return self._first + bisect.bisect_right(self._items, value, key=key)

    def wait(self, predicate: Callable[[T], bool], start: int, timeout: float) -> T | None:
        """The first item from absolute index `start` on for which `predicate` holds, waiting
        up to `timeout` seconds for it; None if none came. Raises the reader's failure."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                self.check()
                begin = max(0, start - self._first)
                for item in self._items[begin:]:
                    if predicate(item):
                        return item
                start = self._first + max(begin, len(self._items))
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self.changed.wait(left)

    def wait_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Wait until `condition()` (called with the lock held) holds; False if it did not
        within `timeout` seconds. Raises the reader's failure."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                self.check()
                if condition():
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.changed.wait(left)
