"""The synchronous client against a real daemon."""

from __future__ import annotations

import math

import numpy as np
import pytest

import ftafm
from ftafm.testing import Daemon


def test_hello_info_and_nodes(ftafm_instrument: ftafm.Instrument) -> None:
    inst = ftafm_instrument
    assert inst.hello["server"] == "ftafm"
    assert inst.hello["protocol"] == 1
    info = inst.info()
    assert info["sample_rate"] == 10e6
    # The default operating point has no warnings; a machine too busy to keep real time
    # (CI beside other work) may add the chain's own, which is not the test's subject.
    assert [w for w in info["warnings"] if "fell behind real time" not in w] == []
    nodes = {n.path: n for n in inst.nodes()}
    modulus = nodes["/sample/youngs_modulus"]
    assert (modulus.unit, modulus.type, modulus.writable) == ("Pa", "float", True)
    assert modulus.min <= modulus.value <= modulus.max
    assert nodes["/spectrum/window"].allowed == ("rectangular", "hann", "blackman_harris", "flat_top")
    assert not nodes["/synth/sample_rate"].writable
    assert [n.path for n in inst.nodes("/drive")] == [
        p for p in nodes if p.startswith("/drive/")
    ]


def test_a_set_returns_when_it_took_effect_and_data_after_it_shows_it(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    before = inst.sample(0)
    t = inst.set("/surface/distance", 12e-9)
    assert t is not None and t >= before["t"] - 0.01
    assert inst.get("/surface/distance") == 12e-9
    reached = inst.wait_until(t + 0.05)
    assert reached >= t + 0.05
    after = inst.sample(0)
    assert after["t"] >= t + 0.05
    # A lower set point taps harder: H1 amplitude follows the set point (about A_set).
    assert after["r"] < before["r"]
    assert math.isclose(after["r"], math.hypot(after["x"], after["y"]), rel_tol=1e-12)


def test_set_many_is_one_change_and_all_or_nothing(ftafm_instrument: ftafm.Instrument) -> None:
    inst = ftafm_instrument
    t = inst.set_many({"/surface/distance": 15e-9, "/demods/3/harmonic": 6})
    assert t is not None and t > 0
    assert inst.get("/demods/3/harmonic") == 6
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.set_many({"/surface/distance": 11e-9, "/demods/3/harmonic": -2})
    assert e.value.code == "invalid_value"
    assert "/demods/3/harmonic" in e.value.message
    assert inst.get("/surface/distance") == 15e-9, "a refused batch changes nothing"


def test_errors_name_the_node(ftafm_instrument: ftafm.Instrument) -> None:
    inst = ftafm_instrument
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.get("/drive/frequncy")
    assert e.value.code == "unknown_path"
    assert "frequency" in e.value.message
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.set("/synth/sample_rate", 20e6)
    assert e.value.code == "read_only"
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.set("/drive/free_amplitude", 1.0)
    assert e.value.code == "invalid_value" and "/drive/free_amplitude" in e.value.message
    with pytest.raises(ValueError, match="/surface/distance"):
        inst.set("/surface/distance", float("nan"))
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.sample(40)
    assert e.value.code == "unknown_path"
    t = inst.set("/demods/20/enable", False)
    inst.wait_until(t + 0.01)  # the newest output is from after the change
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.sample(20)
    assert e.value.code == "no_data" and "/demods/20/enable" in e.value.message
    # The connection goes on after every error.
    assert inst.get("/demods/20/enable") is False
    # numpy values are sent as the numbers they are.
    inst.set("/surface/distance", np.float64(16e-9))
    assert inst.get("/surface/distance") == 16e-9


def test_poll_gives_arrays_per_stream(ftafm_instrument: ftafm.Instrument) -> None:
    inst = ftafm_instrument
    d = inst.poll("demods", 0.05)
    assert isinstance(d, ftafm.DemodData)
    # 1 kHz frames over 0.05 s of simulated time.
    assert 45 <= len(d) <= 51, len(d)
    assert d.x.shape == (len(d), 32) and d.phase.shape == (len(d), 32)
    assert np.all(np.diff(d.t) > 0) and np.all(np.diff(d.seq) == 1 + 0 * d.gaps)
    assert d.gaps == 0
    assert list(d.enabled) == list(range(32))
    assert d.column(17) == 16 and d.harmonic[-1, 16] == 17
    h1 = d.r[:, d.column(1)]
    assert np.all((h1 > 5e-9) & (h1 < 30e-9)), h1

    s = inst.poll("spectrum", 0.25)
    assert isinstance(s, ftafm.SpectrumData) and len(s) >= 2
    assert s.magnitudes.shape[1] == 32768 // 2 + 1
    peak = s.frequency[np.argmax(s.magnitudes[-1])]
    assert s.bin_width == inst.hello["sample_rate"] / 32768, "a number, the bins' spacing"
    assert abs(peak - 100e3) <= s.bin_width

    sc = inst.poll("scope", 0.1)
    assert isinstance(sc, ftafm.ScopeData) and sc.samples.ndim == 2 and len(sc) >= 1
    assert np.nanmax(np.abs(sc.samples)) > 5e-9

    # The first estimate after the setpoint changes above waits for the estimator's rebuild
    # (the coupled engine's table, ~1 s of work at nice 10, and the builder's rest): a loaded
    # machine stretches that past the default 10 s per message.
    f = inst.poll("force", 0.02, timeout=180)
    assert isinstance(f, ftafm.ForceData) and len(f) >= 10
    assert np.all(f.max_force > 0) and f.waveform.shape[0] == len(f)

    st = inst.poll("status", 0.6)
    assert isinstance(st, ftafm.StatusData) and len(st) >= 1
    assert "counters" in st.messages[0]

    with pytest.raises(ValueError, match="streams"):
        inst.poll("demodz", 0.1)


def test_gaps_are_counted_from_seq() -> None:
    msgs = [
        {"stream": "demods", "seq": s, "t": s * 1e-3, "t_synth_ns": 0,
         "demods": [{"index": 2, "harmonic": 3, "x": 1.0, "y": None, "r": 1.0, "phase": None}]}
        for s in (10, 11, 14, 15, 20)
    ]
    d = ftafm.data.from_messages("demods", msgs)
    assert d.gaps == 2 + 4
    assert np.isnan(d.y[0, 2]) and d.x[0, 2] == 1.0 and np.isnan(d.x[0, 0])
    assert d.harmonic[0, 2] == 3 and d.harmonic[0, 0] == -1


def test_settings_save_and_load_round_trip(ftafm_instrument: ftafm.Instrument, tmp_path) -> None:
    inst = ftafm_instrument
    inst.set_many({"/surface/distance": 17e-9, "/sample/youngs_modulus": 60e9})
    saved = tmp_path / "run.toml"
    inst.save_settings(saved)
    inst.set_many({"/surface/distance": 10e-9, "/sample/youngs_modulus": 3e9})
    t = inst.load_settings(saved)
    assert t is not None
    assert inst.get("/surface/distance") == 17e-9
    assert inst.get("/sample/youngs_modulus") == 60e9
    # The file is what the daemon accepts with --config: one started on it runs the same.
    with Daemon(["--config", str(saved)]) as other, ftafm.Instrument(other.url) as second:
        assert second.settings_toml() == inst.settings_toml()
    bad = tmp_path / "bad.toml"
    bad.write_text("[surface]\ndistance = -1\n")
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.load_settings(bad)
    assert e.value.code == "invalid_value" and "/surface/distance" in e.value.message
    assert inst.get("/surface/distance") == 17e-9


def test_presets(ftafm_instrument: ftafm.Instrument) -> None:
    inst = ftafm_instrument
    names = {p["name"] for p in inst.presets()}
    assert {"tap300", "silicon"} <= names
    t = inst.preset("tap150")
    assert t is not None
    assert inst.get("/cantilever/f1") == inst.get("/drive/frequency")
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.preset("tap301")
    assert e.value.code == "invalid_value" and "tap300" in e.value.message


def test_a_lost_daemon_is_an_error_not_a_hang() -> None:
    with Daemon() as d:
        inst = ftafm.Instrument(d.url, timeout=5)
        assert inst.get("/surface/distance") > 0
        assert d.stop() == 0
        with pytest.raises(ftafm.ConnectionLost):
            inst.get("/surface/distance")
        inst.close()


def test_the_instrument_fixture_restores_the_settings(ftafm_daemon: Daemon) -> None:
    from ftafm.pytest_plugin import ftafm_instrument

    gen = ftafm_instrument.__wrapped__(ftafm_daemon)  # type: ignore[attr-defined]
    inst = next(gen)
    original = inst.get("/surface/distance")
    inst.set("/surface/distance", original * 0.9)
    with pytest.raises(StopIteration):
        next(gen)
    with ftafm.Instrument(ftafm_daemon.url) as check:
        assert check.get("/surface/distance") == original


def test_poll_gives_scan_lines_as_images(tmp_path) -> None:
    overlay = tmp_path / "scan.toml"
    overlay.write_text(
        "[scan]\nenable = true\npixels = 16\nline_rate = 20.0\n\n[noise]\nenable = false\n"
    )
    with Daemon(["--config", str(overlay)]) as d, ftafm.Instrument(d.url) as inst:
        im = inst.poll("image", 0.5)
        assert isinstance(im, ftafm.ImageData) and len(im) >= 5
        assert im.gaps == 0
        assert im.channels["height"].shape == (len(im), 16)
        assert im.channels["h17"].shape == (len(im), 16)
        assert im.units["height"] == "m" and im.units["phase"] == "rad"
        assert np.all(np.diff(im.seq) == 1)
        assert set(np.unique(im.line)) <= set(range(16))
        assert np.all(np.isfinite(im.channels["amplitude"]))


def test_no_daemon_says_so_and_how_to_start_one() -> None:
    import socket

    with socket.socket() as s:  # a port nothing listens on once closed
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"ws://127.0.0.1:{port}/ws"
    with pytest.raises(ftafm.NoDaemon) as e:
        ftafm.Instrument(url, timeout=5.0)
    assert isinstance(e.value, ConnectionRefusedError), "code catching the bare one still works"
    assert url in str(e.value) and "ftafm serve" in str(e.value)


def test_many_values_in_one_request_and_the_node_tree_as_attributes(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    values = inst.get_many(["/sample/youngs_modulus", "/demods/16/harmonic", "/demods/0/sample"])
    assert values["/sample/youngs_modulus"] == 129e9 and values["/demods/16/harmonic"] == 17
    assert values["/demods/0/sample"]["harmonic"] == 1
    # zhinst-toolkit's habit: call a node to get it, with a value to set it.
    assert inst.sample.youngs_modulus() == 129e9
    t = inst.sample.youngs_modulus(116.1e9)
    assert t is not None and inst.get("/sample/youngs_modulus") == 116.1e9
    assert inst.sample(16)["harmonic"] == 17, "sample() is still the demodulator's output"
    assert len(inst.demods) == 32 and inst.demods[16].harmonic() == 17
    assert [d.harmonic.path for d in inst.demods][:2] == ["/demods/0/harmonic", "/demods/1/harmonic"]
    under = inst.demods[16]()
    assert under["/demods/16/harmonic"] == 17 and "/demods/16/enable" in under
    assert inst.drive.frequency.node.unit == "Hz"
    with pytest.raises(AttributeError, match="youngs_modulus"):
        inst.sample.youngs_modulos
    with pytest.raises(IndexError):
        inst.demods[32]


def test_a_set_transaction_is_one_change_all_or_nothing(
    ftafm_instrument: ftafm.Instrument,
) -> None:
    inst = ftafm_instrument
    with inst.set_transaction() as tr:
        inst.surface.distance(15e-9)
        inst.set("/demods/3/harmonic", 6)
        assert inst.get("/surface/distance") == 20e-9, "nothing sent before the end"
    assert tr.t is not None and tr.values == {"/surface/distance": 15e-9, "/demods/3/harmonic": 6}
    assert inst.get_many(["/surface/distance", "/demods/3/harmonic"]) == {
        "/surface/distance": 15e-9,
        "/demods/3/harmonic": 6,
    }
    # A refused batch changes nothing; a block that raises sends nothing.
    with pytest.raises(ftafm.InstrumentError, match="/demods/3/harmonic"):
        with inst.set_transaction():
            inst.surface.distance(12e-9)
            inst.demods[3].harmonic(-2)
    with pytest.raises(KeyError):
        with inst.set_transaction():
            inst.surface.distance(12e-9)
            raise KeyError("a script's own error")
    assert inst.get("/surface/distance") == 15e-9


def test_streamed_samples_are_measured_by_the_lock_in(ftafm_instrument: ftafm.Instrument) -> None:
    """A signal made here (int16 codes of two tones, as a digitiser gives them) streamed
    into the chain: each tone's amplitude and phase from the lock-in bank, on the reference
    at the writer's sample count, across a second call that goes on after a gap."""
    inst = ftafm_instrument
    rate = inst.hello["sample_rate"]
    f = inst.get("/drive/frequency")
    inst.set("/source/kind", "stream")
    scale = 1e-12  # m per code
    tones = [(1, 9000.0, 0.4), (2, 2500.0, -1.9)]  # harmonic, amplitude (codes), phase

    def codes(first: int, n: int) -> np.ndarray:
        theta = 2 * np.pi * f / rate * np.arange(first, first + n, dtype=np.float64)
        x = sum(a * np.cos(k * theta + phi) for k, a, phi in tones)
        return np.round(x).astype(np.int16)

    first = 123_457
    got = inst.stream_samples(codes(first, 500_000), scale=scale, first_index=first)
    assert (got.accepted, got.dropped, got.gap) == (500_000, 0, 0)
    after = got.next_index + 77_777
    got = inst.stream_samples(codes(after, 1_000_000), scale=scale, first_index=after)
    assert (got.accepted, got.gap) == (1_000_000, 77_777)
    # Until the chain has taken every sample streamed (an event: the status says so).
    for _ in range(40):
        status = inst.next("status")
        c = status["counters"]
        if status["stream_fill"] == 0 and c["samples_processed"] == c["samples_synthesized"]:
            break
    else:
        pytest.fail(f"the chain never caught up with the stream: {status}")
    for demod, (k, a, phi) in enumerate(tones):
        s = inst.sample(demod)
        assert s["harmonic"] == k
        assert abs(s["r"] / (a * scale) - 1) < 1e-3, s
        assert abs((s["phase"] - phi + np.pi) % (2 * np.pi) - np.pi) < 1e-3, s
    with pytest.raises(ftafm.InstrumentError, match="frames go forward"):
        inst.stream_samples(codes(0, 10), scale=scale, first_index=0)
    with pytest.raises(ftafm.InstrumentError, match="sample rate"):
        inst.stream_samples(codes(after + 2_000_000, 10), rate / 2, scale=scale)

