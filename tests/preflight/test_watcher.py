"""The FC watcher over MSP, against a stand-in MSP port (scaffolding: answers as the test
says): the sticks and modes of each reply, waits woken by the replies, a snapshot only after
the change was asked for, the armed FC heard at once, and a lost link as one error naming
the port."""

from __future__ import annotations

import struct
import time

import pytest

from tests.fc.stand_in import msp_stand_in
from tests.fc.test_msp import status_ex
from wftool.errors import PortError
from wftool.fc.modes import MODE_ARM, MODE_FAILSAFE, MODE_MSP_OVERRIDE
from wftool.fc.msp import Cmd, MspClient
from wftool.preflight.watcher import FcWatcher, Snapshot

MODES = bytes([MODE_ARM, 1, MODE_MSP_OVERRIDE, MODE_FAILSAFE])
"""The stand-in's MSP_BOXIDS: ARM is bit 0, MSP OVERRIDE bit 2, FAILSAFE bit 3."""


class StandInFc:
    """What the stand-in reports: its sticks and active-mode bits, as a test sets them."""

    def __init__(self) -> None:
        self.rc = [1500, 1500, 1500, 1000, 1000, 1000, 1000, 1000]
        self.boxes = 0
        self.arming = 1 << 2

    def reply(self, cmd: int) -> bytes:
        if cmd == Cmd.BOXIDS:
            return MODES
        if cmd == Cmd.RC:
            return struct.pack(f"<{len(self.rc)}H", *self.rc)
        if cmd == Cmd.STATUS_EX:
            return status_ex(self.boxes, self.arming)
        return b""


def test_a_reply_asked_before_is_no_news() -> None:
    """A wait from `since` takes only replies asked for from then on: one already on its way
    shows the FC before the change."""
    fc = StandInFc()
    with msp_stand_in(fc.reply) as url, MspClient.open(url) as msp, FcWatcher(msp) as watcher:
        watcher.latest()
        since = time.monotonic()
        seen = watcher.wait(lambda s: True, since, 5.0)
        assert seen is not None and seen.asked >= since
        assert all(s.asked >= since for s in watcher.since(since))


def test_snapshots_show_the_sticks_and_modes_as_asked() -> None:
    fc = StandInFc()
    with msp_stand_in(fc.reply) as url, MspClient.open(url) as msp, FcWatcher(msp) as watcher:
        first = watcher.latest()
        assert first.sticks == (1500, 1500, 1500, 1000) and first.rx_loss and not first.armed
        assert watcher.has_override
        fc.rc[0], fc.boxes, fc.arming = 1800, 1 << 2 | 1 << 3, 0
        changed = time.monotonic()
        seen = watcher.wait(lambda s: s.override and s.failsafe and s.rc[0] == 1800, changed, 5.0)
        assert seen is not None and not seen.rx_loss and seen.can_arm and not seen.armed
        assert seen.asked >= first.t  # asked for after the change


def test_the_armed_fc_is_heard_from_the_reading_thread() -> None:
    fc = StandInFc()
    heard: list[Snapshot] = []
    with (
        msp_stand_in(fc.reply) as url,
        MspClient.open(url) as msp,
        FcWatcher(msp, heard.append) as watcher,
    ):
        watcher.latest()
        assert heard == []
        fc.boxes = 1
        assert watcher.wait(lambda s: s.armed, time.monotonic(), 5.0) is not None
    assert heard and all(s.armed for s in heard)


def test_a_lost_link_is_one_error_naming_the_port() -> None:
    fc = StandInFc()
    with msp_stand_in(fc.reply) as url:
        msp = MspClient.open(url)
        watcher = FcWatcher(msp).start()
        watcher.latest()
    started = time.monotonic()
    with pytest.raises(PortError, match=f"^{url}: the MSP link to the FC was lost mid-run"):
        watcher.wait(lambda s: False, started, 10.0)
    watcher.stop()
    msp.close()
