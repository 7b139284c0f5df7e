"""Backups against the real SITL: only a `diff all` proven complete becomes a backup.

The faults (a reply pausing after a `# ` line, or losing its rest) are injected by a
faulty transport around the real link (tests/fc/faulty_transport.py); what the FC sends
is Betaflight's own output.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from tests.conftest import answers_msp, fc_settings
from tests.fc.faulty_transport import InjectFaults
from wftool.errors import ProtocolError
from wftool.fc.backup import diff_problems, feature_mask_of, write_backup
from wftool.fc.cli_session import CliSession
from wftool.fc.msp import MspClient
from wftool.fc.params import apply_plan, configuration_session, take_backup
from wftool.fc.plan import parse_cli_script
from wftool.fc.versions import version_of
from wftool.sitl.process import VirtualFC

FEATURE_SECTION = 5
"""`diff all` comment lines: version, the version line, batch, defaults, then `# feature`."""
MSP_SET_BOARD_INFO = 248


def _diff_all(fc: VirtualFC) -> str:
    session = CliSession.open(fc.url)
    try:
        return session.diff_all()
    finally:
        session.exit()
        fc.wait_back()


def test_a_diff_all_pausing_after_a_comment_line_is_backed_up_whole(
    virtual_fc: VirtualFC, tmp_path: Path, inject_faults: InjectFaults
) -> None:
    reference = _diff_all(virtual_fc)
    faults = inject_faults(stall_after_comment=FEATURE_SECTION, stall_s=0.3)
    with configuration_session(virtual_fc, tmp_path) as connected:
        connected.cli.exit()
    virtual_fc.wait_back()
    backup = connected.backup
    assert faults.fired == ["`diff all` paused 0.3 s after b'signature \\r\\n\\r\\n# '"]
    _title, mask, diff = backup.read_text().split("\n", 2)
    assert mask.startswith("# wftool: feature mask 0x")
    assert diff == reference + "\n"


def test_a_diff_all_that_loses_its_end_is_no_backup_and_the_fc_leaves_its_cli(
    virtual_fc: VirtualFC, tmp_path: Path, inject_faults: InjectFaults
) -> None:
    faults = inject_faults(stall_after_comment=FEATURE_SECTION, stall_s=None)
    with (
        pytest.raises(ProtocolError, match=r"`diff all` output .* stopped after 'signature'"),
        configuration_session(virtual_fc, tmp_path / "backups"),
    ):
        pytest.fail("a session without a complete backup must not start")
    assert faults.fired == ["`diff all` lost the rest after b'signature \\r\\n\\r\\n# '"]
    assert list((tmp_path / "backups").iterdir()) == []
    assert answers_msp(virtual_fc)  # out of its CLI (it left with `exit`: one more start)
    assert virtual_fc.starts == 2


def test_only_a_whole_diff_of_this_fc_passes(virtual_fc: VirtualFC) -> None:
    with MspClient.open(virtual_fc.url) as msp:
        fc = msp.identify()
    version = version_of(fc)
    diff = _diff_all(virtual_fc)
    assert diff_problems(diff, fc, version) == []

    lines = diff.splitlines()
    without_profile_2 = "\n".join(line for line in lines if line != "profile 2")
    assert diff_problems(without_profile_2, fc, version) == [
        "the profiles it lists are not 0, 1, … in turn: [0, 1, 3, 0]"
    ]
    cut = "\n".join(lines[: lines.index("# restore original profile selection")])
    kinds = version.profile_kinds  # profile, rateprofile (and battery_profile from 2026.6)
    assert diff_problems(cut, fc, version) == [
        *(f"`# restore original {kind} selection` is missing or out of place" for kind in kinds),
        "`# save configuration` is missing or out of place",
        *(f"the {kind}s it lists are not 0, 1, … in turn: []" for kind in kinds[1:]),
        "it ends with 'profile 3', not `save`",
    ]
    other_build = dataclasses.replace(fc, build=dataclasses.replace(fc.build, time="00:00:00"))
    assert diff_problems(diff, other_build, version) == [
        "its version line (time) is not what the FC reports over MSP"
    ]


def test_a_board_name_puts_no_line_into_a_backup_or_a_restore(
    virtual_fc: VirtualFC, tmp_path: Path
) -> None:
    # Betaflight takes any bytes as a board name (MSP_SET_BOARD_INFO, up to 20) and prints
    # them as they are: in `diff all` (`board_name …`) and in wftool's header.
    rate = fc_settings(virtual_fc, "fsp_rate_hz")
    name = b"\nset fsp_rate_hz=50#"
    with MspClient.open(virtual_fc.url) as msp:
        msp.request(MSP_SET_BOARD_INFO, bytes([len(name)]) + name + b"\x00")
        mask = msp.features()
    backup = take_backup(virtual_fc, tmp_path)
    restored = apply_plan(virtual_fc, parse_cli_script(backup.read_text(), backup.name), tmp_path)
    assert "fsp_rate_hz" not in [row.name for row in restored.rows]
    assert fc_settings(virtual_fc, "fsp_rate_hz") == rate
    lines = backup.read_text().splitlines()
    assert lines[0].startswith("# wftool backup of \\nset fsp_rate_hz=50# (SITL) at ")
    assert lines[2] == "# version"
    assert "# board_name \\nset fsp_rate_hz=50# (not replayed: the CLI takes printable ASCII)" in (
        lines
    )
    assert not any("fsp_rate_hz" in line for line in lines[1:] if not line.startswith("#"))
    assert feature_mask_of(backup.read_text()) == mask


def test_a_board_name_forges_no_header_line(virtual_fc: VirtualFC, tmp_path: Path) -> None:
    # An FC that reports a longer name than Betaflight keeps, and prints it in its dump.
    with MspClient.open(virtual_fc.url) as msp:
        fc, mask = msp.identify(), msp.features()
    diff = _diff_all(virtual_fc)
    name = "X\r\n# wftool: feature mask 0x00000001 (forged)\nset fsp_rate_hz = 50#"
    liar = dataclasses.replace(fc, board=dataclasses.replace(fc.board, board_name=name))
    printed = diff.replace("defaults nosave\n", f"defaults nosave\n\nboard_name {name}\n", 1)
    text = write_backup(
        tmp_path, liar, version_of(fc), mask, printed.replace("\r\n", "\n")
    ).read_text()
    assert feature_mask_of(text) == mask
    commands = [command.text for command in parse_cli_script(text, "b.txt").commands]
    assert not [command for command in commands if "fsp_rate_hz" in command]
    assert text.splitlines()[0].startswith(
        "# wftool backup of X\\r\\n# wftool: feature mask 0x00000001 (forged)\\nset "
    )
    with pytest.raises(ProtocolError, match=r"board_name .* its CLI cannot carry"):
        write_backup(
            tmp_path, liar, version_of(fc), mask, diff
        )  # the dump does not show the name reported
