"""The live PID units through the client: an amplitude loop on the surface distance holds
a set-point the physics reaches, bad settings raise naming the node, and disabling holds
the output; a PLL (a unit on the phase of harmonic 1 driving the drive frequency) finds
the free lever's resonance from 1 % off it, reports itself locked with its frequency
shift, holds the drive frequency away from its node, and bad drive limits are refused
(a real daemon, waiting on the units' update counts and epochs; the asyncio client's
units too)."""

from __future__ import annotations

import asyncio
import math
import time
from typing import Any

import numpy as np
import pytest

import ftafm
import ftafm.aio
from ftafm.pids import WAIT_TIMEOUT, PidStatus
from ftafm.testing import Daemon

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
    assert first.oscillator == "drive"
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
    # No PLL: no lock, no frequency shift; the loop holds the surface distance.
    assert settled.locked is None and settled.frequency_shift is None
    assert settled.lock_losses is None
    assert settled.output == "surface_distance" and settled.output_unit == "m"
    assert inst.pid_held() == ["surface_distance"]
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


#: Updates to let a PLL lock: 20 ms at 100 kHz, four times the few ms tests/pll.rs takes
#: from 1 % off the resonance at a 500 Hz crossover.
PLL_UPDATES = 2000

#: Status messages whose outputs are averaged for the lock's frequency.
PLL_MESSAGES = 4


def free_lever_off_resonance(f1: float) -> dict[str, Any]:
    """The lever out of the surface's reach, driven 1 % above its resonance ``f1`` (Hz)
    at 10 nm free amplitude, the drive frequency its own (not following f1)."""
    return {
        "/surface/distance": 1e-6,
        "/drive/free_amplitude": 10e-9,
        "/drive/follow_f1": False,
        "/drive/frequency": 1.01 * f1,
    }


def pll(f1: float, q: float, bandwidth: float = 500.0) -> dict[str, Any]:
    """A PLL's settings (tests/pll.rs): harmonic 1's phase held at π (the resonance), the
    drive frequency within ±2 % of ``f1``, PI gains for a crossover of ``bandwidth`` (Hz)
    on the lever's phase response (−2Q/f1 rad/Hz; the PI's zero on its pole πf1/Q)."""
    i = -2.0 * math.pi * bandwidth / (2.0 * q / f1)
    return {
        "input": "phase",
        "harmonic": 1,
        "setpoint": math.pi,
        "i": i,
        "p": i * q / (math.pi * f1),
        "d": 0.0,
        "output": "drive_frequency",
        "output_min": 0.98 * f1,
        "output_max": 1.02 * f1,
    }


def held_until(inst: ftafm.Instrument, want: list[str]) -> list[str]:
    """Reads ``status`` until its ``pid_held`` is ``want`` (the synthesiser reports it
    once it has run the change); the timeout only guards against a hang."""
    deadline = time.monotonic() + WAIT_TIMEOUT
    held = inst.pid_held()
    while held != want and time.monotonic() < deadline:
        held = inst.pid_held()
    return held


def test_a_pll_locks_the_drive_to_the_resonance_and_bad_limits_are_refused(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    f1 = float(inst.get("/cantilever/f1"))
    q = float(inst.get("/cantilever/q")[0])
    drive = 1.01 * f1
    inst.set_many(free_lever_off_resonance(f1))
    unit = inst.pids[0]
    settings = pll(f1, q)

    # An upper limit beyond what the drive frequency may be (below sample_rate / 2 / the
    # highest harmonic read): refused when enabled, naming the node; nothing changes.
    before = unit.nodes()
    with pytest.raises(ftafm.InstrumentError) as e:
        unit.configure(**{**settings, "output_max": 1e6}, enable=True)
    assert e.value.code == "invalid_value"
    assert "/pids/0/output_max" in e.value.message and "drive_frequency" in e.value.message
    assert unit.nodes() == before, "a refused batch changes nothing"
    assert inst.get("/drive/frequency") == drive
    # So is a lower limit of 0 Hz (the range is open there).
    with pytest.raises(ftafm.InstrumentError, match="/pids/0/output_min"):
        unit.configure(**{**settings, "output_min": 0.0}, enable=True)
    assert unit.nodes() == before

    unit.configure(**settings, enable=True)
    first = unit.wait()
    assert first.latest is not None
    assert (first.input, first.harmonic, first.output) == ("phase", 1, "drive_frequency")
    assert first.output_unit == "Hz"
    locked = unit.wait(updates=first.latest.updates + PLL_UPDATES)
    # Several status messages, each a later update of the locked loop.
    seen = [locked]
    while len(seen) < PLL_MESSAGES:
        seen.append(unit.wait(lambda s: s.t > seen[-1].t))
    for s in seen:
        print(f"t = {s.t:.3f} s: locked {s.locked}, Δf {s.frequency_shift} Hz, {s.latest}")
    for s in seen:
        assert s.latest is not None
        assert s.locked is True, f"not locked: {s}"
        assert s.lock_losses == 0, f"the lock never lost: {s}"
        assert not s.latest.limited
        assert abs(s.latest.error) < 0.1
        assert s.frequency_shift is not None
        # Δf is the output less the node /drive/frequency, which the PLL leaves alone.
        assert s.frequency_shift == pytest.approx(s.latest.output - drive, abs=1e-6)
        assert abs(s.latest.output - f1) < 20.0, f"{s.latest.output} Hz, f1 = {f1} Hz"
    outputs = [s.latest.output for s in seen if s.latest is not None]
    mean = sum(outputs) / len(outputs)
    assert abs(mean - f1) < 5.0, f"the PLL sits at {mean} Hz, f1 = {f1} Hz"
    shifts = [s.frequency_shift for s in seen if s.frequency_shift is not None]
    assert abs(sum(shifts) / len(shifts) + (drive - f1)) < 5.0
    assert inst.get("/drive/frequency") == drive
    assert held_until(inst, ["drive_frequency"]) == ["drive_frequency"]

    # Stopped, the oscillator stays where the PLL left it until /drive/frequency is set.
    unit.disable()
    off = unit.wait(lambda s: not s.enable, epoch=0)
    assert off.locked is not None, "a stopped unit keeps its latest update"
    assert inst.pid_held() == ["drive_frequency"]
    inst.set("/drive/frequency", f1)
    assert held_until(inst, []) == []


def test_the_async_clients_units_run_a_pll(ftafm_daemon: Daemon) -> None:
    async def main() -> None:
        async with ftafm.aio.Instrument(ftafm_daemon.url) as inst:
            saved = await inst.settings_toml()
            try:
                f1 = float(await inst.get("/cantilever/f1"))
                q = float((await inst.get("/cantilever/q"))[0])
                await inst.set_many(free_lever_off_resonance(f1))
                assert len(inst.pids) == 4
                unit = inst.pids[2]
                assert isinstance(unit, ftafm.AsyncPidUnit)
                await unit.configure(**pll(f1, q), enable=True)
                assert await unit.nodes.enable() is True
                assert await unit.output() == "drive_frequency"
                first = await unit.wait()
                assert first.latest is not None and first.latest.epoch >= inst.epoch
                settled = await unit.wait(
                    lambda s: s.locked is True,
                    updates=first.latest.updates + PLL_UPDATES,
                )
                assert settled.latest is not None and settled.frequency_shift is not None
                assert abs(settled.latest.output - f1) < 20.0
                statuses = await inst.pids.status()
                assert [s.index for s in statuses] == [0, 1, 2, 3]
                assert "drive_frequency" in await inst.pids.held()
                with pytest.raises(TypeError, match="/pids/2 has no setting gain"):
                    await unit.configure(gain=1.0)
                await unit.disable()
                off = await unit.wait(lambda s: not s.enable, epoch=0)
                assert not off.enable
            finally:
                await inst.request("load_settings", toml=saved)

    asyncio.run(main())


def test_the_pids_stream_gives_every_update_as_rows(ftafm_instrument: ftafm.Instrument) -> None:
    """``poll("pids")``: a row per update of the enabled unit, a drive period apart, none
    dropped, its measurement and error adding to the set-point."""
    from ftafm.data import PidsData

    inst = ftafm_instrument
    setpoint = 25e-9  # above the orbit's amplitude at 20 nm: the loop pulls the surface away
    inst.set_many({"/pids/0/setpoint": setpoint, "/pids/0/enable": True})
    data = inst.poll("pids", 0.002)
    assert isinstance(data, PidsData)
    rows = data.of(0)
    assert len(rows) > 10 and len(data.unit) == len(rows)
    assert int(data.dropped.max()) == 0
    period = inst.get("/synth/sample_rate") / inst.get("/drive/frequency")
    gaps = np.diff(data.sample[rows])
    assert np.all(np.abs(gaps - period) <= 1.0), gaps
    assert np.allclose(data.measurement + data.error, setpoint, rtol=0, atol=1e-15)
    assert np.all(np.isnan(data.locked))
