"""The optional packages analysis needs (the `analysis` extra), checked before any work."""

from __future__ import annotations

import importlib

from wftool.errors import UsageError

EXTRA = "analysis"
INSTALL_HINT = f"pip install 'wftool[{EXTRA}]'"

PLOTTING = {"numpy": "NumPy", "scipy": "SciPy", "matplotlib": "Matplotlib"}
EMULATOR = {"unicorn": "Unicorn"}
"""The Cortex-M7 emulator that counts the filter's instructions (part of the same extra)."""


class MissingExtraError(UsageError):
    """An optional dependency is not installed (exit 2, with the pip command that fixes it)."""


def require(modules: dict[str, str]) -> None:
    """Import MODULES (import name -> display name) or say in one line what to install."""
    missing = []
    for module, name in modules.items():
        try:
            importlib.import_module(module)
        except ImportError:
            missing.append(name)
    if missing:
        raise MissingExtraError(f"this needs {' and '.join(missing)}: {INSTALL_HINT}")
