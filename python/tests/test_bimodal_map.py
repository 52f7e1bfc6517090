"""A bimodal AM-FM map through the client: a daemon on tap300 with the example
``config/examples/bimodal_map.toml`` (the second excitation on, mode 2's PLL and amplitude
loop on it) scans; its image lines carry ``frequency_shift2``, ``indentation`` and
``bimodal_modulus`` beside the usual channels, as the daemon's units say, and
:class:`ftafm.ImageData` gives them as lines × pixels like any other channel. A loop on the
drive stays refused while scanning. The maps' accuracy is tested in the daemon's tests
(tests/bimodal_scan.rs); here, that they reach a client whole and show the disc."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

import ftafm
from ftafm.testing import Daemon

EXAMPLE = Path(__file__).resolve().parents[2] / "config" / "examples" / "bimodal_map.toml"
PIXELS = 16  # the example's
BIMODAL = {"frequency_shift2": "Hz", "indentation": "m", "bimodal_modulus": "Pa"}


@pytest.fixture(scope="module")
def bimodal_map() -> Iterator[ftafm.Instrument]:
    """The example's map scanning, free-running (no pixel lost to a busy machine)."""
    with Daemon(["--preset", "tap300", "--config", str(EXAMPLE)]) as daemon:
        # Hang guard per message, not a margin: a busy machine slows the chain down.
        with ftafm.Instrument(daemon.url, timeout=120.0) as inst:
            inst.set_many({"/synth/realtime": False, "/scan/enable": True})
            yield inst


def first_whole_frame(inst: ftafm.Instrument, after_frame: int) -> list[dict[str, Any]]:
    """The lines of the first frame numbered above ``after_frame`` that arrives whole (every
    line, of the settings in force), in order."""
    frames: dict[tuple[int, int], dict[int, dict[str, Any]]] = {}
    bound = 40 * PIXELS  # lines, not time: a bound on a stream that never completes a frame
    for _ in range(bound):
        m = inst.next("image")
        if m.get("stale") or m.get("epoch", 0) < inst.epoch or m["frame"] <= after_frame:
            continue
        lines = frames.setdefault((m["generation"], m["frame"]), {})
        lines[m["line"]] = m
        if len(lines) == PIXELS:
            return [lines[k] for k in range(PIXELS)]
    raise AssertionError(f"no whole frame in {bound} lines: {sorted(frames)}")


def test_a_bimodal_map_brings_its_channels_and_shows_the_disc(
    bimodal_map: ftafm.Instrument,
) -> None:
    inst = bimodal_map
    # Frame 0's first line holds the loops' lock-in: measure frame 1 on.
    lines = first_whole_frame(inst, after_frame=0)
    im = ftafm.data.from_messages("image", lines)
    assert isinstance(im, ftafm.ImageData) and im.gaps == 0
    assert list(im.line) == list(range(PIXELS))
    for name, unit in BIMODAL.items():
        assert name in im.channels, sorted(im.channels)
        assert im.channels[name].shape == (PIXELS, PIXELS)
        assert im.units[name] == unit
    assert im.units["height"] == "m" and "h17" in im.channels
    # Mode 2's PLL runs on drive2, within its limits, where the image reads mode 2's shift
    # (its latest output against the silicon's pixels: the tip may be over the disc, 2.5 %
    # lower). Not its `locked`: at the example's 0.05 nm and the default noise, mode 2's
    # phase leaves the 0.1 rad window of the lock criterion thousands of times a second.
    pll = inst.pid_status()[0]
    assert pll.enable and pll.oscillator == "drive2" and pll.output == "drive2_frequency"
    assert pll.latest is not None and not pll.latest.limited, pll

    # The disc (inclusion 0, at the centre) and the base material around it, by the pixels'
    # centres: the disc's interior, and the base well clear of its edge.
    width, size = inst.get("/inclusions/0/width"), inst.get("/scan/size")
    assert inst.get("/inclusions/0/enable") is True
    pixel = size / PIXELS
    centres = (np.arange(PIXELS) + 0.5) * pixel - size / 2
    r = np.hypot(*np.meshgrid(centres, centres))
    disc, base = r < width / 2 - pixel, r > width / 2 + pixel
    assert disc.sum() >= 4 and base.sum() >= 150

    shift = im.channels["frequency_shift2"]
    modulus = im.channels["bimodal_modulus"]
    indentation = im.channels["indentation"]
    assert np.all(np.isfinite(shift)), "every pixel has mode 2's frequency"
    # The repulsive contact stiffens mode 2: its resonance shifts up over silicon (4.1 kHz,
    # docs/loops.md), every pixel of it.
    assert np.all(shift[base] > 0) and 1e3 < np.median(shift[base]) < 2e4
    assert pll.frequency_shift is not None
    assert abs(pll.frequency_shift / np.median(shift[base]) - 1) < 0.25, pll.frequency_shift
    # The bimodal expressions hold (Δf₂ > 0, φ1 < 90°) nearly everywhere.
    assert np.isfinite(modulus).mean() >= 0.9 and np.isfinite(indentation).mean() >= 0.9
    e_base = np.nanmedian(modulus[base])
    assert 50e9 < e_base < 200e9, f"silicon (129 GPa) reads {e_base:.4g} Pa"
    assert 0.05e-9 < np.nanmedian(indentation[base]) < 1e-9
    # The softer disc: less shift, a deeper indentation, a lower modulus (by 9 %, at a
    # pixel's scatter of 1.5 %).
    e_disc = np.nanmedian(modulus[disc])
    assert np.median(shift[disc]) < np.median(shift[base])
    assert np.nanmedian(indentation[disc]) > np.nanmedian(indentation[base])
    assert 0.8 < e_disc / e_base < 0.97, f"disc {e_disc:.4g} Pa, silicon {e_base:.4g} Pa"


def test_a_loop_on_the_drive_is_refused_while_the_map_scans(
    bimodal_map: ftafm.Instrument,
) -> None:
    inst = bimodal_map
    assert inst.get("/scan/enable") is True and inst.get("/drive2/enable") is True
    before = inst.settings_toml()
    epoch = inst.epoch
    with pytest.raises(ftafm.InstrumentError) as e:
        inst.set_many(
            {
                "/pids/2/enable": True,
                "/pids/2/input": "phase",
                "/pids/2/harmonic": 1,
                "/pids/2/output": "drive_frequency",
            }
        )
    assert e.value.code == "invalid_value"
    assert "/pids/2/output" in e.value.message and "/scan/enable" in e.value.message
    # Nothing changed: not that unit, not the settings' epoch, and the map goes on.
    assert inst.settings_toml() == before and inst.epoch == epoch
    assert inst.get("/pids/2/enable") is False
    assert [s.enable for s in inst.pid_status()[:3]] == [True, True, False]
    lines = first_whole_frame(inst, after_frame=1)
    assert all("bimodal_modulus" in m["channels"] for m in lines)
