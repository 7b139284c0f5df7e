"""`wftool preflight` on the command line: bad options refused in one line before anything is
touched; on the virtual FC as `configure fsp` leaves it, it passes (both set-ups), and it
fails naming the lines where the board hands the sticks back too late."""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import pytest

from tests.conftest import run_cli
from wftool.preflight.run import STALLED
from wftool.preflight.scenarios import SCENARIOS


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (("--sitl", "--limit-ms", "nan"), "--limit-ms must be a number from 1 to 1000 ms, not nan"),
        (("--sitl", "--limit-ms", "inf"), "--limit-ms"),
        (("--sitl", "--config", __file__, "--obc-only"), "--config is the configuration"),
        (("--obc-only", "--fsp-port", "socket://127.0.0.1:1"), "--obc-only: for --sitl"),
        (("--sitl", "--port", "socket://127.0.0.1:1"), "--sitl runs its own virtual FC"),
        (("--port", "socket://127.0.0.1:1"), "give the OBC's FSP port"),
        (("--fsp-port", "socket://nohost"), "--fsp-port socket://nohost"),
    ],
)
def test_bad_options_are_one_line_and_exit_2(
    capsys: pytest.CaptureFixture[str], args: tuple[str, ...], said: str
) -> None:
    code, out, err = run_cli(capsys, "preflight", *args)
    assert code == 2 and out == ""
    lines = [line for line in err.splitlines() if line.strip()]
    assert any(said in line for line in lines), err
    assert "Traceback" not in err


@pytest.mark.parametrize("setup", [(), ("--obc-only", "--arm")], ids=["safety-pilot", "obc-alone"])
def test_what_configure_fsp_leaves_passes(
    sitl_binary: Path,
    capsys: pytest.CaptureFixture[str],
    setup: tuple[str, ...],
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    code, out, err = run_cli(capsys, "preflight", "--sitl", "--binary", str(sitl_binary), *setup)
    assert code == 0, out + err
    assert list(tmp_path.iterdir()) == []  # the virtual FC's scratch directory is gone
    assert "configured by `configure fsp --uart 2" in out
    [verdict] = [line for line in out.splitlines() if " lines passed" in line]
    passed, total = map(int, re.match(r"(\d+) of (\d+) lines passed", verdict).groups())
    assert "failed" not in verdict
    unchecked = verdict.partition(" not checked: ")[2].split("; ") if passed < total else []
    titles = {scenario.title for scenario in SCENARIOS}
    stalled = [name for name in unchecked if name in titles]  # a loaded host: said, not passed
    assert not stalled or STALLED in out
    without_arm = [name for name in unchecked if name not in titles]
    if setup:
        assert without_arm == [] and total >= 34  # stage 2 and the rest, armed
    else:  # without --arm: said, not passed
        assert without_arm == ["the FC stays armed through the OBC's failures"]


def test_stale_commands_held_too_long_fail_naming_the_lines(
    sitl_binary: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """fsp_cmd_timeout_ms 150: over the 100 ms limit, and the pilot's sticks come back only
    then — the setting's line and every handover line fail, and the error names them."""
    code, out, err = run_cli(
        capsys, "preflight", "--sitl", "--binary", str(sitl_binary), "--cmd-timeout-ms", "150",
        "--scenario", "stuck", "--scenario", "closed",
    )  # fmt: skip
    assert code == 1, out + err
    [error] = [line for line in err.splitlines() if line.startswith("error:")]
    assert error.startswith("error: preflight: ") and "failed: fsp_cmd_timeout_ms;" in error
    assert "OBC stuck (repeats its last packet): the pilot's sticks back" in error
    assert "OBC killed (port closed): the pilot's sticks back" in error  # by the sticks
