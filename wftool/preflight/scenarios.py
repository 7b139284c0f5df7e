"""The scenarios: each a way the OBC fails, restarts, doubles, lies or is taken off the sticks,
played on the board and judged by what the FC does (spec §11, §13-§15). Each exists here
once; `wftool preflight`, the SITL tests and `scripts/failsafe_timing.py` run these.

With a safety pilot a scenario starts by putting the OBC in control as the pilot would
(`Flight.take_over`: the switch off, a live OBC proving itself, the switch on) and judges
that the sticks go back to the pilot, stay there, and come back to the OBC only when the pilot
engages it again. With the OBC alone it judges RXLOSS and Betaflight's failsafe, and that
nothing the OBC sends by accident disarms or switches a mode.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from wftool.fsp.clock import U32
from wftool.fsp.packets import Authority, CommandOutcome, UplinkFlag, UplinkStatus
from wftool.preflight.flight import (
    FC_CLOCK,
    HOLD_S,
    HOST_CLOCK,
    PROOF_WAIT_S,
    TOLERANCE_US,
    WAIT_S,
    Flight,
    near,
)
from wftool.preflight.obc import README_COMMAND, Sent
from wftool.preflight.watcher import STICKS
from wftool.sitl.radio import RX_LOSS_MS

PILOT, ALONE = "safety pilot", "the OBC alone"
BOTH = (PILOT, ALONE)
FAILSAFE_LANDING = 2
"""Betaflight's failsafe phases from here on are stage 2 (`FAILSAFE_PHASES`)."""
STEP_BACK_S = -5.0
"""The OBC clock's step back."""
STAYS_S = 1.5
"""How long the pilot must keep the sticks after a loss while the OBC goes on sending: three
proofs of life (spec §15)."""


@dataclass(frozen=True)
class Scenario:
    key: str
    title: str
    setups: tuple[str, ...]
    """Who flies where it applies (`PILOT`, `ALONE`)."""
    run: Callable[[Flight], None]
    needs_arm: str = ""
    """Why it needs `--arm` (props off), if it does."""


# -- the OBC failing ---------------------------------------------------------------------------

FAILURES = {
    "stopped": "OBC stopped (port open)",
    "closed": "OBC killed (port closed)",
    "stuck": "OBC stuck (repeats its last packet)",
    "garbage": "OBC sends garbage",
    "replay": "OBC replays old packets",
}


def _fail(flight: Flight, key: str) -> Sent | None:
    return flight.obc.kill() if key == "closed" else flight.obc.behave(key)


def _failure(key: str) -> Callable[[Flight], None]:
    title = FAILURES[key]
    by_fc = key != "closed"  # the stream breaks off with the port: MSP shows it

    def run(flight: Flight) -> None:
        if not flight.take_over(title):
            return
        last = _fail(flight, key)
        if flight.alone:
            flight.timed(
                f"{title}: RXLOSS",
                last,
                lambda s: s.rx_loss,
                status=lambda s: s.has(UplinkFlag.RX_LOSS),
                by_fc=by_fc,
            )
            time.sleep(HOLD_S)
            still = flight.watcher.latest().rx_loss
            flight.report.check(
                f"{title}: still RXLOSS after {HOLD_S:g} s", still, "yes" if still else "no", "yes"
            )
        else:
            flight.back_to_pilot(title, last, by_fc=by_fc)
        flight.obc.behave("stopped")

    return run


# -- a safety pilot: who flies changes only when the pilot decides ----------------------------


def switch_early(flight: Flight) -> None:
    """The switch turned on while the OBC is silent, then the OBC comes: it proves itself, but
    engages nothing (spec §15: the switch must be turned on while it is ready)."""
    flight.silence()
    flight.switch(False)
    flight.switch(True)
    start = time.monotonic()
    flight.obc.behave("fresh", flight.command())
    flight.holds(
        "override switch on before the OBC is ready, then it sends: engages nothing",
        start,
        flight.pilot_rc,
        STAYS_S,
    )
    flight.obc.behave("stopped")
    flight.switch(False)


def resume(flight: Flight) -> None:
    """The OBC goes silent past the timeout, then resumes (its sequence carrying on): the
    sticks stay the pilot's, the switch untouched."""
    title = "OBC resumes after a timeout, the switch untouched"
    if not flight.take_over(title):
        return
    pilot = flight.pilot_rc[:STICKS]
    last = flight.obc.behave("stopped")
    back = flight.watcher.wait(lambda s: near(s.sticks, pilot), last.written if last else 0, WAIT_S)
    if back is None:
        flight.report.check(f"{title}: the pilot's sticks back", False, "never", "yes")
        return
    flight.silence()
    start = time.monotonic()
    flight.obc.behave("fresh", flight.command())
    flight.holds(f"{title}: it stays with the pilot", start, flight.pilot_rc, STAYS_S)
    flight.obc.behave("stopped")


def reengage(flight: Flight) -> None:
    """The pilot engages a ready OBC: how long from the switch to the OBC steering."""
    title = "the pilot engages the OBC"
    command = flight.command()
    flight.silence()
    flight.switch(False)
    statuses = flight.obc.statuses.end
    flight.obc.behave("fresh", command)
    if flight.authority and flight.wait_authority(Authority.READY, PROOF_WAIT_S, statuses) is None:
        flight.fail(f"{title}: a live OBC becomes ready", "ready")
        return
    flight.flip(
        f"{title}: the switch on to the OBC steering", True, lambda rc: near(rc, command[:STICKS])
    )
    flight.obc.behave("stopped")


def restart_piloted(flight: Flight) -> None:
    """The OBC program restarts (a new sender) while engaged: the sticks go back to the pilot
    and stay there until the pilot engages the new program."""
    title = "OBC restarts (a new sender)"
    if not flight.take_over(title):
        return
    restarted = flight.command((*tuple(v - 100 for v in flight.command()[:3]), 1050))
    statuses = flight.obc.statuses.end
    last = flight.obc.restart(restarted)
    line = flight.back_to_pilot(title, last, stays_s=STAYS_S)
    if line is not None and line.passed and flight.engage(title, statuses):
        steers = flight.watcher.wait(
            lambda s: near(s.sticks, restarted[:STICKS]), time.monotonic(), WAIT_S
        )
        flight.report.check(
            f"{title}: the pilot engages it again: it steers",
            steers is not None,
            "yes" if steers else "no",
            "yes",
        )
    flight.obc.behave("stopped")


def switch_off(flight: Flight) -> None:
    """The pilot turns the switch off while the OBC steers: the sticks are the pilot's."""
    title = "override switch off while the OBC steers: the pilot's sticks back"
    if not flight.take_over(title):
        return
    pilot = flight.pilot_rc[:STICKS]
    flight.flip(title, False, lambda rc: near(rc, pilot))
    flight.obc.behave("stopped")


def radio_lost(flight: Flight) -> None:
    """The pilot's radio is lost while the OBC steers: Betaflight's failsafe, which the OBC
    cannot keep off; the radio back, the OBC stays disengaged."""
    title = "the pilot's radio lost while the OBC steers"
    if not flight.pilot.transmitter(True):
        flight.report.not_checked(title, "this pilot cannot switch the transmitter off")
        return
    if not flight.take_over(title):
        return
    switched = time.monotonic()
    flight.pilot.transmitter(False)
    try:
        lost = flight.watcher.wait(lambda s: s.rx_loss, switched, WAIT_S)
        if flight.pilot.simulated:
            ms = None if lost is None else flight.host_ms(switched, lost)
            flight.report.timing(f"{title}: RXLOSS", ms, RX_LOSS_MS + flight.limit_ms, HOST_CLOCK)
        else:
            flight.report.check(
                f"{title}: RXLOSS", lost is not None, "yes" if lost else "no", "yes"
            )
        time.sleep(HOLD_S)
        still = flight.watcher.latest().rx_loss
        flight.report.check(
            f"{title}: the OBC does not keep it alive (still RXLOSS after {HOLD_S:g} s)",
            still,
            "yes" if still else "no",
            "yes",
        )
    finally:
        flight.pilot.transmitter(True)
    back = flight.watcher.wait(lambda s: not s.rx_loss, time.monotonic(), WAIT_S)
    if back is None:
        flight.report.check(f"{title}: the radio back, RXLOSS clears", False, "no", "yes")
        return
    flight.armed = flight.armed and back.armed
    flight.holds(f"{title}: the radio back, the OBC stays off the sticks", back.t,
                 flight.pilot_rc, STAYS_S)  # fmt: skip
    flight.obc.behave("stopped")


# -- both set-ups: another sender, a clock step, values out of range, late timed commands -------


def twin(flight: Flight) -> None:
    """A second OBC program commands on the same port: ignored and counted; with a safety
    pilot it ends the engagement (spec §11, §15)."""
    title = "a second sender"
    if not flight.take_over(title):
        return
    command = flight.command()
    other = (*(v + 90 for v in command[:3]), command[3] + 40, *command[4:])
    before = flight.obc.status
    frames = flight.obc.frames.end
    statuses = flight.obc.statuses.end
    start = time.monotonic()
    flight.obc.twin(other)
    time.sleep(1.0)
    flight.obc.twin(None)
    seen = flight.watcher.since(start)
    flight.never_shown(f"{title}: its commands never steer", other, frames, start)
    after = flight.obc.status
    foreign = _grew(before, after, "foreign")
    flight.report.check(
        f"{title}: counted foreign (E3)",
        foreign is not None and foreign > 0,
        "not reported (firmware before sender identity)" if foreign is None else f"{foreign}",
        "> 0",
        value=foreign,
        unit="packets",
    )
    if flight.alone:
        lost = [s for s in seen if s.rx_loss or not near(s.sticks, command[:STICKS])]
        flight.report.check(
            f"{title}: the first flies on",
            not lost,
            f"{len(lost)} of {len(seen)} MSP replies not its sticks ({flight.said(lost, statuses)})"
            if lost
            else "yes",
            "yes",
        )
    else:
        pilot = flight.pilot_rc[:STICKS]
        flight.report.check(
            f"{title}: the OBC loses the sticks to the pilot",
            bool(seen) and near(seen[-1].sticks, pilot),
            f"sticks {seen[-1].sticks if seen else '?'}",
            f"{pilot}",
        )
    flight.obc.behave("stopped")


def clock_step(flight: Flight) -> None:
    """The OBC's clock steps back 5 s (its sequence carrying on): a new link at once, which
    steers again (the OBC alone) or waits for the pilot (spec §11, §15)."""
    title = f"OBC clock steps back {-STEP_BACK_S:g} s"
    if not flight.take_over(title):
        return
    command = flight.command()
    stepped = (command[0] + 50, *command[1:])
    statuses = flight.obc.statuses.end
    last = flight.obc.step_clock(STEP_BACK_S, stepped)
    taken = flight.obc.taken_us(last)
    again = None
    if taken is not None and last is not None:
        trip = flight.obc.trips.wait(
            lambda t: t.obc_sent < last.stamp - 1.0 and t.fc_received_us > taken, 0, WAIT_S
        )
        again = None if trip is None else (trip.fc_received_us - taken) / 1000
    if flight.alone:
        steers = flight.timed(
            f"{title}: its commands steer again",
            last,
            lambda s: near(s.sticks, stepped[:STICKS]),
            frame=lambda f: near(f.sticks, stepped[:STICKS]),
        )
        if steers is not None and last is not None:
            lost = [s for s in flight.watcher.since(last.written) if s.rx_loss]
            flight.report.check(
                f"{title}: no RXLOSS",
                not lost,
                f"{len(lost)} MSP replies RXLOSS ({flight.said(lost, statuses)})"
                if lost
                else "none",
                "none",
            )
    else:
        flight.back_to_pilot(title, last, stays_s=STAYS_S)
    flight.report.check(
        f"{title}: its commands taken again",
        again is not None,
        "never (or no time replies)" if again is None else f"{again:.1f} ms",
        "taken",
        value=again,
        unit="ms",
        clock=FC_CLOCK,
    )
    flight.obc.behave("stopped")


def out_of_range(flight: Flight) -> None:
    """One command with the throttle above the FC's pulse range, between fresh ones: refused
    whole and counted, never on the sticks (spec §5); with a safety pilot it ends the
    engagement (spec §15)."""
    title = "a command out of the pulse range"
    if not flight.take_over(title):
        return
    status = flight.obc.status
    high = (status.rc_max_us if status is not None else None) or flight.settings.rx.max_us
    command = flight.command()
    bad = (*command[:3], high + 100, *command[4:])
    frames = flight.obc.frames.end
    start = time.monotonic()
    sent = flight.obc.send_once(bad, unchecked=True)
    time.sleep(HOLD_S)
    seen = flight.watcher.since(start)
    highest = max(
        [f.sticks[3] for f in flight.obc.frames.since(frames)] + [s.sticks[3] for s in seen],
        default=0,
    )
    flight.report.check(
        f"{title} (throttle {high + 100} µs): the sticks never see it",
        highest <= command[3] + TOLERANCE_US,
        f"throttle up to {highest} µs",
        f"≤ {command[3]} µs",
        value=highest,
        unit="µs",
    )
    refused = _grew(status, flight.obc.status, "refused")
    flight.report.check(
        f"{title}: refused whole, counted (E3)",
        refused is not None and refused >= 1,
        "not reported (firmware before refusing)" if refused is None else f"{refused}",
        "≥ 1",
        value=refused,
        unit="packets",
    )
    if flight.alone:
        lost = [s for s in seen if s.rx_loss]
        flight.report.check(
            f"{title}: the link goes on (no RXLOSS)", not lost, f"{len(lost)} RXLOSS", "none"
        )
    else:
        pilot = flight.pilot_rc[:STICKS]
        back = flight.watcher.wait(lambda s: near(s.sticks, pilot), sent.written, WAIT_S)
        ms = None if back is None else flight.host_ms(sent.written, back)
        flight.report.timing(f"{title}: the pilot's sticks back", ms, flight.limit_ms, HOST_CLOCK)
    flight.obc.behave("stopped")


def late(flight: Flight) -> None:
    """A timed command (E4) whose time lies more than the command timeout in the FC's past:
    expired, never applied (spec §13)."""
    title = "a timed command past the timeout"
    if not flight.take_over(title):
        return
    command = flight.command()
    marked = (command[0] + 70, command[1] - 70, *command[2:])
    frame = flight.obc.frames.latest()
    if frame is None:
        flight.report.check(f"{title}: expired", False, "no frames on the stream", "expired")
        return
    at_us = (frame.fc_us - int((flight.timeout_ms + 20) * 1000)) % U32
    frames = flight.obc.frames.end
    reports = flight.obc.reports.end
    start = time.monotonic()
    sent = flight.obc.send_once(marked, at_us=at_us)
    report = flight.obc.reports.wait(lambda r: r.command_seq == sent.packet.seq, reports, WAIT_S)
    outcome = "no report" if report is None else _outcome(report.outcome)
    flight.report.check(
        f"{title}: expired (E4 report)",
        report is not None and report.outcome == CommandOutcome.EXPIRED,
        outcome,
        "expired",
    )
    time.sleep(HOLD_S)
    flight.never_shown(f"{title}: never applied (the sticks never show it)", marked, frames, start)
    flight.obc.behave("stopped")


# -- the OBC alone, armed (props off!) -------------------------------------------------------------


def restart_armed(flight: Flight) -> None:
    """Armed, the OBC program restarts sending the README's command: the FC stays armed."""
    title = "OBC restarts with the README's command"
    if not flight.take_over(title) or not flight.arm_once(title):
        return
    start = time.monotonic()
    flight.obc.restart(README_COMMAND)
    _stays_armed(flight, title, start, flight.timeout_ms / 1000 + 1.0)


def default_command(flight: Flight) -> None:
    """Armed, the OBC sends the README's example command: nothing disarms, no mode switches."""
    title = "the README's command"
    if not flight.take_over(title) or not flight.arm_once(title):
        return
    start = time.monotonic()
    flight.obc.behave("fresh", README_COMMAND)
    _stays_armed(flight, title, start, 1.0)


def _stays_armed(flight: Flight, title: str, start: float, seconds: float) -> None:
    modes = flight.watcher.latest().status.boxes
    time.sleep(seconds)
    seen = flight.watcher.since(start)
    disarmed = [s for s in seen if not s.armed]
    switched = {s.status.boxes ^ modes for s in seen} - {0}
    flight.report.check(
        f"{title}: the FC stays armed, no mode switches",
        bool(seen) and not disarmed and not switched,
        "; ".join(
            part
            for part in (
                "" if seen else "no MSP reply",
                flight.shown("disarmed", disarmed, len(seen), start) if disarmed else "",
                f"modes switched (bits {sorted(switched)})" if switched else "",
            )
            if part
        )
        or "yes",
        "yes",
    )
    flight.obc.behave("stopped")


def stage2(flight: Flight) -> None:
    """Armed, the OBC gets stuck: RXLOSS, then Betaflight's failsafe stage 2 at
    `failsafe_delay`."""
    title = FAILURES["stuck"]
    if not flight.take_over(title) or not flight.arm_once(f"{title}: failsafe stage 2"):
        return
    time.sleep(0.3)
    last = flight.obc.behave("stuck")
    delay = flight.settings.failsafe.delay_ms
    since = last.written if last is not None else time.monotonic()
    seen = flight.watcher.wait(lambda s: s.failsafe or not s.armed, since, delay / 1000 + WAIT_S)
    ms, clock = None, HOST_CLOCK
    if seen is not None:
        fc = flight.fc_ms(
            last,
            status=lambda s: not s.has(UplinkFlag.ARMED) or s.failsafe_phase >= FAILSAFE_LANDING,
        )
        ms, clock = (fc, FC_CLOCK) if fc is not None else (flight.host_ms(since, seen), clock)
    flight.report.check(
        f"{title}: failsafe stage 2 (failsafe_delay {delay} ms)",
        ms is not None and delay <= ms <= delay + flight.limit_ms,
        "never" if ms is None else f"{ms:.1f} ms",
        f"{delay}-{delay + flight.limit_ms:g} ms",
        value=ms,
        unit="ms",
        clock=clock,
    )
    flight.armed = False
    flight.obc.behave("stopped")


def _grew(before: UplinkStatus | None, after: UplinkStatus | None, counter: str) -> int | None:
    """How much the uplink status counter `counter` grew; None if the firmware reports no
    such counter."""
    old = None if before is None else getattr(before, counter)
    new = None if after is None else getattr(after, counter)
    if old is None or new is None:
        return None
    return int(new - old) % (1 << 32)


def _outcome(outcome: int) -> str:
    try:
        return CommandOutcome(outcome).name.lower().replace("_", " ")
    except ValueError:
        return f"outcome {outcome}"


SCENARIOS: tuple[Scenario, ...] = (
    Scenario("switch_early", "override switch on before the OBC is ready", (PILOT,), switch_early),
    *(Scenario(key, title, BOTH, _failure(key)) for key, title in FAILURES.items()),
    Scenario("resume", "OBC resumes after a timeout", (PILOT,), resume),
    Scenario("reengage", "the pilot engages the OBC", (PILOT,), reengage),
    Scenario("restart", "OBC restarts (a new sender)", (PILOT,), restart_piloted),
    Scenario("twin", "a second sender", BOTH, twin),
    Scenario("clock_step", "OBC clock steps back", BOTH, clock_step),
    Scenario("out_of_range", "a command out of the pulse range", BOTH, out_of_range),
    Scenario("late", "a timed command past the timeout", BOTH, late),
    Scenario("switch_off", "override switch off while the OBC steers", (PILOT,), switch_off),
    Scenario("radio_lost", "the pilot's radio lost", (PILOT,), radio_lost),
    Scenario(
        "restart_armed", "OBC restarts with the README's command, armed", (ALONE,), restart_armed,
        needs_arm="a restart that disarms shows only armed",
    ),
    Scenario(
        "default_command", "the README's command, armed", (ALONE,), default_command,
        needs_arm="a command that disarms shows only armed",
    ),
    Scenario(
        "stage2", "failsafe stage 2", (ALONE,), stage2,
        needs_arm="Betaflight enters stage 2 only armed",
    ),
)  # fmt: skip
"""Every scenario, in the order a run plays them (those that may end armed last)."""
BY_KEY = {scenario.key: scenario for scenario in SCENARIOS}


def scenarios_for(alone: bool) -> list[Scenario]:
    setup = ALONE if alone else PILOT
    return [scenario for scenario in SCENARIOS if setup in scenario.setups]
