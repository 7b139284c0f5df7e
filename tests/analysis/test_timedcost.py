"""The timed-command queue on the emulated Cortex-M7: each path reached, counts checked."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from wftool.firmware.project import Project

pytestmark = pytest.mark.slow  # the fixtures fetch the Betaflight tree


@pytest.fixture(scope="module")
def queue_m7(fresh_clone: Project, filter_tree: Path, tmp_path_factory: pytest.TempPathFactory):
    pytest.importorskip("unicorn", reason="needs the analysis extra (Unicorn)")
    from wftool.analysis import timedcost
    from wftool.analysis.m7 import M7Harness, build_image
    from wftool.analysis.sources import arm_gcc, queue_sources
    from wftool.errors import ToolchainError

    try:
        gcc = arm_gcc(fresh_clone.root)
    except ToolchainError as exc:
        pytest.skip(f"no ARM toolchain: {exc}")
    scratch = tmp_path_factory.mktemp("queue")
    sources = queue_sources(filter_tree, scratch)
    image = build_image(sources, scratch / "m7", gcc, timedcost.QUEUE_HARNESS, timedcost.ENTRY)
    return M7Harness(image)


def test_the_pid_loop_pays_a_compare_until_a_command_is_due(queue_m7) -> None:
    from wftool.analysis.timedcost import measure, reference_check

    check = reference_check(queue_m7)
    assert check["executed_instructions"] == check["disassembly_instructions"] > 2
    cases = {case.name: case for case in measure(queue_m7)}  # raises if a path is not reached
    empty = cases["nothing queued"]
    waiting = cases["a command queued, not due"]
    applied = cases["a command due: applied"]
    assert empty.where == waiting.where == applied.where == "PID loop"
    assert empty.instructions <= 10 and waiting.instructions <= 20
    assert applied.instructions > 10 * waiting.instructions  # the hand-over to the receiver
    two = cases["two due at one iteration: one applied, one superseded"]
    assert two.instructions > applied.instructions
    assert empty.us == pytest.approx(empty.cycles / 216.0)


def test_the_queue_takes_its_size_in_ram(queue_m7) -> None:
    queue_m7.call("queueHarnessQueueSize")
    # 8 commands of 32 bytes (each with its late flag, padded: 36) and 8 reports of 32
    # bytes, the counts and the indices
    queue_bytes = queue_m7.result()
    assert queue_bytes == 8 * 36 + 8 * 32 + 6 * 2 + 4
    queue_m7.call("queueHarnessAuthoritySize")
    assert queue_m7.result() > queue_bytes  # the queue lives in the authority, with the gate


def test_an_fsp_task_run_pays_for_who_flies_and_hands_commands_over(queue_m7) -> None:
    from wftool.analysis.timedcost import measure

    cases = {case.name: case for case in measure(queue_m7)}  # raises if a path is not reached
    idle = cases["a run, nothing decoded (who flies, the timeouts)"]
    immediate = cases["a run, a fresh immediate command: to the receiver"]
    timed = cases["a run, a fresh timed command: queued"]
    assert idle.where == immediate.where == timed.where == "FSP task"
    assert idle.instructions < timed.instructions < immediate.instructions
    # the hand-over to the MSP receiver is the PID loop's cost for a timed command too
    assert immediate.instructions > cases["a command due: applied"].instructions / 2


def test_analyze_timed_without_the_emulator_names_the_extra(monkeypatch, capsys) -> None:
    from tests.conftest import run_cli

    monkeypatch.setitem(sys.modules, "unicorn", None)  # import unicorn: ImportError
    code, _, err = run_cli(capsys, "analyze", "timed")
    assert code == 2 and "analyze timed needs Unicorn: pip install 'wftool[analysis]'" in err
    assert "Traceback" not in err
