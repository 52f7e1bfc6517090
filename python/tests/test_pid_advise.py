"""The daemon's PID advisor through the client (``pid_advise``, a real daemon): for a unit set
up as a PLL on the default lever the advice is a PI signed for the drive frequency, near the
hand formula, with the bandwidth and phase margin asked for, and ``configure`` takes it; the
asyncio client's unit gives the same; a bad or unreachable bandwidth, a bad kind and a unit
the advisor does not model raise naming what was wrong."""

from __future__ import annotations

import asyncio
import math

import pytest

import ftafm
import ftafm.aio
from ftafm.pids import PidAdvice
from ftafm.testing import Daemon

#: The target bandwidth (Hz): tests/pll.rs steps the live loop with this one's gains.
TARGET = 500.0

#: A PLL's nodes on unit N (not enabled: the advisor models the unit as configured).
PLL = {"input": "phase", "harmonic": 1, "output": "drive_frequency"}


def test_a_plls_advice_on_the_default_lever_is_sane_and_configure_takes_it(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    f1 = float(inst.get("/cantilever/f1"))
    q = float(inst.get("/cantilever/q")[0])
    unit = inst.pids[0]
    assert unit.configure(**PLL, enable=False) is not None
    advice = unit.advise(TARGET)
    assert isinstance(advice, PidAdvice)
    assert advice == inst.pid_advise(0, TARGET, kind="pi"), "the unit's call is the client's"
    assert advice.unit == 0 and advice.kind == "pi"
    assert advice.epoch == inst.epoch, "it models the settings of the last change"
    assert f"Q {q:g}" in advice.plant and f"f1 {f1:g} Hz" in advice.plant, advice.plant
    # Signed for the drive frequency: the lever's phase falls as the frequency rises.
    assert advice.p < 0 and advice.i < 0 and advice.d == 0.0, advice
    # Near the hand formula: P = −B Hz/rad, I = −2π·B·f1/(2Q) Hz/(rad·s).
    assert advice.p / -TARGET == pytest.approx(1.0, abs=0.2), advice
    assert advice.i / (-2 * math.pi * TARGET * f1 / (2 * q)) == pytest.approx(1.0, abs=0.2), advice
    # The prediction: the bandwidth asked for, at least 45° of margin, a step that settles.
    assert advice.bandwidth == pytest.approx(TARGET, rel=0.01), advice
    assert advice.phase_margin >= 45.0, advice
    assert 0 < advice.crossover < 10 * TARGET, advice
    assert 0.0 <= advice.overshoot < 0.3, advice
    assert 0 < advice.settling_time < 20 / TARGET, advice
    # The derivative's low-pass lies below the unit's Nyquist frequency (half the drive's).
    assert 0 < advice.d_bandwidth < f1 / 2, advice
    # Nothing was set; configure sets the advice in one change, and the unit reads it back.
    assert unit.p() != advice.p
    assert unit.configure(**advice.gains) is not None
    assert [unit.p(), unit.i(), unit.d(), unit.d_bandwidth()] == [
        advice.p,
        advice.i,
        advice.d,
        advice.d_bandwidth,
    ]
    # A PID: a derivative of the same sign.
    pid = unit.advise(TARGET, kind="pid")
    assert pid.kind == "pid" and pid.d < 0 and pid.p < 0 and pid.i < 0, pid
    assert pid.bandwidth == pytest.approx(TARGET, rel=0.01), pid


def test_a_bad_bandwidth_or_kind_raises_naming_the_field(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    inst.pids[1].configure(**PLL)
    for bad in (0.0, -5.0):
        with pytest.raises(ftafm.InstrumentError) as e:
            inst.pid_advise(1, bad)
        assert e.value.code == "bad_request", e.value
        assert 'field "bandwidth"' in e.value.message and "> 0 (Hz)" in e.value.message
    # Beyond the loop's reach: the message gives the reach.
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.pids[1].advise(1e6)
    assert e.value.code == "invalid_value", e.value
    assert 'field "bandwidth"' in e.value.message, e.value
    assert "allowed 0 < bandwidth ≤" in e.value.message and "/pids/1" in e.value.message
    # JSON has no NaN: refused before anything is sent.
    with pytest.raises(ValueError, match='field "bandwidth" of op "pid_advise" = nan'):
        inst.pid_advise(1, float("nan"))
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.pid_advise(1, TARGET, kind="pd")  # type: ignore[arg-type]
    assert e.value.code == "bad_request" and 'field "kind"' in e.value.message, e.value
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.pid_advise(4, TARGET)
    assert e.value.code == "bad_request" and 'field "unit"' in e.value.message, e.value
    # The surface distance's loop is not modelled: the message names the unit's nodes.
    inst.pids[2].configure(input="r", harmonic=1, output="surface_distance")
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.pids[2].advise(TARGET)
    assert e.value.code == "invalid_value", e.value
    assert "/pids/2" in e.value.message and "surface_distance" in e.value.message, e.value


def test_the_async_clients_unit_gives_the_same_advice(ftafm_daemon: Daemon) -> None:
    async def main() -> None:
        async with ftafm.aio.Instrument(ftafm_daemon.url) as inst:
            saved = await inst.settings_toml()
            try:
                unit = inst.pids[3]
                await unit.configure(**PLL)
                advice = await unit.advise(TARGET)
                assert advice == await inst.pid_advise(3, TARGET)
                assert advice.unit == 3 and advice.epoch == inst.epoch
                assert advice.p < 0 and advice.i < 0
                assert advice.bandwidth == pytest.approx(TARGET, rel=0.01)
                with pytest.raises(ftafm.InstrumentError, match='field "bandwidth"'):
                    await unit.advise(-1.0)
            finally:
                await inst.request("load_settings", toml=saved)

    asyncio.run(main())
