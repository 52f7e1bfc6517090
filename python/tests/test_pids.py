"""The live PID units through the client: an amplitude loop on the surface distance holds
a set-point the physics reaches, bad settings raise naming the node, and disabling holds
the output (a real daemon, waiting on the units' update counts and epochs)."""

from __future__ import annotations

import pytest

import ftafm
from ftafm.pids import PidStatus

#: Where the loop starts and where its set-point's amplitude is (m).
START = 20e-9
TARGET = 18e-9

#: Updates to let the loop settle: 20 ms at the default 100 kHz drive, five times the
#: 4.4 ms tests/pids.rs measures for a 2 nm step at I = 1200/s.
SETTLE_UPDATES = 2000


def amplitude_at(inst: ftafm.Instrument, distance: float) -> float:
    """The harmonic-1 amplitude (m) the demodulators read with the surface at
    ``distance`` (m), no loop running: 20 ms of frames from 20 ms after the change."""
    t = inst.set("/surface/distance", distance)
    assert t is not None
    inst.wait_until(t + 0.02)
    frames = inst.poll("demods", 0.02)
    return float(frames.r[:, frames.column(1)].mean())


def release_the_surface(inst: ftafm.Instrument) -> None:
    """Every unit off and a new ``/surface/distance``: the surface leaves the distance the
    loops held (a stopped unit keeps it until that node changes), so the fixture's restore
    of the settings (which sets it back) moves it for the tests after."""
    inst.set_many({f"/pids/{n}/enable": False for n in range(4)})
    inst.set("/surface/distance", START + 1e-9)


def amplitude_loop(inst: ftafm.Instrument, setpoint: float) -> PidStatus:
    """PID 0 holding ``setpoint`` on harmonic 1's amplitude, started from ``START``,
    after ``SETTLE_UPDATES`` updates of its settings."""
    inst.set("/surface/distance", START)
    unit = inst.pids[0]
    t = unit.configure(
        input="r",
        harmonic=1,
        setpoint=setpoint,
        p=0.0,
        i=1200.0,
        d=0.0,
        output_min=0.0,
        output_max=100e-9,
        enable=True,
    )
    assert t is not None
    first = unit.wait()
    assert first.latest is not None
    assert first.enable and first.input == "r" and first.harmonic == 1
    assert first.setpoint == setpoint
    assert first.latest.epoch >= inst.epoch
    return unit.wait(updates=first.latest.updates + SETTLE_UPDATES)


def test_an_amplitude_loop_holds_the_distance_whose_amplitude_it_is_given(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    assert len(inst.pids) == 4
    setpoint = amplitude_at(inst, TARGET)
    assert 5e-9 < setpoint < amplitude_at(inst, START)
    settled = amplitude_loop(inst, setpoint)
    latest = settled.latest
    assert latest is not None
    print(f"set-point {setpoint:e} m: {latest}")
    assert latest.output == pytest.approx(TARGET, abs=0.5e-9), "the physics' distance"
    assert abs(latest.error) < 0.01 * setpoint
    assert latest.measurement == pytest.approx(setpoint - latest.error, rel=1e-12)
    assert not latest.limited
    # The other units never ran in this test's settings; all four are reported.
    statuses = inst.pid_status()
    assert [s.index for s in statuses] == [0, 1, 2, 3]
    assert not any(s.enable for s in statuses[1:])

    # Disabled: no more updates, the latest is kept, the surface holds the last output.
    unit = inst.pids[0]
    unit.disable()
    epoch = inst.epoch
    off = unit.wait(lambda s: not s.enable, epoch=0)
    later = unit.wait(lambda s: s.t > off.t, epoch=0)
    assert off.latest is not None and later.latest is not None
    assert later.latest.updates == off.latest.updates
    assert later.latest.epoch < epoch
    assert unit.nodes.enable() is False
    release_the_surface(inst)


def test_bad_settings_raise_naming_the_node_and_change_nothing(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    unit = inst.pids[1]
    unit.configure(setpoint=1e-8, i=100.0, enable=True)
    # The derivative's bandwidth must stay below the PID's Nyquist frequency f/2.
    with pytest.raises(ftafm.InstrumentError) as e:
        unit.configure(d_bandwidth=60e3, setpoint=2e-8)
    assert e.value.code == "invalid_value"
    assert "/pids/1/d_bandwidth" in e.value.message and "50000" in e.value.message
    # A gain of the other sign than I.
    with pytest.raises(ftafm.InstrumentError) as e:
        unit.p(-0.1)
    assert "/pids/1/p" in e.value.message
    # One output, one enabled unit.
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.pids[2].enable()
    assert "/pids/2/output" in e.value.message and "/pids/1" in e.value.message
    values = unit.nodes()
    assert values["/pids/1/d_bandwidth"] == 1000.0
    assert values["/pids/1/setpoint"] == 1e-8, "a refused batch changes nothing"
    assert values["/pids/1/p"] == 0.0
    assert inst.get("/pids/2/enable") is False
    # A name that is no setting is refused before anything is sent.
    with pytest.raises(TypeError, match="/pids/1 has no setting gain"):
        unit.configure(gain=1.0)
    with pytest.raises(IndexError, match="/pids/3"):
        inst.pids[4]
    release_the_surface(inst)
