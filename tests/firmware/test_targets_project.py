"""Finding the project and resolving target names."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from wftool.errors import UsageError
from wftool.firmware.manifest import BuildFlags
from wftool.firmware.project import PROJECT_ENV, Project, exclusive, find_project
from wftool.firmware.targets import resolve_target

GITMODULES = '[submodule "betaflight"]\n\tpath = betaflight\n\turl = https://example.invalid/bf\n'


@pytest.fixture
def project(tmp_path: Path) -> Project:
    (tmp_path / ".gitmodules").write_text(GITMODULES)
    board = tmp_path / "targets" / "configs" / "SPEEDYBEEF7V3"
    board.mkdir(parents=True)
    (board / "config.h").write_text(
        "#pragma once\n#define FC_TARGET_MCU     STM32F722\n#define BOARD_NAME  SPEEDYBEEF7V3\n"
    )
    other = tmp_path / "targets" / "configs" / "MyBoard"
    other.mkdir()
    (other / "config.h").write_text("#define FC_TARGET_MCU STM32F405\n")
    return Project(tmp_path)


def test_found_from_a_subdirectory(project, monkeypatch):
    monkeypatch.delenv(PROJECT_ENV, raising=False)
    assert find_project(cwd=project.root / "targets" / "configs") == project


def test_explicit_and_environment(project, tmp_path, monkeypatch):
    monkeypatch.setenv(PROJECT_ENV, str(project.root))
    assert find_project(cwd=Path("/")) == project
    with pytest.raises(UsageError, match="not a wftool project"):
        find_project(tmp_path / "targets")


def test_outside_any_project(tmp_path, monkeypatch):
    monkeypatch.delenv(PROJECT_ENV, raising=False)
    with pytest.raises(UsageError, match="no wftool project"):
        find_project(cwd=tmp_path)


def test_targets_case_insensitive(project):
    sitl = resolve_target(project, "SITL")
    assert (sitl.is_sitl, sitl.make_vars, sitl.board) == (True, {"TARGET": "SITL"}, "SITL")
    board = resolve_target(project, "SpeedyBeeF7V3")
    assert board.make_vars == {"CONFIG": "SPEEDYBEEF7V3"}
    assert (board.name, board.board, board.mcu) == ("speedybeef7v3", "SPEEDYBEEF7V3", "STM32F722")
    discovered = resolve_target(project, "myboard")
    assert (discovered.make_vars, discovered.board) == ({"CONFIG": "MyBoard"}, "MyBoard")


def test_unknown_target_lists_the_known_ones(project):
    with pytest.raises(UsageError, match="known: sitl, myboard, speedybeef7v3"):
        resolve_target(project, "nope")


def test_board_with_the_wrong_mcu_is_refused(project):
    header = project.config_dir / "configs" / "SPEEDYBEEF7V3" / "config.h"
    header.write_text("#define FC_TARGET_MCU STM32F405\n#define BOARD_NAME SPEEDYBEEF7V3\n")
    with pytest.raises(UsageError, match="STM32F722 board"):
        resolve_target(project, "speedybeef7v3")


@pytest.mark.parametrize("name", ["STM32F7X2", "STM32F722"])
def test_the_board_mcu_by_either_versions_name(project, name):
    """2025.12 names the F722 target STM32F7X2, 2026.6 by its part (#15470)."""
    header = project.config_dir / "configs" / "SPEEDYBEEF7V3" / "config.h"
    header.write_text(f"#define FC_TARGET_MCU {name}\n#define BOARD_NAME SPEEDYBEEF7V3\n")
    assert resolve_target(project, "speedybeef7v3").mcu == name


def test_flags_become_defines():
    flags = BuildFlags(fsp_rate_hz=1000, mavlink_tunnel=True, defines=("A", "B=2"))
    assert flags.compiler_defines() == [
        "-DFSP_RATE_HZ_DEFAULT=1000",
        "-DUSE_FSP_MAVLINK_TUNNEL",
        "-DA",
        "-DB=2",
    ]
    assert BuildFlags().compiler_defines() == []


def test_second_run_waits_for_the_lock(project):
    waited = threading.Event()

    def second_run() -> None:
        with exclusive(project, waited.set):
            pass

    with exclusive(project):
        second = threading.Thread(target=second_run)
        second.start()
        assert waited.wait(5)
        assert second.is_alive()  # still blocked while the first holds the lock
    second.join(5)
    assert not second.is_alive()
