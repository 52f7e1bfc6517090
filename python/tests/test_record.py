"""HDF5 recordings, read back with h5py and pandas alone."""

from __future__ import annotations

import h5py
import numpy as np
import pandas as pd

import ftafm
from ftafm.testing import Daemon


def test_a_recording_holds_every_stream_with_units_settings_and_gaps(
    ftafm_instrument: ftafm.Instrument, tmp_path
) -> None:
    inst = ftafm_instrument
    inst.set("/surface/distance", 18e-9)
    # Estimates of the new distance come once its estimator is built (longer on a busy
    # machine): wait for the first before recording.
    inst.poll("force", 0.0, timeout=120.0)
    path = tmp_path / "run.h5"
    counts = inst.record(path, ["demods", "force", "spectrum", "status"], seconds=1.2)
    # Force estimates come with the demodulator frames, fewer when the estimator falls
    # behind on a busy machine.
    assert counts["demods"] >= 1000 and counts["force"] >= 1
    assert counts["spectrum"] >= 10 and counts["status"] >= 1

    with h5py.File(path, "r") as f:
        assert f.attrs["ftafm_version"] == inst.hello["version"]
        assert f.attrs["sample_rate"] == 10e6
        assert f.attrs["seconds"] == 1.2
        settings = f.attrs["settings"]
        assert "[surface]\ndistance = 1.8e-8" in settings or "distance = 0.000000018" in settings
        demods = f["demods"]
        n = demods.attrs["messages"]
        assert n == counts["demods"]
        assert demods["r"].shape == (n, 32) and demods["t"].shape == (n,)
        assert demods["r"].attrs["units"] == "m"
        assert demods["phase"].attrs["units"] == "rad"
        assert demods["t"].attrs["units"] == "s"
        seq = demods["seq"][:]
        assert demods.attrs["gaps"] == int(np.sum(np.diff(seq) - 1))
        t = demods["t"][:]
        assert np.all(np.diff(t) > 0) and t[-1] - t[0] < 1.2
        assert f["force"]["max_force"].attrs["units"] == "N"
        assert f["force"]["waveform"].shape[0] == f["force"].attrs["messages"]
        assert f["spectrum"]["magnitudes"].shape[1] == 32768 // 2 + 1
        # The bins' frequencies once (an axis), not once per spectrum.
        freq = f["spectrum"]["frequency"]
        assert freq.shape == (32768 // 2 + 1,) and freq.attrs["units"] == "Hz"
        assert freq[1] == inst.hello["sample_rate"] / 32768
        # NeXus: what h5web and silx plot without code.
        assert f.attrs["NX_class"] == "NXroot" and f.attrs["default"] == "demods"
        for stream, signal, axes in [
            ("demods", "r", ["t", "."]),
            ("spectrum", "magnitudes", ["t", "frequency"]),
            ("force", "max_force", ["t"]),
            ("status", "realtime_factor", ["t"]),
        ]:
            g = f[stream]
            assert g.attrs["NX_class"] == "NXdata" and g.attrs["signal"] == signal
            assert list(g.attrs["axes"]) == axes
            assert g[signal].ndim == len(axes)
            for axis, length in zip(axes, g[signal].shape):
                assert axis == "." or g[axis].shape == (length,), (stream, axis)
        assert list(f["demods"].attrs["auxiliary_signals"]) == ["x", "y", "phase"]
        assert "counters" in f["status"]["messages_json"][0].decode()
        # pandas reads it without the package.
        frame = pd.DataFrame({"t": t, "h1": demods["r"][:, 0], "h17": demods["r"][:, 16]})
        assert frame["h1"].between(5e-9, 30e-9).all()

    # The settings in the file are what the daemon accepts with --config.
    config = tmp_path / "from-recording.toml"
    with h5py.File(path, "r") as f:
        config.write_text(f.attrs["settings"])
    with Daemon(["--config", str(config)]) as d, ftafm.Instrument(d.url) as other:
        assert other.get("/surface/distance") == 18e-9
