"""Betaflight's whole unit-test suite (gtest, clang) — the series' own tests among them — run
once on a fresh clone's patched tree."""

from __future__ import annotations

import shutil

import pytest

from wftool.firmware.project import Project
from wftool.firmware.unittests import (
    UnitTestRun,
    all_tests,
    not_run_reason,
    passed_outputs,
    run_unit_tests,
    series_tests,
)


@pytest.fixture(scope="module")
def whole_suite(unit_test_clone: Project) -> list[UnitTestRun]:
    """Betaflight's `make test` on the patched tree, run once for the tests below."""
    if shutil.which("clang") is None:
        pytest.skip("clang not installed (Betaflight's unit tests need it)")
    return run_unit_tests(unit_test_clone, everything=True)


def test_series_unit_tests_pass(unit_test_clone: Project, whole_suite: list[UnitTestRun]) -> None:
    names = series_tests(unit_test_clone)
    assert {
        "test_fsp_unittest", "test_fsp_command_unittest", "test_fsp_queue_unittest",
        "test_fsp_authority_unittest", "test_acc_rpm_filter_unittest",
        "test_scheduler_late_statistics_unittest",
    } <= set(names)  # fmt: skip
    runs = [run for run in whole_suite if run.name in names]
    failed = {run.name: run.output[-2000:] for run in runs if not run.passed}
    assert not failed, failed
    assert [run.name for run in runs] == names
    assert all("[  PASSED  ]" in run.output for run in runs)


def test_all_of_betaflights_unit_tests_pass_on_the_patched_tree(
    unit_test_clone: Project, whole_suite: list[UnitTestRun]
) -> None:
    """Betaflight's whole suite (`make test`), the series' tests among them."""
    runs = whole_suite
    failed = {run.name: run.output[-2000:] for run in runs if not run.passed and not run.not_run}
    assert not failed, failed
    assert [run.name for run in runs] == all_tests(unit_test_clone)
    assert len(runs) >= 50 and set(series_tests(unit_test_clone)) <= {run.name for run in runs}
    not_run = {run.name: run.not_run for run in runs if run.not_run}
    assert not set(series_tests(unit_test_clone)) & set(not_run)  # the series' own need nothing
    if not_run:  # a submodule the tree could not fetch (offline, without a mirror): say so
        pytest.skip(f"{len(runs) - len(not_run)} of {len(runs)} passed; not built: {not_run}")


def test_a_submodule_make_could_not_fetch_is_a_reason_not_a_failure() -> None:
    output = (
        "git -C ../.. submodule update --init -- lib/modules/dronecan/libcanard\n"
        "fatal: unable to access 'https://github.com/dronecan/libcanard.git/': Could not "
        "resolve host: github.com\n"
        "Failed to clone 'lib/modules/dronecan/libcanard' a second time, aborting\n"
        "make[1]: *** [Makefile:291: ../../lib/modules/dronecan/libcanard/canard.c] Error 1\n"
    )
    assert not_run_reason(output) == (
        "needs lib/modules/dronecan/libcanard, a submodule of the Betaflight tree that could "
        "not be fetched"
    )
    assert not_run_reason("unit/fsp_unittest.cc:12: Failure\n[  FAILED  ] 1 test\n") is None


def test_one_make_of_many_tests_gives_each_passed_test_its_own_output() -> None:
    output = (
        "compiling unit/a_unittest.cc \n"
        "Running main() from ../../lib/test/gtest/src/gtest_main.cc\n"
        "[  PASSED  ] 2 tests.\n"
        "running test_a_unittest: PASS\n"
        "compiling unit/b_unittest.cc \n"
        "Running main() from ../../lib/test/gtest/src/gtest_main.cc\n"
        "[  FAILED  ] 1 test, listed below:\n"
        "make[1]: *** [Makefile:1098: test_b_unittest] Error 1\n"
        "linking ../../obj/test/c_unittest/c_unittest \n"
        "Running main() from ../../lib/test/gtest/src/gtest_main.cc\n"
        "[  PASSED  ] 1 test.\n"
        "running test_c_unittest: PASS\n"
    )
    passed = passed_outputs(output)
    assert set(passed) == {"test_a_unittest", "test_c_unittest"}  # b: run again alone
    assert passed["test_c_unittest"] == (
        "Running main() from ../../lib/test/gtest/src/gtest_main.cc\n"
        "[  PASSED  ] 1 test.\n"
        "running test_c_unittest: PASS"
    )
