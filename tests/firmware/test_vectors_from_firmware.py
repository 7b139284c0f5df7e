"""spec/vectors' E2 time reply, E3 uplink status and E4 command report vectors are the
firmware encoder's own output, byte for byte.

The series' unit test writes them when FSP_VECTORS_DIR is set; the Python decoder is checked
against these files (tests/fsp/test_vectors.py), so it is checked against the C encoder.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from wftool.firmware.project import Project
from wftool.firmware.unittests import run_unit_tests

pytestmark = pytest.mark.slow

FIRMWARE_VECTORS = (
    "time_reply.bin",
    "time_reply.expected.json",
    "time_reply_stream.bin",
    "time_reply_stream.expected.json",
    "uplink_status_v2.bin",
    "uplink_status_v2.expected.json",
    "uplink_status_v2_stream.bin",
    "uplink_status_v2_stream.expected.json",
    "command_report.bin",
    "command_report.expected.json",
    "command_report_stream.bin",
    "command_report_stream.expected.json",
)
WRITERS = "*.WritesConformanceVectors"


def test_e2_e3_e4_vectors_are_the_firmware_encoders_output(
    fresh_clone: Project, sitl_build, vectors_dir: Path, tmp_path: Path
) -> None:
    if shutil.which("clang") is None:
        pytest.skip("clang not installed (Betaflight's unit tests need it)")
    [run] = run_unit_tests(fresh_clone, ["test_fsp_unittest"])
    assert run.passed, run.output[-2000:]
    binary = fresh_clone.tree / "obj" / "test" / "fsp_unittest" / "fsp_unittest"
    subprocess.run(
        [str(binary), f"--gtest_filter={WRITERS}"],
        env={**os.environ, "FSP_VECTORS_DIR": str(tmp_path)},
        cwd=tmp_path,
        check=True,
        capture_output=True,
    )
    for name in FIRMWARE_VECTORS:
        assert (tmp_path / name).read_bytes() == (vectors_dir / name).read_bytes(), name
