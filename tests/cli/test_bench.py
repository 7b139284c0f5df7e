"""`wftool bench decode` runs every path over the same stream and prints them side by side.

Figures are not judged here (benchmarks print, tests do not time); what is checked is that
every path ran over the whole stream and that the FSP paths ended with the same totals.
"""

from __future__ import annotations

import pytest

from tests.conftest import run_cli

pytest.importorskip("numpy", reason="bench decode needs wftool[analysis]")
pytest.importorskip("pymavlink", reason="bench decode needs wftool[mavlink]")


def test_bench_decode_prints_every_path_and_their_agreement(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, err = run_cli(capsys, "bench", "decode", "--minutes", "0.02", "--repeat", "2")
    assert (code, err) == (0, "")
    assert "1,260 frames" in out  # 0.02 min at 525 packets/s, two frames each
    for path in ("per-frame API", "columnar", "OBC clock alignment", "HIGHRES_IMU"):
        assert path in out
    assert "columnar and per-frame totals agree: yes (630 packets, 0 rejected" in out
    assert "OBC times identical to the per-frame decoder's: yes" in out
    assert "every packet kept" in out and "of which the columns themselves" in out


def test_bench_record_prints_both_formats_their_read_back_and_both_writers_stalls(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code, out, err = run_cli(
        capsys, "bench", "record", "--seconds", "2", "--repeat", "1", "--stream", "realistic"
    )
    assert (code, err) == (0, "")
    assert "recording the realistic stream" in out and "sweeping" not in out
    formats, stalls = out.split("reference (decode + monitor")
    rows = {line.split()[1]: line for line in formats.splitlines() if line.startswith("│ ")}
    assert set(rows) == {"ros2", "json"}
    assert "size 1.00x, CPU 1.00x" in rows["json"]  # the reference row
    assert "needs wftool[analysis]" not in out  # columns read back (NumPy is installed)
    writers = {line.split("│")[1].strip(): line.split("│")[2:-1] for line in
               stalls.splitlines() if line.startswith("│ ")}  # fmt: skip
    assert set(writers) == {"writer process", "in-process McapFile"}
    reads, chunks = (int(cell.replace(",", "")) for cell in writers["writer process"][:2])
    assert (
        reads > 1000
        and chunks >= 1
        and writers["in-process McapFile"][:2] == writers["writer process"][:2]
    )  # the same messages, the same chunks


@pytest.mark.usefixtures("ros2_env")
def test_bench_ros2_prints_both_readers_the_hop_and_the_subscriber(
    capsys: pytest.CaptureFixture[str], sitl_binary
) -> None:
    binary = str(sitl_binary)
    code, out, err = run_cli(capsys, "bench", "ros2", "--seconds", "3", "--binary", binary)
    assert (code, err) == (0, "")
    assert "bench ros2: 3 s per reader at fsp_rate_hz 1100" in out
    rows = [line for line in out.splitlines() if "FspReader" in line or "subscriber  " in line]
    assert len(rows) == 2, out
    assert "the node's hop (its read → the subscriber's callback), per frame: P50" in out
    assert " published while it measured (0 lost)" in out
    assert "commands at 50 Hz from the subscriber's process meanwhile: " in out
