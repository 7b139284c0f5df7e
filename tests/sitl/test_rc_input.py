"""The virtual FC takes its radio's frames (SITL's RC input, `feature RX_UDP`) in FC time, as
its UARTs take their bytes: judged against the SITL's true clock (`TrueClock`, the lockstep
anchors), no FSP frame shows a move of the radio from before the instant it was made, however
far behind the wall clock the host has left the FC."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

from wftool.fsp import FspReader
from wftool.fsp.packets import RC_CHANNELS
from wftool.sitl.radio import HIGH, LOW, MID
from wftool.sitl.session import VirtualFcSession
from wftool.sitl.truth import TrueClock

MARK = RC_CHANNELS.index("aux3")
"""The radio's AUX3, which every FSP frame carries and no mode uses here."""
STOPPED_S = 0.04
"""How long the host stops the FC: it runs that far behind, under the 50 ms its clock lags
before it re-anchors."""
NEVER_S = 10.0


def test_the_fc_takes_a_radio_frame_no_sooner_than_it_arrived(
    sitl_binary: Path, tmp_path: Path
) -> None:
    """The host stops the FC; meanwhile the radio moves AUX3, and its frame waits in the
    socket. The FC, running again, is behind the wall clock: it takes the frame once its clock
    has reached the frame's arrival, so the first FSP frame showing the move was sampled after
    it (upstream's RC thread, taking it when it got to run, had it sampled at the FC time the
    host stopped the FC: ~10 ms before)."""
    session = VirtualFcSession(sitl_binary, tmp_path, port_base=None, pilot=True)
    moves: list[tuple[float, int]] = []
    with session, FspReader(session.fsp_url) as reader:
        radio, process = session.radio, session.fc._process
        assert radio is not None and process is not None
        for value in (HIGH, LOW, MID, HIGH, LOW):
            os.kill(process.pid, signal.SIGSTOP)
            time.sleep(STOPPED_S / 4)
            moved = time.monotonic()
            radio.set(aux3=value)
            time.sleep(3 * STOPPED_S / 4)
            os.kill(process.pid, signal.SIGCONT)
            deadline = time.monotonic() + NEVER_S
            shown = None
            while shown is None:
                assert time.monotonic() < deadline, f"no frame showed AUX3 at {value}"
                frames = [f for p in reader.read(0.05) for f in p.frames]
                shown = next((f for f in frames if f.rc[MARK] == value), None)
            assert shown.time_us is not None
            moves.append((moved, shown.time_us))
        truth = TrueClock(session.fc.log_path)
    early = [(moved - truth.instant(fc_us)) * 1e3 for moved, fc_us in moves]
    assert max(early) <= 0, f"frames showed the move this many ms before it: {early}"
