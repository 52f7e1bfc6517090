"""The QCoDeS driver."""

from __future__ import annotations

import pytest

pytest.importorskip("qcodes", reason="the [qcodes] extra")

import ftafm  # noqa: E402
from ftafm.qcodes import FTAFM, parameter_name  # noqa: E402
from ftafm.testing import Daemon  # noqa: E402


def test_every_node_is_a_parameter_with_unit_and_validator(ftafm_daemon: Daemon) -> None:
    assert parameter_name("/sample/youngs_modulus") == "sample_youngs_modulus"
    afm = FTAFM("afm_test", ftafm_daemon.url)
    try:
        saved = afm.client.settings_toml()
        nodes = afm.client.nodes()
        for node in nodes:
            assert parameter_name(node.path) in afm.parameters, node.path
        p = afm.sample_youngs_modulus
        assert p.unit == "Pa"
        assert p() == 129e9
        afm.surface_distance(15e-9)
        assert afm.surface_distance() == 15e-9
        assert afm.client.get("/surface/distance") == 15e-9
        # The validator refuses out of range values before they are sent…
        with pytest.raises(ValueError):
            afm.drive_free_amplitude(1.0)
        with pytest.raises(ValueError):
            afm.spectrum_window("hamming")
        afm.spectrum_window("hann")
        assert afm.spectrum_window() == "hann"
        # …and what only the daemon knows is its error, naming the node.
        with pytest.raises(ftafm.InstrumentError, match="/inversion/harmonic_a"):
            afm.demods_5_enable(False)
        # Read-only nodes are get-only.
        with pytest.raises(NotImplementedError):
            afm.synth_sample_rate(20e6)
        # Measured parameters.
        assert 5e-9 < afm.demod0_r() < 30e-9
        assert -3.2 < afm.demod0_phase() < 3.2
        assert afm.force_max_force() > 0
        assert afm.get_idn()["vendor"] == "ftafm"
        afm.client._run(afm.client._async.request("load_settings", toml=saved))
    finally:
        afm.close()
