"""The filter harness: compiled from the tree's own code, checked against independent numbers.

The series' unit test thresholds, and the group delay scipy computes from the notch
coefficients the firmware code itself reports.
"""

from __future__ import annotations

import dataclasses

import pytest

from wftool.analysis.harness import PRESETS, FilterSettings
from wftool.errors import UsageError

UNIT_TEST_MOTORS = (173.0, 201.0, 229.0, 257.0)  # acc_rpm_filter_unittest.cc


def test_settings_parse_presets_and_reject_bad_values():
    assert FilterSettings.parse("paper") == FilterSettings()
    custom = FilterSettings.parse("wide:harmonics=2,acc_rpm_filter_q=300,weights=100/50/0")
    assert (custom.name, custom.harmonics, custom.q) == ("wide", 2, 300)
    assert custom.weights == (100, 50, 0) and custom.min_hz == 60
    for bad in ("nonesuch", "x:q=20", "x:harmonics=two", "x:colour=red", "x:weights=1/2", ":q=5"):
        with pytest.raises(UsageError):
            FilterSettings.parse(bad)


def worst_axis_gain_db(harness, settings, rate: int, motors, tone_hz: float) -> float:
    """Steady-state gain of a tone on all three axes (worst axis), as the unit test measures."""
    np = pytest.importorskip("numpy")
    count = 8 * rate
    t = np.arange(count) / rate
    x = 1000.0 * np.sin(2 * np.pi * tone_hz * t)
    out = harness.filter(settings, rate, len(motors)).run(
        np.tile(motors, (count, 1)), np.stack([x, 0.5 * x, -x], axis=1)
    )
    settled = slice(4 * rate, count)
    power_in = np.sum(x[settled] ** 2) * np.array([1.0, 0.25, 1.0])
    return float(np.max(10 * np.log10(np.sum(out[settled] ** 2, axis=0) / power_in)))


@pytest.mark.parametrize("rate", [800, 1000])
def test_motor_tone_is_notched_and_motion_passes(host_harness, rate):
    """The unit test's thresholds: > 20 dB at a motor frequency, < 0.5 dB change at 5 Hz."""
    paper = PRESETS["paper"]
    assert worst_axis_gain_db(host_harness, paper, rate, UNIT_TEST_MOTORS, 201.0) < -20.0
    assert abs(worst_axis_gain_db(host_harness, paper, rate, UNIT_TEST_MOTORS, 5.0)) < 0.5
    # and it is a notch, not a low pass: a tone well away from every motor passes
    assert worst_axis_gain_db(host_harness, paper, rate, UNIT_TEST_MOTORS, 330.0) > -3.0


def test_the_harness_runs_the_trees_code(filter_sources, tmp_path):
    """The same harness, built from an acc_rpm_filter.c that never activates, stops notching."""
    from wftool.analysis.harness import HostHarness, compile_host_library

    original = next(p for p in filter_sources.sources if p.name == "acc_rpm_filter.c")
    text = original.read_text()
    marker = "filter->numHarmonics = MIN(config->acc_rpm_filter_harmonics"
    assert marker in text
    inert = tmp_path / "acc_rpm_filter.c"
    inert.write_text(
        text.replace(marker, "filter->numHarmonics = 0 * MIN(config->acc_rpm_filter_harmonics")
    )
    sources = dataclasses.replace(
        filter_sources,
        sources=tuple(inert if p == original else p for p in filter_sources.sources),
        include_dirs=(*filter_sources.include_dirs, original.parent),  # its "acc_rpm_filter.h"
    )
    harness = HostHarness(compile_host_library(sources, tmp_path / "lib"))
    assert abs(worst_axis_gain_db(harness, PRESETS["paper"], 1000, UNIT_TEST_MOTORS, 201.0)) < 0.01


def cascade_group_delay_ms(coefficients, frequencies_hz, rate):
    """scipy's group delay of the weighted notches in series: H = w·B/A + (1 − w)."""
    np = pytest.importorskip("numpy")
    signal = pytest.importorskip("scipy.signal")
    numerator, denominator = np.array([1.0]), np.array([1.0])
    for b0, b1, b2, a1, a2, weight in coefficients.reshape(-1, 6):
        a = np.array([1.0, a1, a2])
        numerator = np.convolve(numerator, weight * np.array([b0, b1, b2]) + (1 - weight) * a)
        denominator = np.convolve(denominator, a)
    _, delay = signal.group_delay((numerator, denominator), w=frequencies_hz, fs=rate)
    return 1e3 * delay / rate


@pytest.mark.parametrize(
    ("preset", "rate", "motors"),
    [
        ("paper", 1000, (150.0, 160.0, 170.0, 180.0)),
        ("paper", 800, (97.0, 99.0, 101.0, 103.0)),  # partly faded in above min_hz
        ("harmonics3", 1000, (120.0, 125.0, 130.0, 135.0)),
        ("q3", 800, (250.0, 260.0, 270.0, 280.0)),
    ],
)
def test_group_delay_agrees_with_the_reported_coefficients(host_harness, preset, rate, motors):
    np = pytest.importorskip("numpy")
    signal = pytest.importorskip("scipy.signal")
    from wftool.analysis.accfilter import MOTION_FREQUENCIES_HZ, fixed_group_delay_ms

    settings = PRESETS[preset]
    measured = fixed_group_delay_ms(host_harness, settings, rate, motors)
    coefficients = host_harness.filter(settings, rate, 4).coefficients(np.asarray(motors))
    assert coefficients.shape == (4, settings.harmonics, 6)
    expected = cascade_group_delay_ms(coefficients, MOTION_FREQUENCIES_HZ, rate)
    assert expected[0] > 0.1  # a real delay, not zero against zero
    np.testing.assert_allclose(measured, expected, rtol=2e-3, atol=1e-4)
    # the reported coefficients are notches at the motors' frequencies
    for index, motor_hz in enumerate(motors):
        b0, b1, b2, a1, a2, _ = coefficients[index, 0]
        _, response = signal.freqz([b0, b1, b2], [1.0, a1, a2], worN=[motor_hz], fs=rate)
        assert abs(response[0]) < 0.01
