"""The second excitation (``/drive2``) and the demodulators' oscillator
(``/demods/N/oscillator``) through the synchronous and the asyncio client."""

from __future__ import annotations

import asyncio

import pytest

import ftafm
import ftafm.aio
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
    # While drive2 runs, a scan is refused, naming drive2's node.
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.set("/scan/enable", True)
    assert "/drive2/enable" in e.value.message
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
