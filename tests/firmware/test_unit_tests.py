"""The series' own Betaflight unit tests (gtest, clang), and all of Betaflight's, run on a
fresh clone's patched tree."""

from __future__ import annotations

import shutil

import pytest

from wftool.firmware.project import Project
from wftool.firmware.unittests import all_tests, run_unit_tests, series_tests


def test_series_unit_tests_pass(unit_test_clone: Project) -> None:
    if shutil.which("clang") is None:
        pytest.skip("clang not installed (Betaflight's unit tests need it)")
    names = series_tests(unit_test_clone)
    assert {
        "test_fsp_unittest", "test_fsp_command_unittest", "test_fsp_queue_unittest",
        "test_rx_msp_override_unittest", "test_acc_rpm_filter_unittest",
    } <= set(names)  # fmt: skip
    runs = run_unit_tests(unit_test_clone)
    failed = {run.name: run.output[-2000:] for run in runs if not run.passed}
    assert not failed, failed
    assert [run.name for run in runs] == names
    assert all("[  PASSED  ]" in run.output for run in runs)


def test_all_of_betaflights_unit_tests_pass_on_the_patched_tree(
    unit_test_clone: Project,
) -> None:
    """Betaflight's whole suite (`make test`), the series' tests among them."""
    if shutil.which("clang") is None:
        pytest.skip("clang not installed (Betaflight's unit tests need it)")
    runs = run_unit_tests(unit_test_clone, everything=True)
    failed = {run.name: run.output[-2000:] for run in runs if not run.passed}
    assert not failed, failed
    assert [run.name for run in runs] == all_tests(unit_test_clone)
    assert len(runs) >= 50 and set(series_tests(unit_test_clone)) <= {run.name for run in runs}
