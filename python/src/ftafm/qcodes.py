"""The QCoDeS driver (``pip install ftafm[qcodes]``).

>>> from ftafm.qcodes import FTAFM
>>> afm = FTAFM("afm", "ws://127.0.0.1:8700/ws")          # doctest: +SKIP
>>> afm.surface.distance(15e-9)                            # doctest: +SKIP
>>> afm.demods[16].harmonic()                              # doctest: +SKIP
>>> afm.drive2.enable(True)            # bimodal AFM: the second excitation  # doctest: +SKIP
>>> afm.demods[3].oscillator("drive2") # its harmonics of /drive2/frequency  # doctest: +SKIP
>>> afm.demods[16].sample()            # x, y, r, phase of one frame   # doctest: +SKIP
>>> afm.snapshot(update=True)          # every parameter, one request  # doctest: +SKIP

The daemon's node tree as QCoDeS modules: a group of nodes (``/sample``, ``/drive``, ...)
is an :class:`InstrumentModule` (``afm.sample.youngs_modulus``), numbered ones
(``/demods/N``, ``/inclusions/N``) are :class:`InstrumentChannel` s in a
:class:`ChannelList` (``afm.demods[3].harmonic``). Each parameter has a label a person
reads ("Sample Young's modulus", "H17 amplitude"), the node's unit and description, and a
validator stating the range as the daemon enforces it, open or closed ends included
(``0 < value ≤ 1e13 Pa``), read from ``list`` at the moment of the set (ranges may depend
on other nodes); a text node with a fixed set of values (``afm.demods[3].oscillator``:
``"drive"`` or ``"drive2"``) has an :class:`~qcodes.validators.Enum` of them. What only
the daemon checks (relations between nodes: ``/drive2/frequency`` below the Nyquist
frequency while ``/drive2/enable``) raises :class:`ftafm.InstrumentError` naming the node.
Read-only nodes are get-only.

The second excitation of bimodal AFM is ``afm.drive2`` (``enable``, ``frequency`` in Hz,
``free_amplitude`` in m). A demodulator reads the harmonics of the oscillator its
``oscillator`` parameter names; the labels of one on ``"drive2"`` say so ("H1 of drive2
amplitude").

Measured parameters: per demodulator ``x``, ``y``, ``r`` (m), ``phase`` (rad) and ``t``
(s) of its newest output, and ``sample``, all four from one frame (a
:class:`MultiParameter`); ``afm.force.max_force`` (N), ``contact_time_ratio`` (1),
``youngs_modulus`` (Pa), ``pulse_phase`` (rad) of the next FT-AFM force estimate
(``/inversion/enable``), all four from one estimate; per PID unit (``afm.pids[0]``,
:class:`PidChannel`) beside its nodes, its latest update from ``status``:
``measurement``, ``error``, ``value`` (the output's value), ``limited``, ``updates``,
and a PLL's ``locked`` and ``frequency_shift``.

A PID unit's gains from a target bandwidth, the daemon's PID advisor (``pid_advise``) on a
PLL or an amplitude loop, as LabOne's PID Advisor gives them:

>>> afm.pids[0].output("drive_frequency"); afm.pids[0].input("phase")  # a PLL  # doctest: +SKIP
>>> advice = afm.pids[0].advise(bandwidth=500.0, kind="pi")   # sets nothing  # doctest: +SKIP
>>> advice.p, advice.i, advice.phase_margin, advice.settling_time       # doctest: +SKIP
>>> afm.pids[0].advise(bandwidth=500.0, apply=True)  # p, i, d, d_bandwidth set  # doctest: +SKIP

``snapshot(update=True)`` reads every node and every demodulator in one request (a
``get`` of many paths), and the force in one more when the inversion runs, instead of a
request per parameter (the daemon allows 200 a second). The names of earlier versions
(``afm.surface_distance``, ``afm.demods_16_harmonic``, ``afm.demod16_r``,
``afm.force_max_force``) still reach the same parameters.
"""

from __future__ import annotations

import math
from typing import Any

from qcodes import validators as vals
from qcodes.instrument import (
    ChannelList,
    Instrument,
    InstrumentBase,
    InstrumentChannel,
    InstrumentModule,
)
from qcodes.parameters import MultiParameter, Parameter

from .aio import Node
from .client import Instrument as Client
from .data import DEMODULATORS
from .errors import InstrumentError
from .pids import AdviceKind, PidAdvice, PidStatus

#: Labels of node names where the name alone does not read well.
_WORDS = {
    "youngs_modulus": "Young's modulus",
    "poisson": "Poisson's ratio",
    "f1": "resonance frequency f1",
    "k": "spring constant k",
    "q": "quality factors Q",
    "hamaker": "Hamaker constant",
    "adc_bits": "ADC bits",
    "adc_range": "ADC range",
    "timeconstant": "time constant",
    "follow_f1": "follows f1",
    "anti_alias": "anti-alias filter",
    "harmonic_a": "harmonic A",
    "harmonic_b": "harmonic B",
    "x": "x position",
    "y": "y position",
}

#: Group titles, for labels ("Sample Young's modulus", "Demodulator 3 harmonic").
_GROUPS = {
    "dsp": "DSP",
    "drive2": "Second drive",
    "synth": "Synthesiser",
    "demods": "Demodulator",
    "inclusions": "Inclusion",
    "pids": "PID",
}

#: The force estimate's parameters: unit, label.
_FORCE = {
    "max_force": ("N", "Peak tap force"),
    "contact_time_ratio": ("", "Contact time ratio"),
    "youngs_modulus": ("Pa", "Sample Young's modulus (FT-AFM estimate)"),
    "pulse_phase": ("rad", "Drive phase of the force peak"),
}

#: A demodulator's measured parts: unit, label after "H<k> ".
_DEMOD_PARTS = {
    "x": ("m", "in-phase x"),
    "y": ("m", "quadrature y"),
    "r": ("m", "amplitude"),
    "phase": ("rad", "phase"),
    "t": ("s", "time of the newest sample"),
}


#: A PID unit's latest update, read from ``status``: parameter → (field of
#: :class:`ftafm.pids.PidUpdate`, unit (``None``: the input's, m or rad; ``"output"``: the
#: output's, m or Hz), label).
_PID_PARTS: dict[str, tuple[str, str | None, str]] = {
    "measurement": ("measurement", None, "measurement"),
    "error": ("error", None, "error (set-point − measurement)"),
    "value": ("output", "output", "output value"),
    "limited": ("limited", "", "held by a limit"),
    "updates": ("updates", "", "updates"),
    "update_epoch": ("epoch", "", "settings epoch of the latest update"),
    "update_sample": ("sample", "", "sample the latest output took effect from"),
}


#: A PID unit's PLL readings, read from ``status`` (fields of
#: :class:`ftafm.pids.PidStatus`, ``None`` for a unit that is no PLL, or not on either
#: excitation's frequency): parameter → (unit, label).
_PID_PLL: dict[str, tuple[str, str]] = {
    "locked": ("", "PLL locked"),
    "frequency_shift": (
        "Hz", "frequency shift Δf (output − /drive/frequency, or /drive2/frequency)"
    ),
}


#: Longest wait (s) of a snapshot for a force estimate: a running estimator sends one with
#: each demodulator frame (1 kHz), so only one still being built takes longer.
FORCE_SNAPSHOT_WAIT = 1.0


def parameter_name(path: str) -> str:
    """The flat name earlier versions gave the node at ``path``: ``/a/b_c/3`` → ``a_b_c_3``
    (still accepted as an attribute of :class:`FTAFM`)."""
    return path.strip("/").replace("/", "_")


def label(path: str) -> str:
    """A label a person reads for the node at ``path``: ``/sample/youngs_modulus`` →
    ``Sample Young's modulus``, ``/demods/3/harmonic`` → ``Demodulator 3 harmonic``."""
    parts = path.strip("/").split("/")
    group = _GROUPS.get(parts[0], parts[0].capitalize())
    if len(parts) == 3 and parts[1].isdigit():
        group = f"{group} {parts[1]}"
    leaf = parts[-1]
    return f"{group} {_WORDS.get(leaf, leaf.replace('_', ' '))}"


def _number(x: float) -> str:
    """``1e13``, ``0.5``, ``-1``: as the daemon writes numbers in its messages."""
    text = f"{x:g}"
    if "e" in text:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}e{int(exponent)}"
    return text


def bounds_text(node: Node) -> str | None:
    """The node's range as the daemon states it (``0 < value ≤ 1e13 Pa``), open or closed
    ends as ``list`` reports them; ``None`` for a node without one."""
    if not isinstance(node.min, (int, float)) or not isinstance(node.max, (int, float)):
        return None
    low = "≤" if node.min_inclusive is not False else "<"
    high = "≤" if node.max_inclusive is not False else "<"
    unit = "" if node.unit in ("", "1") else f" {node.unit}"
    each = "each entry " if node.type == "float_list" else ""
    return f"{each}{_number(node.min)} {low} value {high} {_number(node.max)}{unit}"


def _inside(node: Node, v: float) -> bool:
    low_ok = v >= node.min if node.min_inclusive is not False else v > node.min
    high_ok = v <= node.max if node.max_inclusive is not False else v < node.max
    return bool(low_ok and high_ok)


class LiveRange(vals.Validator[Any]):
    """A node's type, and its range as ``list`` reports it at the moment of the check,
    open or closed ends included (a range may depend on other nodes: the harmonics a
    demodulator may take follow the drive frequency)."""

    def __init__(self, client: Client, node: Node, inner: vals.Validator[Any]):
        self._client = client
        self._node = node
        self._inner = inner
        self._valid_values = inner.valid_values
        self.is_numeric = inner.is_numeric

    def validate(self, value: Any, context: str = "") -> None:
        self._inner.validate(value, context)
        path = self._node.path
        [node] = [n for n in self._client.nodes(path) if n.path == path]
        self._node = node
        entries = value if isinstance(value, (list, tuple)) else [value]
        for v in entries:
            if bounds_text(node) is not None and not _inside(node, v):
                raise ValueError(
                    f"{v!r} is out of range for {path}: allowed {bounds_text(node)}; "
                    f"{context}"
                )

    def __repr__(self) -> str:
        return f"<{bounds_text(self._node) or self._node.type}>"


def _validator(client: Client, node: Node) -> vals.Validator[Any]:
    """The node's type as a validator; numbers also checked against the live range."""
    if node.type == "float":
        return LiveRange(client, node, vals.Numbers())
    if node.type == "integer":
        return LiveRange(client, node, vals.Ints())
    if node.type == "bool":
        return vals.Bool()
    if node.type == "text" and node.allowed:
        return vals.Enum(*node.allowed)
    if node.type == "float_list":
        return LiveRange(client, node, vals.Lists(vals.Numbers()))
    if node.type == "text_list":
        return vals.Lists(vals.Strings())
    return vals.Anything()


class DemodSample(MultiParameter):
    """``x``, ``y``, ``r`` (m) and ``phase`` (rad) of one output frame of a demodulator."""

    def __init__(self, name: str, instrument: "DemodChannel", **kwargs: Any):
        super().__init__(
            name,
            names=("x", "y", "r", "phase"),
            shapes=((), (), (), ()),
            units=("m", "m", "m", "rad"),
            labels=tuple(instrument.part_label(p) for p in ("x", "y", "r", "phase")),
            instrument=instrument,
            docstring=f"x, y, r, phase of one output frame of demodulator "
            f"{instrument.index} (/demods/{instrument.index}/sample).",
            **kwargs,
        )

    def get_raw(self) -> tuple[float, float, float, float]:
        channel: DemodChannel = self.instrument  # type: ignore[assignment]
        value = channel.driver.client.get(f"/demods/{channel.index}/sample")
        channel.took(value)
        return (value["x"], value["y"], value["r"], value["phase"])


class DemodChannel(InstrumentChannel):
    """Demodulator N: its nodes (``harmonic``, ``oscillator``, ``enable``, ...) and its
    newest output (``x``, ``y``, ``r``, ``phase``, ``t``, and ``sample``, the four from one
    frame), labelled with its harmonic and, when not the drive, its oscillator."""

    def __init__(self, driver: "FTAFM", index: int):
        super().__init__(driver, f"demod{index}")
        self.driver = driver
        self.index = index
        for part, (unit, _) in _DEMOD_PARTS.items():
            self.add_parameter(
                part,
                parameter_class=Parameter,
                label=self.part_label(part),
                unit=unit,
                docstring=f"Newest output {part} of demodulator {index} "
                f"(/demods/{index}/sample).",
                get_cmd=lambda part=part: self._read(part),
                set_cmd=False,
            )
        self.add_parameter("sample", parameter_class=DemodSample)

    def harmonic_now(self) -> int | None:
        """The harmonic the driver last saw this demodulator measure."""
        h = self.parameters["harmonic"].cache.get(get_if_invalid=False) \
            if "harmonic" in self.parameters else None
        return int(h) if isinstance(h, (int, float)) else None

    def oscillator_now(self) -> str:
        """The oscillator (``"drive"`` or ``"drive2"``) the driver last saw this demodulator
        read its harmonic of."""
        param = self.parameters.get("oscillator")
        osc = param.cache.get(get_if_invalid=False) if param is not None else None
        return osc if isinstance(osc, str) else "drive"

    def harmonic_name(self) -> str | None:
        """``"H17"`` for a harmonic of the drive, ``"H1 of drive2"`` for one of the second
        excitation; ``None`` before the harmonic is known."""
        k = self.harmonic_now()
        if k is None:
            return None
        osc = self.oscillator_now()
        return f"H{k}" if osc == "drive" else f"H{k} of {osc}"

    def part_label(self, part: str) -> str:
        who = self.harmonic_name() or f"Demodulator {self.index}"
        return f"{who} {_DEMOD_PARTS[part][1]}"

    def relabel(self) -> None:
        """Labels follow the harmonic and its oscillator: "H17 amplitude", "H1 of drive2
        amplitude"."""
        for part in _DEMOD_PARTS:
            param = self.parameters[part]
            assert isinstance(param, Parameter)
            param.label = self.part_label(part)
        sample = self.parameters["sample"]
        assert isinstance(sample, MultiParameter)
        sample.labels = tuple(self.part_label(p) for p in ("x", "y", "r", "phase"))

    def took(self, value: dict[str, Any] | None) -> None:
        """Fills the measured parameters' caches from one frame (``None``: no output, NaN)."""
        frame = value or {}
        for part in _DEMOD_PARTS:
            v = frame.get(part)
            self.parameters[part].cache._set_from_raw_value(math.nan if v is None else v)
        if value is not None:
            sample = self.parameters["sample"]
            sample.cache._set_from_raw_value(
                tuple(value[p] for p in ("x", "y", "r", "phase"))
            )

    def _read(self, part: str) -> float:
        value = self.driver.client.get(f"/demods/{self.index}/sample")
        self.took(value)
        return float(value[part])


class PidChannel(InstrumentChannel):
    """PID unit N (``/pids/N``): its nodes (``setpoint``, ``p``, ``enable``, ``output``,
    ``oscillator``, ``input_bandwidth``, ...) and its latest update from the ``status``
    stream, read-only: ``measurement`` and ``error`` (the input's unit: m, or rad for the
    phase), ``value`` (the output's value, m for the surface distance and either drive
    amplitude, Hz for either drive frequency; LabOne's ``pids/N/value``: ``output`` is the
    node naming what it drives), ``limited``, ``updates``, ``update_epoch`` and
    ``update_sample``; and for a unit on either excitation's frequency ``frequency_shift``
    (Hz, the output less ``/drive/frequency`` or ``/drive2/frequency``) and, for a PLL (a
    unit on the phase), ``locked``. Every get of one reads one status message
    (within 0.5 s) and fills the others' caches from it (:meth:`read_status`); NaN
    (``None`` for ``limited``) before the unit's first update; ``locked`` and
    ``frequency_shift`` are ``None`` for a unit they do not apply to.

    :meth:`advise` gives the unit's gains from a target closed-loop bandwidth (the daemon's
    PID advisor) and, with ``apply=True``, sets them through the unit's ``p``, ``i``,
    ``d`` and ``d_bandwidth`` parameters (:meth:`apply_advice`)."""

    #: The gain parameters :meth:`apply_advice` sets (fields of :class:`PidAdvice`).
    GAINS = ("p", "i", "d", "d_bandwidth")

    def __init__(self, driver: "FTAFM", index: int):
        super().__init__(driver, f"pid{index}")
        self.driver = driver
        self.index = index
        for name, (key, unit, text) in _PID_PARTS.items():
            self.add_parameter(
                name,
                parameter_class=Parameter,
                label=f"PID {index} {text}",
                unit=unit or "",
                docstring=f"{text.capitalize()} of the latest update of PID {index} (the "
                "status stream's pids).",
                get_cmd=lambda key=key: getattr(self._latest(), key),
                set_cmd=False,
            )
            self.parameters[name].cache._set_from_raw_value(
                None if key == "limited" else math.nan
            )
        for name, (unit, text) in _PID_PLL.items():
            self.add_parameter(
                name,
                parameter_class=Parameter,
                label=f"PID {index} {text}",
                unit=unit,
                docstring=f"{text[0].upper()}{text[1:]} of PID {index} (the status stream's "
                "pids; None for a unit it does not apply to).",
                get_cmd=lambda name=name: getattr(self.read_status(), name),
                set_cmd=False,
            )
            self.parameters[name].cache._set_from_raw_value(None)

    def read_status(self, timeout: float | None = None) -> PidStatus:
        """The unit in the next ``status`` message; the update's parameters' caches filled
        from it (their units follow the input: rad for the phase, else m)."""
        status = self.driver.client.pid_status(timeout=timeout)[self.index]
        units = {None: "rad" if status.input == "phase" else "m", "output": status.output_unit}
        for name, (key, fixed, _) in _PID_PARTS.items():
            param = self.parameters[name]
            assert isinstance(param, Parameter)
            if fixed in units:
                param.unit = units[fixed]
            latest = status.latest
            if latest is None:
                param.cache._set_from_raw_value(None if key == "limited" else math.nan)
            else:
                param.cache._set_from_raw_value(getattr(latest, key))
        for name in _PID_PLL:
            self.parameters[name].cache._set_from_raw_value(getattr(status, name))
        return status

    def advise(
        self, bandwidth: float, *, kind: AdviceKind = "pi", apply: bool = False
    ) -> PidAdvice:
        """The daemon's PID advisor (``pid_advise``) for this unit: gains for a closed-loop
        −3 dB ``bandwidth`` (Hz), a PI (``kind="pi"``, D = 0) or a PID (``"pid"``), on the
        model of the loop the unit is set up as at the settings in force (a PLL or an
        amplitude loop, on either excitation; the unit need not be enabled). Returns the
        :class:`ftafm.PidAdvice`: ``p``, ``i``, ``d``, ``d_bandwidth`` and the loop they
        predict (``bandwidth``, ``crossover``, ``phase_margin``, ``overshoot``,
        ``settling_time``). With ``apply=False`` (the default) nothing is set; with
        ``apply=True`` the gains are set as :meth:`apply_advice` does.

        A refusal raises :class:`ftafm.InstrumentError` with the daemon's message naming
        the field (``bandwidth`` not > 0 or beyond the loop's reach, a bad ``kind``, a unit
        the advisor does not model); a NaN or infinite ``bandwidth`` raises
        :class:`ValueError` before anything is sent. Nothing is set when it raises."""
        advice = self.driver.client.pid_advise(self.index, bandwidth, kind=kind)
        if apply:
            self.apply_advice(advice)
        return advice

    def apply_advice(self, advice: PidAdvice) -> float | None:
        """Sets the unit's ``p``, ``i``, ``d`` and ``d_bandwidth`` to ``advice``'s: each
        value checked by its parameter's validator, then all four in one change (one
        ``set_many``: the loop never runs on a mix of old and new gains, which the daemon
        would refuse while the unit runs if their signs differ), and the parameters'
        caches set to them, so that a snapshot shows them. Returns the simulated time (s)
        the change took effect. Raises :class:`ValueError` for another unit's advice or a
        value outside a parameter's range, :class:`ftafm.InstrumentError` if the daemon
        refuses the change; nothing is set then."""
        if advice.unit != self.index:
            raise ValueError(
                f"advice for /pids/{advice.unit} cannot be applied to /pids/{self.index}"
            )
        gains = {name: getattr(advice, name) for name in self.GAINS if name in self.parameters}
        params: dict[str, Parameter] = {}
        for name, value in gains.items():
            param = self.parameters[name]
            assert isinstance(param, Parameter)
            param.validate(value)
            params[name] = param
        t = self.driver.client.set_many(
            {f"/pids/{self.index}/{name}": value for name, value in gains.items()}
        )
        for name, value in gains.items():
            params[name].cache.set(value)
        return t

    def _latest(self) -> Any:
        latest = self.read_status().latest
        if latest is None:
            raise InstrumentError(
                "no_data", f"/pids/{self.index} has made no update yet (enable it first)"
            )
        return latest


class ForceModule(InstrumentModule):
    """The next FT-AFM force estimate (``/inversion/enable``): every parameter's get reads
    one estimate and fills the others' caches from it."""

    def __init__(self, driver: "FTAFM"):
        super().__init__(driver, "force")
        self.driver = driver
        for key, (unit, text) in _FORCE.items():
            self.add_parameter(
                key,
                label=text,
                unit=unit,
                docstring=f"{text} of the newest FT-AFM estimate (the force stream; needs "
                "/inversion/enable).",
                get_cmd=lambda key=key: self.read()[key],
                set_cmd=False,
            )
            self.parameters[key].cache._set_from_raw_value(math.nan)

    def read(self, timeout: float | None = None) -> dict[str, Any]:
        """The next estimate, every parameter's cache filled from it; ``timeout`` (s,
        default: the client's) bounds the wait."""
        estimate = self.driver.client.next("force", timeout=timeout)
        for key in _FORCE:
            v = estimate.get(key)
            self.parameters[key].cache._set_from_raw_value(math.nan if v is None else v)
        return estimate


class FTAFM(Instrument):
    """An ftafm daemon as a QCoDeS instrument: ``name`` for QCoDeS, ``url`` its WebSocket
    endpoint (``ftafm.NoDaemon`` if none answers there)."""

    def __init__(self, name: str, url: str | None = None, *, timeout: float = 10.0,
                 **kwargs: Any):
        super().__init__(name, **kwargs)
        self.client = Client(url, timeout=timeout)
        try:
            self._build()
        except BaseException:
            self.client.close()
            raise

    def _build(self) -> None:
        self.nodes: dict[str, Node] = {}
        #: Node path → its parameter (what a bulk read fills).
        self.by_path: dict[str, Parameter] = {}
        self._old_names: dict[str, Any] = {}
        lists: dict[str, list[InstrumentChannel]] = {}
        modules: dict[str, InstrumentModule] = {}
        for node in self.client.nodes():
            self.nodes[node.path] = node
            parts = node.path.strip("/").split("/")
            owner: InstrumentBase
            if len(parts) == 3 and parts[1].isdigit():
                channels = lists.setdefault(parts[0], [])
                index = int(parts[1])
                while len(channels) <= index:
                    channels.append(self._channel(parts[0], len(channels)))
                owner = channels[index]
            elif len(parts) == 2:
                if parts[0] not in modules:
                    modules[parts[0]] = InstrumentModule(self, parts[0])
                owner = modules[parts[0]]
            else:
                owner = self
            param = owner.add_parameter(
                parts[-1] if owner is not self else parameter_name(node.path),
                label=label(node.path),
                unit="" if node.unit == "1" else node.unit,
                docstring=" ".join(
                    x for x in (node.description, bounds_text(node) and
                                f"Allowed: {bounds_text(node)}.") if x
                ),
                get_cmd=lambda p=node.path: self._get(p),
                set_cmd=(lambda v, p=node.path: self._set(p, v)) if node.writable
                else False,
                vals=_validator(self.client, node),
            )
            assert isinstance(param, Parameter)
            param.cache._set_from_raw_value(node.value)
            self.by_path[node.path] = param
            self._old_names[parameter_name(node.path)] = param
        for group, module in modules.items():
            self.add_submodule(group, module)
        for group, channels in lists.items():
            kind = {"demods": DemodChannel, "pids": PidChannel}.get(group, InstrumentChannel)
            channel_list = ChannelList(self, group, kind, channels)
            self.add_submodule(group, channel_list)
        for channel in lists.get("demods", []):
            assert isinstance(channel, DemodChannel)
            channel.relabel()
            for part in _DEMOD_PARTS:
                self._old_names[f"demod{channel.index}_{part}"] = channel.parameters[part]
        self.force = ForceModule(self)
        self.add_submodule("force", self.force)
        for key in _FORCE:
            self._old_names[f"force_{key}"] = self.force.parameters[key]

    def _channel(self, group: str, index: int) -> InstrumentChannel:
        if group == "demods":
            return DemodChannel(self, index)
        if group == "pids":
            return PidChannel(self, index)
        return InstrumentChannel(self, f"{group.rstrip('s')}{index}")

    def _get(self, path: str) -> Any:
        value = self.client.get(path)
        self._follow(path, value)
        return value

    def _set(self, path: str, value: Any) -> None:
        self.client.set(path, value)
        self._follow(path, value)

    def _follow(self, path: str, value: Any) -> None:
        """A demodulator's labels follow its harmonic and oscillator, read or set."""
        parts = path.split("/")
        if len(parts) == 4 and parts[1] == "demods" and parts[3] in ("harmonic", "oscillator"):
            channel = self.demod_channel(int(parts[2]))
            channel.parameters[parts[3]].cache._set_from_raw_value(value)
            channel.relabel()

    def demod_channel(self, index: int) -> DemodChannel:
        """Demodulator ``index``'s channel (``afm.demods[index]``)."""
        demods = self.submodules["demods"]
        assert isinstance(demods, ChannelList)
        channel = demods[index]
        assert isinstance(channel, DemodChannel)
        return channel

    def __getattr__(self, name: str) -> Any:
        try:
            return super().__getattr__(name)
        except AttributeError:
            old = self.__dict__.get("_old_names", {})
            if name in old:
                return old[name]
            raise

    def refresh(self) -> None:
        """Reads every node and every demodulator's newest output in one request, and the
        next force estimate when the inversion runs, into the parameters' caches."""
        paths = list(self.by_path) + [f"/demods/{n}/sample" for n in range(DEMODULATORS)]
        values = self.client.get_many(paths)
        for path, param in self.by_path.items():
            param.cache._set_from_raw_value(values[path])
        demods = self.submodules.get("demods")
        if isinstance(demods, ChannelList):
            for channel in demods:
                assert isinstance(channel, DemodChannel)
                channel.took(values.get(f"/demods/{channel.index}/sample"))
                channel.relabel()
        if values.get("/inversion/enable"):
            try:
                self.force.read(timeout=FORCE_SNAPSHOT_WAIT)
            except InstrumentError:
                # No estimate yet (the estimator is built after a start or a change, longer
                # on a busy machine): the force keeps its last values, NaN before the first.
                pass

    def snapshot_base(
        self,
        update: bool | None = False,
        params_to_skip_update: Any = None,
    ) -> dict[Any, Any]:
        """The QCoDeS snapshot; with ``update`` (``True`` or ``None``) every value is read
        first by :meth:`refresh` (one or two requests), not one request per parameter."""
        if update is not False:
            self.refresh()
        return super().snapshot_base(update=False, params_to_skip_update=params_to_skip_update)

    def get_idn(self) -> dict[str, str | None]:
        hello = self.client.hello
        return {
            "vendor": "ftafm",
            "model": "virtual FT-AFM",
            "serial": self.client.url,
            "firmware": f"{hello.get('version')} (protocol {hello.get('protocol')})",
        }

    def close(self) -> None:
        self.client.close()
        super().close()
