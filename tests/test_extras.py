"""Optional dependencies: a missing one is one line naming the extra that installs it."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from wftool.errors import EXIT_USAGE, MissingExtraError
from wftool.extras import EXTRAS, require

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib


def test_missing_modules_are_named_with_the_pip_command(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "numpy", None)  # importing it now raises ImportError
    with pytest.raises(MissingExtraError) as error:
        require("analysis", "numpy", what="spectra")
    assert str(error.value) == "spectra needs NumPy: pip install 'wftool[analysis]'"
    assert error.value.exit_code == EXIT_USAGE


def test_an_installed_extra_passes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "numpy", None)
    require("mavlink")  # scripts/setup installs it; NumPy is not part of it
    with pytest.raises(MissingExtraError, match=r"^this needs NumPy: pip install"):
        require("analysis")


def test_every_extra_is_declared_in_pyproject() -> None:
    pyproject = Path(__file__).parents[1] / "pyproject.toml"
    declared = tomllib.loads(pyproject.read_text())["project"]["optional-dependencies"]
    assert set(EXTRAS) <= set(declared)
