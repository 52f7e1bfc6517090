"""``ftafm.bimodal``: the expressions give back the modulus and indentation of a Hertz
contact whose averages over a swing are integrated numerically, and refuse what they
cannot take, naming it."""

import math

import numpy as np
import pytest

from ftafm import bimodal


def test_a_hertz_swing_inverts_to_its_modulus() -> None:
    modulus, radius, a1, d = 1e9, 10e-9, 20e-9, 1.5e-9
    theta = np.linspace(-math.pi, math.pi, 2_000_001)[:-1] + math.pi / 2_000_000
    delta = np.clip(d - a1 * (1.0 - np.cos(theta)), 0.0, None)
    force = float(np.mean(4.0 / 3.0 * modulus * math.sqrt(radius) * delta**1.5))
    stiffness = float(np.mean(2.0 * modulus * math.sqrt(radius) * np.sqrt(delta)))
    k1, q1, k2, f2, free = 20.0, 100.0, 800.0, 626e3, 30e-9
    e = bimodal.estimate(
        k1=k1,
        q1=q1,
        k2=k2,
        f2=f2,
        tip_radius=radius,
        free_amplitude=free,
        amplitude=a1,
        phase_lag=math.acos(force * 2.0 * q1 / (k1 * free)),
        frequency_shift=stiffness * f2 / (2.0 * k2),
    )
    assert e.mean_force == pytest.approx(force, rel=1e-12)
    assert e.mean_stiffness == pytest.approx(stiffness, rel=1e-12)
    # The parabola the expressions take for the swing's bottom: a few per cent at d/A1 = 7.5 %.
    assert e.indentation == pytest.approx(d, rel=0.03)
    assert e.reduced_modulus == pytest.approx(modulus, rel=0.03)


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
