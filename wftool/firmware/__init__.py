"""Reproducible firmware builds: the pinned Betaflight tree + patches/ + targets/ -> build/.

`build()` is the entry point the CLI and the tests call; the modules below it hold one
concern each (project, tree, patches, toolchain, make, manifest, targets).
"""

from wftool.firmware.builder import BuildOptions, BuildResult, build
from wftool.firmware.manifest import BuildFlags
from wftool.firmware.project import Project, find_project

__all__ = ["BuildFlags", "BuildOptions", "BuildResult", "Project", "build", "find_project"]
