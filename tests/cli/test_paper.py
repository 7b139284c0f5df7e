"""`wftool paper timing` end to end on the virtual FC: the files and both rows of Table 1.

The timings themselves are not judged here (a loaded machine makes them what it makes
them); the statistics are checked against known intervals in tests/analysis/test_timing.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.conftest import run_cli

pytest.importorskip("matplotlib", reason="needs the analysis extra (Matplotlib)")
pytestmark = pytest.mark.slow

FILES = (
    "table1.md", "table1.json", "fig2-histograms.png", "fig3-intervals.png",
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
    table = (out / "table1.md").read_text()
    for row in ("| FSP |", "| FSP: the paper |", "| MSP |", "| MSP: the paper |"):
        assert row in table
    data = json.loads((out / "table1.json").read_text())
    assert [r["protocol"] for r in data["recordings"]] == ["FSP", "MSP"]
    assert all(r["stats"]["intervals"] > 0 for r in data["recordings"])
    assert set(data["paper"]) == {"FSP", "MSP"}
    for label in ("FSP  ", "FSP: the paper", "MSP  ", "MSP: the paper", "not available"):
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
