"""The paper's published figures hang together as the paper states them: each statistic of
Table 1 against the others (the table rounds to 1 µs), the rates of §5.2 against the means,
FSP's expected interval against the set-up of §5.1–§5.2. A slip in copying one shows."""

from __future__ import annotations

import pytest

from wftool.analysis.published import MSP_MODES_US, SETUP, TABLE1

TABLE_ROUNDING_US = 1.0


@pytest.mark.parametrize("protocol", ["MSP", "FSP"])
def test_table1_is_consistent_in_itself(protocol: str) -> None:
    row = TABLE1[protocol]
    assert row.p1_us.value <= row.median_us.value <= row.p99_us.value
    spread = row.p99_us.value - row.p1_us.value
    assert row.spread_us.value == pytest.approx(spread, abs=TABLE_ROUNDING_US)
    assert row.rate_hz.value == pytest.approx(1e6 / row.mean_us.value, abs=1.0)
    assert all(figure.source == "Table 1" for figure in row.figures().values())
    assert row.rate_hz.source.startswith("§5.2")


def test_fsp_expected_interval_follows_from_the_setup() -> None:
    loop_hz, n = SETUP.loop_hz.value, SETUP.lockstep_n.value
    assert TABLE1["FSP"].expected_us.value == pytest.approx(n * 1e6 / loop_hz, abs=0.5)
    # fsp_rate_hz 1100 at the nominal 3.2 kHz loop: N = floor(909.1 µs / 312.5 µs) + 1 = 3
    nominal_us = 1e6 / SETUP.loop_nominal_hz.value
    assert (1e6 / SETUP.fsp_rate_hz.value) // nominal_us + 1 == n
    assert TABLE1["MSP"].expected_us.value == 1e6 / SETUP.msp_rates_hz["RAW_IMU"].value


def test_msp_modes_lie_within_the_published_spread() -> None:
    row = TABLE1["MSP"]
    assert all(row.p1_us.value <= mode.value <= row.p99_us.value for mode in MSP_MODES_US)
