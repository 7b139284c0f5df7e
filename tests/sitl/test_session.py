"""The virtual FC session against the real SITL: a configuration made once (`WFTOOL_SITL_CACHE`)
starts the next fresh virtual FC with the same options from the EEPROM it left — in one boot,
with the same settings — and nothing else does."""

from __future__ import annotations

from pathlib import Path

import pytest

from wftool.fc.params import take_backup
from wftool.sitl.session import CACHE_ENV, EEPROM, VirtualFcSession


def settings(session: VirtualFcSession, backups: Path) -> list[str]:
    """The FC's whole configuration (`diff all`, from its backup), without the backup's
    header (the time it was taken)."""
    text = take_backup(session.fc, backups).read_text()
    return [line for line in text.splitlines() if not line.startswith("#")]


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    cache = tmp_path / "cache"
    cache.mkdir()
    monkeypatch.setenv(CACHE_ENV, str(cache))
    return cache


def test_a_configuration_made_once_starts_the_next_in_one_boot_with_its_settings(
    sitl_binary: Path, tmp_path: Path, cache: Path
) -> None:
    with VirtualFcSession(sitl_binary, tmp_path / "first", port_base=None, pilot=True) as first:
        assert first.fc.starts > 1  # configured through the CLI: a save is a reset
        made = settings(first, tmp_path / "backups")
    [entry] = cache.iterdir()
    with VirtualFcSession(sitl_binary, tmp_path / "next", port_base=None, pilot=True) as then:
        assert then.fc.starts == 1
        assert (tmp_path / "next" / EEPROM).read_bytes() != b""
        assert settings(then, tmp_path / "backups") == made
    assert list(cache.iterdir()) == [entry]


def test_other_options_or_an_eeprom_of_its_own_are_configured_through_the_cli(
    sitl_binary: Path, tmp_path: Path, cache: Path
) -> None:
    with VirtualFcSession(sitl_binary, tmp_path / "fc", port_base=None) as fc:
        assert fc.fc.starts > 1
    with VirtualFcSession(sitl_binary, tmp_path / "other", port_base=None, cmd_timeout_ms=80) as fc:
        assert fc.fc.starts > 1  # not the first one's EEPROM
    assert len(list(cache.iterdir())) == 2
    own = (tmp_path / "fc" / EEPROM).read_bytes()
    with VirtualFcSession(sitl_binary, tmp_path / "fc", port_base=None, cmd_timeout_ms=80) as fc:
        assert fc.fc.starts > 1  # its own EEPROM, configured as asked: not replaced
    assert (tmp_path / "fc" / EEPROM).read_bytes() != own
    assert len(list(cache.iterdir())) == 2


def test_without_the_cache_every_virtual_fc_is_configured(
    sitl_binary: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(CACHE_ENV, raising=False)
    for name in ("one", "two"):
        with VirtualFcSession(sitl_binary, tmp_path / name, port_base=None) as fc:
            assert fc.fc.starts > 1
