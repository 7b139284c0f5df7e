"""Backups against the real SITL: only a `diff all` proven complete becomes a backup.

The faults (a reply pausing after a `# ` line, or losing its rest) are injected by a
faulty transport around the real link (tests/fc/faulty_transport.py); what the FC sends
is Betaflight's own output.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from tests.conftest import answers_msp
from tests.fc.faulty_transport import InjectFaults
from wftool.errors import ProtocolError
from wftool.fc.backup import diff_problems
from wftool.fc.cli_session import CliSession
from wftool.fc.msp import MspClient
from wftool.fc.params import configuration_session
from wftool.sitl.process import VirtualFC

FEATURE_SECTION = 5
"""`diff all` comment lines: version, the version line, batch, defaults, then `# feature`."""


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
    with configuration_session(virtual_fc, tmp_path) as (session, _msp, backup):
        session.exit()
    virtual_fc.wait_back()
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
    diff = _diff_all(virtual_fc)
    assert diff_problems(diff, fc) == []

    lines = diff.splitlines()
    without_profile_2 = "\n".join(line for line in lines if line != "profile 2")
    assert diff_problems(without_profile_2, fc) == [
        "the profiles it lists are not 0, 1, … in turn: [0, 1, 3, 0]"
    ]
    cut = "\n".join(lines[: lines.index("# restore original profile selection")])
    assert diff_problems(cut, fc) == [
        "`# restore original profile selection` is missing or out of place",
        "`# restore original rateprofile selection` is missing or out of place",
        "`# save configuration` is missing or out of place",
        "the rateprofiles it lists are not 0, 1, … in turn: []",
        "it ends with 'profile 3', not `save`",
    ]
    other_build = dataclasses.replace(fc, build=dataclasses.replace(fc.build, time="00:00:00"))
    assert diff_problems(diff, other_build) == [
        "its version line (time) is not what the FC reports over MSP"
    ]
