"""Shared fixtures: the repo's fixed inputs, the firmware built from a fresh clone, and the
virtual flight controller (the patched Betaflight SITL).

The firmware fixtures clone this repository's HEAD (commit before running them locally),
fetch the pinned Betaflight tree and build once per session; they skip, with the reason,
only where the Betaflight repository cannot be reached. WFTOOL_SITL_BINARY points the SITL
tests at an existing binary instead (WFTOOL_PREVIOUS_SITL_BINARY the compatibility tests'
FC of the previous pin). Every virtual FC a test starts takes a free port base
(`free_port_base()`), so test sessions, benchmarks and a `wftool sitl` run side by side.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import random
import shutil
import subprocess
from collections.abc import Iterator
from importlib.util import find_spec
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

from tests import shared
from tests.fc.faulty_transport import FaultyTransport, InjectFaults
from wftool.cli import fc as fc_commands
from wftool.cli import main
from wftool.errors import MspError
from wftool.fc import params
from wftool.fc.cli_session import CliSession
from wftool.fc.msp import MspClient
from wftool.fc.versions import BETAFLIGHT_2025_12, BetaflightVersion
from wftool.firmware import BuildOptions, BuildResult, build, patches, tree
from wftool.firmware.project import SUBMODULE_PATH, Project
from wftool.firmware.targets import SITL, resolve_target
from wftool.ros2 import typesupport
from wftool.sitl.process import VirtualFC
from wftool.sitl.session import CACHE_ENV

pytest_plugins = ["tests.tiers", "pytester"]

# Hypothesis' per-example deadline and its "generation is slow" health check time the host:
# on a loaded one (a full parallel run, another session's build) they fail what passes.
settings.register_profile("wftool", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("wftool")

REPO = Path(__file__).resolve().parent.parent
BUILD_JOBS = min(os.cpu_count() or 1, 2)


@pytest.fixture(scope="session")
def vectors_dir() -> Path:
    """The FSP conformance vectors (spec/vectors), from an independent encoder."""
    return REPO / "spec" / "vectors"


def _head() -> str:
    return _git(REPO, "rev-parse", "HEAD")


def _clone_of_head(factory: pytest.TempPathFactory, name: str, *, patched: bool = False) -> Project:
    """A `git clone` of this repository's HEAD, with the submodule not initialised (or,
    `patched`, fetched and at the series): made once per test run under NAME, shared by its
    workers (tests/shared.py)."""
    if not (REPO / ".git").exists():
        pytest.skip("not running from a git checkout of wftool")

    def clone(directory: Path) -> Project:
        url = _git(REPO, "config", "-f", ".gitmodules", "submodule.betaflight.url")
        reachable = subprocess.run(
            ["git", "ls-remote", "--exit-code", url, "HEAD"], capture_output=True, timeout=120
        )
        if reachable.returncode != 0:
            pytest.skip(f"Betaflight repository {url} unreachable")
        root = directory / "wftool"
        _git(REPO, "clone", "-q", str(REPO), str(root))
        project = Project(root)
        if patched:
            tree.ensure_tree(project, resolve_target(project, SITL))
            patches.apply(project)
        return project

    return shared.once(factory, f"{name}-{_head()[:12]}", clone)


@pytest.fixture(scope="session")
def fresh_clone(tmp_path_factory: pytest.TempPathFactory) -> Project:
    """A fresh clone of this repository, where the run's firmware is built."""
    return _clone_of_head(tmp_path_factory, "clone")


@pytest.fixture(scope="session")
def unit_test_clone(tmp_path_factory: pytest.TempPathFactory) -> Project:
    """A clone of its own for Betaflight's unit tests, its tree fetched and patched: they
    check out src/test and compile into the tree's obj/test, kept apart from the builds in
    `fresh_clone`, so that both run at once without sharing a git index."""
    return _clone_of_head(tmp_path_factory, "unit-test-clone", patched=True)


@contextlib.contextmanager
def _build_date(project: Project) -> Iterator[None]:
    """Build with SOURCE_DATE_EPOCH at the clone's commit time: the session's builds carry one
    `__DATE__`/`__TIME__`, so the SITL build can stand in for the board build's firmware
    (tests/flash/virtual_board.py)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("SOURCE_DATE_EPOCH", _git(project.root, "log", "-1", "--format=%ct"))
        yield


def _first_build(
    factory: pytest.TempPathFactory, project: Project, target: str
) -> tuple[BuildResult, Path]:
    """The run's build of TARGET in the clone, and a copy of its firmware file that later
    builds in the clone (other flags, tests/firmware/test_e2e.py) leave alone."""

    def make(directory: Path) -> tuple[BuildResult, Path]:
        with _build_date(project):
            result = build(project, target, BuildOptions(jobs=BUILD_JOBS))
        kept = directory / result.firmware.name
        shutil.copy2(result.firmware, kept)
        return result, kept

    return shared.once(factory, f"{target}-build-{_head()[:12]}", make)


@pytest.fixture(scope="session")
def sitl_build(fresh_clone: Project, tmp_path_factory: pytest.TempPathFactory) -> BuildResult:
    """The run's first build: fetches the tree, applies the series, builds SITL."""
    return _first_build(tmp_path_factory, fresh_clone, "sitl")[0]


@pytest.fixture(scope="session")
def board_build(
    fresh_clone: Project, sitl_build: BuildResult, tmp_path_factory: pytest.TempPathFactory
) -> BuildResult:
    """speedybeef7v3 in the same clone (widens the sparse checkout to STM32F7)."""
    return _first_build(tmp_path_factory, fresh_clone, "speedybeef7v3")[0]


PREVIOUS_PIN = BETAFLIGHT_2025_12
"""The Betaflight the firmware series was pinned to before the current pin (boards in the
field run it): the compatibility tests build it as main last had it."""


def last_commit_pinning(version: BetaflightVersion) -> str:
    """The newest commit of this repository's first-parent history that pins VERSION's
    release: HEAD while it still does, else main's last commit before the pin moved."""
    for commit in _git(REPO, "rev-list", "--first-parent", "HEAD").split():
        listing = _git(REPO, "ls-tree", commit, SUBMODULE_PATH).split()
        if len(listing) >= 3 and listing[2] == version.commit:
            return commit
    pytest.fail(f"no commit of this repository pins Betaflight {version.release}")


@pytest.fixture(scope="session")
def previous_sitl(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The SITL of the previous pin (`PREVIOUS_PIN` with its series, from the last commit
    that pinned it), built by this wftool in a clone of its own, once per session; while HEAD
    still pins it, the session's own (`sitl_binary`): the very same firmware.
    WFTOOL_PREVIOUS_SITL_BINARY points at an existing one instead."""
    if path := os.environ.get("WFTOOL_PREVIOUS_SITL_BINARY"):
        return Path(path)
    request.getfixturevalue("fresh_clone")  # skips, saying why, where Betaflight is unreachable
    commit = last_commit_pinning(PREVIOUS_PIN)
    head = _git(REPO, "rev-parse", "HEAD")
    same = all(
        _git(REPO, "rev-parse", f"{commit}:{path}") == _git(REPO, "rev-parse", f"{head}:{path}")
        for path in ("patches", SUBMODULE_PATH)
    )
    if same:
        binary: Path = request.getfixturevalue("sitl_binary")
        return binary
    root = tmp_path_factory.mktemp("previous-pin") / "wftool"
    _git(REPO, "clone", "-q", "--no-checkout", str(REPO), str(root))
    _git(root, "checkout", "-q", "--detach", commit)
    project = Project(root)
    with _build_date(project):
        return build(project, "sitl", BuildOptions(jobs=BUILD_JOBS)).firmware


@pytest.fixture(scope="session", autouse=True)
def sitl_eeproms(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """The run's cache of configured virtual FCs' EEPROMs, shared by its workers and by the
    wftool processes tests start (wftool.sitl.session): each configuration goes through
    `configure fsp` once, and a virtual FC configured as one before starts in one boot."""
    directory = shared.run_dir(tmp_path_factory) / "sitl-eeproms"
    directory.mkdir(exist_ok=True)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(CACHE_ENV, str(directory))
        yield


@pytest.fixture(scope="session")
def board_firmware(
    fresh_clone: Project, board_build: BuildResult, tmp_path_factory: pytest.TempPathFactory
) -> Path:
    """The board build's hex as it was built (a copy no later build in the clone changes)."""
    return _first_build(tmp_path_factory, fresh_clone, "speedybeef7v3")[1]


@pytest.fixture(scope="session")
def sitl_binary(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The patched SITL: WFTOOL_SITL_BINARY if set, else this run's build (a copy no later
    build in the clone changes)."""
    path = os.environ.get("WFTOOL_SITL_BINARY")
    if path:
        return Path(path)
    project = request.getfixturevalue("fresh_clone")
    request.getfixturevalue("sitl_build")
    return _first_build(tmp_path_factory, project, "sitl")[1]


@pytest.fixture(scope="session")
def firmware_tree(request: pytest.FixtureRequest) -> Path:
    """The patched Betaflight tree `sitl_binary` was built from."""
    if os.environ.get("WFTOOL_SITL_BINARY"):
        tree = REPO / "betaflight"
        if not (tree / "src" / "main").is_dir():
            pytest.skip("WFTOOL_SITL_BINARY is set but betaflight/ is not checked out")
        return tree
    request.getfixturevalue("sitl_build")
    return request.getfixturevalue("fresh_clone").tree


@pytest.fixture
def virtual_fc(sitl_binary: Path, tmp_path: Path) -> Iterator[VirtualFC]:
    """A freshly started SITL with an empty configuration, stopped after the test."""
    with VirtualFC(sitl_binary, tmp_path / "sitl", port_base=None) as fc:
        yield fc


@pytest.fixture
def on_sitl(virtual_fc: VirtualFC, monkeypatch: pytest.MonkeyPatch) -> VirtualFC:
    """The virtual FC as the board the CLI finds (`find_board`, how it locates a USB FC);
    everything below that is the real code path."""
    monkeypatch.setattr(fc_commands, "find_board", lambda port, present=True: virtual_fc)
    return virtual_fc


@pytest.fixture
def inject_faults(monkeypatch: pytest.MonkeyPatch) -> InjectFaults:
    """`inject_faults(**faults)`: the links the parameter workflow (and so backup and flash)
    opens go through a FaultyTransport with these faults (tests/fc/faulty_transport.py)."""

    def inject(**faults: Any) -> FaultyTransport:
        transport = FaultyTransport(**faults)
        monkeypatch.setattr(params, "open_port", transport.open_port)
        return transport

    return inject


def fc_settings(fc: VirtualFC, *names: str) -> dict[str, str]:
    """What the FC's CLI says the settings NAMES are (it leaves the CLI with `exit`)."""
    session = CliSession.open(fc.url)
    try:
        return {name: session.get(name).value for name in names}
    finally:
        session.exit()
        fc.wait_back()


def answers_msp(fc: VirtualFC) -> bool:
    """Whether the FC answers MSP, i.e. is not sitting in its CLI."""
    with MspClient.open(fc.url) as msp:
        try:
            return msp.fc_variant() == "BTFL"
        except MspError:
            return False


NEEDS_MATPLOTLIB = pytest.mark.skipif(
    find_spec("matplotlib") is None, reason="needs the analysis extra (Matplotlib)"
)
"""For a module's `pytestmark`: Matplotlib found, not imported (its import takes ~0.4 s of CPU
in every worker that collects the module)."""


def run_cli(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    """Run `wftool ARGS` in-process: (exit code, stdout, stderr)."""
    with pytest.raises(SystemExit) as exit_info:
        main(list(args))
    captured = capsys.readouterr()
    return int(exit_info.value.code or 0), captured.out, captured.err


def _git(cwd: Path, *args: str) -> str:
    return subprocess.run(
        ["git", *args], cwd=cwd, check=True, capture_output=True, text=True
    ).stdout.strip()


@pytest.fixture(scope="session")
def ros2_env() -> None:
    """ROS 2 from the `ros2` extra's wheels (rclpy on Fast DDS), with wftool_msgs' type support
    built into this environment (once; cached while the .msg files are unchanged).

    The session gets a DDS domain of its own and discovery on this host, so that other test
    sessions on the machine are not heard; subprocesses inherit both. The workers of one
    run (pytest-xdist) take consecutive domains from one random start, so none hears
    another."""
    try:
        import rclpy  # noqa: F401
    except ImportError as exc:
        pytest.skip(
            f"ROS 2 wheels not installed ({exc}); scripts/setup installs the ros2 extra where "
            "its wheels exist (CPython 3.11 on Linux)"
        )
    if shutil.which("cmake") is None:
        pytest.skip("cmake not installed (scripts/setup installs it when run as root)")
    typesupport.build()
    os.environ["ROS_DOMAIN_ID"] = str(_ros_domain())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


def _ros_domain() -> int:
    """A DDS domain of 1-100: random for the run, one apart per xdist worker ("gw3": 3)."""
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
    if run:
        start = int(hashlib.sha256(run.encode()).hexdigest(), 16)
    else:
        start = random.SystemRandom().randrange(100)
    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").lstrip("gw") or 0)
    return 1 + (start + worker) % 100
