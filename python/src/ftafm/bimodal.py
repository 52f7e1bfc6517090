"""Bimodal AM-FM: the sample's reduced modulus and the indentation from what a bimodal
instrument reads, the same expressions as the daemon's ``src/physics/bimodal.rs``
(Herruzo, Perrino & Garcia, Nat. Commun. 5, 3126 (2014); Benaglia et al., Nat. Protoc. 13,
2890 (2018); derived with this project's conventions in docs/loops.md).

The first mode taps under amplitude modulation: its amplitude A1 and phase lag φ1 (90° free
at resonance, below it in repulsive tapping) against its free amplitude A01. The second,
driven at a small amplitude, shifts its resonance by Δf2 with the contact's stiffness
averaged over the first's swing. Amplitudes are the tip's, peak (m); k1, k2 the modes'
tip-referred stiffnesses (N/m).

- ⟨F·cos θ⟩ = k1·A01·cos φ1/(2·Q1), the first mode's virial (θ the swing's phase from
  its lowest point; the mean force ⟨F⟩ of a short tap);
- ⟨k_ts⟩ = 2·k2·Δf2/f2;
- a Hertz contact at the bottom of the swing, δ = d − A1·(1 − cos θ) where positive, solved
  over the whole swing for d and E* (``indentation``, ``reduced_modulus``); the published
  short-tap closed forms d = 2⟨F⟩/⟨k_ts⟩, E* = ⟨k_ts⟩·√(2·A1)/(√R·d) beside them
  (``short_tap_indentation``, ``short_tap_modulus``), 11 % above E* at d/A1 = 0.38.

>>> from ftafm import bimodal
>>> e = bimodal.estimate(k1=40.0, q1=400.0, k2=1560.0, f2=1.88e6, tip_radius=10e-9,
...                      free_amplitude=30e-9, amplitude=20e-9, phase_lag=0.74,
...                      frequency_shift=1630.0)
>>> round(e.indentation * 1e9, 2), round(e.reduced_modulus / 1e9, 2)   # nm, GPa
(0.83, 6.54)
>>> round(e.short_tap_indentation * 1e9, 2), round(e.short_tap_modulus / 1e9, 2)
(0.82, 6.61)
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np

__all__ = ["Estimate", "estimate"]


class Estimate(NamedTuple):
    """What the bimodal expressions give."""

    mean_force: float
    """The first mode's virial ⟨F·cos θ⟩ (N): the tip's mean force ⟨F⟩ for a short tap."""
    mean_stiffness: float
    """The contact's mean stiffness ⟨k_ts⟩ (N/m)."""
    indentation: float
    """The deepest indentation d (m), the Hertz swing solved whole."""
    reduced_modulus: float
    """E* (Pa), the Hertz swing solved whole: 1/E* = (1 − ν_t²)/E_t + (1 − ν_s²)/E_s."""
    short_tap_indentation: float
    """d by the published short-tap closed form 2⟨F⟩/⟨k_ts⟩ (m)."""
    short_tap_modulus: float
    """E* by the published short-tap closed form (Pa)."""


def estimate(
    *,
    k1: float,
    q1: float,
    k2: float,
    f2: float,
    tip_radius: float,
    free_amplitude: float,
    amplitude: float,
    phase_lag: float,
    frequency_shift: float,
) -> Estimate:
    """The bimodal AM-FM estimate (module docs). k1, k2 in N/m; f2, Δf2 (``frequency_shift``)
    in Hz; ``tip_radius`` and the amplitudes in m; ``phase_lag`` φ1 in rad.

    Raises ``ValueError`` naming the argument for a value the expressions cannot take: a
    non-positive constant or amplitude, a Δf2 ≤ 0 (no repulsive contact), a lag at or
    beyond π/2 (no repulsive tapping), or readings no Hertz swing gives."""
    positive = {
        "k1": k1,
        "q1": q1,
        "k2": k2,
        "f2": f2,
        "tip_radius": tip_radius,
        "free_amplitude": free_amplitude,
        "amplitude": amplitude,
        "frequency_shift": frequency_shift,
    }
    for name, value in positive.items():
        if not (math.isfinite(value) and value > 0.0):
            allowed = (
                "> 0 (a repulsive contact raises the second resonance)"
                if name == "frequency_shift"
                else "finite and > 0"
            )
            raise ValueError(f"{name} = {value} is out of range: allowed {allowed}")
    cos = math.cos(phase_lag)
    if not (math.isfinite(phase_lag) and cos > 0.0):
        raise ValueError(
            f"phase_lag = {phase_lag} is out of range: allowed within (−π/2, π/2) rad: "
            "repulsive tapping, below the free lag of π/2"
        )
    mean_force = k1 * free_amplitude * cos / (2.0 * q1)
    mean_stiffness = 2.0 * k2 * frequency_shift / f2
    short_d = 2.0 * mean_force / mean_stiffness
    short_e = mean_stiffness * math.sqrt(2.0 * amplitude) / (math.sqrt(tip_radius) * short_d)
    x_grid, ratio_grid, s_grid = _swing_table()
    ratio = short_d / amplitude
    if ratio >= ratio_grid[-1]:
        raise ValueError(
            f"the readings put the indentation at d/A1 = {ratio:.3f} by the short-tap "
            "expression, beyond what a Hertz contact on a swing gives (at most 1.090, at "
            "d/A1 = 1.86): mode 1's phase lag or mode 2's Δf2 is not a Hertz contact's"
        )
    x = float(np.interp(ratio, ratio_grid, x_grid))
    s = float(np.interp(ratio, ratio_grid, s_grid))
    return Estimate(
        mean_force,
        mean_stiffness,
        x * amplitude,
        mean_stiffness / (2.0 * math.sqrt(tip_radius * amplitude) * s),
        short_d,
        short_e,
    )


@functools.cache
def _swing_table() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x = d/A1 on (0, 1.86], the ratio (4/3)·f(x)/s(x) (x for a short tap) and s(x), where
    f(x) = ⟨(δ/A1)^{3/2}·cos θ⟩ and s(x) = ⟨(δ/A1)^{1/2}⟩ over a period: the table
    ``src/physics/bimodal.rs`` builds, by the same quadrature (θ = θ0·sin u, the midpoint
    rule over u), up to where the ratio stops rising."""
    n = 2048
    x = 2.0 * (np.arange(513) / 512.0) ** 2
    u = -math.pi / 2 + (np.arange(n) + 0.5) * math.pi / n
    theta0 = np.arccos(np.maximum(1.0 - x, -1.0))[:, None]
    theta = theta0 * np.sin(u)[None, :]
    delta = np.maximum(x[:, None] - (1.0 - np.cos(theta)), 0.0)
    weight = theta0 * np.cos(u)[None, :]
    scale = math.pi / n / (2.0 * math.pi)
    f = np.sum(delta**1.5 * np.cos(theta) * weight, axis=1) * scale
    s = np.sum(np.sqrt(delta) * weight, axis=1) * scale
    ratio = np.zeros_like(x)
    ratio[1:] = 4.0 / 3.0 * f[1:] / s[1:]
    rising = int(np.argmax(np.diff(ratio) <= 0.0)) + 1 if np.any(np.diff(ratio) <= 0.0) else len(x)
    return x[:rising], ratio[:rising], s[:rising]
