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
    path = tmp_path / "run.h5"
    counts = inst.record(path, ["demods", "force", "spectrum", "status"], seconds=1.2)
    assert counts["demods"] >= 1000 and counts["force"] >= 1000
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
        assert demods["r"].attrs["unit"] == "m"
        assert demods["phase"].attrs["unit"] == "rad"
        assert demods["t"].attrs["unit"] == "s"
        seq = demods["seq"][:]
        assert demods.attrs["gaps"] == int(np.sum(np.diff(seq) - 1))
        t = demods["t"][:]
        assert np.all(np.diff(t) > 0) and t[-1] - t[0] < 1.2
        assert f["force"]["max_force"].attrs["unit"] == "N"
        assert f["force"]["waveform"].shape[0] == f["force"].attrs["messages"]
        assert f["spectrum"]["magnitudes"].shape[1] == 32768 // 2 + 1
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
