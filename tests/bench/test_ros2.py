"""`wftool bench ros2` on the virtual FC: both readers ran over the stream, the subscriber got
what the node published. Figures are printed, not judged (a shared machine is noisy)."""

from __future__ import annotations

from pathlib import Path

import pytest

from wftool.bench.ros2 import run_ros2_bench

pytestmark = pytest.mark.usefixtures("ros2_env")


def test_both_readers_run_and_the_subscriber_gets_what_was_published(sitl_binary: Path):
    result = run_ros2_bench(sitl_binary, seconds=4.0)
    for reader in (result.direct, result.node):
        assert reader.frames > 1000, reader
        assert 0 < reader.cpu_s < reader.seconds * 2  # two cores at most
        assert reader.latency is not None and 0 < reader.latency.p50_us < reader.latency.max_us
    assert result.published >= 3000
    assert result.received_of_published == result.published  # reliable: nothing lost
    assert result.hop is not None and result.hop.p50_us > 0
    # From the stamp, the subscriber cannot have a frame before the node read it.
    assert result.node.latency.p50_us > result.hop.p50_us
    # Commands meanwhile: each accounted for; how many were sent is the figure, not judged.
    commands = result.commands
    assert commands.received > 0 and commands.sent > 0, commands
    assert commands.sent + commands.superseded + commands.stale == commands.received, commands
    assert commands.links >= 1 and commands.foreign == commands.not_newer == 0, commands
