"""FM-AFM: the frequency shift of an oscillating lever over a force law, and the
Sader–Jarvis inversion of a measured frequency-shift curve back to the force.

The same maths as the daemon's ``src/physics/fm`` and ``ftafm fm-invert``, in numpy:
:func:`invert` gives the Rust command's numbers (the same operations in the same order),
:func:`frequency_shift` is the forward model (Giessibl's integral over the oscillation).

Conventions (Giessibl 1997; Sader & Jarvis 2004):

- the force F(d) (N) acts on the tip at distance d (m) from the sample, **positive when
  repulsive**, negative when attractive;
- ``z`` is the **distance of closest approach** of the oscillating tip, which swings over
  [z, z + 2A];
- the amplitude A is **zero to peak** (m); k is the spring constant (N/m), f0 the free
  resonance frequency (Hz), Δf the shift of the resonance (Hz);
- an attractive force lowers the resonance: **Δf < 0**. In the small-amplitude limit
  Δf = −f0/(2k)·dF/dz at the orbit's centre z + A.

>>> import numpy as np
>>> from ftafm import fm
>>> law = lambda d: -1e-9 * np.exp(-d / 0.5e-9)          # N, an exponential attraction
>>> z = np.linspace(0.1e-9, 15e-9, 1500)                   # m
>>> df = fm.frequency_shift(law, z, k=30.0, f0=300e3, amplitude=1e-9)   # Hz
>>> curve = fm.invert(z, df, k=30.0, f0=300e3, amplitude=1e-9)
>>> bool(np.max(np.abs(curve.force - law(curve.z))) < 0.02 * 1e-9)
True
"""

from __future__ import annotations

import math
from collections.abc import Callable
from decimal import Decimal
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

__all__ = [
    "DEFAULT_NODES",
    "FmError",
    "ForceCurve",
    "LengthsError",
    "NotFiniteError",
    "NotIncreasingError",
    "ParameterError",
    "TooShortError",
    "frequency_shift",
    "invert",
]

FloatArray = npt.NDArray[np.float64]

#: Quadrature nodes :func:`frequency_shift` uses by default: enough for 0.1 % on a force
#: law with a kink (Hertz contact) at amplitudes up to 10⁴ times its decay length.
DEFAULT_NODES = 4096

#: Elements of the largest intermediate array (rows × columns) the functions build at once.
_BLOCK = 1 << 18


def _display(value: float) -> str:
    """``value`` as Rust's ``{}`` writes an f64 (shortest round-trip digits, never an
    exponent; ``NaN``, ``inf``), so the messages are the daemon's word for word."""
    if math.isnan(value):
        return "NaN"
    if math.isinf(value):
        return "inf" if value > 0 else "-inf"
    text = format(Decimal(repr(value)), "f")
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text


class FmError(ValueError):
    """A bad input of the FM-AFM maths; the subclass and its attributes say which, and the
    message (the Rust ``FmError``'s, word for word) names the parameter or the sample."""


class ParameterError(FmError):
    """A scalar parameter out of its range: ``name`` (``"k"``, ``"f0"``, ``"amplitude"``,
    ``"nodes"``), the ``value`` given and what is ``allowed``."""

    def __init__(self, name: str, value: float, allowed: str):
        super().__init__(f"{name} = {_display(value)} is out of range: allowed {allowed}")
        self.name = name
        self.value = value
        self.allowed = allowed


class LengthsError(FmError):
    """``z`` and ``df`` of different lengths (``z``, ``df``: their lengths)."""

    def __init__(self, z: int, df: int):
        super().__init__(
            f"z has {z} samples but df has {df}: give one frequency shift per distance"
        )
        self.z = z
        self.df = df


class TooShortError(FmError):
    """Fewer than 3 samples (``len``) to invert."""

    def __init__(self, length: int):
        super().__init__(f"{length} samples given: at least 3 are needed")
        self.len = length


class NotFiniteError(FmError):
    """A sample that is NaN or infinite: ``name`` (``"z"`` or ``"df"``), its ``index`` and
    ``value``."""

    def __init__(self, name: str, index: int, value: float):
        super().__init__(f"{name}[{index}] = {_display(value)} is not finite")
        self.name = name
        self.index = index
        self.value = value


class NotIncreasingError(FmError):
    """``z`` not strictly increasing: the offending ``index``, its ``value`` and the
    ``previous`` sample (m)."""

    def __init__(self, index: int, value: float, previous: float):
        super().__init__(
            f"z must increase strictly: z[{index}] = {_display(value)} follows "
            f"z[{index - 1}] = {_display(previous)}"
        )
        self.index = index
        self.value = value
        self.previous = previous


class ForceCurve(NamedTuple):
    """A force curve: ``z``, the distances of closest approach (m, increasing), and
    ``force``, the force on the tip at each (N, repulsive positive). A tuple, so
    ``z, force = invert(...)`` unpacks it."""

    z: FloatArray
    force: FloatArray


def _lever(k: float, f0: float, amplitude: float) -> tuple[float, float, float]:
    """The lever's parameters as floats; each must be finite and > 0 (Rust's
    ``FmLever::new``, in its order)."""
    checked = []
    for name, value, allowed in (
        ("k", k, "a finite stiffness > 0 N/m"),
        ("f0", f0, "a finite frequency > 0 Hz"),
        ("amplitude", amplitude, "a finite amplitude > 0 m"),
    ):
        v = float(value)
        if not (math.isfinite(v) and v > 0.0):
            raise ParameterError(name, v, allowed)
        checked.append(v)
    return checked[0], checked[1], checked[2]


def _samples(name: str, values: npt.ArrayLike) -> FloatArray:
    """``values`` as a 1-D float64 array (a copy the caller cannot change under us)."""
    array = np.array(values, dtype=np.float64)
    if array.ndim != 1:
        raise FmError(f"{name} must be one-dimensional, got an array of shape {array.shape}")
    return array


def _first_not_finite(name: str, values: FloatArray) -> None:
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        index = int(bad[0])
        raise NotFiniteError(name, index, float(values[index]))


def _validate(z: FloatArray, df: FloatArray) -> None:
    """Equal lengths, ≥ 3 samples, finite, z strictly increasing (Rust's order)."""
    if len(z) != len(df):
        raise LengthsError(len(z), len(df))
    if len(z) < 3:
        raise TooShortError(len(z))
    _first_not_finite("z", z)
    _first_not_finite("df", df)
    bad = np.flatnonzero(z[1:] <= z[:-1])
    if bad.size:
        index = int(bad[0]) + 1
        raise NotIncreasingError(index, float(z[index]), float(z[index - 1]))


def invert(
    z: npt.ArrayLike,
    df: npt.ArrayLike,
    *,
    k: float,
    f0: float,
    amplitude: float,
) -> ForceCurve:
    """The force F(z) (N, repulsive positive) from the frequency shifts ``df`` (Hz)
    measured at the distances of closest approach ``z`` (m, strictly increasing), by the
    Sader–Jarvis formula (J. E. Sader & S. P. Jarvis, Appl. Phys. Lett. 84, 1801 (2004),
    eq. 9), valid at any amplitude:

    F(z) = 2k ∫_z^∞ [ (1 + A^{1/2}/(8·√(π(t − z)))) Ω(t) − A^{3/2}/√(2(t − z)) · dΩ/dt ] dt,

    Ω = Δf/f0; ``k`` the spring constant (N/m), ``f0`` the free resonance (Hz),
    ``amplitude`` A (m, zero to peak).

    Discretisation (as ``ftafm fm-invert``): Ω is taken piecewise linear between the
    samples (dΩ/dt each interval's finite difference) and every interval is integrated
    exactly against the kernels 1 and (t − z)^{−1/2} (product integration), on any (even
    uneven) grid; Ω is zero beyond the last sample, so the data must reach where Δf has
    died out. The force comes at every sample but the last (where the integral over the
    data is empty): the curve has ``len(z) - 1`` points.

    Raises a :class:`FmError` naming the input: :class:`ParameterError` (k, f0 or
    amplitude not finite and > 0), :class:`LengthsError`, :class:`TooShortError` (< 3
    samples), :class:`NotFiniteError` (``z[i]`` or ``df[i]``),
    :class:`NotIncreasingError` (``z[i]``).
    """
    k, f0, a = _lever(k, f0, amplitude)
    zs, dfs = _samples("z", z), _samples("df", df)
    _validate(zs, dfs)
    n = len(zs)
    c_half = math.sqrt(a) / (8.0 * math.sqrt(math.pi))
    c_three_halves = a * math.sqrt(a) / math.sqrt(2.0)
    omega = dfs / f0
    slope = (omega[1:] - omega[:-1]) / (zs[1:] - zs[:-1])
    force = np.empty(n - 1)
    rows = max(1, _BLOCK // n)
    # Force j sums the intervals i = j .. n − 2 in order, as the Rust loop does: row j of a
    # block holds zeros before column j, and a running sum along the row adds them first
    # (0 + … + 0 + t_j = t_j exactly) and then t_{j+1}, t_{j+2}, … one at a time. The
    # columns before j get lo = 0, hi = 1 (finite, and dropped).
    for start in range(0, n - 1, rows):
        j = np.arange(start, min(start + rows, n - 1))
        i = np.arange(start, n - 1)
        inside = i[None, :] >= j[:, None]
        lo = np.where(inside, zs[i][None, :] - zs[j][:, None], 0.0)
        hi = np.where(inside, zs[i + 1][None, :] - zs[j][:, None], 1.0)
        sqrt_lo, sqrt_hi = np.sqrt(lo), np.sqrt(hi)
        # r = √hi − √lo without cancellation; the exact integrals of the interval:
        # ∫ du/√u = 2r, ∫ (u − lo)/√u du = (2/3)·r²·(√hi + 2√lo).
        r = (hi - lo) / (sqrt_hi + sqrt_lo)
        k0 = 2.0 * r
        k1 = 2.0 / 3.0 * r * r * (sqrt_hi + 2.0 * sqrt_lo)
        om_i, om_next, s = omega[i], omega[i + 1], slope[i]
        plain = 0.5 * (hi - lo) * (om_i + om_next)
        over_sqrt = om_i * k0 + s * k1
        term = plain + c_half * over_sqrt - c_three_halves * s * k0
        term = np.where(inside, term, 0.0)
        force[j] = 2.0 * k * np.cumsum(term, axis=1)[:, -1]
    return ForceCurve(z=zs[:-1].copy(), force=force)


def frequency_shift(
    force_law: Callable[[FloatArray], npt.ArrayLike],
    z: npt.ArrayLike,
    *,
    k: float,
    f0: float,
    amplitude: float,
    nodes: int = DEFAULT_NODES,
) -> FloatArray:
    """The frequency shift Δf (Hz) at each distance of closest approach of ``z`` (m;
    any shape, a scalar too) of a lever of spring constant ``k`` (N/m) and free resonance
    ``f0`` (Hz) oscillating at ``amplitude`` A (m, zero to peak) over ``force_law`` (the
    force in N, repulsive positive, of the distance in m):

    Δf(d) = −f0/(π·k·A) · ∫₋₁¹ F(d + A(1 + u)) · u/√(1 − u²) du,

    by Gauss–Chebyshev quadrature of ``nodes`` points (u = cos θ at the midpoints of
    [0, π] in θ), which takes the weight 1/√(1 − u²) exactly; its nodes cluster at the
    turning points, where the tip meets the force. The same quadrature as the daemon's
    ``frequency_shift``/``frequency_shift_curve`` (whose default is also
    :data:`DEFAULT_NODES`). Attraction gives Δf < 0.

    ``force_law`` is called with 2-D numpy arrays of distances (about 2¹⁸ at once) and
    must return the forces elementwise, of the same shape (numpy expressions do;
    ``numpy.where`` for piecewise laws; a law of plain floats can be wrapped in
    ``numpy.vectorize``). Returns an array of ``z``'s shape (0-d for a scalar).

    Raises :class:`ParameterError` for k, f0 or amplitude not finite and > 0, or
    ``nodes`` < 1, and :class:`NotFiniteError` for a distance that is not finite.
    """
    k, f0, a = _lever(k, f0, amplitude)
    if int(nodes) != nodes or nodes < 1:
        raise ParameterError("nodes", float(nodes), "an integer ≥ 1")
    nodes = int(nodes)
    d = np.asarray(z, dtype=np.float64)
    flat = d.reshape(-1)
    _first_not_finite("z", flat)
    step = math.pi / nodes
    u = np.cos((np.arange(nodes) + 0.5) * step)
    out = np.empty(flat.shape)
    rows = max(1, _BLOCK // nodes)
    for start in range(0, len(flat), rows):
        block = flat[start : start + rows]
        distances = block[:, None] + a * (1.0 + u)[None, :]
        forces = np.broadcast_to(np.asarray(force_law(distances), dtype=np.float64),
                                 distances.shape)
        # Summed node by node in order, as the Rust iterator's sum.
        out[start : start + rows] = np.cumsum(forces * u[None, :], axis=1)[:, -1]
    result: FloatArray = (-f0 / (math.pi * k * a) * out * step).reshape(d.shape)
    return result
