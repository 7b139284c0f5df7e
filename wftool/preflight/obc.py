"""wftool as the OBC on the FSP port: commands at a steady rate, and the ways an OBC fails —
silent, killed, stuck, garbling, replaying, restarted, twinned, its clock stepped back, a
value out of range, a timed command too late. The stream is read alongside, each thing by
the FC clock: the frames' sticks, the uplink statuses (E3), the time replies (E2) and the
command reports (E4). Everything on the port happens in one thread; callers wait on what it
records.
"""

from __future__ import annotations

import concurrent.futures
import os
import random
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, TypeVar

from wftool.errors import PortError, WftoolError
from wftool.fsp.decoder import StateDecoder
from wftool.fsp.encoder import (
    CommandSender,
    checked_rc,
    encode_arming_request,
    encode_command,
)
from wftool.fsp.packets import (
    ArmingAction,
    ArmingRequest,
    CommandPacket,
    CommandReport,
    UplinkStatus,
)
from wftool.fsp.reader import DEFAULT_BAUDRATE
from wftool.fsp.twoway import RoundTrip
from wftool.link.transport import Port, open_port, port_errors, read_within, selectable_fd
from wftool.preflight.record import Record

R = TypeVar("R")
COMMAND_RATE_HZ = 100.0
"""How often the OBC commands: several commands per timeout (spec §11)."""
STALL_FRACTION = 0.8
"""A stall of the OBC's own thread: this much of the FC's command timeout without a fresh
command while it meant to send them — the FC may have counted it gone (`Obc.stall_s`)."""
STALL_S = STALL_FRACTION * 0.05
REPLY_WAIT_S = 0.02
"""How long a killed OBC waits for the FC's answer to its last command before its port
closes (the FC answers within a task period or two when `fsp_time_reply` is ON)."""
ACTION_WAIT_S = 5.0
"""How long a caller waits for the OBC's thread to do what it asked."""
BEHAVIOURS = ("fresh", "stopped", "stuck", "garbage", "replay")
"""What the OBC does from tick to tick: fresh commands, nothing, the last packet again,
random bytes, or older packets again."""
README_COMMAND = (1500, 1500, 1500, 1000, 1000, 1000)
"""The README's example command, which a program restarting with defaults sends too."""


@dataclass(frozen=True)
class Sent:
    """A command the OBC wrote."""

    stamp: float
    """The OBC time it carries (`tx_time_us`, s): its sender's clock, stepped or not."""
    written: float
    """Host `time.monotonic()` right after the write."""
    packet: CommandPacket
    wire: bytes


@dataclass(frozen=True)
class FrameSeen:
    """A state frame's sample time (FC µs, unwrapped) and what it carries of the RC."""

    fc_us: int
    rc: tuple[int, ...]
    """roll, pitch, yaw, throttle, aux3, aux4 (rcData)."""

    @property
    def sticks(self) -> tuple[int, ...]:
        return self.rc[:4]


class Obc:
    """Plays the OBC on `url` from a thread: `behave` sets what it does each tick."""

    def __init__(
        self,
        url: str,
        baudrate: int = DEFAULT_BAUDRATE,
        rate_hz: float = COMMAND_RATE_HZ,
        *,
        closing: Callable[[Callable[[], None]], object] | None = None,
        guard: Callable[[], None] | None = None,
    ) -> None:
        """`closing(close)` closes the port when the OBC is killed (default: `close()`); the
        virtual FC's waits until SITL has let go of the connection (`VirtualFC.close_client`),
        so the new one is not dropped. `guard()` is called before every write and raises when
        the OBC must not send (the FC was armed without `--arm`)."""
        self.url = url
        self.baudrate = baudrate
        self._period = 1.0 / rate_hz
        self._closing = closing
        self._guard = guard
        self.decoder = StateDecoder(time_replies=True)
        matcher = self.decoder.round_trips
        assert matcher is not None
        matcher.on_round_trip = self._answered
        self._clock_offset = 0.0
        self.sender = self._new_sender()
        self.frames: Record[FrameSeen] = Record()
        self.statuses: Record[UplinkStatus] = Record(4096)
        self.trips: Record[RoundTrip] = Record(4096)
        self.reports: Record[CommandReport] = Record(4096)
        self.last_fresh: Sent | None = None
        """The last fresh command written."""
        self.stall_s = STALL_S
        """A gap between two fresh commands longer than this is a stall of this program."""
        self.stalls: Record[float] = Record(4096)
        """The stalls, each the gap (s) between two fresh commands in a row as they were
        written, or as the FC took them (their time replies, FC clock): this program, its host
        or the link was late, and what the FC did meanwhile is no evidence about the FC."""
        self._steady = False
        self._taken_us: int | None = None
        """FC time the latest fresh command of the steady run was taken."""
        self._counted_from = 0.0
        """The OBC time (a command's stamp) from which the FC's taking counts for stalls:
        replies to commands sent before a new link (a restart, a clock step, a pause) do not."""
        self._fresh: deque[Sent] = deque(maxlen=50)
        self._port: Port | None = None
        self._fd: int | None = None
        self._lock = threading.Lock()
        self._mode = "stopped"
        self._rc: tuple[int, ...] = README_COMMAND
        self._twin: tuple[CommandSender, tuple[int, ...]] | None = None
        self._actions: list[tuple[Callable[[], Any], concurrent.futures.Future[Any]]] = []
        self._random = random.Random(os.urandom(8))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="preflight-obc", daemon=True)

    # -- the caller's side -------------------------------------------------------------------

    def start(self) -> Obc:
        self._open()
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(ACTION_WAIT_S)
        self._close()

    def __enter__(self) -> Obc:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def clock(self) -> float:
        """The OBC's clock: the host's monotonic clock, stepped by `step_clock`."""
        return time.monotonic() + self._clock_offset

    @property
    def status(self) -> UplinkStatus | None:
        """The FC's newest uplink status (E3)."""
        return self.statuses.latest()

    def behave(self, mode: str, rc: Sequence[int] | None = None) -> Sent | None:
        """Send fresh commands carrying `rc` ("fresh"), or fail as `mode` says, from the next
        tick on; the last fresh command written before (None: none yet)."""
        if mode not in BEHAVIOURS:
            raise ValueError(f"no OBC behaviour {mode!r} (one of {', '.join(BEHAVIOURS)})")

        def change() -> Sent | None:
            self._mode = mode
            if rc is not None:
                self._rc = tuple(rc)
            return self.last_fresh

        return self._do(change)

    def kill(self) -> Sent | None:
        """The OBC program is killed: it stops sending, its port closes (once the FC answered
        the last command, if it answers), and a new connection reads on, silent (another
        program, say); the last fresh command written."""

        def killed() -> Sent | None:
            self._mode = "stopped"
            last = self.last_fresh
            if last is not None:
                deadline = time.monotonic() + REPLY_WAIT_S
                while self._taken(last) is None and time.monotonic() < deadline:
                    self._read(deadline - time.monotonic())
            if self._closing is None:
                self._close()
            else:
                self._closing(self._close)
            self._open()
            return last

        return self._do(killed)

    def restart(self, rc: Sequence[int] = README_COMMAND) -> Sent | None:
        """The OBC program restarts: a new sender (a new numbering) sends fresh commands
        carrying `rc`; the old one's last fresh command."""

        def restarted() -> Sent | None:
            last = self.last_fresh
            self._new_link()  # the new program's link
            self.sender = self._new_sender()
            self._mode, self._rc = "fresh", tuple(rc)
            return last

        return self._do(restarted)

    def twin(self, rc: Sequence[int] | None) -> None:
        """A second OBC program on the port sends fresh commands carrying `rc` each tick
        besides this one's (None: it stops), numbered just ahead of this one's (a program
        started a moment before: where the FC tells no senders apart, its commands win)."""

        def twinned() -> None:
            self._twin = None
            if rc is not None:
                other = self._new_sender()
                other.seq = self.sender.seq + 1
                self._twin = (other, tuple(rc))

        self._do(twinned)

    def step_clock(self, seconds: float, rc: Sequence[int] | None = None) -> Sent | None:
        """The OBC's clock steps by `seconds` (back: negative) from the next command on,
        which carries `rc` (default: as before); the last fresh command stamped before."""

        def stepped() -> Sent | None:
            self._clock_offset += seconds
            self._new_link()  # a new link (spec §11)
            if rc is not None:
                self._rc = tuple(rc)
            return self.last_fresh

        return self._do(stepped)

    def send_once(
        self, rc: Sequence[int], *, at_us: int | None = None, unchecked: bool = False
    ) -> Sent:
        """One command now, numbered with the others (the ticks go on as they were); with
        `at_us` a timed one (E4); `unchecked`: `rc` as given, even values the FC must refuse
        (the sender itself refuses them: `ValueError`, nothing sent)."""
        if not unchecked:
            checked_rc(rc, self.sender.fc_pulse_range)

        def once() -> Sent:
            stamp = self.clock()
            if unchecked:
                packet = self.sender.next(README_COMMAND, stamp, at_us=at_us)
                packet = replace(packet, rc=tuple(rc))  # type: ignore[arg-type]
            else:
                packet = self.sender.next(rc, stamp, at_us=at_us)
            return self._send(packet, stamp)

        return self._do(once)

    def request_arming(self, action: ArmingAction) -> ArmingRequest:
        """An arming request (E5, spec §14) now, numbered with the commands."""

        def once() -> ArmingRequest:
            packet = self.sender.arming_request(action, self.clock())
            self._write(encode_arming_request(packet))
            return packet

        return self._do(once)

    def taken_us(self, sent: Sent | None, timeout: float = 1.0) -> int | None:
        """FC time (µs, the stream's) the FC took `sent`, by its time reply (E2); None if it
        did not answer (`fsp_time_reply` OFF, or it was not fresh)."""
        if sent is None:
            return None
        trip = self.trips.wait(lambda t: t.obc_sent == sent.stamp, 0, timeout)
        return None if trip is None else trip.fc_received_us

    def frame_after(
        self, fc_us: int, predicate: Callable[[FrameSeen], bool], timeout: float
    ) -> FrameSeen | None:
        """The first frame sampled after FC time `fc_us` for which `predicate` holds."""
        start = self.frames.index_after(fc_us, _sample_time)
        return self.frames.wait(lambda f: f.fc_us > fc_us and predicate(f), start, timeout)

    def status_after(
        self, fc_us: int, predicate: Callable[[UplinkStatus], bool], timeout: float
    ) -> UplinkStatus | None:
        """The first uplink status written after FC time `fc_us` for which `predicate` holds."""
        return self.statuses.wait(
            lambda s: s.sent_us is not None and s.sent_us > fc_us and predicate(s), 0, timeout
        )

    def next_status(
        self, predicate: Callable[[UplinkStatus], bool], timeout: float
    ) -> UplinkStatus | None:
        """The first uplink status read from now on for which `predicate` holds."""
        return self.statuses.wait(predicate, self.statuses.end, timeout)

    # -- the thread's side -------------------------------------------------------------------

    def _new_sender(self) -> CommandSender:
        """A new program's sender: a new identity (spec §11), the FC's pulse range known."""
        sender = CommandSender(self.clock, round_trips=self.decoder.round_trips)
        status = self.decoder.uplink_status
        if status is not None:
            sender.observe(status)
        return sender

    def _do(self, action: Callable[[], R]) -> R:
        future: concurrent.futures.Future[R] = concurrent.futures.Future()
        with self._lock:
            self.frames.check()  # the thread has failed (its reason), so nothing will act: now
            self._actions.append((action, future))
        try:
            return future.result(ACTION_WAIT_S)
        except concurrent.futures.TimeoutError:
            self.frames.check()  # the thread failed: its reason
            raise PortError(f"{self.url}: the OBC's thread did not act within 5 s") from None

    def _open(self) -> None:
        port = open_port(self.url, self.baudrate, timeout=0)
        self._port, self._fd = port, selectable_fd(port)
        self.decoder.resync()

    def _close(self) -> None:
        if self._port is not None:
            self._port.close()
            self._port = None

    def _run(self) -> None:
        next_t = time.monotonic()
        try:
            while not self._stop.is_set():
                with self._lock:
                    actions, self._actions = self._actions, []
                for action, future in actions:
                    try:
                        future.set_result(action())
                    except BaseException as exc:
                        future.set_exception(exc)
                        raise
                now = time.monotonic()
                if now >= next_t:
                    self._tick()
                    next_t = max(next_t + self._period, now)
                self._read(max(0.0, next_t - time.monotonic()))
        except BaseException as exc:
            error = exc
            if not isinstance(exc, WftoolError):
                error = PortError(f"{self.url}: the OBC failed mid-run ({exc!r})")
            elif isinstance(exc, PortError) and not str(exc).startswith(self.url):
                error = PortError(f"{self.url}: the FSP link was lost mid-run ({exc})")
            for record in (self.frames, self.statuses, self.trips, self.reports):
                record.fail(error)
            with self._lock:
                for _, future in self._actions:
                    future.set_exception(error)
                self._actions = []

    def _tick(self) -> None:
        mode = self._mode
        if mode == "fresh":
            stamp = self.clock()
            self._fresh.append(self._send(self.sender.next(self._rc, stamp), stamp))
            last, self.last_fresh = self.last_fresh, self._fresh[-1]
            if self._steady and last is not None:
                gap = self.last_fresh.written - last.written
                if gap > self.stall_s:
                    self.stalls.add(gap)
        elif mode == "stuck" and self._fresh:
            self._write(self._fresh[-1].wire)
        elif mode == "replay" and len(self._fresh) > 1:
            self._write(self._random.choice(list(self._fresh)[:-1]).wire)
        elif mode == "garbage":
            junk = bytearray(self._random.randbytes(30))
            junk[self._random.randrange(8, 30)] = 0  # chunks of any length, most not a command's
            self._write(bytes(junk))
        if self._twin is not None:
            twin, rc = self._twin
            self._write(encode_command(twin.next(rc, self.clock())))
        steady = mode == "fresh"
        if steady and not self._steady:
            self._new_link()
        self._steady = steady

    def _send(self, packet: CommandPacket, stamp: float) -> Sent:
        wire = encode_command(packet)
        self._write(wire)
        return Sent(stamp, time.monotonic(), packet, wire)

    def _write(self, data: bytes) -> None:
        if self._guard is not None:
            self._guard()
        assert self._port is not None
        with port_errors(self.url):
            self._port.write(data)

    def _read(self, timeout: float) -> None:
        assert self._port is not None
        with port_errors(self.url):
            data = read_within(self._port, self._fd, timeout)
        if not data:
            return
        arrival = time.monotonic()
        decoder = self.decoder
        for packet in decoder.feed(data, arrival):
            for frame in packet.frames:
                if frame.time_us is not None:
                    self.frames.add(FrameSeen(frame.time_us, tuple(frame.rc)))
        for status in decoder.take_uplink_statuses():
            self.sender.observe(status)  # the FC's pulse range
            self.statuses.add(status)
        for report in decoder.take_command_reports():
            self.reports.add(report)

    def _answered(self, trip: RoundTrip) -> None:
        self.trips.add(trip)
        if self._steady and trip.obc_sent >= self._counted_from:
            if self._taken_us is not None:
                gap = (trip.fc_received_us - self._taken_us) / 1e6
                if gap > self.stall_s:
                    self.stalls.add(gap)
            self._taken_us = trip.fc_received_us

    def _new_link(self) -> None:
        """The FC's taking of commands from now on is a new run of them (no stall across)."""
        self._taken_us = None
        self._counted_from = self.clock()

    def _taken(self, sent: Sent) -> int | None:
        with self.trips.changed:
            trips = self.trips.since(0)
        return next((t.fc_received_us for t in trips if t.obc_sent == sent.stamp), None)


def _sample_time(frame: FrameSeen) -> float:
    return frame.fc_us
