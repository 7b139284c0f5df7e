"""The FC over MSP while preflight runs: MSP_RC and MSP_STATUS_EX read in turn from a thread,
as fast as the FC answers, every reply kept as a `Snapshot` (the sticks, armed, RXLOSS,
failsafe, MSP OVERRIDE, the modes on) that other threads wait on.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from wftool.errors import PortError, WftoolError
from wftool.fc.modes import MODE_ARM, MODE_FAILSAFE, MODE_MSP_OVERRIDE
from wftool.fc.msp import ArmingDisabled, Cmd, FcStatus, MspClient, parse_rc, parse_status_ex
from wftool.preflight.record import Record

REPLY_TIMEOUT_S = 5.0
"""An FC that answers no MSP request for this long has lost its MSP link."""
STICKS = 4
"""MSP_RC's first channels: roll, pitch, yaw, throttle (rcData, the FC's function order)."""


@dataclass(frozen=True)
class Snapshot:
    """What the FC reported by one MSP reply (and the latest of the other kind before it)."""

    t: float
    """Host `time.monotonic()` when the reply arrived."""
    asked: float
    """Host time the older of its two replies was asked for: what it shows is of some
    instant from then on."""
    rc: tuple[int, ...]
    """MSP_RC: rcData in Betaflight's order (roll, pitch, yaw, throttle, AUX1, ...)."""
    status: FcStatus
    armed: bool
    override: bool
    """The MSP OVERRIDE mode is on."""
    failsafe: bool
    """Failsafe stage 2 (the FAILSAFE mode)."""

    @property
    def sticks(self) -> tuple[int, ...]:
        return self.rc[:STICKS]

    @property
    def rx_loss(self) -> bool:
        """RXLOSS: the receiver has no signal (arming disable flag RX_FAILSAFE)."""
        return ArmingDisabled.RX_FAILSAFE in self.status.arming_disabled

    @property
    def can_arm(self) -> bool:
        """Nothing but the ARM switch itself keeps the FC from arming."""
        return self.status.arming_disabled & ~ArmingDisabled.ARM_SWITCH == 0


class FcWatcher:
    """Reads the FC over MSP from a thread until stopped; `snapshots` is what it read."""

    def __init__(self, msp: MspClient, on_armed: Callable[[Snapshot], None] | None = None):
        """`on_armed` hears every snapshot that shows the FC armed (from the reading thread)."""
        self.url = msp.link.port or "the MSP link"
        self._msp = msp
        self._msp_lock = threading.Lock()
        self.bits = msp.mode_bits()
        """Permanent mode id → its bit in MSP_STATUS_EX, for the modes the FC has."""
        self.snapshots: Record[Snapshot] = Record()
        self._on_armed = on_armed
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="preflight-msp", daemon=True)

    @property
    def has_override(self) -> bool:
        """The FC has the MSP OVERRIDE mode (`msp_override_channels_mask` set)."""
        return MODE_MSP_OVERRIDE in self.bits

    def start(self) -> FcWatcher:
        self._thread.start()
        self.latest()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(REPLY_TIMEOUT_S + 1)

    def __enter__(self) -> FcWatcher:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def request(self, cmd: int, payload: bytes = b"") -> bytes:
        """One MSP exchange, between the watcher's own; a lost link is a `PortError` naming
        the port."""
        with self._msp_lock:
            try:
                return self._msp.request(cmd, payload, timeout=REPLY_TIMEOUT_S)
            except WftoolError as exc:
                raise self._lost(exc) from exc

    def _lost(self, exc: WftoolError) -> PortError:
        return PortError(f"{self.url}: the MSP link to the FC was lost mid-run ({exc})")

    def _run(self) -> None:
        try:
            status_asked = time.monotonic()
            status = parse_status_ex(self.request(Cmd.STATUS_EX))
            while not self._stop.is_set():
                rc_asked = time.monotonic()
                rc = parse_rc(self.request(Cmd.RC))
                self._record(min(rc_asked, status_asked), rc, status)
                status_asked = time.monotonic()
                status = parse_status_ex(self.request(Cmd.STATUS_EX))
                self._record(rc_asked, rc, status)
        except BaseException as exc:  # raised to whoever waits
            self.snapshots.fail(exc)

    def _record(self, asked: float, rc: tuple[int, ...], status: FcStatus) -> None:
        bits = self.bits
        snapshot = Snapshot(
            time.monotonic(), asked, rc, status, status.active(bits.get(MODE_ARM)),
            status.active(bits.get(MODE_MSP_OVERRIDE)), status.active(bits.get(MODE_FAILSAFE)),
        )  # fmt: skip
        self.snapshots.add(snapshot)
        if snapshot.armed and self._on_armed is not None:
            self._on_armed(snapshot)

    def latest(self, timeout: float = REPLY_TIMEOUT_S) -> Snapshot:
        """The newest snapshot (waiting for the first)."""
        first = self.snapshots.wait(lambda s: True, 0, timeout)
        if first is None:
            raise PortError(f"{self.url}: the FC answered no MSP_RC within {timeout:.0f} s")
        latest = self.snapshots.latest()
        assert latest is not None
        return latest

    def since(self, t: float) -> list[Snapshot]:
        """The snapshots asked for from host time `t` on: what the FC showed after `t`."""
        kept = self.snapshots.since(self.snapshots.index_after(t, _arrival))
        return [s for s in kept if s.asked >= t]

    def wait(
        self, predicate: Callable[[Snapshot], bool], since: float, timeout: float
    ) -> Snapshot | None:
        """The first snapshot asked for from host time `since` on (so showing the FC after
        `since`, not a reply already on its way) for which `predicate` holds, waiting up to
        `timeout` seconds from now; None if none came."""
        start = self.snapshots.index_after(since, _arrival)
        return self.snapshots.wait(lambda s: s.asked >= since and predicate(s), start, timeout)


def _arrival(snapshot: Snapshot) -> float:
    return snapshot.t
