"""The second excitation (``/drive2``) and the demodulators' oscillator
(``/demods/N/oscillator``) through the synchronous and the asyncio client."""

from __future__ import annotations

import asyncio
import math
from typing import Any

import pytest

import ftafm
import ftafm.aio
from ftafm.pids import PidStatus
from ftafm.testing import Daemon


def test_drive2_and_a_demodulators_oscillator_through_the_sync_client(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    nodes = {n.path: n for n in inst.nodes()}
    # The nodes as list declares them: off by default, at the lever's second resonance.
    assert (nodes["/drive2/enable"].type, nodes["/drive2/enable"].value) == ("bool", False)
    assert (nodes["/drive2/frequency"].unit, nodes["/drive2/frequency"].value) == ("Hz", 626.689e3)
    assert (nodes["/drive2/free_amplitude"].unit, nodes["/drive2/free_amplitude"].value) == ("m", 1e-9)
    osc = nodes["/demods/3/oscillator"]
    assert (osc.type, osc.value, osc.allowed) == ("text", "drive", ("drive", "drive2"))
    assert [n.path for n in inst.nodes("/drive2")] == [
        "/drive2/enable", "/drive2/frequency", "/drive2/free_amplitude"
    ]

    # Set through paths and through the tree; the daemon reads back what was set.
    t = inst.set_many({"/drive2/enable": True, "/drive2/frequency": 620e3})
    assert t is not None
    inst.drive2.free_amplitude(2e-9)
    inst.demods[3].oscillator("drive2")
    assert inst.get_many(
        ["/drive2/enable", "/drive2/frequency", "/drive2/free_amplitude", "/demods/3/oscillator"]
    ) == {
        "/drive2/enable": True,
        "/drive2/frequency": 620e3,
        "/drive2/free_amplitude": 2e-9,
        "/demods/3/oscillator": "drive2",
    }
    assert inst.drive2.frequency() == 620e3 and inst.demods[3].oscillator() == "drive2"
    assert inst.demods[4].oscillator() == "drive", "the others stay on the drive"
    assert inst.drive2.frequency.node.unit == "Hz"

    # A harmonic of drive2 beyond Nyquist: out of band, and the warning names drive2's node.
    inst.demods[3].harmonic(8)  # 8 × 620 kHz = 4.96 MHz: in band
    assert inst.nodes("/demods/3/harmonic")[0].warning is None
    inst.demods[3].harmonic(9)  # 5.58 MHz ≥ 5 MHz
    warning = inst.nodes("/demods/3/harmonic")[0].warning
    assert warning is not None and "/drive2/frequency" in warning, warning

    # Refusals name the node; a refused value changes nothing.
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.set("/demods/3/oscillator", "drive3")
    assert e.value.code == "invalid_value" and "/demods/3/oscillator" in e.value.message
    assert inst.get("/demods/3/oscillator") == "drive2"
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.set("/drive2/frequency", 6e6)  # above Nyquist (5 MHz) while enabled
    assert e.value.code == "invalid_value" and "/drive2/frequency" in e.value.message
    assert "Nyquist" in e.value.message
    assert inst.get("/drive2/frequency") == 620e3
    # While drive2 runs, the paper engine is refused, naming drive2's node.
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.set("/synth/engine", "paper")
    assert "/drive2/enable" in e.value.message
    assert inst.get("/synth/engine") == "coupled"
    # Disabled, drive2 is only a reference: the same frequency is accepted.
    inst.set_many({"/drive2/enable": False, "/drive2/frequency": 6e6})
    assert inst.get("/drive2/frequency") == 6e6


def test_drive2_and_a_demodulators_oscillator_through_the_async_client(
    ftafm_daemon: Daemon,
) -> None:
    async def main() -> None:
        async with ftafm.aio.Instrument(ftafm_daemon.url) as inst:
            saved = await inst.settings_toml()
            try:
                await inst.drive2.enable(True)
                await inst.drive2.frequency(630e3)
                await inst.set("/drive2/free_amplitude", 0.5e-9)
                async with inst.set_transaction():
                    await inst.demods[7].oscillator("drive2")
                    await inst.demods[7].harmonic(1)
                values = await inst.demods[7]()
                assert values["/demods/7/oscillator"] == "drive2"
                assert values["/demods/7/harmonic"] == 1
                assert await inst.get("/drive2/enable") is True
                assert await inst.drive2.frequency() == 630e3
                assert await inst.drive2.free_amplitude() == 0.5e-9
                with pytest.raises(ftafm.InstrumentError) as e:
                    await inst.demods[3].oscillator("drive3")
                assert e.value.code == "invalid_value"
                assert "/demods/3/oscillator" in e.value.message
                with pytest.raises(ftafm.InstrumentError) as e:
                    await inst.set("/drive2/frequency", 5e6)  # Nyquist itself: not below
                assert "/drive2/frequency" in e.value.message
                assert await inst.get("/drive2/frequency") == 630e3
            finally:
                await inst.request("load_settings", toml=saved)
            assert await inst.get("/drive2/enable") is False
            assert await inst.get("/demods/7/oscillator") == "drive"

    asyncio.run(main())


#: Mode 2's PLL (tests/bimodal_loops.rs ``mode_two_pll``): a 300 Hz PI crossover on mode
#: 2's phase response (−2Q₂/f₂ rad/Hz, the PI's zero on its pole πf₂/Q₂), Q₂ of the default
#: lever (``ftafm info``).
Q2 = 417.0
PLL2_BANDWIDTH = 300.0

#: Updates to let mode 2's PLL lock: 20 ms at the default 100 kHz drive, the span
#: tests/bimodal_loops.rs runs it from 0.4 % off (settled from 12 ms on).
PLL2_UPDATES = 2000

#: Status messages whose outputs are averaged for the lock's frequency.
PLL2_MESSAGES = 4


def mode_two_pll(f2: float, setpoint: float) -> dict[str, Any]:
    """Mode 2's PLL: the phase of harmonic 1 of ``drive2`` held at ``setpoint`` (rad) by
    ``drive2_frequency``, within ±1 % of ``f2`` (Hz)."""
    i = -2.0 * math.pi * PLL2_BANDWIDTH / (2.0 * Q2 / f2)
    return {
        "oscillator": "drive2",
        "input": "phase",
        "harmonic": 1,
        "setpoint": setpoint,
        "i": i,
        "p": i * Q2 / (math.pi * f2),
        "d": 0.0,
        "output": "drive2_frequency",
        "output_min": 0.99 * f2,
        "output_max": 1.01 * f2,
    }


def locked_statuses(inst: ftafm.Instrument, unit: int) -> list[PidStatus]:
    """``PLL2_MESSAGES`` status messages of ``unit``, the first ``PLL2_UPDATES`` updates
    after its first under this client's last change, each a later message."""
    pll = inst.pids[unit]
    first = pll.wait()
    assert first.latest is not None
    seen = [pll.wait(updates=first.latest.updates + PLL2_UPDATES)]
    while len(seen) < PLL2_MESSAGES:
        seen.append(pll.wait(lambda s: s.t > seen[-1].t))
    for s in seen:
        print(f"t = {s.t:.3f} s: locked {s.locked}, Δf₂ {s.frequency_shift} Hz, {s.latest}")
    return seen


def test_mode_two_pll_locks_the_second_excitation_to_mode_twos_resonance(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    f2 = float(inst.get("/drive2/frequency"))
    assert f2 == pytest.approx(626.689e3), "the default lever's f2 (ftafm info)"
    # The set-point: the phase mode 2 reads at its resonance, the lever free (the surface
    # out of reach), demodulated at harmonic 1 of drive2 by demodulator 7.
    t = inst.set_many({
        "/surface/distance": 1e-6,
        "/drive2/enable": True,
        "/demods/7/enable": True,
        "/demods/7/oscillator": "drive2",
        "/demods/7/harmonic": 1,
    })
    assert t is not None
    inst.wait_until(t + 0.02)
    setpoint = float(inst.poll("demods", 0.02).phase[:, 7].mean())
    print(f"mode 2's phase at f2 = {f2} Hz: {setpoint} rad")

    # Started 0.4 % above the resonance (2.7 of mode 2's linewidths): the PLL finds it.
    off = 1.004 * f2
    inst.set("/drive2/frequency", off)
    unit = inst.pids[1]
    unit.configure(**mode_two_pll(f2, setpoint), input_bandwidth=2000.0, enable=True)
    assert unit.nodes.oscillator() == "drive2" and unit.input_bandwidth() == 2000.0
    seen = locked_statuses(inst, 1)
    for s in seen:
        assert s.latest is not None
        assert (s.oscillator, s.input, s.harmonic, s.output) == (
            "drive2", "phase", 1, "drive2_frequency"
        )
        assert s.output_unit == "Hz"
        assert s.locked is True, f"not locked: {s}"
        assert not s.latest.limited
        # Δf₂ is the output less the node /drive2/frequency, which the PLL leaves alone.
        assert s.frequency_shift == pytest.approx(s.latest.output - off, abs=1e-6)
        assert abs(s.latest.output - f2) < 10.0, f"{s.latest.output} Hz, f2 = {f2} Hz"
    mean = sum(s.latest.output for s in seen if s.latest is not None) / len(seen)
    assert abs(mean - f2) < 3.0, f"mode 2's PLL sits at {mean} Hz, f2 = {f2} Hz"
    assert inst.get("/drive2/frequency") == off
    assert "drive2_frequency" in inst.pid_held()
    # The drive's unit is untouched: Δf₂ is reported for the second excitation only.
    assert inst.pid_status()[0].frequency_shift is None

    # /drive2/frequency set to the resonance while the PLL runs: the node takes the
    # oscillator back, and the PLL holds it there, Δf₂ near 0.
    inst.set("/drive2/frequency", f2)
    seen = locked_statuses(inst, 1)
    for s in seen:
        assert s.latest is not None and s.frequency_shift is not None
        assert s.locked is True, f"not locked: {s}"
        assert abs(s.frequency_shift) < 10.0, f"Δf₂ {s.frequency_shift} Hz"
    shift = sum(s.frequency_shift for s in seen if s.frequency_shift is not None) / len(seen)
    assert abs(shift) < 3.0, f"mean Δf₂ {shift} Hz at f2"
    unit.disable()


def test_a_unit_on_drive2_needs_the_second_excitation(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    assert inst.get("/drive2/enable") is False
    nodes = {n.path: n for n in inst.nodes("/pids/2")}
    osc = nodes["/pids/2/oscillator"]
    assert (osc.type, osc.value, osc.allowed) == ("text", "drive", ("drive", "drive2"))
    bandwidth = nodes["/pids/2/input_bandwidth"]
    assert (bandwidth.unit, bandwidth.value) == ("Hz", 2000.0)
    unit = inst.pids[2]
    before = unit.nodes()
    # An enabled unit reading drive2 while the second excitation is off: refused, naming
    # the unit's oscillator node; nothing changes.
    with pytest.raises(ftafm.InstrumentError) as e:
        unit.configure(oscillator="drive2", input="r", harmonic=1, enable=True)
    print(e.value.message)
    assert e.value.code == "invalid_value"
    assert "/pids/2/oscillator" in e.value.message and "/drive2/enable" in e.value.message
    assert unit.nodes() == before, "a refused batch changes nothing"
    # Disabled, the unit may be set to drive2 ahead of the excitation.
    unit.configure(oscillator="drive2", input_bandwidth=1000.0)
    assert (unit.nodes.oscillator(), unit.input_bandwidth()) == ("drive2", 1000.0)
    with pytest.raises(ftafm.InstrumentError, match="/pids/2/oscillator"):
        unit.enable()
    assert unit.nodes.enable() is False
    # A bandwidth the unit cannot read once a drive period (above /drive/frequency / 4)
    # is refused while enabled on drive2, naming the node.
    inst.set("/drive2/enable", True)
    with pytest.raises(ftafm.InstrumentError) as e:
        unit.configure(input_bandwidth=30e3, enable=True)
    print(e.value.message)
    assert "/pids/2/input_bandwidth" in e.value.message
    assert unit.nodes.enable() is False and unit.input_bandwidth() == 1000.0
    with pytest.raises(TypeError, match="/pids/2 has no setting bandwidth"):
        unit.configure(bandwidth=1e3)


def test_a_live_change_of_drive2_alone_moves_mode_two(ftafm_instrument: ftafm.Instrument) -> None:
    """The second excitation's nodes changed alone (no other node in the batch) reach the
    synthesis and the demodulators on drive2: mode 2 rings up at f2 when /drive2/enable
    is switched on; a quarter of its linewidth above f2 its phase is atan(1/2) lower (the
    excitation keeps the free amplitude /drive2/free_amplitude at the new frequency); it
    stops when switched off."""
    inst = ftafm_instrument
    f2 = float(inst.get("/drive2/frequency"))

    def reading(t: float | None) -> tuple[float, float]:
        assert t is not None
        inst.wait_until(t + 0.02)  # a hundred of mode 2's envelope time constants
        frames = inst.poll("demods", 0.02)
        return float(frames.r[:, 7].mean()), float(frames.phase[:, 7].mean())

    quiet, _ = reading(inst.set_many({
        "/surface/distance": 1e-6,
        "/demods/7/enable": True,
        "/demods/7/oscillator": "drive2",
        "/demods/7/harmonic": 1,
    }))
    r_on, phase_on = reading(inst.set("/drive2/enable", True))
    # A quarter linewidth above: 2·Q2·Δf/f2 = 1/2.
    r_up, phase_up = reading(inst.set("/drive2/frequency", f2 * (1.0 + 1.0 / (4.0 * Q2))))
    r_off, _ = reading(inst.set("/drive2/enable", False))
    print(f"off {quiet} m; on {r_on} m, {phase_on} rad; above {r_up} m, {phase_up} rad; "
          f"off again {r_off} m")
    assert quiet < 1e-10, "mode 2 is still before the excitation"
    assert r_on > 1e-9, f"mode 2 rings at f2 once /drive2/enable is on: {r_on} m"
    assert r_up == pytest.approx(r_on, rel=0.02), "the same free amplitude"
    assert phase_up - phase_on == pytest.approx(-math.atan(0.5), abs=0.02)
    assert r_off < 1e-10, f"mode 2 dies down once /drive2/enable is off: {r_off} m"
