"""How the virtual FC hands control back, and to whom: `wftool preflight`'s own scenarios, each
played N times in a row, with min / median / max of every figure they measure.

    .venv/bin/python scripts/failsafe_timing.py [--trials 5] [--binary SITL] [--port-base N]
        [--cmd-timeout-ms 50] [--setup pilot|alone] [--scenario KEY ...]

One virtual FC per set-up, configured by `configure fsp`'s planner (a safety pilot on AUX2,
or the OBC alone with DROP), armed (props are no question here): the scenarios of
`wftool.preflight.scenarios`, nothing else. Times are by the FC clock where the FC gives one
(its time replies, E2; the frames' sample times; the uplink statuses' send times, E3), else
from the host's write to the MSP reply that showed it (an upper bound; the column says which).
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from pathlib import Path

from wftool.fc.fsp_setup import ObcOnly, SafetyPilot
from wftool.preflight.report import Line, Report
from wftool.preflight.scenarios import BY_KEY
from wftool.preflight.virtual import on_virtual_fc
from wftool.stats import median

SETUPS = {"pilot": SafetyPilot(), "alone": ObcOnly("drop")}


def span(values: list[float]) -> str:
    return f"{min(values):g} / {median(values):g} / {max(values):g}"


def table(setup: str, report: Report) -> list[str]:
    """A row per line of the scenarios: passed in how many trials, the figure's spread."""
    lines: dict[str, list[Line]] = defaultdict(list)
    for line in report.lines:
        lines[line.name].append(line)
    rows = []
    for name, runs in lines.items():
        values = [line.value for line in runs if line.value is not None]
        figure = f"{span(values)} {runs[0].unit}" if values else "—"
        clocks = "/".join(sorted({line.clock for line in runs if line.clock}))
        passed = sum(line.passed for line in runs)
        rows.append(f"| {setup} | {name} | {figure} | {clocks} | {passed}/{len(runs)} |")
    return rows


def failures(setup: str, report: Report) -> list[str]:
    """What each failed line measured (the table counts them)."""
    return [f"{setup}: FAIL {line.name}: {line.measured}" for line in report.failed]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--binary", type=Path, default=Path("build/sitl/betaflight_2026.6.1_SITL"))
    parser.add_argument("--port-base", type=int, default=None)
    parser.add_argument("--cmd-timeout-ms", type=int, default=50)
    parser.add_argument("--setup", choices=list(SETUPS), action="append")
    parser.add_argument("--scenario", choices=list(BY_KEY), action="append")
    args = parser.parse_args()
    rows: list[str] = []
    failed: list[str] = []
    for setup in args.setup or list(SETUPS):
        with on_virtual_fc(
            args.binary,
            control=SETUPS[setup],
            cmd_timeout_ms=args.cmd_timeout_ms,
            port_base=args.port_base,
            arm=True,
            only=args.scenario,
            trials=args.trials,
            log=print,
        ) as preflight:
            report = preflight.run()
        rows += table(setup, report)
        failed += failures(setup, report)
    print(f"\nfsp_cmd_timeout_ms {args.cmd_timeout_ms}, {args.trials} trials each (virtual FC)")
    print("| set-up | line | min / median / max | clock | passed |")
    print("|---|---|---|---|---|")
    print("\n".join(rows))
    print("\n".join(failed))


if __name__ == "__main__":
    main()
