"""The series' own Betaflight unit tests (gtest, clang), run on the freshly built tree."""

from __future__ import annotations

import shutil

import pytest

from wftool.firmware.project import Project
from wftool.firmware.unittests import all_tests, run_unit_tests, series_tests

pytestmark = pytest.mark.slow


def test_series_unit_tests_pass(fresh_clone: Project, sitl_build) -> None:
    if shutil.which("clang") is None:
        pytest.skip("clang not installed (Betaflight's unit tests need it)")
    names = series_tests(fresh_clone)
    assert {
        "test_fsp_unittest", "test_fsp_command_unittest", "test_fsp_queue_unittest",
        "test_rx_msp_override_unittest", "test_acc_rpm_filter_unittest",
    } <= set(names)  # fmt: skip
    runs = run_unit_tests(fresh_clone)
    failed = {run.name: run.output[-2000:] for run in runs if not run.passed}
    assert not failed, failed
    assert [run.name for run in runs] == names
    assert all("[  PASSED  ]" in run.output for run in runs)


def test_all_of_betaflights_unit_tests_pass_on_the_patched_tree(
    fresh_clone: Project, sitl_build
) -> None:
    """Betaflight's whole suite (`make test`), the series' tests among them."""
    if shutil.which("clang") is None:
        pytest.skip("clang not installed (Betaflight's unit tests need it)")
    runs = run_unit_tests(fresh_clone, everything=True)
    failed = {run.name: run.output[-2000:] for run in runs if not run.passed}
    assert not failed, failed
    assert [run.name for run in runs] == all_tests(fresh_clone)
    assert len(runs) >= 50 and set(series_tests(fresh_clone)) <= {run.name for run in runs}
