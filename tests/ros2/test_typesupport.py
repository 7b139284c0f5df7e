"""Building wftool_msgs' type support from the wheels: the wheels' CMake files pointed at this
Python, the cache, and the one-line errors. The real build runs in the `ros2_env` fixture."""

from __future__ import annotations

import shutil
import sys
import sysconfig
from pathlib import Path

import pytest

from wftool.errors import MissingExtraError, Ros2Error
from wftool.recording.ros2msg import WFTOOL_MSGS
from wftool.ros2 import typesupport

EXPORT = """\
set_target_properties(std_msgs::std_msgs__rosidl_generator_py PROPERTIES
  INTERFACE_INCLUDE_DIRECTORIES "${_IMPORT_PREFIX}/include/std_msgs;\
/opt/python/cp311-cp311/include/python3.11;\
/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"
)
"""


def test_wheel_cmake_files_are_pointed_at_this_python(tmp_path: Path):
    export = tmp_path / "share" / "std_msgs" / "cmake" / "export_pyExport.cmake"
    other = tmp_path / "share" / "rcl" / "cmake" / "rclConfig.cmake"
    for path, text in ((export, EXPORT), (other, "set(rcl_FOUND TRUE)\n")):
        path.parent.mkdir(parents=True)
        path.write_text(text)
    assert typesupport.repoint_wheel_cmake(tmp_path) == 1
    fixed = export.read_text()
    paths = sysconfig.get_paths()
    assert "/opt/python" not in fixed
    assert f"{paths['include']};{paths['purelib']}/numpy/_core/include" in fixed
    assert other.read_text() == "set(rcl_FOUND TRUE)\n"
    assert typesupport.repoint_wheel_cmake(tmp_path) == 0  # once is enough


@pytest.fixture
def package_copy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    copy = tmp_path / "wftool_msgs"
    shutil.copytree(WFTOOL_MSGS, copy)
    monkeypatch.setattr(typesupport, "WFTOOL_MSGS", copy)
    return copy


def test_the_digest_follows_every_file(package_copy: Path):
    before = typesupport.sources_digest()
    assert typesupport.sources_digest() == before
    (package_copy / "msg" / "RcChannels.msg").write_text("int16 roll\n")
    changed = typesupport.sources_digest()
    assert changed != before
    (package_copy / "msg" / "New.msg").write_text("int16 x\n")
    assert typesupport.sources_digest() not in (before, changed)


def test_without_the_generators_it_names_the_extra(tmp_path: Path, monkeypatch):
    monkeypatch.setattr(sys, "prefix", str(tmp_path))
    with pytest.raises(MissingExtraError, match=r"pip install 'wftool\[ros2\]'"):
        typesupport.build()


def test_without_cmake_it_says_so(tmp_path: Path, monkeypatch):
    (tmp_path / "share" / "rosidl_default_generators").mkdir(parents=True)
    monkeypatch.setattr(sys, "prefix", str(tmp_path))
    monkeypatch.setattr(shutil, "which", lambda name: None if name == "cmake" else "/usr/bin/x")
    with pytest.raises(Ros2Error, match=r"^building wftool_msgs needs cmake \(Debian"):
        typesupport.build()


@pytest.mark.usefixtures("ros2_env")
def test_built_and_current_until_a_definition_changes(tmp_path: Path, monkeypatch):
    """The fixture built it; a changed .msg file makes it out of date."""
    assert typesupport.is_current()
    assert typesupport.build() is False  # nothing to do
    copy = tmp_path / "wftool_msgs"
    shutil.copytree(WFTOOL_MSGS, copy)
    (copy / "msg" / "Attitude.msg").write_text("float64 roll_deg\n")
    monkeypatch.setattr(typesupport, "WFTOOL_MSGS", copy)
    assert not typesupport.is_current()
