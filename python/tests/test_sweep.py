"""Instrument.sweep against the daemon's sweeper."""

from __future__ import annotations

import numpy as np
import pytest

import ftafm


def test_a_tune_and_an_approach_curve(ftafm_instrument: ftafm.Instrument) -> None:
    inst = ftafm_instrument
    inst.set("/surface/distance", 200e-9)
    tune = inst.sweep("/drive/frequency", 99.5e3, 100.5e3, 41)
    assert isinstance(tune, ftafm.SweepResult) and tune.outcome == "done"
    assert len(tune) == 41 and tune.leg == ["up"] * 41
    assert tune.value[0] == 99.5e3 and tune.value[-1] == 100.5e3
    h1 = tune.r_of(1)
    assert np.argmax(h1) == 20, "the peak at f1"
    assert abs(tune.final["tune"]["f0"] / 100e3 - 1) < 5e-4
    assert abs(tune.final["tune"]["q"] / 100 - 1) < 0.03
    assert np.all(tune.free_amplitude > 0)
    assert inst.get("/drive/frequency") == 100e3, "restored"

    inst.set("/surface/distance", 20e-9)
    curve = inst.sweep("/surface/distance", 36e-9, 12e-9, 13, direction="both")
    assert curve.outcome == "done" and len(curve) == 26
    assert curve.leg[:13] == ["up"] * 13 and curve.leg[13:] == ["down"] * 13
    approach = curve.final["approach"]
    assert 27e-9 <= approach["contact_up"] <= 31e-9
    r = curve.r_of(1)[:13]
    assert r[-1] < 0.5 * r[0], "tapping at 12 nm"
    # The force estimates of each point (the default config runs the inversion).
    touching = curve.value < 26e-9
    assert np.all(np.isfinite(curve.max_force[touching]))
    assert np.all((curve.max_force[touching] > 30e-9) & (curve.max_force[touching] < 120e-9))
    assert np.all(curve.max_force_sigma[touching] > 0)
    free = curve.value > 32e-9
    assert np.all(np.isnan(curve.max_force[free]))
    assert all(isinstance(curve.force_error[i], str) for i in np.flatnonzero(free))
    assert np.all(np.isnan(curve.mean_deflection)), "no demodulator at harmonic 0 by default"
    assert inst.get("/surface/distance") == 20e-9


def test_a_bad_sweep_raises_naming_the_node(ftafm_instrument: ftafm.Instrument) -> None:
    with pytest.raises(ftafm.InstrumentError) as e:
        ftafm_instrument.sweep("/surface/distance", -1e-9, 10e-9, 5)
    assert e.value.code == "invalid_value" and "/sweeper/start" in e.value.message
    with pytest.raises(ftafm.InstrumentError) as e:
        ftafm_instrument.sweep("/cantilever/k", 1, 2, 5)
    assert "/sweeper/parameter" in e.value.message or "/surface/distance" in e.value.message


def test_a_sweep_that_times_out_is_aborted_and_the_next_gets_its_own_points(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    inst.set("/surface/distance", 200e-9)
    # Long enough that its first point cannot come within the timeout.
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.sweep("/drive/frequency", 99e3, 101e3, 400, settling=0.5, timeout=0.05)
    assert e.value.code == "timeout"
    assert inst.get("/sweeper/enable") is False, "the interrupted sweep was aborted"
    tune = inst.sweep("/drive/frequency", 99.5e3, 100.5e3, 5)
    assert tune.outcome == "done" and len(tune) == 5
    assert list(tune.value) == [99.5e3, 99.75e3, 100e3, 100.25e3, 100.5e3]
    assert inst.get("/drive/frequency") == 100e3, "restored"


def test_each_sweep_has_its_own_defaults_and_reports_its_progress(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    inst.set("/surface/distance", 200e-9)
    seen: list[tuple[int, int]] = []
    both = inst.sweep(
        "/drive/frequency", 99.9e3, 100.1e3, 3, direction="both", averaging=2,
        progress=lambda done, total: seen.append((done, total)),
    )
    assert len(both) == 6 and both.leg == ["up"] * 3 + ["down"] * 3
    assert seen == [(k, 6) for k in range(7)]
    assert inst.get("/sweeper/direction") == "both"
    # A later call without direction= is a call of its own: up, not what the last one left.
    up = inst.sweep("/drive/frequency", 99.9e3, 100.1e3, 3, progress=True)
    assert len(up) == 3 and up.leg == ["up"] * 3
    assert inst.get_many(["/sweeper/direction", "/sweeper/averaging", "/sweeper/scale"]) == {
        "/sweeper/direction": "up",
        "/sweeper/averaging": 4,
        "/sweeper/scale": "linear",
    }
