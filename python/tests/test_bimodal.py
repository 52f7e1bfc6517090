"""``ftafm.bimodal``: the expressions give back the modulus and indentation of a Hertz
contact whose averages over a swing are integrated numerically, the whole swing at any
depth and the short-tap closed forms on a short tap, and refuse what they cannot take,
naming it."""

import math

import numpy as np
import pytest

from ftafm import bimodal


K1, Q1, K2, F2, FREE, RADIUS = 20.0, 100.0, 800.0, 626e3, 30e-9, 10e-9


def hertz_reading(modulus: float, a1: float, d: float) -> tuple[dict[str, float], float, float]:
    """The arguments a Hertz contact of ``modulus`` at depth ``d`` under a swing ``a1``
    gives, its averages summed over 2e6 phases independently of the module's quadrature:
    the virial ⟨F·cos θ⟩ sets cos φ1, ⟨k_ts⟩ sets Δf2. With ⟨F⟩ and ⟨k_ts⟩."""
    theta = np.linspace(-math.pi, math.pi, 2_000_001)[:-1] + math.pi / 2_000_000
    delta = np.clip(d - a1 * (1.0 - np.cos(theta)), 0.0, None)
    f = 4.0 / 3.0 * modulus * math.sqrt(RADIUS) * delta**1.5
    force, virial = float(np.mean(f)), float(np.mean(f * np.cos(theta)))
    stiffness = float(np.mean(2.0 * modulus * math.sqrt(RADIUS) * np.sqrt(delta)))
    args = dict(
        k1=K1,
        q1=Q1,
        k2=K2,
        f2=F2,
        tip_radius=RADIUS,
        free_amplitude=FREE,
        amplitude=a1,
        phase_lag=math.acos(virial * 2.0 * Q1 / (K1 * FREE)),
        frequency_shift=stiffness * F2 / (2.0 * K2),
    )
    return args, force, stiffness


def test_a_short_tap_inverts_by_the_published_expressions() -> None:
    args, force, stiffness = hertz_reading(1e9, 20e-9, 1.5e-9)
    e = bimodal.estimate(**args)
    assert e.mean_force == pytest.approx(force, rel=0.03)
    assert e.mean_stiffness == pytest.approx(stiffness, rel=1e-12)
    # The short tap's parabola: a few per cent at d/A1 = 7.5 %.
    assert e.short_tap_indentation == pytest.approx(1.5e-9, rel=0.03)
    assert e.short_tap_modulus == pytest.approx(1e9, rel=0.03)


@pytest.mark.parametrize(("x", "modulus"), [(1e-3, 100e9), (0.075, 1e9), (0.38, 10e6), (1.8, 1e6)])
def test_the_whole_swing_inverts_to_its_modulus_at_any_depth(x: float, modulus: float) -> None:
    a1 = 20e-9
    args, _, _ = hertz_reading(modulus, a1, x * a1)
    e = bimodal.estimate(**args)
    assert e.reduced_modulus == pytest.approx(modulus, rel=1e-4)
    assert e.indentation == pytest.approx(x * a1, rel=1e-4)
    if x > 0.3:
        assert e.short_tap_modulus > 1.1 * modulus


def test_readings_beyond_any_swing_are_refused() -> None:
    args, _, _ = hertz_reading(1e6, 20e-9, 1.8 * 20e-9)
    args["phase_lag"] = math.acos(math.cos(args["phase_lag"]) * 1.1)
    with pytest.raises(ValueError, match="beyond what a Hertz contact on a swing gives"):
        bimodal.estimate(**args)


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("phase_lag", 2.0, "phase_lag = 2.0 is out of range"),
        ("frequency_shift", -3.0, "frequency_shift = -3.0 is out of range: allowed > 0"),
        ("tip_radius", 0.0, "tip_radius = 0.0 is out of range"),
    ],
)
def test_what_it_cannot_take_is_named(name: str, value: float, message: str) -> None:
    args = dict(
        k1=20.0,
        q1=100.0,
        k2=800.0,
        f2=626e3,
        tip_radius=10e-9,
        free_amplitude=30e-9,
        amplitude=20e-9,
        phase_lag=0.8,
        frequency_shift=500.0,
    )
    args[name] = value
    with pytest.raises(ValueError, match=message):
        bimodal.estimate(**args)
