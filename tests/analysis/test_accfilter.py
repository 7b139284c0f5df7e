"""The evaluation: flight figures against theory, and `wftool analyze accfilter` end to end."""

from __future__ import annotations

import json
import re

import pytest

from tests.analysis.test_harness import cascade_group_delay_ms
from tests.conftest import run_cli

np = pytest.importorskip("numpy", reason="needs the analysis extra (NumPy)")
pytest.importorskip("scipy", reason="needs the analysis extra (SciPy)")

from wftool.analysis import accfilter  # noqa: E402 - after the extra's check
from wftool.analysis.flight import FlightSpec  # noqa: E402
from wftool.analysis.harness import PRESETS  # noqa: E402


def test_flight_figures_match_theory_and_follow_the_settings(host_harness):
    """A steady flight: the cross-spectrum delay is the coefficients' delay; H2 needs harmonics."""
    spec = FlightSpec(duration_s=8.0, start_hz=200.0, end_hz=200.0, wobble=0.0)
    settings = [PRESETS["paper"], PRESETS["harmonics3"]]
    evaluation = accfilter.evaluate(host_harness, settings, [1000], spec, repeat=1)
    paper, harmonics3 = (config.rates[0] for config in evaluation.configs)

    motors = 200.0 * np.asarray(spec.motor_ratio)
    coefficients = host_harness.filter(settings[0], 1000, 4).coefficients(motors)
    theory = cascade_group_delay_ms(coefficients, accfilter.MOTION_FREQUENCIES_HZ[:4], 1000)
    np.testing.assert_allclose(paper.motion_group_delay_ms[:4], theory, rtol=0.05)
    np.testing.assert_allclose(paper.fixed_group_delay_ms[1][:4], theory, rtol=0.01)
    assert abs(paper.motion_gain_db[3]) < 0.05

    h1, h2 = paper.attenuation_db[0][0], paper.attenuation_db[1][0]
    assert h1 is not None and h1 < -30.0
    assert h2 is not None and h2 > -1.0  # the paper's default leaves the 2nd harmonic alone
    assert harmonics3.attenuation_db[1][0] < -30.0
    assert harmonics3.vibration_reduction_db < paper.vibration_reduction_db < -3.0
    assert harmonics3.group_delay_mean_ms > paper.group_delay_mean_ms


def test_accfilter_command_writes_report_and_series(firmware_tree, capsys, tmp_path):
    pytest.importorskip("unicorn", reason="needs the analysis extra (Unicorn)")
    out_dir = tmp_path / "report"
    code, stdout, stderr = run_cli(
        capsys, "analyze", "accfilter", "--project", str(firmware_tree.parent),
        "--config", "paper", "--config", "narrow:q=800,harmonics=2", "--rate", "1000",
        "--duration", "4", "--repeat", "2", "--out", str(out_dir),
    )  # fmt: skip
    assert code == 0, stderr
    report = json.loads((out_dir / "accfilter.json").read_text())
    assert [c["settings"]["name"] for c in report["configs"]] == ["paper", "narrow"]
    assert report["configs"][1]["settings"]["q"] == 800
    assert re.fullmatch(r"[0-9a-f]{40}(-dirty)?", report["provenance"]["betaflight revision"])
    rate = report["configs"][0]["rates"][0]
    assert rate["m7"]["us_per_sample"] > 0 and rate["host"]["total_ns_per_sample_axis"] > 0
    assert report["m7_check"]["agrees"] is True
    assert "| narrow | 1000 |" in (out_dir / "accfilter.md").read_text()
    assert "narrow" in stdout and "notches" in stdout

    from wftool.analysis.spectrum import read_series

    series = read_series(out_dir / "flight-1000hz.npz")
    assert [p.label for p in series.panels] == ["raw", "filtered"]
    assert series.motor_hz.shape == (4000, 4)


def test_bad_filter_setting_is_exit_2(capsys, tmp_path):
    code, _, stderr = run_cli(
        capsys, "analyze", "accfilter", "--config", "x:q=20", "--out", str(tmp_path / "r")
    )
    assert code == 2 and "outside 250..3000" in stderr
    assert len(stderr.strip().splitlines()) == 1
