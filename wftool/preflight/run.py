"""One preflight run: an armed FC is refused before anything is sent; the board's settings are
read and checked; then the scenarios play against that configuration, and the report says
what passed, failed and was not checked.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator, Sequence

from wftool.errors import UsageError, WftoolError
from wftool.fc.board import Board
from wftool.fc.modes import MODE_ARM
from wftool.fc.msp import MspClient
from wftool.fsp.reader import DEFAULT_BAUDRATE
from wftool.preflight.flight import LIMIT_MS, Flight
from wftool.preflight.obc import README_COMMAND, STALL_FRACTION, Obc
from wftool.preflight.pilot import NoPilot, Pilot
from wftool.preflight.report import Report
from wftool.preflight.scenarios import Scenario, scenarios_for
from wftool.preflight.settings import BoardSettings, check_settings, read_settings
from wftool.preflight.watcher import FcWatcher, Snapshot
from wftool.progress import Log, quiet

FIRST_STATUS_S = 1.0
"""How long the FC may take to answer a first packet with an uplink status (E3)."""
TRIES = 5
"""A scenario during which wftool's own OBC's commands came late (its host or the link
stalled), or the simulated radio's frames did, is played again, up to this often."""
STALLED = "wftool's OBC or radio came late"
"""How the line of a scenario not checked for that begins."""


class ArmedError(UsageError):
    """The FC is armed, and preflight was not told it may command an armed FC."""


def refuse_armed(url: str) -> None:
    """`ArmedError` if the FC on `url` is armed: Betaflight opens no CLI then (the settings
    cannot be read), and preflight commands an FC only from disarmed, arming it itself when
    told to (`--arm`)."""
    with MspClient.open(url) as msp:
        bit = msp.mode_bits().get(MODE_ARM)
        armed = msp.status_ex().active(bit)
    if armed:
        raise ArmedError(
            f"the FC on {url} is armed: preflight sends nothing to an armed FC; disarm it "
            "(with --arm, props off, preflight arms it itself)"
        )


class ArmedGuard:
    """Stops the OBC when the FC shows armed and arming was not allowed."""

    def __init__(self, allowed: bool) -> None:
        self.allowed = allowed
        self._seen: Snapshot | None = None
        self._lock = threading.Lock()

    def saw(self, snapshot: Snapshot) -> None:
        with self._lock:
            if not self.allowed and self._seen is None:
                self._seen = snapshot

    def check(self) -> None:
        """Raise `ArmedError` once the FC was seen armed without leave."""
        with self._lock:
            if self._seen is not None:
                raise ArmedError(
                    "the FC was armed during the run, without --arm: preflight stopped "
                    "commanding it"
                )


class Preflight:
    """One run on a board (or the virtual FC); `run()` returns the report."""

    def __init__(
        self,
        board: Board,
        fsp_url: str,
        pilot: Callable[[BoardSettings], Pilot],
        *,
        baudrate: int = DEFAULT_BAUDRATE,
        limit_ms: float = LIMIT_MS,
        arm: bool = False,
        settings_only: bool = False,
        only: Sequence[str] | None = None,
        trials: int = 1,
        subject: Sequence[str] = (),
        log: Log = quiet,
        closing: Callable[[Callable[[], None]], object] | None = None,
    ) -> None:
        """`pilot(settings)`: who holds the radio, once the settings say who flies;
        `only`: the keys of the scenarios to play (default: all that apply), each `trials`
        times in a row; `closing`: how the OBC's port closes when it is killed (see `Obc`)."""
        self.board = board
        self.fsp_url = fsp_url
        self.pilot = pilot
        self.baudrate = baudrate
        self.limit_ms = limit_ms
        self.arm = arm
        self.settings_only = settings_only
        self.only = only
        self.trials = trials
        self.log = log
        self.closing = closing
        self.report = Report(list(subject))
        self.settings: BoardSettings | None = None
        self._guard = ArmedGuard(arm)

    def run(self) -> Report:
        settings = self.read()
        scenarios = self.scenarios()
        if self.settings_only:
            for scenario in scenarios:
                self.report.not_checked(scenario.title, "--settings-only: nothing was commanded")
            return self.report
        with self.flying() as flight:
            for scenario in scenarios:
                self.play(flight, scenario)
            if not settings.obc_alone and not self.arm:
                self.report.not_checked(
                    "the FC stays armed through the OBC's failures", "needs --arm (props off)"
                )
        return self.report

    def read(self) -> BoardSettings:
        """Refuse an armed FC, then read the board's settings and check them (their lines)."""
        refuse_armed(self.board.url)
        settings = self.settings = read_settings(self.board, self.log)
        self.report.subject += settings.describe()
        self.report.extend(check_settings(settings, self.limit_ms))
        return settings

    def scenarios(self) -> list[Scenario]:
        """The scenarios that apply to the board's set-up (and were asked for)."""
        assert self.settings is not None, "read() first"
        return [
            scenario
            for scenario in scenarios_for(self.settings.obc_alone)
            if self.only is None or scenario.key in self.only
        ]

    @contextlib.contextmanager
    def flying(self) -> Iterator[Flight]:
        """The OBC on the FSP port and the FC watched over MSP, the pilot holding the override
        switch off (and, with `arm`, the pilot's FC armed); the FC's first uplink status's
        lines in the report. An FC that arms without `arm` stops the OBC (`ArmedError`)."""
        settings = self.settings
        assert settings is not None, "read() first"
        refuse_armed(self.board.url)
        self._guard = guard = ArmedGuard(self.arm)
        pilot = NoPilot() if settings.obc_alone else self.pilot(settings)
        with MspClient.open(self.board.url) as msp, FcWatcher(msp, guard.saw) as watcher:
            obc = Obc(self.fsp_url, self.baudrate, closing=self.closing, guard=guard.check)
            with obc:
                flight = Flight(watcher, obc, pilot, settings, self.report, self.limit_ms,
                                self.arm, self.log)  # fmt: skip
                try:
                    self._first_status(flight)
                    flight.start()
                    if self.arm and not settings.obc_alone:
                        flight.arm_once()
                    yield flight
                finally:
                    with contextlib.suppress(WftoolError):  # the error that ended it goes on
                        if flight.armed:
                            flight.disarm()
                        obc.behave("stopped")
                    pilot.hold(override=False)
        guard.check()

    def play(self, flight: Flight, scenario: Scenario) -> None:
        """`scenario`, `trials` times, its lines in `flight.report` (not checked, saying why,
        where it needs `arm`)."""
        if scenario.needs_arm and not self.arm:
            flight.report.not_checked(
                scenario.title, f"needs --arm (props off): {scenario.needs_arm}"
            )
            return
        report = flight.report
        for trial in range(self.trials):
            count = f" ({trial + 1} of {self.trials})" if self.trials > 1 else ""
            stalls: list[float] = []
            for _ in range(TRIES):
                self.log(f"scenario: {scenario.title}{count}")
                lines, start = len(report.lines), flight.obc.stalls.end
                started = time.monotonic()
                scenario.run(flight)
                self._guard.check()
                stall = flight.obc.stalls.since(start)
                radio = flight.pilot.stalls_since(started)
                if not stall and not radio:
                    break
                report.take_back(lines)  # this program was late: no evidence of the FC's
                stalls += stall + radio
                late = []
                if stall:
                    late.append(f"the OBC's commands came {max(stall) * 1e3:.0f} ms apart")
                if radio:
                    late.append(f"the radio's frames came {max(radio) * 1e3:.0f} ms apart")
                self.log(
                    f"{scenario.title}: {' and '.join(late)} (wftool's host or the link "
                    "stalled): played again"
                )
            else:
                report.not_checked(
                    scenario.title,
                    f"{STALLED} (up to {max(stalls) * 1e3:.0f} ms apart) in each of {TRIES} "
                    "tries: wftool's host or the link stalled",
                )

    def _first_status(self, flight: Flight) -> None:
        """A lone packet (the FC takes no command from one: spec §11) brings the FC's first
        uplink status: what the firmware reports of itself."""
        report, settings = self.report, flight.settings
        start = flight.obc.statuses.end
        flight.obc.send_once(README_COMMAND)
        status = flight.obc.statuses.wait(lambda s: True, start, FIRST_STATUS_S)
        if status is not None:
            flight.obc.stall_s = STALL_FRACTION * status.timeout_ms / 1000
        if status is None:
            report.check(
                "the FC reports on the uplink (E3 uplink status)",
                False,
                f"none in {FIRST_STATUS_S:g} s",
                "a status",
            )
            return
        report.check(
            "the firmware reports who flies (E3 authority, spec §15)",
            status.reports_authority,
            "yes" if status.reports_authority else "no: a 36-byte status, firmware before it",
            "yes",
        )
        report.check(
            "fsp_cmd_timeout_ms as the FC applies it (E3)",
            status.timeout_ms == settings.timeout_ms,
            f"{status.timeout_ms} ms",
            f"{settings.timeout_ms} ms (the setting)",
        )
        if status.pulse_range is not None:
            rx = settings.rx
            low, high = status.pulse_range
            report.check(
                "the pulse range as the FC applies it (E3)",
                (low, high) == (rx.min_us, rx.max_us),
                f"{low}-{high} µs",
                f"{rx.min_us}-{rx.max_us} µs (rx_min_usec, rx_max_usec)",
            )
