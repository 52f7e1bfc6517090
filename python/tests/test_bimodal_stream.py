"""The ``bimodal`` stream through the client: ``poll`` gives a :class:`ftafm.data.BimodalData`
row per demodulator frame, stamped with the settings epoch, and says why a frame has no
estimate (here: no PID unit is mode 2's PLL). The estimate itself is tested against the
configured modulus in the daemon's tests (tests/bimodal_loops.rs)."""

from __future__ import annotations

import numpy as np

import ftafm
from ftafm.data import BimodalData


def test_the_bimodal_stream_says_why_it_has_no_estimate(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    inst.set("/drive2/enable", True)
    data = inst.poll("bimodal", 0.005)
    assert isinstance(data, BimodalData)
    assert len(data) > 0 and data.gaps == 0
    assert np.all(np.isnan(data.reduced_modulus)) and np.all(np.isnan(data.frequency_shift2))
    assert np.all(np.isnan(data.pll_sample)) and np.all(np.isnan(data.pll_age))
    assert data.epoch.dtype == np.int64 and np.all(data.epoch >= 1)
    assert all(r is not None and "mode 2's PLL" in r for r in data.reason), data.reason[:3]
