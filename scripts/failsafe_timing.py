"""How fast the virtual FC fails safe when its OBC fails: min / median / max over trials.

    .venv/bin/python scripts/failsafe_timing.py [--trials 5] [--binary SITL] [--port-base N]
        [--cmd-timeout-ms 50]

Safety pilot (the simulated radio the receiver, armed, MSP OVERRIDE on): the OBC flies the
sticks with fresh commands at 100 Hz, then is killed (port closed), stops, repeats its last
packet or sends garbage; measured is the time from the write of its last fresh command to the
MSP_RC reply that shows all four of the pilot's stick values again, and whether the FC is still
armed 0.5 s later. Switched on before any fresh command: the largest stick move within 0.5 s.
The OBC alone (RX_MSP, armed by the OBC on AUX3, DROP): the OBC repeats its last packet; the
times to RXLOSS and to failsafe stage 2 (the disarm). Built from wftool.verify.preflight's
parts; every time is an upper bound (the reply that showed it).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

from wftool.fc.msp import MspClient
from wftool.sitl.radio import SimulatedPilot
from wftool.sitl.session import OBC_ARM, PILOT_ARM, PILOT_OVERRIDE, Motion, VirtualFcSession
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
FAILURES = ("closed", "stopped", "stuck", "garbage")
NAMES = {"closed": "killed", "stopped": "stopped", "stuck": "stuck", "garbage": "garbage"}


def roll_is(value: int) -> Callable[[Snapshot], bool]:
    return lambda snapshot: snapshot.rc[0] == value


def safety_pilot(binary: Path, port_base: int | None, trials: int, timeout_ms: int) -> dict:
    results: dict[str, list[float]] = {}
    armed_after: dict[str, list[bool]] = {}
    with tempfile.TemporaryDirectory() as workdir, VirtualFcSession(
        binary, Path(workdir), motion=Motion(), port_base=port_base, pilot=True,
        cmd_timeout_ms=timeout_ms,
    ) as session, MspClient.open(session.msp_url) as msp:  # fmt: skip
        assert session.radio is not None
        pilot = SimulatedPilot(session.radio, PILOT_OVERRIDE, PILOT_ARM)
        watcher = FcWatcher(msp).start()
        obc = Obc(session.fsp_url).start()
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
                moved = max(
                    max(abs(a - b) for a, b in zip(s.rc[:STICKS], pilot_rc[:STICKS]))
                    for s in watcher.since(start)
                )
                results.setdefault("override on before any command: largest move (µs)", []).append(
                    moved
                )
            for failure in FAILURES:
                for _ in range(trials):
                    obc.behave("fresh", command)
                    assert watcher.wait(
                        lambda s: near(s.rc[:STICKS], command[:STICKS]), time.monotonic(), 2.0
                    )
                    time.sleep(0.3)
                    t0 = obc.behave(failure)
                    back = watcher.wait(lambda s: near(s.rc[:STICKS], pilot_rc[:STICKS]), t0, 2.0)
                    time.sleep(HOLD_S)
                    latest = watcher.latest()
                    roll = pilot_rc[0] + 100  # the pilot flies: the FC follows the stick
                    session.radio.set(roll=roll)
                    follows = watcher.wait(roll_is(roll), time.monotonic(), 1.0)
                    session.radio.set(roll=pilot_rc[0])
                    watcher.wait(lambda s: s.rc[0] == pilot_rc[0], time.monotonic(), 1.0)
                    ms = ms_after(back, t0)
                    name = f"override on, OBC {NAMES[failure]}: pilot's sticks back (ms)"
                    results.setdefault(name, []).append(float("inf") if ms is None else ms)
                    flying = latest.armed and near(latest.rc[:STICKS], pilot_rc[:STICKS])
                    armed_after.setdefault(name, []).append(flying and follows is not None)
                    obc.behave("stopped")
                    time.sleep(0.1)
        finally:
            obc.stop()
            watcher.stop()
    return {"times": results, "armed": armed_after}


def obc_alone(binary: Path, port_base: int | None, trials: int, timeout_ms: int) -> dict:
    results: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory() as workdir, VirtualFcSession(
        binary, Path(workdir), motion=Motion(), port_base=port_base, pilot=False,
        cmd_timeout_ms=timeout_ms, arm_switch=OBC_ARM,
    ) as session, MspClient.open(session.msp_url) as msp:  # fmt: skip
        watcher = FcWatcher(msp).start()
        obc = Obc(session.fsp_url).start()
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
                lost = watcher.wait(lambda s: s.rx_loss, t0, 2.0)
                stage2 = watcher.wait(lambda s: s.failsafe or not s.armed, t0, 5.0)
                for name, snapshot in (
                    ("OBC alone, stuck: RXLOSS (ms)", lost),
                    ("OBC alone, stuck: failsafe stage 2, disarmed (ms)", stage2),
                ):
                    ms = ms_after(snapshot, t0)
                    results.setdefault(name, []).append(float("inf") if ms is None else ms)
                obc.behave("stopped")
                time.sleep(0.2)
        finally:
            obc.stop()
            watcher.stop()
    return {"times": results, "armed": {}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--binary", type=Path, default=Path("build/sitl/betaflight_2025.12.5_SITL"))
    parser.add_argument("--port-base", type=int, default=None)
    parser.add_argument("--cmd-timeout-ms", type=int, default=50)
    args = parser.parse_args()
    runs = [
        safety_pilot(args.binary, args.port_base, args.trials, args.cmd_timeout_ms),
        obc_alone(args.binary, args.port_base, args.trials, args.cmd_timeout_ms),
    ]
    print(f"fsp_cmd_timeout_ms {args.cmd_timeout_ms}, {args.trials} trials each (virtual FC)")
    print("| case | min | median | max | |")
    print("|---|---:|---:|---:|---|")
    for run in runs:
        for name, values in run["times"].items():
            note = ""
            if name in run["armed"]:
                ok = run["armed"][name]
                note = f"0.5 s on armed, the pilot's sticks, following them: {sum(ok)}/{len(ok)}"
            print(
                f"| {name} | {min(values):.1f} | {statistics.median(values):.1f} | "
                f"{max(values):.1f} | {note} |"
            )


if __name__ == "__main__":
    main()
