"""Bimodal AM-FM: the sample's reduced modulus and the indentation from what a bimodal
instrument reads, the same expressions as the daemon's ``src/physics/bimodal.rs``
(Herruzo, Perrino & Garcia, Nat. Commun. 5, 3126 (2014); Benaglia et al., Nat. Protoc. 13,
2890 (2018); derived with this project's conventions in docs/loops.md).

The first mode taps under amplitude modulation: its amplitude A1 and phase lag φ1 (90° free
at resonance, below it in repulsive tapping) against its free amplitude A01. The second,
driven at a small amplitude, shifts its resonance by Δf2 with the contact's stiffness
averaged over the first's swing. Amplitudes are the tip's, peak (m); k1, k2 the modes'
tip-referred stiffnesses (N/m).

- ⟨F⟩ = k1·A01·cos φ1/(2·Q1), the first mode's virial;
- ⟨k_ts⟩ = 2·k2·Δf2/f2;
- d = 2⟨F⟩/⟨k_ts⟩, E* = ⟨k_ts⟩·√(2·A1)/(√R·d).

>>> from ftafm import bimodal
>>> e = bimodal.estimate(k1=40.0, q1=400.0, k2=1560.0, f2=1.88e6, tip_radius=10e-9,
...                      free_amplitude=30e-9, amplitude=20e-9, phase_lag=0.74,
...                      frequency_shift=1630.0)
>>> round(e.indentation * 1e9, 2), round(e.reduced_modulus / 1e9, 1)   # nm, GPa
(0.82, 6.6)
"""

from __future__ import annotations

import math
from typing import NamedTuple

__all__ = ["Estimate", "estimate"]


class Estimate(NamedTuple):
    """What the bimodal expressions give."""

    mean_force: float
    """The tip's mean force ⟨F⟩ (N)."""
    mean_stiffness: float
    """The contact's mean stiffness ⟨k_ts⟩ (N/m)."""
    indentation: float
    """The deepest indentation d (m)."""
    reduced_modulus: float
    """E* (Pa): 1/E* = (1 − ν_t²)/E_t + (1 − ν_s²)/E_s."""


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
    beyond π/2 (no repulsive tapping)."""
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
    indentation = 2.0 * mean_force / mean_stiffness
    reduced_modulus = (
        mean_stiffness * math.sqrt(2.0 * amplitude) / (math.sqrt(tip_radius) * indentation)
    )
    return Estimate(mean_force, mean_stiffness, indentation, reduced_modulus)
