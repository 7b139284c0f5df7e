"""`Record`: what one thread adds, others wait on — woken by the add, not by a clock — with
absolute indices that survive forgetting, and the reader's failure raised to every waiter."""

from __future__ import annotations

import threading

import pytest

from wftool.errors import PortError
from wftool.preflight.record import Record


def test_a_waiter_is_woken_by_the_item_it_waits_for() -> None:
    record: Record[int] = Record()

    def add() -> None:
        with record.changed:  # held until this thread's wait releases it: the adds come later
            pass
        for value in range(5):
            record.add(value)

    with record.changed:
        thread = threading.Thread(target=add)
        thread.start()
        assert record.wait(lambda v: v == 3, 0, 10.0) == 3
    thread.join()


def test_a_wait_ends_at_its_timeout_with_none() -> None:
    record: Record[int] = Record()
    record.add(1)
    assert record.wait(lambda v: v > 1, 0, 0.05) is None
    assert record.wait(lambda v: v == 1, 1, 0.05) is None  # from index 1: the 1 is before it


def test_indices_stay_absolute_when_the_oldest_go() -> None:
    record: Record[int] = Record(keep=4)
    for value in range(20):
        record.add(value)
    assert record.end == 20
    kept = record.since(0)
    assert kept[-1] == 19 and len(kept) <= 8 and kept == list(range(20 - len(kept), 20))
    assert record.since(18) == [18, 19]
    assert record.index_after(17.5, float) == 18
    assert record.wait(lambda v: True, 19, 0.0) == 19


def test_the_readers_failure_reaches_every_waiter() -> None:
    record: Record[int] = Record()
    failure = PortError("socket://x: the link was lost")
    errors: list[BaseException] = []

    def wait() -> None:
        try:
            record.wait(lambda v: False, 0, 10.0)
        except PortError as exc:
            errors.append(exc)

    threads = [threading.Thread(target=wait) for _ in range(3)]
    for thread in threads:
        thread.start()
    record.fail(failure)
    for thread in threads:
        thread.join(10.0)
    assert errors == [failure] * 3
    with pytest.raises(PortError):
        record.wait_until(lambda: True, 1.0)
