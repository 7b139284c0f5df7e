"""`wftool paper timing` end to end on the virtual FC: the paper's board, the files, report.md
with both rows of Table 1 beside the paper's, and the MSP port's baud-rate sweep.

The timings themselves are not judged here (a loaded machine makes them what it makes
them); the statistics are checked against known intervals in tests/analysis/test_timing.py.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from tests.conftest import NEEDS_MATPLOTLIB, run_cli

pytestmark = NEEDS_MATPLOTLIB

FILES = (
    "report.md", "table1.json", "msp-115200/metadata.yaml", "msp-1000000/metadata.yaml",
    "fig2-histograms.png", "fig3-intervals.png",
    "fig4-fsp-spectrum.png", "fig4-accfilter-spectrum.png", "accfilter/accfilter.md",
    "fsp/metadata.yaml", "msp/metadata.yaml",
)  # fmt: skip


def test_paper_timing_on_the_virtual_fc(
    sitl_binary: Path, firmware_tree: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "paper"
    args = ["paper", "timing", "--duration", "3", "--out", str(out), "--binary", str(sitl_binary)]
    code, stdout, stderr = run_cli(capsys, *args, "--project", str(firmware_tree.parent))
    assert code == 0, stderr
    for name in FILES:
        assert (out / name).is_file(), name
    for name in FILES:
        if name.endswith(".png"):
            assert (out / name).read_bytes()[:4] == b"\x89PNG"
    report = (out / "report.md").read_text()
    for section in ("## Set-up", "## MSP: ", "## FSP: ", "## MSP and the MSP port's baud rate",
                    "## The FC's own account", "## Figures"):  # fmt: skip
        assert section in report, section
    for metric in ("expected", "mean", "median", "1st percentile", "99th percentile"):
        assert report.count(f"| {metric} |") == 2  # MSP and FSP
    # the paper's board: the FC's own scheduler runs the 3148 Hz loop, FSP N = 3
    tasks = report.split("# tasks", 1)[1]
    assert re.search(r"\(\s+PID\)\s+314[789]\s", tasks), tasks
    assert "| expected | 0.953 | 0.953 |" in report
    assert "| 115200 | 2083 | 480 |" in report
    assert not (out / "table1.md").exists()  # one report
    data = json.loads((out / "table1.json").read_text())
    assert [r["protocol"] for r in data["recordings"]] == ["FSP", "MSP"]
    assert all(r["stats"]["intervals"] > 0 for r in data["recordings"])
    assert set(data["paper"]) == {"FSP", "MSP"}
    for label in ("FSP  ", "FSP: the paper", "FSP − the paper", "MSP  ", "MSP: the paper"):
        assert label in stdout
    assert "RAW_IMU" in stdout  # what the MSP poll asked and got

    code, _, stderr = run_cli(capsys, *args, "--no-accfilter")
    assert code == 2 and "already holds a run" in stderr


def test_paper_timing_bad_options(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    for extra, message in (
        (["--port", "/dev/null"], "needs both --port"),
        (["--keep-serial-rate", "--binary", __file__], "--keep-serial-rate is for a board"),
    ):
        code, stdout, stderr = run_cli(capsys, "paper", "timing", "--out", str(tmp_path), *extra)
        assert code == 2, stdout + stderr
        assert len(stderr.strip().splitlines()) == 1 and message in stderr, stderr
