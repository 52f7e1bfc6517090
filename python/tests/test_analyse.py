"""``ftafm.analyse`` on numpy arrays and h5py datasets: the tones' amplitudes and phases."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

import ftafm
from ftafm.analyse import AnalysisError, analyse

FS, F = 1e6, 10_123.4


def _tones(seconds: float = 0.1) -> np.ndarray:
    """The signal (two tones, V) and the excitation, as samples × channels."""
    theta = 2 * np.pi * F * np.arange(int(seconds * FS)) / FS
    signal = 0.5 * np.cos(theta + 0.3) + 0.1 * np.cos(3 * theta - 1.0)
    return np.stack([signal, 0.8 * np.cos(theta)], axis=1)


@pytest.fixture
def no_inversion(tmp_path):
    path = tmp_path / "noinv.toml"
    path.write_text("[inversion]\nenable = false\n")
    return path


def _check(result: ftafm.Analysis, scale: float) -> None:
    d = result.demods
    assert len(d) >= 90
    h = d["harmonic"][0]
    settled = d[20:]
    i1, i3 = int(np.flatnonzero(h == 1)[0]), int(np.flatnonzero(h == 3)[0])
    np.testing.assert_allclose(settled["r"][:, i1], 0.5 * scale, rtol=1e-4)
    np.testing.assert_allclose(settled["r"][:, i3], 0.1 * scale, rtol=1e-3)
    np.testing.assert_allclose(settled["phase"][:, i1], 0.3, atol=1e-3)
    np.testing.assert_allclose(settled["phase"][:, i3], -1.0, atol=2e-3)
    assert np.all(np.diff(d["t"]) > 0)


def test_an_array_with_its_excitation_channel_gives_each_tones_amplitude_and_phase(
    no_inversion, tmp_path
) -> None:
    invols = 50e-9
    result = analyse(
        _tones(), FS, invols=invols, reference_channel=1, config=no_inversion
    )
    _check(result, invols)
    assert result.summary["reference"]["source"] == "channel 1"
    assert abs(result.summary["reference"]["frequency"] - F) < 1e-3
    assert result.force is None and result.summary["why_no_force"]
    assert result.spectrum is not None and len(result.frequency) == result.spectrum[
        "magnitudes"
    ].shape[1]
    path = tmp_path / "a.h5"
    result.save_hdf5(path)
    with h5py.File(path, "r") as f:
        assert f.attrs["sample_rate"] == FS
        assert f["demods"]["r"].shape == result.demods["r"].shape
        assert f["demods"]["r"].attrs["units"] == "m"
        assert f["spectrum"]["frequency"].attrs["units"] == "Hz"


def test_a_second_excitation_channel_is_drive2s_reference(tmp_path) -> None:
    # Demodulator 1 on drive2 at harmonic 1; the second excitation on channel 2 at an
    # unrelated frequency and phase, the signal's tone at it 0.7 rad on.
    config = tmp_path / "drive2.toml"
    config.write_text(
        "[inversion]\nenable = false\n[drive2]\nfrequency = 63e3\n"
        '[demods.1]\nharmonic = 1\noscillator = "drive2"\n'
    )
    n = np.arange(int(0.1 * FS))
    theta, theta2 = 2 * np.pi * F * n / FS, 2 * np.pi * 63_456.7 * n / FS - 2.1
    signal = 0.5 * np.cos(theta + 0.3) + 0.2 * np.cos(theta2 + 0.7)
    data = np.stack([signal, 0.8 * np.cos(theta), 0.6 * np.cos(theta2)], axis=1)
    result = analyse(
        data, FS, units="m", reference_channel=1, reference2_channel=2, config=config
    )
    assert result.summary["reference2"]["source"] == "channel 2"
    assert abs(result.summary["reference2"]["frequency"] - 63_456.7) < 1e-3
    settled = result.demods[20:]
    np.testing.assert_allclose(settled["r"][:, 1], 0.2, rtol=1e-4)
    np.testing.assert_allclose(settled["phase"][:, 1], 0.7, atol=1e-3)
    np.testing.assert_allclose(settled["phase"][:, 0], 0.3, atol=1e-3)
    with pytest.raises(AnalysisError, match="--reference2-channel must differ"):
        analyse(
            data, FS, units="m", reference_channel=1, reference2_channel=0, config=config
        )


def test_an_hdf5_dataset_is_streamed_to_the_binary(no_inversion, tmp_path) -> None:
    path = tmp_path / "in.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("signal", data=_tones().astype("f4"))
    with h5py.File(path, "r") as f:
        result = analyse(
            f["signal"], FS, units="m", reference_channel=1, config=no_inversion
        )
    _check(result, 1.0)
    assert result.summary["samples"] == 100_000


def test_bad_input_raises_the_binarys_message(no_inversion) -> None:
    with pytest.raises(AnalysisError, match="--invols"):
        analyse(_tones(), FS, reference_channel=1, config=no_inversion)
    bad = _tones()
    bad[500, 0] = np.nan
    with pytest.raises(AnalysisError, match="sample 500 of channel 0 is NaN"):
        analyse(bad, FS, units="m", reference_channel=1, config=no_inversion)
