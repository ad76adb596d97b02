"""The numpy Butterworth and zero-phase filter against scipy.signal, on series with a known
low-frequency signal."""
import numpy as np
import pytest

from mvm.rig.filters import butter_lowpass, filtfilt, filtfilt_many

signal = pytest.importorskip("scipy.signal")


@pytest.mark.parametrize("order", [1, 2, 3, 4])
@pytest.mark.parametrize("wn", [0.05, 0.4, 0.9])
def test_butter_lowpass_equals_scipy(order, wn):
    b, a = butter_lowpass(order, wn)
    expected_b, expected_a = signal.butter(order, wn)
    np.testing.assert_allclose(b, expected_b, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(a, expected_a, rtol=1e-12, atol=1e-15)


def test_filtfilt_equals_scipy_and_keeps_a_slow_signal():
    rng = np.random.default_rng(0)
    t = np.arange(200) / 30.0
    truth = np.stack([np.sin(2 * np.pi * 0.5 * t), np.cos(2 * np.pi * 0.3 * t), t], axis=1)   # (200, 3)
    noisy = truth + rng.normal(0, 0.05, truth.shape)
    b, a = butter_lowpass(2, 6.0 / 15.0)
    smooth = filtfilt(b, a, noisy)
    np.testing.assert_allclose(smooth, signal.filtfilt(b, a, noisy, axis=0), rtol=0, atol=1e-12)
    # white noise keeps about sqrt(0.4) of its amplitude through a cut-off at 0.4 of the Nyquist frequency
    assert np.abs(smooth - truth).mean() < 0.75 * np.abs(noisy - truth).mean()


def test_filtfilt_many_equals_one_at_a_time():
    rng = np.random.default_rng(1)
    series = [rng.normal(size=(n, c)).cumsum(0) for n, c in ((13, 3), (80, 6), (31, 1))]
    b, a = butter_lowpass(2, 0.3)
    for x, y in zip(series, filtfilt_many(b, a, series)):
        np.testing.assert_allclose(y, signal.filtfilt(b, a, x, axis=0), rtol=0, atol=1e-12)


def test_too_short_and_bad_cutoff_are_refused():
    b, a = butter_lowpass(2, 0.3)
    with pytest.raises(ValueError, match="longer than 9"):
        filtfilt(b, a, np.zeros((9, 3)))
    with pytest.raises(ValueError, match="cut-off"):
        butter_lowpass(2, 1.0)


@pytest.mark.parametrize("order", [1, 2, 3, 4, 6, 8])
def test_at_the_lowest_cut_off_a_constant_series_is_kept(order):
    from mvm.rig.filters import min_cutoff

    x = np.full((400, 3), 5.0)
    b, a = butter_lowpass(order, min_cutoff(order))
    assert np.abs(filtfilt(b, a, x) - x).max() < 1e-6 * 5.0
    with pytest.raises(ValueError, match="reliable"):
        butter_lowpass(order, min_cutoff(order) / 2)


@pytest.mark.parametrize("sets, field", [(["--frame-rate", "1e12"], "frame_rate"),
                                         (["--rig-set", "cutoff_hz=1e-9"], "cutoff_hz"),
                                         (["--rig-set", "cutoff_hz=1e-3", "--rig-set", "filter_order=16"],
                                          "cutoff_hz")])
def test_a_cut_off_the_filter_cannot_reach_is_one_line_naming_the_setting(tmp_path, sets, field):
    from click.testing import CliRunner

    from mvm.cli.main import main

    result = CliRunner().invoke(main, ["rig", "reconstruct", str(tmp_path), *sets])
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert result.exit_code == 2 and len(lines) == 1 and f"{field}: a cut-off of" in lines[0], result.output


def test_savgol_smoothing_has_no_cut_off_to_check(tmp_path):
    from mvm.rig.options import RigOptions
    from mvm.rig.reconstruct_rig import check_smoothing

    check_smoothing(RigOptions(smoothing="savgol", frame_rate=1e12))
    check_smoothing(RigOptions(frame_rate=30.0, cutoff_hz=0.01))
