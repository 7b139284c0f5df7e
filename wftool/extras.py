"""Optional dependencies (the extras in pyproject.toml), checked before any work is done.

A command that needs an extra that is not installed says, in one line, what is missing and
the pip command that installs it (`MissingExtraError`, exit 2): never a late traceback.
"""

from __future__ import annotations

import importlib

from wftool.errors import MissingExtraError

EXTRAS: dict[str, dict[str, str]] = {
    "analysis": {
        "numpy": "NumPy",
        "scipy": "SciPy",
        "matplotlib": "Matplotlib",
        "unicorn": "Unicorn",
    },
    "mavlink": {"pymavlink": "pymavlink"},
    "foxglove": {"foxglove": "the Foxglove SDK"},
    "ros2": {"rclpy": "ROS 2 (rclpy)"},
}
"""Per extra, its modules (import name -> the name a user knows). Keep in step with
pyproject.toml's [project.optional-dependencies]."""


def install_hint(extra: str) -> str:
    return f"pip install 'wftool[{extra}]'"


def require(extra: str, *modules: str, what: str = "this") -> None:
    """Import `modules` of `extra` (default: all of them), or raise `MissingExtraError`:
    "`what` needs NumPy and SciPy: pip install 'wftool[analysis]'"."""
    known = EXTRAS[extra]
    missing = []
    for module in modules or tuple(known):
        try:
            importlib.import_module(module)
        except ImportError:
            missing.append(known[module])
    if missing:
        raise MissingExtraError(f"{what} needs {' and '.join(missing)}: {install_hint(extra)}")
