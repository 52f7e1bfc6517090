"""Stream messages as numpy arrays.

``Instrument.poll`` returns one of these per stream: a row per message, in the order the
daemon sent them, with ``t`` (simulated time, s), ``seq`` and ``t_synth_ns`` beside the
stream's own fields, and ``gaps``, the number of messages the daemon dropped for this
client in between (counted from ``seq``; a slow reader loses messages, never silently).
A JSON ``null`` (a NaN or infinite value on the daemon's side) becomes NaN.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

#: Demodulators of the daemon's bank; demodulator N is column N of the demods arrays.
DEMODULATORS = 32

#: SI unit of each array, by stream and field (what HDF5 recordings store as ``units``).
UNITS: dict[str, dict[str, str]] = {
    "common": {"t": "s", "seq": "1", "t_synth_ns": "ns"},
    "demods": {"harmonic": "1", "x": "m", "y": "m", "r": "m", "phase": "rad"},
    "spectrum": {"magnitudes": "m", "frequency": "Hz", "bin_width": "Hz"},
    "scope": {"samples": "m", "dt": "s", "start_phase": "rad", "phase_step": "rad"},
    "force": {
        "contact_time_ratio": "1",
        "contact_time_ratio_sigma": "1",
        "max_force": "N",
        "max_force_sigma": "N",
        "youngs_modulus": "Pa",
        "youngs_modulus_sigma": "Pa",
        "youngs_modulus_interval": "Pa",
        "pulse_phase": "rad",
        "waveform": "N",
    },
    "status": {"realtime_factor": "1", "ring_fill": "1", "messages_dropped": "1"},
    "image": {"line": "1", "frame": "1", "generation": "1"},
}


def unit(stream: str, name: str) -> str:
    """The SI unit of array ``name`` of ``stream`` (``""`` if unknown)."""
    return UNITS.get(stream, {}).get(name) or UNITS["common"].get(name, "")


def _floats(values: Sequence[Any]) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], dtype=float)


def _rows(rows: Sequence[Sequence[Any] | None]) -> np.ndarray:
    """Rows of possibly different lengths as a 2-D float array, NaN-padded."""
    width = max((len(r) for r in rows if r is not None), default=0)
    out = np.full((len(rows), width), np.nan)
    for i, r in enumerate(rows):
        if r:
            out[i, : len(r)] = [np.nan if v is None else v for v in r]
    return out


def count_gaps(seq: np.ndarray) -> int:
    """Messages missing between consecutive ``seq`` values."""
    if len(seq) < 2:
        return 0
    steps = np.diff(seq.astype(np.int64))
    return int(np.sum(np.where(steps > 1, steps - 1, 0)))


@dataclass
class StreamData:
    """Messages of one stream as arrays: ``t`` (s), ``seq``, ``t_synth_ns`` (Unix ns)."""

    stream: str
    t: np.ndarray
    seq: np.ndarray
    t_synth_ns: np.ndarray
    gaps: int

    def __len__(self) -> int:
        return len(self.t)

    @classmethod
    def _common(cls, stream: str, messages: Sequence[dict[str, Any]]) -> dict[str, Any]:
        seq = np.array([m["seq"] for m in messages], dtype=np.int64)
        return {
            "stream": stream,
            "t": _floats([m["t"] for m in messages]),
            "seq": seq,
            "t_synth_ns": np.array([m["t_synth_ns"] for m in messages], dtype=np.int64),
            "gaps": count_gaps(seq),
        }

    @classmethod
    def from_messages(cls, messages: Sequence[dict[str, Any]]) -> "StreamData":
        """The arrays of ``messages`` (a row per message)."""
        raise NotImplementedError(f"{cls.__name__} is built by a stream's own class")

    def arrays(self) -> dict[str, np.ndarray]:
        """Every array field by name (what a recording stores)."""
        return {
            k: v
            for k, v in vars(self).items()
            if isinstance(v, np.ndarray)
        }


@dataclass
class DemodData(StreamData):
    """The lock-in outputs: arrays of frames × 32 demodulators, column N for demodulator N.

    Columns of demodulators that produced nothing in a frame (disabled, out of band) hold
    NaN, and ``harmonic`` −1 there.
    """

    harmonic: np.ndarray = field(default_factory=lambda: np.empty((0, DEMODULATORS)))
    x: np.ndarray = field(default_factory=lambda: np.empty((0, DEMODULATORS)))
    y: np.ndarray = field(default_factory=lambda: np.empty((0, DEMODULATORS)))
    r: np.ndarray = field(default_factory=lambda: np.empty((0, DEMODULATORS)))
    phase: np.ndarray = field(default_factory=lambda: np.empty((0, DEMODULATORS)))

    @classmethod
    def from_messages(cls, messages: Sequence[dict[str, Any]]) -> "DemodData":
        n = len(messages)
        arrays = {k: np.full((n, DEMODULATORS), np.nan) for k in ("x", "y", "r", "phase")}
        harmonic = np.full((n, DEMODULATORS), -1, dtype=np.int64)
        for i, m in enumerate(messages):
            for d in m["demods"]:
                j = d["index"]
                harmonic[i, j] = d["harmonic"]
                for k in arrays:
                    v = d[k]
                    arrays[k][i, j] = np.nan if v is None else v
        return cls(
            **cls._common("demods", messages),
            harmonic=harmonic,
            x=arrays["x"],
            y=arrays["y"],
            r=arrays["r"],
            phase=arrays["phase"],
        )

    @property
    def enabled(self) -> np.ndarray:
        """Demodulator indices that produced output in at least one frame."""
        return np.flatnonzero((self.harmonic >= 0).any(axis=0))

    def column(self, harmonic: int) -> int:
        """The first demodulator measuring ``harmonic`` in the last frame."""
        if len(self) == 0:
            raise ValueError("no frames")
        hits = np.flatnonzero(self.harmonic[-1] == harmonic)
        if len(hits) == 0:
            raise ValueError(f"no demodulator measures harmonic {harmonic}")
        return int(hits[0])


@dataclass
class SpectrumData(StreamData):
    """Sliding-FFT magnitudes: ``magnitudes`` (spectra × bins, peak m), ``frequency`` (Hz,
    the bins' centres) and ``bin_width`` (Hz), the newest spectrum's (NaN if none): bin k
    is at k × ``bin_width``."""

    bin_width: float = float("nan")
    magnitudes: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    frequency: np.ndarray = field(default_factory=lambda: np.empty(0))

    @classmethod
    def from_messages(cls, messages: Sequence[dict[str, Any]]) -> "SpectrumData":
        mags = _rows([m["magnitudes"] for m in messages])
        bw = float(messages[-1]["bin_width"]) if messages else float("nan")
        freq = np.arange(mags.shape[1]) * (bw if messages else 0.0)
        return cls(**cls._common("spectrum", messages), bin_width=bw, magnitudes=mags,
                   frequency=freq)


@dataclass
class ScopeData(StreamData):
    """Raw photodiode traces: ``samples`` (traces × samples, m), ``dt`` (s), phases (rad)."""

    samples: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    dt: np.ndarray = field(default_factory=lambda: np.empty(0))
    start_phase: np.ndarray = field(default_factory=lambda: np.empty(0))
    phase_step: np.ndarray = field(default_factory=lambda: np.empty(0))

    @classmethod
    def from_messages(cls, messages: Sequence[dict[str, Any]]) -> "ScopeData":
        return cls(
            **cls._common("scope", messages),
            samples=_rows([m["samples"] for m in messages]),
            dt=_floats([m["dt"] for m in messages]),
            start_phase=_floats([m["start_phase"] for m in messages]),
            phase_step=_floats([m["phase_step"] for m in messages]),
        )


@dataclass
class ForceData(StreamData):
    """FT-AFM force estimates: τ, F (N), modulus (Pa), their sigmas, and the waveform (N)."""

    contact_time_ratio: np.ndarray = field(default_factory=lambda: np.empty(0))
    contact_time_ratio_sigma: np.ndarray = field(default_factory=lambda: np.empty(0))
    max_force: np.ndarray = field(default_factory=lambda: np.empty(0))
    max_force_sigma: np.ndarray = field(default_factory=lambda: np.empty(0))
    youngs_modulus: np.ndarray = field(default_factory=lambda: np.empty(0))
    youngs_modulus_sigma: np.ndarray = field(default_factory=lambda: np.empty(0))
    #: The 68 % profile interval of the modulus (Pa): one (low, high) row per estimate,
    #: asymmetric where the modulus is poorly resolved.
    youngs_modulus_interval: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    pulse_phase: np.ndarray = field(default_factory=lambda: np.empty(0))
    waveform: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    method: list[str] = field(default_factory=list)
    table_range: list[str] = field(default_factory=list)
    #: The settings epoch each estimate reflects, and whether it was made by the model of
    #: older settings (``poll`` leaves those out unless asked).
    epoch: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    stale: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))

    @classmethod
    def from_messages(cls, messages: Sequence[dict[str, Any]]) -> "ForceData":
        def col(k: str) -> np.ndarray:
            return _floats([m.get(k) for m in messages])

        return cls(
            **cls._common("force", messages),
            contact_time_ratio=col("contact_time_ratio"),
            contact_time_ratio_sigma=col("contact_time_ratio_sigma"),
            max_force=col("max_force"),
            max_force_sigma=col("max_force_sigma"),
            youngs_modulus=col("youngs_modulus"),
            youngs_modulus_sigma=col("youngs_modulus_sigma"),
            youngs_modulus_interval=_rows(
                [m.get("youngs_modulus_interval") or [None, None] for m in messages]
            ).reshape(len(messages), 2),
            pulse_phase=col("pulse_phase"),
            waveform=_rows([m.get("waveform") for m in messages]),
            method=[m.get("method", "") for m in messages],
            table_range=[m.get("table_range", "") for m in messages],
            epoch=np.array([m.get("epoch", 0) for m in messages], dtype=np.int64),
            stale=np.array([bool(m.get("stale", False)) for m in messages], dtype=bool),
        )


@dataclass
class StatusData(StreamData):
    """Pipeline health: ``realtime_factor``, ``ring_fill``, ``messages_dropped`` as arrays,
    and every message whole in ``messages`` (counters, latencies, warnings).

    A status message's ``t`` is the simulated time of the newest sample the lock-in had
    processed when it was made (every 0.5 s of wall time), on the same clock as the other
    streams: at or after the ``t`` of every ``demods`` frame sent before it (a frame is
    sent at the end of its period: typically 0.03–0.7 ms behind at 1 kHz, tens of ms while
    the daemon starts), while frames sent after it carry later times."""

    realtime_factor: np.ndarray = field(default_factory=lambda: np.empty(0))
    ring_fill: np.ndarray = field(default_factory=lambda: np.empty(0))
    messages_dropped: np.ndarray = field(default_factory=lambda: np.empty(0))
    messages: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def from_messages(cls, messages: Sequence[dict[str, Any]]) -> "StatusData":
        return cls(
            **cls._common("status", messages),
            realtime_factor=_floats([m.get("realtime_factor") for m in messages]),
            ring_fill=_floats([m.get("ring_fill") for m in messages]),
            messages_dropped=_floats([m.get("messages_dropped") for m in messages]),
            messages=list(messages),
        )


@dataclass
class ImageData(StreamData):
    """Scan lines: ``line``, ``frame``, ``generation`` per line and ``channels``, each
    lines × pixels in the channel's unit (``units``)."""

    line: np.ndarray = field(default_factory=lambda: np.empty(0))
    frame: np.ndarray = field(default_factory=lambda: np.empty(0))
    generation: np.ndarray = field(default_factory=lambda: np.empty(0))
    channels: dict[str, np.ndarray] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_messages(cls, messages: Sequence[dict[str, Any]]) -> "ImageData":
        names = sorted({k for m in messages for k in m.get("channels", {})})
        return cls(
            **cls._common("image", messages),
            line=np.array([m["line"] for m in messages], dtype=np.int64),
            frame=np.array([m["frame"] for m in messages], dtype=np.int64),
            generation=np.array([m["generation"] for m in messages], dtype=np.int64),
            channels={k: _rows([m["channels"].get(k) for m in messages]) for k in names},
            units=dict(messages[-1].get("units", {})) if messages else {},
        )

    def arrays(self) -> dict[str, np.ndarray]:
        out = super().arrays()
        out.update({f"channels/{k}": v for k, v in self.channels.items()})
        return out


FORCE_KEYS = (
    "max_force",
    "max_force_sigma",
    "contact_time_ratio",
    "contact_time_ratio_sigma",
    "youngs_modulus",
    "youngs_modulus_sigma",
)


@dataclass
class SweepResult:
    """A sweep's points as arrays (``Instrument.sweep``): ``value`` (the parameter's unit)
    and ``leg`` (``"up"``/``"down"``) per point, every demodulator's averaged ``x``, ``y``,
    ``r`` (m), ``phase`` (rad) and ``harmonic`` as points × 32 (NaN / −1 where it gave
    nothing), ``free_amplitude`` (m) per point of a tune, ``mean_deflection`` (m, from a
    demodulator at harmonic 0 if one runs), the force estimates per point (``max_force``
    (N), ``contact_time_ratio`` (1), ``youngs_modulus`` (Pa), each with its ``_sigma``, NaN
    where the point has none, ``force_error`` saying why) and ``final``, the sweep's final
    message (``outcome``, and ``tune`` or ``approach``)."""

    parameter: str
    value: np.ndarray
    leg: list[str]
    harmonic: np.ndarray
    x: np.ndarray
    y: np.ndarray
    r: np.ndarray
    phase: np.ndarray
    free_amplitude: np.ndarray
    mean_deflection: np.ndarray
    max_force: np.ndarray
    max_force_sigma: np.ndarray
    contact_time_ratio: np.ndarray
    contact_time_ratio_sigma: np.ndarray
    youngs_modulus: np.ndarray
    youngs_modulus_sigma: np.ndarray
    force_error: list[str | None]
    final: dict[str, Any]

    def __len__(self) -> int:
        return len(self.value)

    @classmethod
    def from_messages(cls, points: Sequence[dict[str, Any]], final: dict[str, Any]) -> "SweepResult":
        n = len(points)
        arrays = {k: np.full((n, DEMODULATORS), np.nan) for k in ("x", "y", "r", "phase")}
        harmonic = np.full((n, DEMODULATORS), -1, dtype=np.int64)
        force = {
            key: _floats([(m.get("force") or {}).get(key) for m in points])
            for key in FORCE_KEYS
        }
        for i, m in enumerate(points):
            for d in m["demods"]:
                j = d["index"]
                harmonic[i, j] = d["harmonic"]
                for k in arrays:
                    v = d[k]
                    arrays[k][i, j] = np.nan if v is None else v
        return cls(
            parameter=str(final.get("parameter", "")),
            value=_floats([m["value"] for m in points]),
            leg=[str(m["leg"]) for m in points],
            harmonic=harmonic,
            x=arrays["x"],
            y=arrays["y"],
            r=arrays["r"],
            phase=arrays["phase"],
            free_amplitude=_floats([m.get("free_amplitude") for m in points]),
            mean_deflection=_floats([m.get("mean_deflection") for m in points]),
            max_force=force["max_force"],
            max_force_sigma=force["max_force_sigma"],
            contact_time_ratio=force["contact_time_ratio"],
            contact_time_ratio_sigma=force["contact_time_ratio_sigma"],
            youngs_modulus=force["youngs_modulus"],
            youngs_modulus_sigma=force["youngs_modulus_sigma"],
            force_error=[(m.get("force") or {}).get("error") for m in points],
            final=dict(final),
        )

    @property
    def outcome(self) -> str:
        """``"done"``, ``"aborted"`` or ``"failed"`` (``final["reason"]`` says why)."""
        return str(self.final.get("outcome", ""))

    def column(self, harmonic: int) -> int:
        """The first demodulator measuring ``harmonic`` at the last point."""
        if len(self) == 0:
            raise ValueError("no points")
        hits = np.flatnonzero(self.harmonic[-1] == harmonic)
        if len(hits) == 0:
            raise ValueError(f"no demodulator measures harmonic {harmonic}")
        return int(hits[0])

    def r_of(self, harmonic: int) -> np.ndarray:
        """Amplitude (m) of ``harmonic`` at every point."""
        return self.r[:, self.column(harmonic)]

    def phase_of(self, harmonic: int) -> np.ndarray:
        """Phase (rad) of ``harmonic`` at every point."""
        return self.phase[:, self.column(harmonic)]


@dataclass
class BimodalData(StreamData):
    """The bimodal AM-FM estimate, one row per demodulator frame (docs/protocol.md,
    ``bimodal``): mode 1's amplitude (m) and phase lag (rad), mode 2's frequency shift
    (Hz), and the expressions' mean force (N), mean contact stiffness (N/m), indentation
    (m), reduced modulus and the sample's Young's modulus (Pa), the Hertz swing solved
    whole, with the published short-tap closed forms beside them; NaN where a frame gave no
    estimate, ``reason`` saying why."""

    amplitude1: np.ndarray = field(default_factory=lambda: np.empty(0))
    phase_lag1: np.ndarray = field(default_factory=lambda: np.empty(0))
    frequency_shift2: np.ndarray = field(default_factory=lambda: np.empty(0))
    mean_force: np.ndarray = field(default_factory=lambda: np.empty(0))
    mean_stiffness: np.ndarray = field(default_factory=lambda: np.empty(0))
    indentation: np.ndarray = field(default_factory=lambda: np.empty(0))
    reduced_modulus: np.ndarray = field(default_factory=lambda: np.empty(0))
    youngs_modulus: np.ndarray = field(default_factory=lambda: np.empty(0))
    #: d and E* by the published short-tap closed forms (m, Pa), beside the whole swing's.
    short_tap_indentation: np.ndarray = field(default_factory=lambda: np.empty(0))
    short_tap_modulus: np.ndarray = field(default_factory=lambda: np.empty(0))
    #: The sample from which mode 2's PLL update paired with the frame took effect (the
    #: newest the daemon saw at or before the frame), and how long before the frame (s);
    #: NaN where a frame gave no estimate.
    pll_sample: np.ndarray = field(default_factory=lambda: np.empty(0))
    pll_age: np.ndarray = field(default_factory=lambda: np.empty(0))
    #: The settings epoch each row's calibration is for.
    epoch: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    reason: list[str | None] = field(default_factory=list)

    @classmethod
    def from_messages(cls, messages: Sequence[dict[str, Any]]) -> "BimodalData":
        def col(k: str) -> np.ndarray:
            return _floats([m.get(k) for m in messages])

        return cls(
            **cls._common("bimodal", messages),
            amplitude1=col("amplitude1"),
            phase_lag1=col("phase_lag1"),
            frequency_shift2=col("frequency_shift2"),
            mean_force=col("mean_force"),
            mean_stiffness=col("mean_stiffness"),
            indentation=col("indentation"),
            reduced_modulus=col("reduced_modulus"),
            youngs_modulus=col("youngs_modulus"),
            short_tap_indentation=col("short_tap_indentation"),
            short_tap_modulus=col("short_tap_modulus"),
            pll_sample=col("pll_sample"),
            pll_age=col("pll_age"),
            epoch=np.array([m.get("epoch", 0) for m in messages], dtype=np.int64),
            reason=[m.get("reason") for m in messages],
        )


@dataclass
class PidsData(StreamData):
    """Every update of the PID units (docs/protocol.md, ``pids``), one row per update, in
    time order: ``unit`` (N of ``/pids/N``), ``sample`` (from which its output took
    effect), ``epoch``, ``measurement`` and ``error`` (the input's unit), ``output`` (the
    output's unit), ``limited``, ``locked`` (NaN for units that are no PLL, else 0 or 1),
    and ``dropped``, the updates the daemon's queue had no room for, per message. ``t``
    is per message (its newest update's); an update's own time is ``sample`` over the
    sample rate."""

    unit: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    sample: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    epoch: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    measurement: np.ndarray = field(default_factory=lambda: np.empty(0))
    error: np.ndarray = field(default_factory=lambda: np.empty(0))
    output: np.ndarray = field(default_factory=lambda: np.empty(0))
    limited: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))
    locked: np.ndarray = field(default_factory=lambda: np.empty(0))
    dropped: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=np.int64))

    @classmethod
    def from_messages(cls, messages: Sequence[dict[str, Any]]) -> "PidsData":
        def cat(k: str) -> list[Any]:
            return [v for m in messages for v in m.get(k, [])]

        return cls(
            **cls._common("pids", messages),
            unit=np.array(cat("unit"), dtype=np.int64),
            sample=np.array(cat("sample"), dtype=np.int64),
            epoch=np.array(cat("epoch"), dtype=np.int64),
            measurement=_floats(cat("measurement")),
            error=_floats(cat("error")),
            output=_floats(cat("output")),
            limited=np.array(cat("limited"), dtype=bool),
            locked=_floats([None if v is None else float(v) for v in cat("locked")]),
            dropped=np.array([m.get("dropped", 0) for m in messages], dtype=np.int64),
        )

    def of(self, unit: int) -> np.ndarray:
        """The rows of ``unit``'s updates (an index array)."""
        return np.flatnonzero(self.unit == unit)


_KINDS: dict[str, type[StreamData]] = {
    "demods": DemodData,
    "spectrum": SpectrumData,
    "scope": ScopeData,
    "force": ForceData,
    "status": StatusData,
    "image": ImageData,
    "sweep": StreamData,
    "bimodal": BimodalData,
    "pids": PidsData,
}

#: The streams the daemon offers.
STREAMS = tuple(_KINDS)


def from_messages(stream: str, messages: Sequence[dict[str, Any]]) -> StreamData:
    """The arrays of ``messages`` of ``stream`` (a row per message)."""
    try:
        kind = _KINDS[stream]
    except KeyError:
        raise ValueError(f"unknown stream {stream!r}; streams: {', '.join(STREAMS)}") from None
    return kind.from_messages(messages)
