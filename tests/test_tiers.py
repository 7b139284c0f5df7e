"""The tiers follow from what a test uses (tests/tiers.py), and a test that needs the SITL,
the firmware or ROS 2 without a fixture that says so fails, naming the fixture."""

from __future__ import annotations

import pytest

from tests.conftest import REPO
from tests.tiers import SHARED_TREES

STAND_INS = """
import pytest
from pathlib import Path

@pytest.fixture(scope="session")
def sitl_binary():
    return Path("/bin/false")

@pytest.fixture(scope="session")
def fresh_clone():
    return None

@pytest.fixture(scope="session")
def ros2_env():
    return None

@pytest.fixture(scope="module")
def module_fc(sitl_binary):
    return sitl_binary
"""

TESTS = """
import pytest

def test_plain():
    pass

def test_through_a_fixture(module_fc):
    pass

@pytest.mark.usefixtures("ros2_env")
def test_used(tmp_path):
    pass

def test_clone(fresh_clone, sitl_binary):
    pass
"""


@pytest.fixture
def suite(pytester: pytest.Pytester) -> pytest.Pytester:
    """A suite of its own, with stand-ins for the tier fixtures, run with the tiers plugin."""
    pytester.makeconftest(STAND_INS)
    pytester.makepyfile(test_suite=TESTS)
    return pytester


def collected(suite: pytest.Pytester, *args: str) -> dict[str, pytest.Item]:
    items, _ = suite.inline_genitems("-p", "tests.tiers", *args)
    return {item.name: item for item in items}


def selected(suite: pytest.Pytester, *args: str) -> list[str]:
    result = suite.runpytest_inprocess("-p", "tests.tiers", "--collect-only", "-q", *args)
    return [line.split("::")[1] for line in result.outlines if "::" in line]


def marks(item: pytest.Item) -> set[str]:
    return {mark.name for mark in item.iter_markers()} - {"usefixtures", "xdist_group"}


def group(item: pytest.Item) -> str | None:
    mark = item.get_closest_marker("xdist_group")
    return None if mark is None else mark.args[0]


def test_tiers_come_from_the_fixture_closure(suite: pytest.Pytester) -> None:
    items = collected(suite)
    assert marks(items["test_plain"]) == set()
    assert marks(items["test_through_a_fixture"]) == {"sitl", "slow"}
    assert marks(items["test_used"]) == {"ros2", "slow"}
    assert marks(items["test_clone"]) == {"firmware", "sitl", "slow"}
    assert selected(suite, "--quick") == ["test_plain"]
    assert selected(suite, "-m", "not slow") == ["test_plain"]
    assert selected(suite, "-m", "sitl") == ["test_clone", "test_through_a_fixture"]


def test_workers_take_the_clone_first_then_the_quick_tier(suite: pytest.Pytester) -> None:
    """The builds first, the quick tier beside them, the virtual FCs and ROS 2 after (in the
    order they were collected)."""
    assert selected(suite) == ["test_clone", "test_plain", "test_through_a_fixture", "test_used"]


def test_what_shares_a_fixture_or_the_clone_shares_a_worker(suite: pytest.Pytester) -> None:
    items = collected(suite)
    assert group(items["test_plain"]) is None and group(items["test_used"]) is None
    assert group(items["test_through_a_fixture"]) == "test_suite.py"  # its module-scoped FC
    assert group(items["test_clone"]) == SHARED_TREES["fresh_clone"]


GUARDED = """
from pathlib import Path

from wftool.firmware import make, tree
from wftool.firmware.project import Project
from wftool.firmware.targets import SITL, resolve_target
from wftool.sitl.process import VirtualFC

REPO = Path({repo!r})

def test_starts_the_sitl(tmp_path):
    VirtualFC(Path("/bin/false"), tmp_path, port_base=None).start()

def test_runs_make_in_a_betaflight_tree(tmp_path):
    (tmp_path / "src" / "main" / "fc").mkdir(parents=True)
    make.plan(make.MakeCommand(tree=tmp_path, variables={{}}, jobs=1, hook=tmp_path / "h.mk"))

def test_fetches_betaflight(tmp_path):
    (tmp_path / ".gitmodules").write_text((REPO / ".gitmodules").read_text())
    project = Project(tmp_path)
    tree.ensure_tree(project, resolve_target(Project(REPO), SITL))

def test_initialises_rclpy():
    import rclpy
    rclpy.init()
"""


def test_a_quick_test_that_needs_a_tier_fails_naming_its_fixture(
    pytester: pytest.Pytester,
) -> None:
    from tests.tiers import REPO

    pytester.makepyfile(test_guarded=GUARDED.format(repo=str(REPO)))
    result = pytester.runpytest_inprocess("-p", "tests.tiers", "-p", "no:cacheprovider")
    reports = result.reprec.getfailures()  # runpytest_inprocess keeps its recorder
    failed = {report.nodeid.split("::")[-1]: report for report in reports}
    said = {name: str(report.longrepr) for name, report in failed.items()}
    expected = {
        "test_starts_the_sitl": "starts the SITL but none of its fixtures puts it in the sitl tier",
        "test_runs_make_in_a_betaflight_tree": "runs make in the Betaflight tree but",
        "test_fetches_betaflight": "fetches or builds the Betaflight tree but",
    }
    try:
        import rclpy  # noqa: F401
    except ImportError:
        pass
    else:
        expected["test_initialises_rclpy"] = "initialises rclpy (a ROS 2 graph) but"
    for name, message in expected.items():
        assert name in said, f"{name} passed: the guard let it through"
        assert "TierError" in said[name] and message in said[name], said[name]


PROPERTIES = """
from hypothesis import given, settings, strategies as st

from tests.tiers import examples

drawn = {"own": 0, "default": 0}


@settings(max_examples=examples(60), database=None)
@given(st.integers())
def test_its_own_count(n):
    drawn["own"] += 1


@settings(database=None)
@given(st.integers())
def test_the_default_count(n):
    drawn["default"] += 1


def test_report():
    print("drawn", drawn["own"], drawn["default"])
"""


@pytest.mark.parametrize(("args", "own", "default"), [((), 60, 100), (("--quick",), 20, 33)])
def test_the_quick_tier_draws_a_third_of_each_propertys_examples_and_the_full_suite_all(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch, args: tuple, own: int, default: int
) -> None:
    pytester.makepyfile(test_properties=PROPERTIES)
    monkeypatch.setenv("PYTHONPATH", str(REPO))  # a process of its own: the profile is global
    result = pytester.runpytest_subprocess("-p", "tests.tiers", "-p", "no:randomly", "-s", *args)
    result.assert_outcomes(passed=3)
    result.stdout.fnmatch_lines([f"*drawn {own} {default}*"])
