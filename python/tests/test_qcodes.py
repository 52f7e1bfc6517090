"""The QCoDeS driver."""

from __future__ import annotations

import dataclasses
import logging
import math
import warnings
from typing import Any

import pytest

pytest.importorskip("qcodes", reason="the [qcodes] extra")

from qcodes.instrument import ChannelList  # noqa: E402

import ftafm  # noqa: E402
import ftafm.pids  # noqa: E402
from ftafm.qcodes import FTAFM, label, parameter_name  # noqa: E402
from ftafm.testing import Daemon  # noqa: E402


@pytest.fixture
def afm(ftafm_daemon: Daemon) -> Any:
    driver = FTAFM("afm_test", ftafm_daemon.url)
    saved = driver.client.settings_toml()
    try:
        yield driver
    finally:
        driver.client._run(driver.client._async.request("load_settings", toml=saved))
        driver.close()


def count_requests(afm: FTAFM) -> list[str]:
    """The ops the driver's client sends from now on."""
    sent: list[str] = []
    inner = afm.client._async.request

    async def counting(op: str, **fields: Any) -> dict[str, Any]:
        sent.append(op)
        return await inner(op, **fields)

    afm.client._async.request = counting  # type: ignore[method-assign]
    return sent


def test_the_node_tree_as_modules_and_channel_lists_with_readable_labels(afm: FTAFM) -> None:
    nodes = afm.client.nodes()
    assert set(afm.by_path) == {n.path for n in nodes}
    assert isinstance(afm.demods, ChannelList) and len(afm.demods) == 32
    assert isinstance(afm.inclusions, ChannelList) and len(afm.inclusions) == 8
    assert afm.demods[3].harmonic is afm.by_path["/demods/3/harmonic"]
    assert afm.sample.youngs_modulus is afm.by_path["/sample/youngs_modulus"]
    e = afm.sample.youngs_modulus
    assert (e.label, e.unit) == ("Sample Young's modulus", "Pa")
    assert label("/demods/3/harmonic") == "Demodulator 3 harmonic"
    assert afm.demods[16].r.label == "H17 amplitude" and afm.demods[16].r.unit == "m"
    # The validators state the ranges as the daemon enforces them, open ends included.
    assert repr(e.vals) == "<0 < value ≤ 1e13 Pa>"
    assert repr(afm.drive.frequency.vals).endswith(" value < 5e6 Hz>"), "below Nyquist"
    assert repr(afm.demods[3].harmonic.vals) == "<0 ≤ value ≤ 10000>"
    assert e() == 129e9
    afm.surface.distance(15e-9)
    assert afm.surface.distance() == 15e-9
    assert afm.client.get("/surface/distance") == 15e-9
    # The validator refuses out of range values before they are sent, saying why…
    with pytest.raises(ValueError, match="0 < value ≤ 1e13 Pa"):
        e(0.0)
    e.validate(1e13)  # the closed end is allowed
    with pytest.raises(ValueError):
        afm.drive.free_amplitude(1.0)
    with pytest.raises(ValueError):
        afm.spectrum.window("hamming")
    afm.spectrum.window("hann")
    assert afm.spectrum.window() == "hann"
    # …and what only the daemon knows is its error, naming the node.
    with pytest.raises(ftafm.InstrumentError, match="/inversion/harmonic_a"):
        afm.demods[5].enable(False)
    # Read-only nodes are get-only.
    with pytest.raises(NotImplementedError):
        afm.synth.sample_rate(20e6)
    # Labels follow the harmonic a demodulator measures.
    afm.demods[3].harmonic(9)
    assert afm.demods[3].r.label == "H9 amplitude"
    assert afm.get_idn()["vendor"] == "ftafm"


def test_x_y_r_phase_of_one_frame_and_the_force_of_one_estimate(afm: FTAFM) -> None:
    x, y, r, phase = afm.demods[0].sample()
    assert math.isclose(r, math.hypot(x, y), rel_tol=1e-12) and 5e-9 < r < 30e-9
    channel = afm.demods[0]
    assert (channel.x.cache.get(), channel.y.cache.get(), channel.r.cache.get()) == (x, y, r)
    assert -3.2 < afm.demods[0].phase() < 3.2
    # The estimator may still be built after the previous test's changes (longer on a busy
    # machine): wait as the daemon's sweeper does.
    estimate = afm.force.read(timeout=120.0)
    assert afm.force.max_force.cache.get() == estimate["max_force"] > 0
    assert afm.force.youngs_modulus.cache.get() == estimate["youngs_modulus"] > 0
    assert afm.force.max_force() > 0


def test_a_snapshot_of_every_parameter_is_one_request_and_warns_of_nothing(
    afm: FTAFM, caplog: pytest.LogCaptureFixture
) -> None:
    t = afm.client.set("/demods/4/enable", False)
    assert t is not None
    afm.client.wait_until(t + 0.01)  # the newest frame is one without it
    sent = count_requests(afm)
    caplog.set_level(logging.WARNING)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        snap = afm.snapshot(update=True)
    assert [r for r in caplog.records if r.levelno >= logging.WARNING] == []
    # One get of every node and demodulator; the force's subscription when it runs.
    assert sent.count("get") == 1 and len(sent) <= 3, sent
    params = 0
    for module in snap["submodules"].values():
        for channel in module.get("channels", {None: module}).values():
            params += len(channel["parameters"])
    assert params >= 307 + 32 * 6 + 4, params
    demods = snap["submodules"]["demods"]["channels"]
    h17 = demods["afm_test_demod16"]["parameters"]["r"]
    assert h17["label"] == "H17 amplitude" and 1e-13 < h17["value"] < 1e-9
    assert math.isnan(demods["afm_test_demod4"]["parameters"]["r"]["value"]), "disabled"
    modulus = snap["submodules"]["sample"]["parameters"]["youngs_modulus"]
    assert modulus["value"] == 129e9
    assert demods["afm_test_demod4"]["parameters"]["enable"]["value"] is False


def test_the_names_of_earlier_versions_reach_the_same_parameters(afm: FTAFM) -> None:
    assert parameter_name("/sample/youngs_modulus") == "sample_youngs_modulus"
    assert afm.sample_youngs_modulus is afm.sample.youngs_modulus
    assert afm.demods_16_harmonic is afm.demods[16].harmonic
    assert afm.demod16_r is afm.demods[16].r
    assert afm.force_max_force is afm.force.max_force
    with pytest.raises(AttributeError):
        afm.no_such_parameter


def test_pid_units_as_a_channel_list_reading_their_latest_update(afm: FTAFM) -> None:
    from ftafm.qcodes import PidChannel

    assert isinstance(afm.pids, ChannelList) and len(afm.pids) == 4
    unit = afm.pids[0]
    assert isinstance(unit, PidChannel)
    assert unit.setpoint is afm.by_path["/pids/0/setpoint"]
    assert (unit.i.label, unit.i.unit) == ("PID 0 i", "1/s")
    assert unit.input.vals is not None and "phase" in repr(unit.input.vals)
    # The outputs the daemon offers: the surface distance and either excitation (a PLL).
    assert unit.output.vals is not None
    for output in ftafm.pids.OUTPUTS:
        unit.output.vals.validate(output)
    assert "drive2_frequency" in ftafm.pids.OUTPUTS
    with pytest.raises(ValueError):
        unit.output.vals.validate("z")
    # The oscillator its demodulator reads and the low-pass of a unit on drive2: nodes.
    assert unit.oscillator is afm.by_path["/pids/0/oscillator"]
    assert unit.oscillator() == "drive" and unit.oscillator.vals is not None
    unit.oscillator.vals.validate("drive2")
    with pytest.raises(ValueError):
        unit.oscillator.vals.validate("drive3")
    assert (unit.input_bandwidth.unit, unit.input_bandwidth()) == ("Hz", 2000.0)
    assert (unit.frequency_shift.unit, unit.locked.cache.get()) == ("Hz", None)
    # Its nodes set through the client's path; the same values read back.
    afm.surface.distance(20e-9)
    unit.setpoint(17e-9)
    unit.i(1200.0)
    unit.output_max(100e-9)
    unit.enable(True)
    epoch = afm.client.epoch
    assert afm.client.get("/pids/0/setpoint") == 17e-9 == unit.setpoint()
    # The update's parameters come from one status message, the same as the client reads.
    status = afm.client.pids[0].wait()
    assert status.latest is not None and status.latest.epoch >= epoch
    read = unit.read_status()
    latest = read.latest
    assert latest is not None and latest.updates >= status.latest.updates
    assert unit.error.cache.get() == latest.error
    assert unit.measurement.cache.get() == latest.measurement
    assert unit.value.cache.get() == latest.output
    assert unit.limited.cache.get() is latest.limited
    assert unit.updates.cache.get() == latest.updates
    assert unit.update_epoch.cache.get() == latest.epoch
    assert unit.error.unit == "m" and unit.value.unit == "m"
    # No PLL: the lock and the frequency shift do not apply.
    assert read.locked is None and read.frequency_shift is None
    assert unit.locked.cache.get() is None and unit.frequency_shift() is None
    assert latest.measurement + latest.error == pytest.approx(17e-9, rel=1e-12)
    # A get reads a newer message: the count only grows while the unit runs.
    assert unit.updates() >= latest.updates
    # A gain of the wrong sign is the daemon's error, naming the node.
    with pytest.raises(ftafm.InstrumentError, match="/pids/0/p"):
        unit.p(-0.5)
    assert unit.p() == 0.0
    # Before a read of its own, a unit's update parameters hold NaN (in a snapshot too).
    assert math.isnan(afm.pids[3].error.cache.get())
    # Off, and the surface released from the distance the unit held (until the node
    # changes), so that the restore of the settings after the test moves it back.
    unit.enable(False)
    afm.surface.distance(21e-9)


def test_the_second_drive_and_a_demodulators_oscillator(afm: FTAFM) -> None:
    from qcodes import validators as vals

    drive2 = afm.drive2
    assert drive2.enable is afm.by_path["/drive2/enable"]
    assert (drive2.enable.label, drive2.enable.unit) == ("Second drive enable", "")
    assert (drive2.frequency.label, drive2.frequency.unit) == ("Second drive frequency", "Hz")
    assert (drive2.free_amplitude.label, drive2.free_amplitude.unit) == (
        "Second drive free amplitude", "m")
    assert isinstance(drive2.enable.vals, vals.Bool)
    assert repr(drive2.free_amplitude.vals) == "<0 < value ≤ 1e-6 m>"
    osc = afm.demods[3].oscillator
    assert osc is afm.by_path["/demods/3/oscillator"]
    assert osc.label == "Demodulator 3 oscillator"
    assert isinstance(osc.vals, vals.Enum) and set(osc.vals.valid_values) == {"drive", "drive2"}
    assert osc.cache.get() == "drive"
    # Set and read back, and the daemon holds the same.
    drive2.enable(True)
    drive2.frequency(610e3)
    drive2.free_amplitude(3e-9)
    afm.demods[3].harmonic(2)
    osc("drive2")
    assert (drive2.enable(), drive2.frequency(), drive2.free_amplitude(), osc()) == (
        True, 610e3, 3e-9, "drive2")
    assert afm.client.get_many(["/drive2/frequency", "/demods/3/oscillator"]) == {
        "/drive2/frequency": 610e3, "/demods/3/oscillator": "drive2"}
    # The labels say which oscillator's harmonic a demodulator measures, in a snapshot too.
    assert afm.demods[3].r.label == "H2 of drive2 amplitude"
    assert afm.demods[3].sample.labels[0] == "H2 of drive2 in-phase x"
    assert afm.demods[4].r.label == "H5 amplitude"
    snap = afm.snapshot(update=True)
    demod3 = snap["submodules"]["demods"]["channels"]["afm_test_demod3"]["parameters"]
    assert demod3["oscillator"]["value"] == "drive2"
    assert demod3["r"]["label"] == "H2 of drive2 amplitude"
    assert snap["submodules"]["drive2"]["parameters"]["frequency"]["value"] == 610e3
    # A value outside the Enum is refused before it is sent; the daemon still holds drive2.
    with pytest.raises(ValueError, match="drive3"):
        afm.demods[3].oscillator("drive3")
    assert afm.client.get("/demods/3/oscillator") == "drive2"
    # Above Nyquist while enabled: `list` gives the limit while drive2 drives, so the
    # validator refuses it before it is sent, with the range.
    with pytest.raises(ValueError, match=r"/drive2/frequency: allowed 0 < value < 5e6 Hz"):
        drive2.frequency(6e6)
    assert drive2.frequency() == 610e3
    # Back on the drive: the labels say the plain harmonic again.
    osc("drive")
    assert afm.demods[3].r.label == "H2 amplitude"
    # A change made elsewhere (a script on another connection) shows once read.
    afm.client.set("/demods/3/oscillator", "drive2")
    assert afm.demods[3].r.label == "H2 amplitude", "not read yet"
    assert osc() == "drive2"
    assert afm.demods[3].r.label == "H2 of drive2 amplitude"


#: A PLL's nodes on a unit (the advisor models the unit as configured, enabled or not).
PLL = {"input": "phase", "harmonic": 1, "output": "drive_frequency"}


def gains_read_back(afm: FTAFM, index: int) -> list[float]:
    """``p``, ``i``, ``d``, ``d_bandwidth`` of ``/pids/index`` as the daemon holds them."""
    values = afm.client.get_many([f"/pids/{index}/{g}" for g in ("p", "i", "d", "d_bandwidth")])
    return [values[f"/pids/{index}/{g}"] for g in ("p", "i", "d", "d_bandwidth")]


def test_a_pid_channels_advice_is_the_clients_and_apply_sets_the_gains(afm: FTAFM) -> None:
    from ftafm.qcodes import PidChannel

    unit = afm.pids[1]
    assert isinstance(unit, PidChannel)
    afm.client.pids[1].configure(**PLL)
    before = gains_read_back(afm, 1)
    epoch = afm.client.epoch
    # The advice is the client's for the same settings, PI and PID; nothing is set.
    advice = unit.advise(bandwidth=500.0, kind="pi", apply=False)
    assert isinstance(advice, ftafm.PidAdvice)
    assert advice == afm.client.pid_advise(1, 500.0, kind="pi")
    assert advice.unit == 1 and advice.kind == "pi" and advice.epoch == epoch
    assert advice.p < 0 and advice.i < 0 and advice.d == 0.0, "a PLL's: negative"
    assert advice.bandwidth == pytest.approx(500.0, rel=0.01)
    assert advice.phase_margin >= 45.0 and 0.0 <= advice.overshoot < 0.3
    assert 0 < advice.settling_time < 20 / 500.0
    pid = unit.advise(500.0, kind="pid")
    assert pid == afm.client.pid_advise(1, 500.0, kind="pid") and pid.d < 0
    assert gains_read_back(afm, 1) == before and afm.client.epoch == epoch
    # apply=True: the client's advice, its gains set in one change through the parameters,
    # read back from the daemon and in the snapshot.
    expected = afm.client.pid_advise(1, 200.0, kind="pid")
    sent = count_requests(afm)
    applied = unit.advise(bandwidth=200.0, kind="pid", apply=True)
    assert applied == expected
    assert sent.count("pid_advise") == 1 and sent.count("set") == 1, sent
    assert gains_read_back(afm, 1) == [applied.p, applied.i, applied.d, applied.d_bandwidth]
    assert [unit.p(), unit.i(), unit.d(), unit.d_bandwidth()] == list(applied.gains.values())
    assert afm.client.epoch > epoch
    snap = afm.snapshot(update=False)["submodules"]["pids"]["channels"]["afm_test_pid1"]
    assert {g: snap["parameters"][g]["value"] for g in applied.gains} == applied.gains
    # Another unit's advice is not applied to this one.
    with pytest.raises(ValueError, match="/pids/0 cannot be applied to /pids/1"):
        unit.apply_advice(dataclasses.replace(applied, unit=0))


def test_apply_sets_the_gains_of_a_running_unit_in_one_change(afm: FTAFM) -> None:
    # A running PLL on gains of the amplitude loop's sign (the defaults: i = 1200 1/s):
    # set one by one, the first negative gain would be refused beside the others.
    unit = afm.pids[2]
    f = afm.drive.frequency()
    afm.client.pids[2].configure(**PLL, setpoint=0.0, p=0.0, i=1e-3,
                                 output_min=0.9 * f, output_max=1.1 * f, enable=True)
    try:
        with pytest.raises(ftafm.InstrumentError, match="/pids/2/p"):
            unit.p(-1.0)
        advice = unit.advise(bandwidth=300.0, apply=True)
        assert advice.p < 0 and advice.i < 0
        assert gains_read_back(afm, 2) == list(advice.gains.values())
        assert unit.enable() is True
    finally:
        unit.enable(False)
        # The disabled unit holds the drive where it left it until /drive/frequency is
        # written (docs/loops.md): a write of f takes it back for the tests after.
        afm.drive.frequency(f)
        assert afm.client.pid_held() == []


def test_a_refused_advice_names_the_field_and_sets_nothing(afm: FTAFM) -> None:
    unit = afm.pids[3]
    afm.client.pids[3].configure(**PLL)
    before = gains_read_back(afm, 3)
    for bad in (0.0, -5.0):
        with pytest.raises(ftafm.InstrumentError) as e:
            unit.advise(bandwidth=bad, apply=True)
        assert e.value.code == "bad_request", e.value
        assert 'field "bandwidth"' in e.value.message, e.value
    # Beyond the loop's reach: the message names the field and gives the reach.
    with pytest.raises(ftafm.InstrumentError) as e:
        unit.advise(bandwidth=1e6, apply=True)
    assert e.value.code == "invalid_value", e.value
    assert 'field "bandwidth"' in e.value.message and "allowed 0 < bandwidth ≤" in e.value.message
    with pytest.raises(ftafm.InstrumentError, match='field "kind"'):
        unit.advise(500.0, kind="pd", apply=True)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match='field "bandwidth"'):
        unit.advise(float("nan"), apply=True)
    # A unit the advisor does not model (the surface distance): its nodes named.
    afm.client.pids[3].configure(input="r", harmonic=1, output="surface_distance")
    with pytest.raises(ftafm.InstrumentError) as e:
        unit.advise(500.0, apply=True)
    assert e.value.code == "invalid_value" and "/pids/3" in e.value.message, e.value
    assert "surface_distance" in e.value.message, e.value
    assert gains_read_back(afm, 3) == before
