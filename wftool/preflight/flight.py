"""One preflight run's parts — the FC over MSP, the OBC on the FSP port, the pilot, the board's
settings, the report — and the moves every scenario makes with them: put the OBC in control
as the board lets it (the pilot engaging it, or the OBC alone), and time what the sticks,
RXLOSS and arming do, by the FC clock where the FC gives one.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from wftool.fc.fsp_setup import OBC_AUX
from wftool.fc.modes import MODE_ARM
from wftool.fsp.packets import ArmingAction, Authority, UplinkFlag, UplinkStatus
from wftool.preflight.obc import FrameSeen, Obc, Sent
from wftool.preflight.pilot import Pilot
from wftool.preflight.report import Line, Report
from wftool.preflight.settings import BoardSettings
from wftool.preflight.watcher import STICKS, FcWatcher, Snapshot
from wftool.progress import Log, quiet

LIMIT_MS = 100.0
"""The pilot's sticks back, or RXLOSS, within this long after the OBC's last fresh command."""
WAIT_S = 5.0
"""How long preflight waits for what it asked of the FC before it says "never" (timings are
judged against their limits, not this)."""
HOLD_S = 0.5
"""How long the FC must stay safe while a failure goes on."""
PROOF_WAIT_S = 3.0
"""How long a live OBC may take to become ready for the pilot (its proof of life, spec §15,
is 500 ms; the virtual FC on a busy host runs slow)."""
LINK_UP_S = 10.0
"""An OBC-alone FC needs `failsafe_recovery_delay` of commands before RXLOSS clears (a wait,
not a limit)."""
STEADY_S = 0.3
"""How long the OBC steers before a scenario makes it fail: the FC in a steady state."""
MSP_STALL_S = 0.02
"""An MSP reply that took longer than this (the FC answers within a serial task period or
two) says the host, or the virtual FC, stalled: host-clock timings around it are void."""
TOLERANCE_US = 10
"""A stick within this of the pilot's value is the pilot's (a real radio's values jitter)."""
FC_CLOCK = "FC clock"
HOST_CLOCK = "host clock: MSP"


def near(values: Sequence[int], wanted: Sequence[int], tolerance: int = TOLERANCE_US) -> bool:
    return all(abs(a - b) <= tolerance for a, b in zip(values, wanted, strict=True))


def largest_move(snapshots: Sequence[Snapshot], wanted: Sequence[int]) -> int:
    """How far the sticks went from `wanted` (µs) in `snapshots`."""
    return max(
        (max(abs(a - b) for a, b in zip(s.sticks, wanted, strict=True)) for s in snapshots),
        default=0,
    )


def away_from(sticks: Sequence[int]) -> tuple[int, int, int, int]:
    """Stick values the OBC commands: far from `sticks` (300 µs; throttle 150 µs above)."""
    roll, pitch, yaw, throttle = sticks[:STICKS]
    away = [v - 300 if v > 1500 else v + 300 for v in (roll, pitch, yaw)]
    return (away[0], away[1], away[2], min(throttle + 150, 2000))


@dataclass
class Flight:
    """The parts of one run, and the report its scenarios add their lines to."""

    watcher: FcWatcher
    obc: Obc
    pilot: Pilot
    settings: BoardSettings
    report: Report = field(default_factory=Report)
    limit_ms: float = LIMIT_MS
    arm: bool = False
    """Arming allowed (props off): the pilot, or the OBC alone, arms."""
    log: Log = quiet
    armed: bool = False
    """The FC was armed for this run (`arm_once`)."""
    pilot_rc: tuple[int, ...] = ()
    """What MSP_RC shows while the pilot flies (read by `start`)."""
    arming_failed: bool = False

    @property
    def alone(self) -> bool:
        return self.settings.obc_alone

    @property
    def authority(self) -> bool:
        """The firmware reports who flies (spec §15)."""
        status = self.obc.status
        return status is not None and status.reports_authority

    @property
    def timeout_ms(self) -> float:
        status = self.obc.status
        if status is not None:
            return status.timeout_ms
        return self.settings.timeout_ms or 150

    def command(self, sticks: Sequence[int] | None = None) -> tuple[int, ...]:
        """The OBC's command: sticks away from the pilot's (or, alone, level with throttle low:
        arming needs it), aux3/aux4 where they switch no mode (or, alone and armed through
        AUX3/AUX4 on firmware before arming requests, where they keep it armed)."""
        if sticks is None:
            sticks = (1400, 1600, 1450, 1000) if self.alone else away_from(self.pilot_rc)
        return (*sticks[:STICKS], *self._aux(self.armed))

    def _aux(self, armed: bool) -> tuple[int, int]:
        aux = []
        for channel in OBC_AUX:
            ranges = [r for r in self.settings.ranges if r.channel == channel]
            if armed and (arm := [r for r in ranges if r.mode == MODE_ARM]):
                aux.append(arm[0].on_us)
                continue
            free = [v for v in (1000, 2000, 1500) if not any(r.covers(v) for r in ranges)]
            aux.append(free[0] if free else 1000)
        if not self.alone and len(self.pilot_rc) >= 8:  # away from the pilot's AUX3/AUX4
            aux = [2000 if v < 1500 else 1000 for v in self.pilot_rc[6:8]]
        return aux[0], aux[1]

    # -- the OBC in and out of control --------------------------------------------------------

    def start(self) -> None:
        """The pilot holds the override switch off and the sticks still, and the FC receives
        the pilot's radio (an FC that has just started, as it does after its settings were
        read, is in RX loss until its receiver has had frames for a while); read the sticks'
        values. A radio the FC does not receive is a failed line."""
        if not self.alone:
            self.switch(False)
            received = self.watcher.wait(
                lambda s: not s.rx_loss and not s.failsafe, time.monotonic(), LINK_UP_S
            )
            if received is None:
                latest = self.watcher.latest()
                self.report.check(
                    "the FC receives the pilot's radio",
                    False,
                    "RXLOSS" if latest.rx_loss else "failsafe",
                    "no RXLOSS or failsafe",
                )
        self.pilot_rc = self.watcher.latest().rc

    def silence(self) -> None:
        """The OBC stops; returns once the FC has no command in effect (it timed out)."""
        self.obc.behave("stopped")
        self.obc.twin(None)
        gone = self.obc.next_status(lambda s: not s.has(UplinkFlag.LIVE), WAIT_S)
        if gone is None:  # no status (firmware without E3): a timeout's worth, and some
            time.sleep((self.timeout_ms + 50) / 1000)

    def take_over(self, what: str, command: Sequence[int] | None = None) -> bool:
        """The OBC in control, flying `command` (default: `command()`): with a safety pilot the
        pilot turns the override switch off, the OBC sends fresh commands until it is ready
        (spec §15), and the pilot turns the switch on; with the OBC alone, fresh commands until
        RXLOSS clears. False, with a failed line naming `what`, if it does not come to that."""
        command = tuple(command or self.command())
        self.silence()
        if not self.alone:
            self.switch(False)
        statuses = self.obc.statuses.end
        self.obc.behave("fresh", command)
        if not self.alone and not self.engage(what, statuses):
            self.obc.behave("stopped")
            return False
        flying = self.watcher.wait(
            lambda s: near(s.sticks, command[:STICKS]) and not s.rx_loss,
            time.monotonic(),
            LINK_UP_S if self.alone else WAIT_S,
        )
        if flying is None:
            latest = self.watcher.latest()
            self.report.check(
                f"{what}: fresh commands fly the sticks",
                False,
                f"sticks {latest.sticks}" + (", RXLOSS" if latest.rx_loss else ""),
                f"{command[:STICKS]}",
            )
            self.obc.behave("stopped")
            return False
        time.sleep(STEADY_S)
        return True

    def switch(self, on: bool) -> bool:
        """The pilot turns the override switch on or off; True once the FC shows it (the MSP
        OVERRIDE mode, asked for after the move)."""
        self.pilot.hold(override=on)
        return self.watcher.wait(lambda s: s.override == on, time.monotonic(), WAIT_S) is not None

    def engage(self, what: str, since: int) -> bool:
        """The pilot engages a live OBC: once it is ready (spec §15: a status from index
        `since` on says so; at once on firmware that does not say), the switch off, then on.
        False, with a failed line naming `what`, if the OBC does not become ready or the FC
        never shows the switch."""
        if self.authority and self.wait_authority(Authority.READY, PROOF_WAIT_S, since) is None:
            self.fail(f"{what}: a live OBC becomes ready for the pilot", "ready")
            return False
        if not (self.switch(False) and self.switch(True)):
            latest = self.watcher.latest()
            self.report.check(
                f"{what}: the pilot's override switch reaches the FC",
                False,
                f"MSP OVERRIDE {'on' if latest.override else 'off'}",
                "off, then on",
            )
            return False
        return True

    def said(self, seen: Sequence[Snapshot], statuses: int) -> str:
        """What MSP showed in `seen` (the first and last, host seconds apart), and what the
        FC's uplink statuses from index `statuses` on said: for a failed line's reader."""
        sticks = sorted({s.sticks for s in seen})[:3]
        span = f"{1e3 * (seen[-1].t - seen[0].t):.0f} ms" if seen else "-"
        flags = {
            f"{s.authority.name.lower() if s.authority else '?'}"
            f"/{s.exit.name.lower() if s.exit else '?'}"
            f"{'+rx_loss' if s.has(UplinkFlag.RX_LOSS) else ''}"
            for s in self.obc.statuses.since(statuses)
        }
        return f"over {span}: sticks {sticks}; the FC said {sorted(flags)}"

    def fail(self, name: str, wanted: str) -> Line:
        """A failed line: what the FC's uplink status says instead of `wanted`."""
        status = self.obc.status
        said = "no uplink status" if status is None else describe(status)
        return self.report.check(name, False, said, wanted)

    def wait_authority(
        self, wanted: Authority, timeout: float, since: int | None = None
    ) -> UplinkStatus | None:
        """An uplink status from index `since` on (default: the newest) saying `wanted`."""
        start = self.obc.statuses.end - 1 if since is None else since
        return self.obc.statuses.wait(lambda s: s.authority is wanted, start, timeout)

    def arm_once(self, what: str = "") -> bool:
        """Arm for the run (`--arm`, props off): the pilot arms, or the OBC alone — in control
        (`take_over`) — asks the FC to (an arming request, spec §14; firmware before it arms
        through an ARM range on AUX3/AUX4). False, with a failed line, if the FC does not
        arm; once it did not, `what` is not checked (saying so) and no arming is tried."""
        if self.armed:
            latest = self.watcher.latest()
            if latest.armed:
                return True
            flags = latest.status.arming_disabled
            line = self.report.check(  # Betaflight disarmed it since: armed again, this is said
                "the FC is still armed from before", False, f"disarmed ({flags!r})", "armed"
            )
            self.report.lasting.append(line)  # a scenario played again does not say it again
            self.armed = False
        if self.arming_failed:
            self.report.not_checked(what, "the FC could not be armed (above)")
            return False
        status = self.obc.status
        held = status is not None and status.has(UplinkFlag.ARM_SWITCH)
        if self.alone and self.authority and held:  # on since Betaflight disarmed: off first
            self.obc.request_arming(ArmingAction.DISARM)
            self.obc.next_status(lambda s: not s.has(UplinkFlag.ARM_SWITCH), WAIT_S)
        ready = self.watcher.wait(lambda s: s.can_arm, time.monotonic(), 15.0)
        if ready is None:
            flags = self.watcher.latest().status.arming_disabled
            line = self.report.check(
                "the FC can be armed", False, f"arming disabled ({flags!r})", ""
            )
            self.report.lasting.append(line)
            self.arming_failed = True
            return False
        self.armed = True
        moved = time.monotonic()
        if not self.alone:
            self.pilot.hold(armed=True)
        elif self.authority:
            self.obc.request_arming(ArmingAction.ARM)
        else:
            self.obc.behave("fresh", self.command())
        armed = self.watcher.wait(lambda s: s.armed, moved, WAIT_S)
        who = "the OBC (an arming request)" if self.alone else "the pilot"
        line = self.report.check(
            f"{who} arms (--arm)", armed is not None, "armed" if armed else "not armed", "armed"
        )
        self.report.lasting.append(line)  # a scenario played again finds the FC armed
        self.armed = armed is not None
        self.arming_failed = not self.armed
        return self.armed

    def disarm(self) -> None:
        """Disarm what `arm_once` armed: the pilot's switch, or the OBC's disarm request (its
        command in effect)."""
        if not self.watcher.latest().armed:
            self.armed = False
            return
        if not self.alone:
            self.pilot.hold(armed=False)
        elif self.authority:
            self.obc.behave("fresh", self.command())
            self.obc.next_status(lambda s: s.has(UplinkFlag.LIVE), WAIT_S)
            self.obc.request_arming(ArmingAction.DISARM)
        self.watcher.wait(lambda s: not s.armed, time.monotonic(), WAIT_S)
        self.armed = False

    # -- timing what the FC does ---------------------------------------------------------------

    def timed(
        self,
        name: str,
        last: Sent | None,
        shows: Callable[[Snapshot], bool],
        *,
        frame: Callable[[FrameSeen], bool] | None = None,
        status: Callable[[UplinkStatus], bool] | None = None,
        limit_ms: float | None = None,
        by_fc: bool = True,
    ) -> Snapshot | None:
        """A line timing what MSP `shows` from the OBC's `last` fresh command on: by the FC
        clock (from the FC time the FC took it, by its time reply, to the first `frame` or
        uplink `status` that shows it) where it can (`by_fc`, the FC answers commands), else
        from the write to the MSP reply (an upper bound). The snapshot that showed it."""
        limit = self.limit_ms if limit_ms is None else limit_ms
        since = last.written if last is not None else time.monotonic()
        seen = self.watcher.wait(shows, since, WAIT_S)
        ms: float | None = None
        clock = HOST_CLOCK
        if seen is not None:
            fc = self.fc_ms(last, frame=frame, status=status) if by_fc else None
            ms, clock = (fc, FC_CLOCK) if fc is not None else (self.host_ms(since, seen), clock)
        self.report.timing(name, ms, limit, clock)
        return seen

    def flip(self, name: str, on: bool, sticks: Callable[[tuple[int, ...]], bool]) -> None:
        """A line timing the pilot's switch turned `on` (or off) to the sticks showing what
        `sticks` asks: by the FC clock, from the uplink status the change of the switch
        brought (written in the FSP task run of the change) to the first frame; else from the
        move (a person: the MSP reply that showed the switch) to the MSP reply."""
        statuses = self.obc.statuses.end
        switched = time.monotonic()
        self.pilot.hold(override=on)
        seen = self.watcher.wait(lambda s: sticks(s.sticks), switched, WAIT_S)
        ms, clock = None, HOST_CLOCK
        if seen is not None:
            said = self.obc.statuses.wait(
                lambda s: s.has(UplinkFlag.OVERRIDE) == on, statuses, WAIT_S
            )
            frame = None
            if said is not None and said.sent_us is not None:
                frame = self.obc.frame_after(said.sent_us, lambda f: sticks(f.sticks), WAIT_S)
            if frame is not None and said is not None and said.sent_us is not None:
                ms, clock = (frame.fc_us - said.sent_us) / 1000, FC_CLOCK
            else:
                moved = self.watcher.wait(lambda s: s.override == on, switched, WAIT_S)
                start = switched if self.pilot.simulated or moved is None else moved.t
                ms = self.host_ms(start, seen)
        self.report.timing(name, ms, self.limit_ms, clock)

    def host_ms(self, since: float, seen: Snapshot) -> float:
        """Host milliseconds from `since` to the MSP reply `seen`: an upper bound of how long
        the FC took, good only while the FC answered MSP promptly. A reply in between that
        took longer than `MSP_STALL_S` says the host (or the virtual FC) stalled: the
        measurement is then no evidence, recorded as a stall (`Obc.stalls`)."""
        replies = [s for s in self.watcher.since(since) if s.t <= seen.t]
        slowest = max((s.t - s.asked for s in replies), default=0.0)
        if slowest > MSP_STALL_S:
            self.obc.stalls.add(slowest)
        return 1e3 * (seen.t - since)

    def fc_ms(
        self,
        last: Sent | None,
        *,
        frame: Callable[[FrameSeen], bool] | None = None,
        status: Callable[[UplinkStatus], bool] | None = None,
    ) -> float | None:
        """FC milliseconds from the FC taking `last` to the first `frame` or `status` that
        shows the change; None if the FC did not answer `last` or the stream did not show it."""
        taken = self.obc.taken_us(last)
        if taken is None:
            return None
        if frame is not None:
            seen = self.obc.frame_after(taken, frame, WAIT_S)
            return None if seen is None else (seen.fc_us - taken) / 1000
        if status is not None:
            said = self.obc.status_after(taken, status, WAIT_S)
            return None if said is None or said.sent_us is None else (said.sent_us - taken) / 1000
        return None

    def never_shown(self, name: str, rc: Sequence[int], frames: int, since: float) -> Line:
        """A line: no frame from index `frames` on, nor MSP reply after host time `since`,
        carries the sticks of `rc`."""
        wanted = rc[:STICKS]
        shown = [f for f in self.obc.frames.since(frames) if near(f.sticks, wanted)]
        replies = [s for s in self.watcher.since(since) if near(s.sticks, wanted)]
        return self.report.check(
            name,
            not shown and not replies,
            f"its sticks in {len(shown)} frames, {len(replies)} MSP replies",
            "none",
            value=len(shown),
            unit="frames",
        )

    def back_to_pilot(
        self, title: str, last: Sent | None, *, by_fc: bool = True, stays_s: float = HOLD_S
    ) -> Line | None:
        """Lines: the pilot's sticks back within the limit after the OBC's `last` fresh
        command (`timed`), and then staying the pilot's for `stays_s` (`holds`), which is
        the line returned (None: the sticks never came back)."""
        pilot = self.pilot_rc[:STICKS]
        back = self.timed(
            f"{title}: the pilot's sticks back",
            last,
            lambda s: near(s.sticks, pilot),
            frame=lambda f: near(f.sticks, pilot),
            by_fc=by_fc,
        )
        if back is None:
            return None
        return self.holds(f"{title}: it stays with the pilot", back.t, pilot, stays_s)

    def shown(self, what: str, found: list[Snapshot], replies: int, start: float) -> str:
        """How the FC was seen `what` from host time `start` on: in how many of its `replies`,
        from when, what the first of `found` showed, and the newest uplink status."""
        first = found[0]
        showed = [
            name for name, on in (("RXLOSS", first.rx_loss), ("failsafe", first.failsafe)) if on
        ]
        showed.append(f"arming disabled {first.status.arming_disabled!r}")
        status = self.obc.status
        said = "no uplink status" if status is None else describe(status)
        return (
            f"{what} in {len(found)} of {replies} MSP replies, from "
            f"{(first.asked - start) * 1e3:.0f} ms on ({', '.join(showed)}; uplink: {said})"
        )

    def holds(
        self, name: str, since: float, wanted: Sequence[int], seconds: float = HOLD_S
    ) -> Line:
        """A line: for `seconds` from host time `since` the sticks stay at `wanted` (the
        pilot's), no RXLOSS or failsafe, and — armed — the FC stays armed."""
        time.sleep(max(0.0, since + seconds - time.monotonic()))
        after = [s for s in self.watcher.since(since) if s.t <= since + seconds]
        moved = largest_move(after, wanted[:STICKS])
        problems = []
        if moved > TOLERANCE_US:
            problems.append(f"sticks moved {moved} µs")
        if lost := [s for s in after if s.rx_loss or s.failsafe]:
            problems.append(self.shown("RXLOSS/failsafe", lost, len(after), since))
        if self.armed and (disarmed := [s for s in after if not s.armed]):
            problems.append(self.shown("disarmed", disarmed, len(after), since))
        what = "the pilot flies" + (", armed" if self.armed else "")
        return self.report.check(
            f"{name}: {seconds:g} s on, {what}",
            not problems,
            "; ".join(problems) or "yes",
            "yes",
            value=moved,
            unit="µs",
        )


def describe(status: UplinkStatus) -> str:
    """An uplink status in a few words."""
    flags = [flag.name.lower() for flag in UplinkFlag if status.has(flag) and flag.name]
    who = ""
    if status.authority is not None and status.exit is not None:
        who = f"authority {status.authority.name.lower()} (exit {status.exit.name.lower()}), "
    return f"{who}{'+'.join(flags) or 'no flags'}, accepted {status.accepted}"
