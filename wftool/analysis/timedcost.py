"""`wftool analyze timed`: what the uplink's command path — timed commands (E4) and who flies
(spec §15) — costs the SPEEDYBEEF7V3, counted as the accelerometer filter's cost is: the
series' own code built for the Cortex-M7 and run in Unicorn (`m7`), per PID iteration, per
FSP task run and per command, and its RAM (docs/analysis.md).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from wftool import __version__
from wftool.analysis import sources
from wftool.analysis.harness import HARNESS_DIR, HarnessError
from wftool.analysis.m7 import CLOCK_HZ, M7_FLAGS, CallCost, M7Harness, build_image

QUEUE_HARNESS = HARNESS_DIR / "fsp_queue_harness.c"
ENTRY = "queueHarnessSetup"
PID_RATES_HZ = (8000.0, 3148.0)
"""The PID loops a cost is put beside: the SITL's and the paper's board's (BMI270)."""
CHECKED_FUNCTION = "fspCommandGateTakeEffect"
"""Straight-line code: it must execute exactly as many instructions as its disassembly has."""
T0_US = 10_000_000
LEAD_US = 5000
TIMEOUT_US = 50_000
"""The harness's fsp_cmd_timeout_ms (the default)."""


@dataclass(frozen=True)
class Case:
    """One measured call: what the firmware runs, in which state."""

    name: str
    where: str
    """PID loop (each iteration), RX check (each gyro iteration), FSP task (per command)."""
    instructions: int
    cycles: int

    @property
    def us(self) -> float:
        return self.cycles / CLOCK_HZ * 1e6

    def percent_of(self, rate_hz: float) -> float:
        """Its share of one iteration of a loop at `rate_hz`."""
        return 100.0 * self.us * rate_hz / 1e6


@dataclass(frozen=True)
class TimedCost:
    cases: tuple[Case, ...]
    queue_bytes: int
    """sizeof(fspQueue_t): the commands waiting, the reports waiting, the counts."""
    authority_bytes: int
    """sizeof(fspAuthority_t): the queue, the freshness gate and who flies."""
    check: dict[str, Any] = field(default_factory=dict)
    """The emulator's count checked against a straight-line function's disassembly."""
    provenance: dict[str, object] = field(default_factory=dict)


def measure(m7: M7Harness) -> tuple[Case, ...]:
    """Each case from a state prepared by calls that are not counted; the state after each
    is checked, so a harness that does not reach the path it names fails here."""
    cases = []
    pid, rx, task = "PID loop", "RX check", "FSP task"

    def case(name: str, where: str, cost: CallCost) -> None:
        cases.append(Case(name, where, cost.instructions, cost.cycles))

    def take(seq: int, at_us: int) -> None:
        m7.call("queueHarnessTake", seq, at_us % 2**32, T0_US)
        if m7.result() not in (0, 1):  # on time or late: queued
            raise HarnessError(f"the harness did not queue command {seq}")

    def expect_queued(count: int, what: str) -> None:
        m7.call("queueHarnessQueued")
        if m7.result() != count:
            raise HarnessError(f"{what}: {m7.result()} commands queued, not {count}")

    def loop(now_us: int) -> CallCost:
        return m7.call("queueHarnessPidLoop", now_us)

    m7.call(ENTRY, T0_US)
    case("nothing queued", pid, loop(T0_US + 125))
    take(3, T0_US + LEAD_US)
    case("a command queued, not due", pid, loop(T0_US + 125))
    expect_queued(1, "not due")
    case("a command due: applied", pid, loop(T0_US + LEAD_US + 60))
    expect_queued(0, "due")
    m7.call(ENTRY, T0_US)
    for seq in range(3, 3 + 8):
        take(seq, T0_US + LEAD_US + 200 * (seq - 3))
    case("the queue full, the first due: applied", pid, loop(T0_US + LEAD_US + 1))
    expect_queued(7, "full")
    m7.call(ENTRY, T0_US)
    take(3, T0_US + LEAD_US)
    take(4, T0_US + LEAD_US + 50)
    case("two due at one iteration: one applied, one superseded", pid, loop(T0_US + LEAD_US + 100))
    expect_queued(0, "two due")
    case("the receiver's signal delay", rx, m7.call("queueHarnessSignalDelay"))

    m7.call(ENTRY, T0_US)
    case(
        "a run, nothing decoded (who flies, the timeouts)",
        task,
        m7.call("harnessFspRun", 0, T0_US + 1000),
    )
    m7.call("queueHarnessDecode", 3, 0)
    case(
        "a run, a fresh immediate command: to the receiver",
        task,
        m7.call("harnessFspRun", 1, T0_US + 2000),
    )
    expect_queued(0, "immediate")
    m7.call("queueHarnessDecode", 4, T0_US + 2000 + LEAD_US)
    case("a run, a fresh timed command: queued", task, m7.call("harnessFspRun", 1, T0_US + 3000))
    expect_queued(1, "taken")
    loop(T0_US + 2000 + LEAD_US)
    case("pop a report", task, m7.call("queueHarnessPopReport"))
    wire = m7.address("harnessScratch")
    case("encode and frame a report", task, m7.call("queueHarnessEncodeReport", wire))
    case("encode and frame an uplink status", task, m7.call("queueHarnessEncodeStatus", wire))
    return tuple(cases)


def reference_check(m7: M7Harness) -> dict[str, Any]:
    """The instructions a straight-line function executes against its disassembly."""
    gate = m7.address("harnessAuthority")  # the gate is its first member
    executed = m7.call(CHECKED_FUNCTION, gate, T0_US).instructions
    m7.call(ENTRY, T0_US)  # the gate as it was
    return {
        "function": CHECKED_FUNCTION,
        "executed_instructions": executed,
        "disassembly_instructions": m7.image.straight_line_length(CHECKED_FUNCTION),
        "gcc": m7.image.gcc_version,
        "clock_hz": CLOCK_HZ,
    }


def run(
    project_dir: Path | None, progress: Callable[[str], None] = lambda message: None
) -> TimedCost:
    """`wftool analyze timed` as a call: the series' queue (betaflight/ of the project,
    fetched and patched if needed) built for the Cortex-M7 and measured."""
    tree = sources.patched_tree(project_dir)
    with tempfile.TemporaryDirectory(prefix="wftool-timed-") as scratch:
        queue_sources = sources.queue_sources(tree, Path(scratch))
        gcc = sources.arm_gcc(project_dir)
        progress(f"building the queue for the Cortex-M7 with {gcc}")
        image = build_image(queue_sources, Path(scratch) / "m7", gcc, QUEUE_HARNESS, ENTRY)
        m7 = M7Harness(image)
        m7.call("queueHarnessQueueSize")
        queue_bytes = m7.result()
        m7.call("queueHarnessAuthoritySize")
        authority_bytes = m7.result()
        return TimedCost(
            cases=measure(m7),
            queue_bytes=queue_bytes,
            authority_bytes=authority_bytes,
            check=reference_check(m7),
            provenance={
                "wftool": __version__,
                "betaflight revision": queue_sources.revision,
                "sources": ", ".join(str(p.relative_to(tree)) for p in queue_sources.sources),
                "sources sha256": queue_sources.sha256,
                "m7 flags": " ".join([*M7_FLAGS, *(f"-D{d}" for d in queue_sources.defines)]),
                "m7 compiler": f"{gcc} {image.gcc_version}",
            },
        )
