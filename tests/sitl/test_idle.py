"""The virtual FC's TCP UARTs drop a client only when nothing moved either way for the SITL's
idle timeout: a client that only reads the FSP stream stays connected for good.

Against the patched SITL with its idle timeout set to IDLE_TIMEOUT_S (`--tcp-idle-timeout`;
its own is upstream's 120 s): an FSP reader that never sends and, on the MSP port, a client
that neither sends nor is sent anything, in the same window.
"""

from __future__ import annotations

import select
import socket
import time
from pathlib import Path

from wftool.fsp import StateDecoder
from wftool.sitl.process import LOOPBACK
from wftool.sitl.session import VirtualFcSession

IDLE_TIMEOUT_S = 10
"""The SITL's idle timeout of a TCP UART client, as the test sets it (`--tcp-idle-timeout`)."""
MARGIN_S = 8.0
"""Past the timeout: the SITL checks idle clients a few times a second."""


def _connect(url: str) -> socket.socket:
    host, port = url.removeprefix("socket://").rsplit(":", 1)
    assert host == LOOPBACK
    return socket.create_connection((host, int(port)), timeout=5)


def test_a_client_that_only_reads_stays_connected_past_the_idle_timeout(
    sitl_binary: Path, tmp_path: Path
) -> None:
    with (
        VirtualFcSession(
            sitl_binary, tmp_path, port_base=None, idle_timeout_s=IDLE_TIMEOUT_S
        ) as fc,
        _connect(fc.fsp_url) as reader,
        _connect(fc.msp_url) as idle,
    ):
        start = time.monotonic()
        decoder = StateDecoder()
        seqs: list[int] = []
        reader_closed_at = idle_closed_at = None
        while time.monotonic() - start < IDLE_TIMEOUT_S + MARGIN_S:
            open_ = [s for s in (reader, idle) if s.fileno() >= 0]
            ready, _, _ = select.select(open_, [], [], 1.0)
            if reader in ready:
                chunk = reader.recv(65536)
                if not chunk:
                    reader_closed_at = time.monotonic() - start
                    break
                seqs.extend(packet.seq for packet in decoder.feed(chunk))
            if idle in ready and not idle.recv(1):
                idle_closed_at = time.monotonic() - start
                idle.close()

    assert reader_closed_at is None, f"the FC dropped the FSP reader after {reader_closed_at:.1f} s"
    assert len(seqs) > IDLE_TIMEOUT_S * 400
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))  # no packet lost on the way
    assert decoder.stats.errors <= 1  # at most the chunk cut by joining mid-stream
    # a client with no traffic either way is still let go, at the timeout
    assert idle_closed_at is not None, "an idle MSP client was never dropped"
    assert IDLE_TIMEOUT_S - 1 <= idle_closed_at <= IDLE_TIMEOUT_S + MARGIN_S
