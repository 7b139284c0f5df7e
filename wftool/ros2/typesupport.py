"""Builds the `wftool_msgs` package's type support into this Python environment from the
ROS 2 wheels (the `ros2` extra), with cmake and a C++ compiler, without colcon.

    from wftool.ros2.typesupport import build
    build()          # ~1 minute the first time; a no-op while the .msg files are unchanged

Then `import wftool_msgs.msg` works in this environment, as after `colcon build` in a
workspace. The notes (why the wheels' CMake files are edited, what is cached) are in
docs/ros2.md.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import importlib.metadata
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from collections.abc import Iterator
from pathlib import Path

from wftool.errors import MissingExtraError, Ros2Error
from wftool.extras import install_hint
from wftool.progress import Log, quiet
from wftool.recording.ros2msg import WFTOOL_MSGS

PACKAGE = "wftool_msgs"
STAMP = Path("share") / PACKAGE / "wftool-sources.sha256"
"""Under the environment's prefix: the digest of what was built (`sources_digest`)."""

WHEEL_PYTHON = re.compile(r"/opt/python/cp3\d+-cp3\d+")
"""The Python prefix of the image the ROS 2 wheels were built in, which their exported CMake
files name (Python's and NumPy's include directories)."""

_VERSIONED = ("ros-rclpy", "ros-rosidl-generator-py", "ros-rosidl-runtime-c")
"""Wheels whose version goes into the digest: a new one means building again."""


def prefix() -> Path:
    """The environment the type support goes into: this interpreter's."""
    return Path(sys.prefix)


def sources_digest() -> str:
    """SHA-256 of the package's files and of the ROS 2 wheels' versions it is built against."""
    digest = hashlib.sha256()
    for path in sorted(p for p in WFTOOL_MSGS.rglob("*") if p.is_file()):
        digest.update(path.relative_to(WFTOOL_MSGS).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    for name in _VERSIONED:
        with contextlib.suppress(importlib.metadata.PackageNotFoundError):
            digest.update(f"{name}=={importlib.metadata.version(name)}\0".encode())
    digest.update(f"python{sys.version_info[0]}.{sys.version_info[1]}".encode())
    return digest.hexdigest()


def is_current() -> bool:
    """The type support of the current definitions is installed in this environment."""
    stamp = prefix() / STAMP
    try:
        return stamp.read_text().strip() == sources_digest()
    except OSError:
        return False


def build(*, jobs: int | None = None, log: Log = quiet, force: bool = False) -> bool:
    """Build and install the type support unless it is current; True if it was built.

    Raises `MissingExtraError` without the `ros2` extra, `Ros2Error` if a tool is missing or
    a step fails (naming the step and the log that holds its output).
    """
    root = prefix()
    if not (root / "share" / "rosidl_default_generators").is_dir():
        raise MissingExtraError(
            f"building {PACKAGE} needs the ROS 2 message generators: {install_hint('ros2')}"
        )
    with _locked(root):
        if not force and is_current():
            return False
        compiler = shutil.which("c++") or shutil.which("g++")
        cmake = shutil.which("cmake")
        if cmake is None or compiler is None:
            missing = " and ".join(n for n, p in (("cmake", cmake), ("g++", compiler)) if not p)
            raise Ros2Error(f"building {PACKAGE} needs {missing} (Debian: cmake, g++)")
        include = Path(sysconfig.get_paths()["include"])
        if not (include / "Python.h").is_file():
            raise Ros2Error(f"building {PACKAGE} needs Python's C headers (Python.h) in {include}")
        repointed = repoint_wheel_cmake(root)
        if repointed:
            log(f"pointed {repointed} CMake files of the ROS 2 wheels at this Python")
        _build(root, cmake, jobs or min(os.cpu_count() or 1, 2), log)
        (root / STAMP).write_text(sources_digest() + "\n")
    return True


def repoint_wheel_cmake(root: Path) -> int:
    """Point the wheels' exported CMake files at this Python's include directories; how many
    files changed.

    The wheels name the include directories of the image they were built in; CMake refuses an
    imported target whose include directory does not exist, so generating a package's Python
    type support against them fails until they name this Python's.
    """
    python_include = sysconfig.get_paths()["include"]
    site_packages = sysconfig.get_paths()["purelib"]
    changed = 0
    for path in sorted((root / "share").glob("*/cmake/*.cmake")):
        text = path.read_text(encoding="utf-8")
        if not WHEEL_PYTHON.search(text):
            continue
        fixed = re.sub(
            WHEEL_PYTHON.pattern + r"/include/python3\.\d+", lambda _m: python_include, text
        )
        fixed = re.sub(
            WHEEL_PYTHON.pattern + r"/lib/python3\.\d+/site-packages",
            lambda _m: site_packages,
            fixed,
        )
        if fixed != text:
            path.write_text(fixed, encoding="utf-8")
            changed += 1
    return changed


def _build(root: Path, cmake: str, jobs: int, log: Log) -> None:
    work = Path(tempfile.mkdtemp(prefix=f"{PACKAGE}-build-"))
    env = dict(os.environ, AMENT_PREFIX_PATH=str(root), CMAKE_PREFIX_PATH=str(root))
    python = root / "bin" / "python"
    steps = (
        (
            "configure",
            [
                cmake, "-S", str(WFTOOL_MSGS), "-B", str(work / "build"),
                f"-DCMAKE_INSTALL_PREFIX={root}", f"-DCMAKE_PREFIX_PATH={root}",
                f"-DPython3_EXECUTABLE={python if python.exists() else sys.executable}",
                "-DCMAKE_BUILD_TYPE=Release", "-DBUILD_TESTING=OFF",
            ],
        ),
        ("compile", [cmake, "--build", str(work / "build"), "--parallel", str(jobs)]),
        ("install", [cmake, "--install", str(work / "build")]),
    )  # fmt: skip
    for step, command in steps:
        log(f"{PACKAGE}: {step}")
        output = work / f"{step}.log"
        with output.open("wb") as sink:
            result = subprocess.run(command, stdout=sink, stderr=subprocess.STDOUT, env=env)
        if result.returncode != 0:
            code = result.returncode
            raise Ros2Error(f"building {PACKAGE} failed at {step} (exit {code}): see {output}")
    check = subprocess.run(
        [sys.executable, "-c", f"import {PACKAGE}.msg"], capture_output=True, text=True
    )
    if check.returncode != 0:
        last = (check.stderr.strip().splitlines() or ["no output"])[-1]
        raise Ros2Error(f"{PACKAGE} was built and installed but does not import: {last}")
    shutil.rmtree(work, ignore_errors=True)


@contextlib.contextmanager
def _locked(root: Path) -> Iterator[None]:
    """One build at a time per environment (setup, a test session and a user may race)."""
    with (root / f".{PACKAGE}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
