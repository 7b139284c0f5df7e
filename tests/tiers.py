"""The test tiers, from what each test uses: its fixtures say whether it needs the firmware
built, the virtual FC (SITL) or a ROS 2 graph; a test that needs none of them is quick.

A test is marked `firmware`, `sitl` and/or `ros2` (and `slow`, any of them) by the fixtures in
its closure (`TIER_FIXTURES`: one that reaches one of these through another is found
through it); `--quick` deselects every marked test. Nothing is marked by hand. A quick
test that reaches for one of them anyway, by a way no fixture says (starting a SITL, building
or fetching the Betaflight tree, initialising rclpy), fails saying which fixture it lacks, so
a wrong tier shows in every run (tests/test_tiers.py holds the guard to that).

Each test also gets the `xdist_group` that keeps what it shares together under
`pytest -n` (`--dist loadgroup`): the tests that build in, or run from, the session's clone of
this repository in one group (they change its build outputs and tree in turn), those that
run Betaflight's unit tests in another clone in another, and the tests
of one module (or class) that share a virtual FC or another fixture of that scope on one
worker, so that fixture starts once.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import settings

QUICK_OPTION = "--quick"

_FIRMWARE = (
    "fresh_clone unit_test_clone sitl_build board_build board_firmware firmware_tree built_hex"
    " previous_sitl"
)
TIER_FIXTURES: dict[str, frozenset[str]] = {
    "firmware": frozenset(_FIRMWARE.split()),
    "sitl": frozenset({"sitl_binary"}),
    "ros2": frozenset({"ros2_env"}),
}
"""Tier → the fixtures whose use puts a test in it (directly or through another fixture;
`sitl_binary` gets its build by `getfixturevalue`, so it is named here itself)."""

SHARED_TREES = {
    "fresh_clone": "firmware-clone",
    "sitl_build": "firmware-clone",
    "board_build": "firmware-clone",
    "firmware_tree": "firmware-clone",
    "unit_test_clone": "firmware-unit-tests",
}
"""The fixtures that hand out a clone to build, patch or test in (its tree, its build outputs,
its lock), with the xdist group of the tests that use one: they run on one worker, in turn.
Tests that only run what was built take `sitl_binary` or `built_hex` (copies)."""

REPO = Path(__file__).resolve().parent.parent


def tiers_of(fixturenames: list[str] | tuple[str, ...]) -> list[str]:
    """The tiers a test with these fixtures (its closure) belongs to; none: quick."""
    used = set(fixturenames)
    return [tier for tier, names in TIER_FIXTURES.items() if used & names]


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        QUICK_OPTION,
        action="store_true",
        help="only the quick tier: tests that need no firmware build, no SITL, no ROS 2 graph",
    )


_quick = False
"""This run is the quick tier (set before the test modules are imported)."""


def examples(full: int) -> int:
    """A property test's `max_examples`: `full` in the full suite, a third of it (20 at least)
    in the quick tier. The quick tier is the edit-test loop, and drawing examples is most of
    what these tests cost there; the full suite, which CI runs before anything lands, draws
    them all."""
    return max(20, full // 3) if _quick else full


def pytest_configure(config: pytest.Config) -> None:
    global _quick
    _quick = bool(config.getoption(QUICK_OPTION))
    if _quick:  # property tests that take hypothesis' default (100 examples) too
        settings.register_profile("wftool-quick", settings(), max_examples=examples(100))
        settings.load_profile("wftool-quick")
    for tier, names in TIER_FIXTURES.items():
        config.addinivalue_line(
            "markers", f"{tier}: uses {', '.join(sorted(names))} (set from the fixtures)"
        )
    config.addinivalue_line(
        "markers", "slow: needs the firmware, the SITL or ROS 2 (set from the fixtures)"
    )
    if not config.pluginmanager.hasplugin("xdist"):  # the groups are set all the same
        config.addinivalue_line("markers", "xdist_group(name): pytest-xdist's (not installed)")


@pytest.hookimpl(tryfirst=True)  # before pytest-xdist reads the groups
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    quick, other = [], []
    for item in items:
        names = list(getattr(item, "fixturenames", ()))
        tiers = tiers_of(names)
        for tier in tiers:
            item.add_marker(tier)
        if tiers:
            item.add_marker("slow")
            other.append(item)
        else:
            quick.append(item)
        if group := _group(item, names):
            item.add_marker(pytest.mark.xdist_group(group))
    if config.getoption(QUICK_OPTION):
        config.hook.pytest_deselected(items=other)
        items[:] = quick
    else:
        items[:] = sorted(items, key=_start_order)


@pytest.hookimpl(trylast=True)  # after pytest-xdist has put the groups into the node ids
def pytest_collection_finish(session: pytest.Session) -> None:
    if not session.config.getoption("loadgroup", False):
        return
    for item in session.items:
        mark = item.get_closest_marker("xdist_group")
        if mark is not None and not item.nodeid.endswith(f"@{mark.args[0]}"):
            raise pytest.UsageError(
                f"pytest-xdist did not group {item.nodeid} (pytest {pytest.__version__}): "
                "the tests that share a clone would run at once; see the test extra's pins"
            )


def _start_order(item: pytest.Item) -> int:
    """Where a test goes in the order workers take them (`--no-loadscope-reorder`): the
    builds and Betaflight's unit tests first, the longest work and the one that makes the
    SITL; then the quick tier, which takes the other workers' CPU while those compile; then
    the virtual FCs and ROS 2, whose timing a host busy compiling would only disturb."""
    shared = item.get_closest_marker("xdist_group")
    if shared is not None and shared.args[0] in SHARED_TREES.values():
        return 0
    return 2 if item.get_closest_marker("slow") else 1


def _group(item: pytest.Item, names: list[str]) -> str | None:
    """The xdist group of a test: its clone's, or the module or class whose fixture it shares."""
    for name in names:
        if name in SHARED_TREES:
            return SHARED_TREES[name]
    info = getattr(item, "_fixtureinfo", None)
    if info is None or not tiers_of(names):
        return None
    scopes = {
        definitions[-1].scope for name in names if (definitions := info.name2fixturedefs.get(name))
    }
    for scope, node_type in (("package", pytest.Package), ("module", pytest.Module)):
        if scope in scopes and (node := item.getparent(node_type)) is not None:
            return node.nodeid or scope
    if "class" in scopes and (node := item.getparent(pytest.Class)) is not None:
        return node.nodeid
    return None


# -- the guard: a quick test that needs a tier after all ---------------------------------------


class TierError(AssertionError):
    """A test in the quick tier used what only a tier's fixtures may hand out."""


def _refuse(what: str, tier: str) -> Callable[..., Any]:
    def refuse(*args: Any, **kwargs: Any) -> Any:
        fixtures = ", ".join(sorted(TIER_FIXTURES[tier]))
        raise TierError(
            f"this test {what} but none of its fixtures puts it in the {tier} tier: "
            f"take it from one of {fixtures} (tests/tiers.py)"
        )

    return refuse


@functools.cache
def _betaflight_url() -> str:
    from wftool.firmware.project import Project
    from wftool.firmware.tree import submodule_url

    return submodule_url(Project(REPO))


def _is_betaflight(project: Any) -> bool:
    from wftool.firmware.tree import submodule_url

    try:
        return submodule_url(project) == _betaflight_url()
    except Exception:
        return False


@pytest.fixture(autouse=True)
def _tier_guard(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """In a quick test: starting a SITL, building or fetching Betaflight, or initialising
    rclpy fails, naming the fixture that would have put the test in its tier."""
    if tiers_of(request.fixturenames):
        return
    from wftool.firmware import make, tree
    from wftool.sitl.process import VirtualFC

    spawn, starts = VirtualFC._spawn, _refuse("starts the SITL", "sitl")

    def guarded_spawn(fc: VirtualFC) -> Any:
        if fc.binary.is_file():  # (a missing one is a test of the error that says so)
            starts()
        return spawn(fc)

    monkeypatch.setattr(VirtualFC, "_spawn", guarded_spawn)
    ensure_tree, plan, run = tree.ensure_tree, make.plan, make.run
    fetches = _refuse("fetches or builds the Betaflight tree", "firmware")
    builds = _refuse("runs make in the Betaflight tree", "firmware")

    def guarded_tree(project: Any, *args: Any, **kwargs: Any) -> Any:
        if _is_betaflight(project):
            fetches()
        return ensure_tree(project, *args, **kwargs)

    def guarded(real: Callable[..., Any]) -> Callable[..., Any]:
        def make_in(command: Any, *args: Any, **kwargs: Any) -> Any:
            if (Path(command.tree) / "src" / "main" / "fc").is_dir():
                builds()
            return real(command, *args, **kwargs)

        return make_in

    monkeypatch.setattr(tree, "ensure_tree", guarded_tree)
    monkeypatch.setattr(make, "plan", guarded(plan))
    monkeypatch.setattr(make, "run", guarded(run))
    try:
        import rclpy
    except ImportError:
        return
    monkeypatch.setattr(rclpy, "init", _refuse("initialises rclpy (a ROS 2 graph)", "ros2"))
