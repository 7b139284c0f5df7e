"""Fig. 4 from a recording written by the real recorder, from a harness series, and bad input."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from tests.conftest import NEEDS_MATPLOTLIB, run_cli
from tests.recording.test_reader import RecordingMonitor
from wftool.fsp import SensorFrame, StatePacket
from wftool.fsp.encoder import encode_state
from wftool.recording.recorder import Recorder

np = pytest.importorskip("numpy", reason="needs the analysis extra (NumPy)")
pytest.importorskip("scipy", reason="needs the analysis extra (SciPy)")
pytestmark = NEEDS_MATPLOTLIB

from wftool.analysis.spectrum import Panel, read_series, spectrogram, write_series  # noqa: E402

PERIOD_US = 1000
ONE_G = 2048
MOTOR_RPM = 7200  # 120 Hz


def tone_frame(t_us: int, start_us: int) -> SensorFrame:
    """x: 120 Hz at 0.5 g (the motors); z: gravity plus 250 Hz at 0.3 g."""
    t = (t_us - start_us) * 1e-6
    acc = (
        round(ONE_G * 0.5 * math.sin(2 * math.pi * 120.0 * t)),
        0,
        round(ONE_G * (-1.0 + 0.3 * math.sin(2 * math.pi * 250.0 * t))),
    )
    return SensorFrame(
        t_us % 2**32, acc, ONE_G, 0.06, (0, 0, 0), (32767, 0, 0, 0), (1500,) * 6,
        (MOTOR_RPM,) * 4, 1600,
    )  # fmt: skip


def write_recording(path: Path, segments: list[tuple[int, int]]) -> None:
    """An MCAP file of `verify --record`: each segment (FC start time µs, packets) after the
    previous one on the OBC clock; a segment starting earlier on the FC clock is a reset."""
    arrival = 100.0
    seq = 0
    with Recorder(path, None, {"port": "test"}) as recorder:
        live = RecordingMonitor(recorder)
        live.connected(arrival)
        for start_us, packets in segments:
            for index in range(packets):
                t = start_us + 2 * index * PERIOD_US
                frames = (tone_frame(t, start_us), tone_frame(t + PERIOD_US, start_us))
                arrival += 2 * PERIOD_US * 1e-6
                packet = StatePacket(t + PERIOD_US + 50, frames, seq % 2**24, True, 0)
                live.feed(encode_state(packet), arrival)
                seq += 1
        live.disconnected(arrival)


def test_recording_spectrum_shows_the_tones_and_the_motors(tmp_path, capsys):
    recording, png = tmp_path / "run.mcap", tmp_path / "fig4.png"
    write_recording(recording, [(5_000_000, 1500)])  # 3 s at 1 kHz
    code, stdout, stderr = run_cli(capsys, "analyze", "spectrum", str(recording), "--out", str(png))
    assert code == 0, stderr
    assert "120 Hz" in stdout and "250 Hz" in stdout
    picture = imread(png)
    assert picture.ndim == 3 and picture.shape[0] > 300 and picture.shape[1] > 800

    series = read_series(recording)
    assert series.sample_rate_hz == pytest.approx(1000.0)
    np.testing.assert_allclose(series.motor_hz, 120.0)
    for axis, tone in (("x", 120.0), ("z", 250.0)):
        spec = spectrogram(series, axis)
        strongest = spec.frequencies_hz[np.argmax(spec.power[0], axis=0)]
        assert np.all(np.abs(strongest - tone) <= 5.0)  # the 0.2 s window's 5 Hz bins


def test_fc_reset_splits_and_says_so(tmp_path, capsys):
    recording = tmp_path / "reset.mcap"
    write_recording(recording, [(50_000_000, 400), (2_000_000, 1000)])
    code, stdout, stderr = run_cli(capsys, "analyze", "spectrum", str(recording))
    assert code == 0, stderr
    assert "FC reset" in stderr and "2.0 s of" in stderr
    assert (tmp_path / "reset.spectrum.png").is_file()
    assert "2.0 s at 1000 Hz" in stdout


def test_series_panels_before_and_after(tmp_path, capsys):
    rate, seconds = 800, 3.0
    t = np.arange(int(rate * seconds)) / rate
    raw = np.stack([np.sin(2 * np.pi * 150 * t), 0.2 * np.sin(2 * np.pi * 7 * t), -1 + 0 * t], 1)
    filtered = raw * np.array([0.01, 1.0, 1.0])
    path = tmp_path / "flight.npz"
    write_series(
        path, t, np.full((t.size, 4), 150.0),
        [Panel("raw", "before", raw), Panel("filtered", "after", filtered)],
    )  # fmt: skip
    code, stdout, stderr = run_cli(capsys, "analyze", "spectrum", str(path), "--axis", "x")
    assert code == 0, stderr
    peaks = dict(
        re.findall(r"^\s+(before|after): strongest peaks 150 Hz \((-?\d+) dB\)", stdout, re.M)
    )
    assert int(peaks["after"]) - int(peaks["before"]) == pytest.approx(-40, abs=1)
    spec = spectrogram(read_series(path), "x")
    band = np.abs(spec.frequencies_hz - 150.0) <= 5.0
    ratio_db = 10 * np.log10(spec.power[1][band].sum() / spec.power[0][band].sum())
    assert ratio_db == pytest.approx(-40.0, abs=0.5)
    two_panels = imread(tmp_path / "flight.spectrum.png")
    assert two_panels.shape[0] > 1.5 * 504  # taller than a one-panel figure (4.2 in at 120 dpi)


def bad_inputs(tmp_path: Path) -> dict[str, Path]:
    good = tmp_path / "good.mcap"
    write_recording(good, [(5_000_000, 600)])
    data = good.read_bytes()
    files = {
        "empty": b"",
        "cut_in_its_header": data[:20],
        "foreign": b"time,acc\n0,1\n",
        "not_a_series": None,
    }
    paths = {}
    for name, content in files.items():
        path = tmp_path / f"{name}.bin"
        if content is None:
            with open(path, "wb") as handle:
                np.savez(handle, x=np.zeros(3))
        else:
            path.write_bytes(content)
        paths[name] = path
    paths["missing"] = tmp_path / "nonesuch.mcap"
    no_frames = tmp_path / "no-frames.mcap"
    with Recorder(no_frames, None, {}):
        pass
    paths["no_frames"] = no_frames
    return paths


def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys):
    for name, path in bad_inputs(tmp_path).items():
        code, stdout, stderr = run_cli(capsys, "analyze", "spectrum", str(path))
        assert code == 2, (name, stdout, stderr)
        assert len(stderr.strip().splitlines()) == 1, (name, stderr)
        assert "error:" in stderr and "Traceback" not in stderr
        assert not path.with_suffix(".spectrum.png").exists()


def test_a_recording_cut_short_is_analysed_as_far_as_it_goes(tmp_path, capsys):
    good = tmp_path / "good.mcap"
    write_recording(good, [(5_000_000, 3000)])
    data = good.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 3 // 4])  # as a killed writer leaves it
    code, stdout, stderr = run_cli(capsys, "analyze", "spectrum", str(cut))
    assert code == 0, stderr
    assert "was not finished" in stdout + stderr and "lost:" in stdout + stderr
    assert cut.with_suffix(".spectrum.png").exists()


def test_missing_extra_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch):
    import sys

    recording = tmp_path / "run.mcap"
    write_recording(recording, [(5_000_000, 300)])
    monkeypatch.setitem(sys.modules, "scipy", None)  # `import scipy` now raises ImportError
    code, _, stderr = run_cli(capsys, "analyze", "spectrum", str(recording))
    assert code == 2
    assert stderr.strip() == "error: analyze spectrum needs SciPy: pip install 'wftool[analysis]'"
    assert len(stderr.strip().splitlines()) == 1

    monkeypatch.setitem(sys.modules, "unicorn", None)
    code, _, stderr = run_cli(capsys, "analyze", "accfilter", "--out", str(tmp_path / "r"))
    assert code == 2 and "SciPy and Unicorn: pip install 'wftool[analysis]'" in stderr
    assert not (tmp_path / "r").exists()


def imread(path: Path) -> np.ndarray:
    """The picture at `path` (Matplotlib, imported here: see `NEEDS_MATPLOTLIB`)."""
    from matplotlib import image

    return image.imread(path)
