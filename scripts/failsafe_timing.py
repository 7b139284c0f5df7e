"""How fast the virtual FC fails safe when its OBC fails: min / median / max over trials.

    .venv/bin/python scripts/failsafe_timing.py [--trials 5] [--binary SITL] [--port-base N]
        [--cmd-timeout-ms 50]

Safety pilot (the simulated radio the receiver, armed, MSP OVERRIDE on): the OBC flies the
sticks with fresh commands at 100 Hz, then is killed (port closed), stops, repeats its last
packet or sends garbage; measured is the time until all four of the pilot's stick values are
back, and whether 0.5 s later the FC is still armed on the pilot's sticks and follows them.
Switched on before any fresh command: the largest stick move within 0.5 s. The OBC alone
(RX_MSP, armed by the OBC on AUX3, DROP): the OBC repeats its last packet; the times to RXLOSS
and to failsafe stage 2 (the disarm).

Two clocks: the FC's (from the FC time the last fresh command was taken, by its time reply, to
the first frame with the pilot's sticks or the uplink status that reports the change; for a
killed OBC, whose stream breaks off, the FC's timeout as the status reports it) and the host's
(from the write of the last fresh command to the MSP reply that showed the change: an upper
bound, and on a busy host a measure of the host). Built from wftool.verify.preflight's parts.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

from wftool.fc.msp import MspClient
from wftool.fsp.packets import UplinkFlag
from wftool.sitl.radio import SimulatedPilot
from wftool.sitl.session import (
    FSP_UART,
    OBC_ARM,
    PILOT_ARM,
    PILOT_OVERRIDE,
    Motion,
    VirtualFcSession,
)
from wftool.verify.preflight import (
    STICKS,
    FcWatcher,
    Obc,
    Snapshot,
    ms_after,
    near,
    offset_rc,
)

HOLD_S = 0.5
FAILURES = {"closed": "killed", "stopped": "stopped", "stuck": "stuck", "garbage": "garbage"}
Results = dict[str, dict[str, list[float]]]


def roll_is(value: int) -> Callable[[Snapshot], bool]:
    return lambda snapshot: snapshot.rc[0] == value


def fc_ms(obc: Obc, timed_out: bool = False, **what: Any) -> float:
    """`Obc.wait_fc_elapsed_us` in milliseconds; inf if the stream never showed it."""
    us = obc.wait_fc_elapsed_us(timed_out=timed_out, **what)
    return float("inf") if us is None else us / 1000


def record(results: Results, name: str, fc: float, host: float | None) -> None:
    entry = results.setdefault(name, {"fc": [], "host": []})
    entry["fc"].append(fc)
    entry["host"].append(float("inf") if host is None else host)


def session(binary: Path, port_base: int | None, **options: Any) -> VirtualFcSession:
    workdir = Path(tempfile.mkdtemp(prefix="wftool-failsafe-timing-"))
    return VirtualFcSession(
        binary, workdir, motion=Motion(), port_base=port_base, time_reply=True, **options
    )


def safety_pilot(binary: Path, port_base: int | None, trials: int, timeout_ms: int) -> tuple:
    results: Results = {}
    flying_after: dict[str, list[bool]] = {}
    moves: list[int] = []
    with (
        session(binary, port_base, pilot=True, cmd_timeout_ms=timeout_ms) as fc,
        MspClient.open(fc.msp_url) as msp,
    ):
        assert fc.radio is not None
        radio = fc.radio
        pilot = SimulatedPilot(radio, PILOT_OVERRIDE, PILOT_ARM)
        watcher = FcWatcher(msp).start()
        obc = Obc(fc.fsp_url, closing=partial(fc.fc.close_client, FSP_UART)).start()
        try:
            watcher.wait(lambda s: s.can_arm, time.monotonic(), 20.0)
            pilot.hold(armed=True)
            assert watcher.wait(lambda s: s.armed, time.monotonic(), 5.0), "not armed"
            pilot_rc = watcher.latest().rc
            command = (*offset_rc(pilot_rc), 2000, 2000)
            for _ in range(trials):  # switched on before any fresh command (after a timeout)
                pilot.hold(override=False)
                time.sleep(0.3)
                pilot.hold(override=True)
                obc.send_one(command)  # alone: no evidence, never taken
                start = time.monotonic()
                time.sleep(HOLD_S)
                moves.append(
                    max(
                        max(abs(a - b) for a, b in zip(s.rc[:STICKS], pilot_rc[:STICKS]))
                        for s in watcher.since(start)
                    )
                )
            sticks = pilot_rc[:STICKS]
            for failure, label in FAILURES.items():
                name = f"override on, OBC {label}: pilot's sticks back"
                for _ in range(trials):
                    obc.behave("fresh", command)
                    taken = watcher.wait(
                        lambda s: near(s.rc[:STICKS], command[:STICKS]), time.monotonic(), 5.0
                    )
                    assert taken is not None, "the OBC does not fly the sticks"
                    time.sleep(0.3)
                    t0 = obc.behave(failure)
                    back = watcher.wait(lambda s: near(s.rc[:STICKS], sticks), t0, 5.0)
                    closed = failure == "closed"
                    ms = fc_ms(obc, closed, sticks=lambda rc: near(rc, sticks))
                    record(results, name, ms, ms_after(back, t0))
                    time.sleep(HOLD_S)
                    latest = watcher.latest()
                    roll = pilot_rc[0] + 100  # the pilot flies: the FC follows the stick
                    radio.set(roll=roll)
                    follows = watcher.wait(roll_is(roll), time.monotonic(), 2.0)
                    radio.set(roll=pilot_rc[0])
                    watcher.wait(roll_is(pilot_rc[0]), time.monotonic(), 2.0)
                    flying = latest.armed and near(latest.rc[:STICKS], sticks)
                    flying_after.setdefault(name, []).append(flying and follows is not None)
                    obc.behave("stopped")
                    time.sleep(0.1)
        finally:
            obc.stop()
            watcher.stop()
    return results, flying_after, moves


def obc_alone(binary: Path, port_base: int | None, trials: int, timeout_ms: int) -> Results:
    results: Results = {}
    with (
        session(binary, port_base, cmd_timeout_ms=timeout_ms, arm_switch=OBC_ARM) as fc,
        MspClient.open(fc.msp_url) as msp,
    ):
        watcher = FcWatcher(msp).start()
        obc = Obc(fc.fsp_url).start()
        try:
            disarmed = (1400, 1600, 1450, 1000, 1000, 1000)
            armed = (1400, 1600, 1450, 1000, 1850, 1000)
            for _ in range(trials):
                obc.behave("fresh", disarmed)
                assert watcher.wait(lambda s: s.can_arm and not s.armed, time.monotonic(), 20.0)
                obc.behave("fresh", armed)
                assert watcher.wait(lambda s: s.armed, time.monotonic(), 5.0), "the OBC did not arm"
                time.sleep(0.3)
                t0 = obc.behave("stuck")
                lost = watcher.wait(lambda s: s.rx_loss, t0, 5.0)
                stage2 = watcher.wait(lambda s: s.failsafe or not s.armed, t0, 10.0)
                fc_lost = fc_ms(obc, status=lambda s: s.has(UplinkFlag.RX_LOSS))
                fc_stage2 = fc_ms(obc, status=lambda s: not s.has(UplinkFlag.ARMED))
                record(results, "OBC alone, stuck: RXLOSS", fc_lost, ms_after(lost, t0))
                name = "OBC alone, stuck: failsafe stage 2 (DROP: disarmed)"
                record(results, name, fc_stage2, ms_after(stage2, t0))
                obc.behave("stopped")
                time.sleep(0.2)
        finally:
            obc.stop()
            watcher.stop()
    return results


def span(values: list[float]) -> str:
    return f"{min(values):.1f} / {statistics.median(values):.1f} / {max(values):.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--binary", type=Path, default=Path("build/sitl/betaflight_2026.6.1_SITL"))
    parser.add_argument("--port-base", type=int, default=None)
    parser.add_argument("--cmd-timeout-ms", type=int, default=50)
    args = parser.parse_args()
    piloted, flying, moves = safety_pilot(
        args.binary, args.port_base, args.trials, args.cmd_timeout_ms
    )
    alone = obc_alone(args.binary, args.port_base, args.trials, args.cmd_timeout_ms)
    print(f"fsp_cmd_timeout_ms {args.cmd_timeout_ms}, {args.trials} trials each (virtual FC)")
    print("| case | FC clock ms (min / median / max) | host clock ms | |")
    print("|---|---|---|---|")
    print(f"| override on before any fresh command: largest stick move | {span(moves)} µs | | |")
    for results in (piloted, alone):
        for name, clocks in results.items():
            note = ""
            if name in flying:
                ok = flying[name]
                note = f"0.5 s on: armed, the pilot's sticks, following them {sum(ok)}/{len(ok)}"
            print(f"| {name} | {span(clocks['fc'])} | {span(clocks['host'])} | {note} |")


if __name__ == "__main__":
    main()
