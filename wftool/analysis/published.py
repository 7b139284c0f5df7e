"""The paper's published figures, each with where in the paper it stands: Table 1, the set-up
of §5.1–§5.2 and what the captions of Figs. 2–3 say. The one place for them.

    TABLE1["FSP"].p99_us   # Published(956.0, "Table 1")

Table 1 gives intervals in ms to three decimals; they are held in µs. Nothing here is
derived or estimated: a figure the paper does not give is not here.
"""

from __future__ import annotations

from dataclasses import dataclass

NOT_AVAILABLE = "not available"
PAPER = "the Weitflug paper"
"""What every source below is in: Weitflug (Betaflight + FSP), §5 Evaluation."""


@dataclass(frozen=True)
class Published:
    """One published figure and where the paper gives it."""

    value: float
    source: str
    """Table, section or figure of the paper, e.g. "Table 1", "§5.2"."""

    def cite(self) -> str:
        return f"{PAPER}, {self.source}"


@dataclass(frozen=True)
class PublishedRow:
    """A protocol's column of the paper's Table 1 (intervals in µs) and its mean rate."""

    protocol: str
    setup: str
    """What the paper's figures are intervals of, in its words (§5.2)."""
    expected_us: Published
    mean_us: Published
    median_us: Published
    p1_us: Published
    p99_us: Published
    spread_us: Published
    rate_hz: Published
    """The mean rate §5.2 states, 1 / mean interval."""

    def figures(self) -> dict[str, Published]:
        """The Table 1 figures by statistic, in table order."""
        return {
            "expected_us": self.expected_us,
            "mean_us": self.mean_us,
            "median_us": self.median_us,
            "p1_us": self.p1_us,
            "p99_us": self.p99_us,
            "spread_us": self.spread_us,
        }


def _table1(ms: float) -> Published:
    return Published(round(ms * 1000.0, 3), "Table 1")


TABLE1: dict[str, PublishedRow] = {
    "MSP": PublishedRow(
        "MSP",
        "OBC reception times of MSP_RAW_IMU replies, requested at 1000 Hz",
        expected_us=_table1(1.000),
        mean_us=_table1(1.284),
        median_us=_table1(1.003),
        p1_us=_table1(0.845),
        p99_us=_table1(4.159),
        spread_us=_table1(3.313),
        rate_hz=Published(778.0, "§5.2: MSP reaches a mean reception rate of 778 Hz"),
    ),
    "FSP": PublishedRow(
        "FSP",
        "decoded, clock-aligned sensor-frame timestamps",
        expected_us=_table1(0.953),
        mean_us=_table1(0.952),
        median_us=_table1(0.952),
        p1_us=_table1(0.948),
        p99_us=_table1(0.956),
        spread_us=_table1(0.007),
        rate_hz=Published(1050.0, "§5.2: FSP reports a mean rate of 1050 Hz"),
    ),
}
"""Table 1 ("Timestamp deltas between consecutive IMU samples") by protocol."""


@dataclass(frozen=True)
class Setup:
    """The paper's test set-up (§5.1, §5.2)."""

    board: str
    loop_nominal_hz: Published
    loop_hz: Published
    serial_update_rate_hz: Published
    fsp_rate_hz: Published
    lockstep_n: Published
    msp_rates_hz: dict[str, Published]
    """MSP requests per command, by the command's MSP name."""


SETUP = Setup(
    board="SPEEDYBEEF7V3 (STM32F7, BMI270), Jetson Orin NX 16GB as the OBC (§5.1)",
    loop_nominal_hz=Published(3200.0, "§5.1: a nominal control-loop frequency of 3.2 kHz"),
    loop_hz=Published(3148.0, "§5.1: the scheduler reports an actual frequency of 3148 Hz"),
    serial_update_rate_hz=Published(1000.0, "§5.1: serial_update_rate_hz set to 1000 Hz"),
    fsp_rate_hz=Published(1100.0, "§5.2: the lockstep target is 1100 Hz"),
    lockstep_n=Published(3.0, "§5.2: the integer lockstep interval is three iterations"),
    msp_rates_hz={
        "RAW_IMU": Published(1000.0, "§5.2: IMU data requested at 1000 Hz"),
        "RC": Published(100.0, "§5.2: RC commands at 100 Hz"),
        "ATTITUDE": Published(100.0, "§5.2: attitude at 100 Hz"),
        "ANALOG": Published(10.0, "§5.2: battery voltage at 10 Hz"),
    },
)

MSP_MODES_US: tuple[Published, ...] = tuple(
    Published(ms * 1000.0, "Fig. 2: MSP modes around 1 ms, 1.2 ms, 3.2 ms and 4 ms")
    for ms in (1.0, 1.2, 3.2, 4.0)
)
"""Where the paper's MSP interval distribution has its modes (Fig. 2's caption)."""


@dataclass(frozen=True)
class Said:
    """What the paper says of its figures, in its words, and where."""

    text: str
    source: str


FSP_SPREAD_CAUSE = Said(
    "flight-controller scheduling and timer quantization",
    "Fig. 2: FSP's remaining spread is attributed to",
)
FSP_MEAN_CAUSE = Said(
    "clock-rate mismatch, timer quantization, and rounding in the synchronization estimate",
    "§5.2: the difference of the 1050 Hz from the selected 1049 Hz may arise from",
)
MSP_OUTLIERS = Said("up to about four times the expected interval", "Fig. 3: periodic MSP outliers")
MSP_OUTLIER_RATIO = 4.0
"""How far the paper's MSP outliers reach, in expected intervals (Fig. 3's caption)."""
MSP_BAUD = "the paper does not state the MSP port's baud rate"
FSP_BAUD = "the paper does not state the FSP port's baud rate"
