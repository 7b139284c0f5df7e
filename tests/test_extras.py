"""Optional dependencies: a missing one is one line naming the extra that installs it."""

from __future__ import annotations

import sys

import pytest

from wftool.errors import EXIT_USAGE, MissingExtraError
from wftool.extras import require

if sys.version_info >= (3, 11):
    pass
else:
    pass


def test_missing_modules_are_named_with_the_pip_command(monkeypatch: pytest.MonkeyPatch) -> None:
    for module in ("numpy", "scipy"):
        monkeypatch.setitem(sys.modules, module, None)  # importing it now raises ImportError
    with pytest.raises(MissingExtraError) as error:
        require("analysis", "numpy", "scipy", what="spectra")
    assert str(error.value) == "spectra needs NumPy and SciPy: pip install 'wftool[analysis]'"
    assert error.value.exit_code == EXIT_USAGE


def test_only_the_modules_asked_for_are_checked(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "unicorn", None)
    require("analysis", "numpy", "scipy")  # scripts/setup installs the extra
    require("mavlink")
    with pytest.raises(MissingExtraError, match=r"^this needs Unicorn: pip install"):
        require("analysis")
