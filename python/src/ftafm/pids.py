"""The live PID units ``/pids/0`` … ``/pids/3`` (docs/loops.md, "Live PID units").

>>> unit = afm.pids[0]                                                  # doctest: +SKIP
>>> unit.configure(input="r", harmonic=1, setpoint=16.7e-9, p=0.0, i=1200.0,
...                output_min=0.0, output_max=100e-9, enable=True)      # doctest: +SKIP
>>> unit.wait(lambda s: abs(s.latest.error) < 1e-11)                    # doctest: +SKIP
>>> unit.disable()                                                      # doctest: +SKIP

Each unit reads its own demodulator once per drive period and drives one output
(``/pids/N/output``, :data:`OUTPUTS`): the surface distance (the z piezo, on the coupled
engine), the drive frequency (a unit on the phase of harmonic 1 with this output is a
PLL: the drive and the lock-in's reference follow it; :attr:`PidStatus.locked`,
:attr:`PidStatus.frequency_shift`) or the drive amplitude (as the free amplitude it gives
at ``/drive/frequency``), or the same two of the second excitation (``drive2_frequency``,
``drive2_amplitude``; ``/drive2/enable``). Its demodulator reads harmonic ``harmonic`` of
``/pids/N/oscillator`` (:data:`OSCILLATORS`): the drive, or the second excitation through
a low-pass of ``/pids/N/input_bandwidth`` (Hz). A unit on the phase of harmonic 1 of
``drive2`` driving ``drive2_frequency`` is mode 2's PLL (bimodal AM-FM, docs/loops.md
"Mode 2's loops"). Its settings are nodes (``configure`` sets any of
them in one ``set_many``, all or nothing); its updates reach a client through the
``status`` stream (every 0.5 s of wall time), each stamped with the settings epoch it ran
under and a running count, so a caller waits on those, not on the clock
(:meth:`PidUnit.wait`). The daemon refuses bad settings (a gain of the wrong sign, a
derivative bandwidth above the PID's Nyquist frequency, limits outside the output's
range, a drive output during a scan, a unit on ``drive2`` while ``/drive2/enable`` is
false) with :class:`ftafm.InstrumentError`, whose message names the node and the range.

:meth:`PidUnit.advise` asks the daemon's PID advisor (``pid_advise``) for a unit's gains
from a target bandwidth, for a PLL or an amplitude loop on either excitation
(:class:`PidAdvice`); it sets nothing, ``unit.configure(**advice.gains)`` does.

>>> advice = afm.pids[0].advise(500.0)                                  # doctest: +SKIP
>>> afm.pids[0].configure(**advice.gains)                               # doctest: +SKIP
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterator, Literal, Mapping, Sequence, TypeVar

from .errors import InstrumentError
from .tree import NodeBranch, NodeLeaf

if TYPE_CHECKING:
    from . import aio
    from .client import Instrument

#: PID units of the daemon: ``/pids/0`` … ``/pids/3``.
PID_COUNT = 4

#: The settings of one unit (node names under ``/pids/N``).
SETTINGS = (
    "enable",
    "input",
    "harmonic",
    "setpoint",
    "p",
    "i",
    "d",
    "d_bandwidth",
    "output_min",
    "output_max",
    "rate",
    "output",
    "oscillator",
    "input_bandwidth",
)

#: What a unit can drive (``/pids/N/output``).
PidOutput = Literal[
    "surface_distance", "drive_frequency", "drive_amplitude", "drive2_frequency", "drive2_amplitude"
]

#: The outputs, and the unit each one's value is in (``output``, ``output_min``,
#: ``output_max``; ``rate`` is in this unit per second).
OUTPUT_UNITS: dict[str, str] = {
    "surface_distance": "m",
    "drive_frequency": "Hz",
    "drive_amplitude": "m",
    "drive2_frequency": "Hz",
    "drive2_amplitude": "m",
}
OUTPUTS: tuple[str, ...] = tuple(OUTPUT_UNITS)

#: The oscillator whose harmonic a unit's demodulator reads (``/pids/N/oscillator``).
PidOscillator = Literal["drive", "drive2"]
OSCILLATORS: tuple[str, ...] = ("drive", "drive2")


def output_unit(output: str) -> str:
    """The unit of ``output``'s values (``"m"`` or ``"Hz"``); raises :class:`ValueError`
    naming the outputs for a name that is none of them."""
    try:
        return OUTPUT_UNITS[output]
    except KeyError:
        raise ValueError(
            f"/pids/N/output = {output!r} is no output: it is one of {', '.join(OUTPUTS)}"
        ) from None


#: The controller ``pid_advise`` designs: a PI (D = 0) or a PID.
AdviceKind = Literal["pi", "pid"]


@dataclass(frozen=True)
class PidAdvice:
    """Gains for a PID unit from a target bandwidth: the daemon's ``pid_advise`` reply
    (docs/protocol.md), its PID advisor on the loop's model at the settings in force, as
    LabOne's PID Advisor gives them. Nothing is set: ``unit.configure(**advice.gains)``
    sets them.

    ``unit``: N of ``/pids/N``; ``kind``: ``"pi"`` (D = 0) or ``"pid"``; ``epoch``: the
    settings epoch the advice modelled; ``plant``: the model, in words.

    The gains, in the unit's own units and signed for its actuator (a PLL's are negative:
    the lever's phase falls as the frequency rises), input unit rad for the phase, m for
    the amplitude, output unit Hz for either drive frequency, m for either drive amplitude
    (:data:`OUTPUT_UNITS`): ``p``, output unit per input unit (Hz/rad for a PLL); ``i``,
    the same per second (Hz/(rad·s)); ``d``, the same times seconds (Hz·s/rad);
    ``d_bandwidth``, the derivative's low-pass, Hz.

    The model's prediction of the loop with them: ``bandwidth``, the closed loop's −3 dB
    bandwidth, Hz; ``crossover``, the open loop's unity-gain frequency, Hz;
    ``phase_margin``, degrees (at least 45); ``overshoot``, of a step of the resonance (a
    PLL) or of the set-point (an amplitude loop), a fraction of the step (0.1 is 10 %);
    ``settling_time``, to within 2 % of that step, s.
    """

    unit: int
    kind: str
    epoch: int
    plant: str
    p: float
    i: float
    d: float
    d_bandwidth: float
    bandwidth: float
    crossover: float
    phase_margin: float
    overshoot: float
    settling_time: float

    @property
    def gains(self) -> dict[str, float]:
        """The unit's gain nodes as advised, ``{"p": …, "i": …, "d": …, "d_bandwidth":
        …}`` (units above): ``unit.configure(**advice.gains)`` sets them in one change."""
        return {"p": self.p, "i": self.i, "d": self.d, "d_bandwidth": self.d_bandwidth}

    @classmethod
    def from_json(cls, m: Mapping[str, Any]) -> "PidAdvice":
        return cls(
            unit=int(m["unit"]),
            kind=str(m["kind"]),
            epoch=int(m["epoch"]),
            plant=str(m["plant"]),
            p=float(m["p"]),
            i=float(m["i"]),
            d=float(m["d"]),
            d_bandwidth=float(m["d_bandwidth"]),
            bandwidth=float(m["bandwidth"]),
            crossover=float(m["crossover"]),
            phase_margin=float(m["phase_margin"]),
            overshoot=float(m["overshoot"]),
            settling_time=float(m["settling_time"]),
        )


#: Longest wait (s) of :meth:`PidUnit.wait` unless told: the status stream comes every
#: 0.5 s of wall time, so this is many messages, for a daemon slower than real time.
WAIT_TIMEOUT = 60.0


@dataclass(frozen=True)
class PidUpdate:
    """One update of a unit, as the synthesiser made it (the ``latest`` of ``status``).

    ``sample``: index of the sample from which the output took effect (its simulated time
    is ``sample / sample_rate`` s); ``epoch``: the settings epoch the synthesiser ran
    under; ``measurement`` and ``error`` (set-point minus measurement): the input's unit,
    m for ``r``, ``x``, ``y``, rad for ``phase`` and Hz for ``frequency_shift`` (a PLL's
    Δf); ``output``: the output's value, m for
    the surface distance and either drive amplitude, Hz for either drive frequency
    (:data:`OUTPUT_UNITS`); ``limited``: whether ``output_min``, ``output_max`` or ``rate`` held the
    output; ``updates``: the unit's updates since the daemon started.
    """

    sample: int
    epoch: int
    measurement: float
    error: float
    output: float
    limited: bool
    updates: int

    @classmethod
    def from_json(cls, m: Mapping[str, Any]) -> "PidUpdate":
        nan = float("nan")
        return cls(
            sample=int(m["sample"]),
            epoch=int(m["epoch"]),
            # JSON null: a NaN on the daemon's side.
            measurement=nan if m["measurement"] is None else float(m["measurement"]),
            error=nan if m["error"] is None else float(m["error"]),
            output=nan if m["output"] is None else float(m["output"]),
            limited=bool(m["limited"]),
            updates=int(m["updates"]),
        )


@dataclass(frozen=True)
class PidStatus:
    """One unit in one ``status`` message: the settings in force (``enable``, ``input``,
    ``harmonic``, ``output``, ``setpoint`` in the input's unit, ``oscillator``: ``"drive"``
    or ``"drive2"``) and ``latest``, its latest update (``None`` before its first; a
    disabled unit keeps its last). ``t`` is the status message's simulated time (s).

    ``locked``: for a PLL (a unit on the phase driving ``drive_frequency`` or
    ``drive2_frequency``), its lock after its latest update: acquired after 16 updates in a
    row within 0.1 rad of the set-point and not held by a limit, lost at the first that is
    not; ``lock_losses``: its losses of lock since the daemon started, each counted however
    brief. Both ``None`` for other units and before the first update.
    ``frequency_shift``: for a unit on either frequency, its latest output less
    ``/drive/frequency`` (or ``/drive2/frequency`` for ``drive2_frequency``: Δf₂), in Hz,
    the frequency shift Δf; ``None`` otherwise."""

    index: int
    enable: bool
    input: str
    harmonic: int
    output: str
    setpoint: float
    latest: PidUpdate | None
    t: float
    locked: bool | None = None
    frequency_shift: float | None = None
    oscillator: str = "drive"
    lock_losses: int | None = None

    @property
    def output_unit(self) -> str:
        """The unit of the output's values: m, or Hz for either drive frequency."""
        return OUTPUT_UNITS.get(self.output, "")

    @classmethod
    def from_json(cls, m: Mapping[str, Any], t: float) -> "PidStatus":
        latest = m.get("latest")
        locked = m.get("locked")
        shift = m.get("frequency_shift")
        return cls(
            index=int(m["index"]),
            enable=bool(m["enable"]),
            input=str(m["input"]),
            harmonic=int(m["harmonic"]),
            output=str(m["output"]),
            setpoint=float(m["setpoint"]),
            latest=None if latest is None else PidUpdate.from_json(latest),
            t=t,
            locked=None if locked is None else bool(locked),
            frequency_shift=None if shift is None else float(shift),
            # A daemon before the second excitation's units has only the drive.
            oscillator=str(m.get("oscillator", "drive")),
            lock_losses=None if m.get("lock_losses") is None else int(m["lock_losses"]),
        )


def from_status(message: Mapping[str, Any]) -> list[PidStatus]:
    """The PID units of one ``status`` message, by index (``[]`` from a daemon without
    them)."""
    t = float(message.get("t", float("nan")))
    return [PidStatus.from_json(u, t) for u in message.get("pids", [])]


def held_from_status(message: Mapping[str, Any]) -> list[str]:
    """The outputs a PID unit holds away from their nodes in one ``status`` message
    (``pid_held``: one runs on it, or one ran and left it there until the node is
    written), e.g. ``["drive_frequency"]`` or ``["drive2_frequency"]``; ``[]`` from a daemon
    without them."""
    return [str(o) for o in message.get("pid_held", [])]


def _satisfies(
    status: PidStatus, epoch: int, updates: int, until: Callable[[PidStatus], bool] | None
) -> bool:
    """Whether ``status`` ends a :meth:`PidUnit.wait`."""
    latest = status.latest
    return (
        latest is not None
        and latest.epoch >= epoch
        and latest.updates >= updates
        and (until is None or until(status))
    )


def _wait_timeout(
    path: str, epoch: int, updates: int, timeout: float, last: PidStatus | None
) -> InstrumentError:
    return InstrumentError(
        "timeout",
        f"{path}: no update of epoch ≥ {epoch} with ≥ {updates} updates satisfying the "
        f"condition within {timeout} s; last: {last}",
    )


def _check_keys(settings: Mapping[str, Any], index: int) -> None:
    unknown = sorted(set(settings) - set(SETTINGS))
    if unknown:
        raise TypeError(
            f"/pids/{index} has no setting {', '.join(unknown)}: it has {', '.join(SETTINGS)}"
        )


class PidUnit:
    """PID unit ``index`` (``/pids/N``) of a synchronous :class:`ftafm.Instrument`.

    Its nodes are reachable as on the node tree (``unit.setpoint()``, ``unit.p(0.1)``),
    except ``enable``, which here is the action (``unit.enable()``, ``unit.disable()``);
    ``unit.nodes.enable()`` reads the node.
    """

    def __init__(self, client: "Instrument", index: int):
        if not 0 <= index < PID_COUNT:
            raise IndexError(f"no PID unit /pids/{index}: /pids/0 … /pids/{PID_COUNT - 1}")
        self._client = client
        self.index = index
        self.path = f"/pids/{index}"

    @property
    def nodes(self) -> NodeBranch:
        """The unit's branch of the node tree (``unit.nodes.enable()`` reads the node)."""
        pids = self._client.root.pids
        assert isinstance(pids, NodeBranch), "the daemon has no /pids"
        branch = pids[self.index]
        assert isinstance(branch, NodeBranch)
        return branch

    def __getattr__(self, name: str) -> NodeBranch | NodeLeaf:
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.nodes, name)  # type: ignore[no-any-return]

    def configure(self, **settings: Any) -> float | None:
        """Sets any of the unit's nodes (``input``, ``harmonic``, ``setpoint``, ``p``,
        ``i``, ``d``, ``d_bandwidth``, ``output_min``, ``output_max``, ``rate``,
        ``output``, ``oscillator``, ``input_bandwidth``, ``enable``; units in docs/configuration.md) in one ``set_many``: one
        change at one sample boundary, all or nothing. Returns the simulated time (s) it
        took effect (``None`` inside ``set_transaction``). A refused value raises
        :class:`ftafm.InstrumentError` naming the node and its range; an unknown name
        :class:`TypeError` before anything is sent."""
        _check_keys(settings, self.index)
        return self._client.set_many({f"{self.path}/{k}": v for k, v in settings.items()})

    def enable(self, on: bool = True) -> float | None:
        """Starts the unit (bumpless: its first output is the output's present value);
        ``enable(False)`` is :meth:`disable`. Returns the simulated time (s) it took
        effect."""
        return self._client.set(f"{self.path}/enable", bool(on))

    def disable(self) -> float | None:
        """Stops the unit; its output stays where the unit left it. Returns the simulated
        time (s) it took effect."""
        return self.enable(False)

    def advise(self, bandwidth: float, *, kind: AdviceKind = "pi") -> PidAdvice:
        """The daemon's advised gains for this unit at a closed-loop −3 dB ``bandwidth``
        (Hz), a PI or (``kind="pid"``) a PID, for the input and output the unit has now
        (:meth:`ftafm.Instrument.pid_advise`). Sets nothing."""
        return self._client.pid_advise(self.index, bandwidth, kind=kind)

    def status(self, *, timeout: float | None = None) -> PidStatus:
        """The unit in the next ``status`` message (settings in force, latest update);
        ``timeout`` (s, default: the client's) bounds the wait for it."""
        return self._client.pid_status(timeout=timeout)[self.index]

    def wait(
        self,
        until: Callable[[PidStatus], bool] | None = None,
        *,
        updates: int = 1,
        epoch: int | None = None,
        timeout: float = WAIT_TIMEOUT,
    ) -> PidStatus:
        """Waits, message by message of ``status``, until the unit's latest update was made
        under settings epoch ``epoch`` or later (default: this client's last change,
        :attr:`ftafm.Instrument.epoch`), counts at least ``updates`` (since the daemon
        started), and ``until(status)`` holds (``status.latest`` is then never ``None``);
        returns that status. Raises :class:`ftafm.InstrumentError` (``timeout``) with the
        last status seen if none comes within ``timeout`` s."""
        want = self._client.epoch if epoch is None else epoch
        deadline = time.monotonic() + timeout
        last: PidStatus | None = None
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise _wait_timeout(self.path, want, updates, timeout, last)
            last = self.status(timeout=left)
            if _satisfies(last, want, updates, until):
                return last

    def __repr__(self) -> str:
        return f"<ftafm PID unit {self.path}>"


_Unit = TypeVar("_Unit")


class _Units(Sequence[_Unit]):
    """The four units by index, with an error naming the range past them."""

    _units: list[_Unit]

    def __getitem__(self, index: int) -> _Unit:  # type: ignore[override]
        try:
            return self._units[index]
        except IndexError:
            raise IndexError(
                f"no PID unit /pids/{index}: /pids/0 … /pids/{PID_COUNT - 1}"
            ) from None

    def __len__(self) -> int:
        return len(self._units)

    def __iter__(self) -> Iterator[_Unit]:
        return iter(self._units)


class Pids(_Units[PidUnit]):
    """The PID units of a synchronous :class:`ftafm.Instrument`: ``afm.pids[0]``,
    ``len(afm.pids)``, iteration, and :meth:`status` of all four from one message."""

    def __init__(self, client: "Instrument"):
        self._client = client
        self._units = [PidUnit(client, n) for n in range(PID_COUNT)]

    def status(self, *, timeout: float | None = None) -> list[PidStatus]:
        """Every unit in the next ``status`` message (:meth:`ftafm.Instrument.pid_status`)."""
        return self._client.pid_status(timeout=timeout)

    def held(self, *, timeout: float | None = None) -> list[str]:
        """The outputs the units hold away from their nodes in the next ``status`` message
        (:meth:`ftafm.Instrument.pid_held`)."""
        return self._client.pid_held(timeout=timeout)

    def __repr__(self) -> str:
        return f"<ftafm PID units /pids/0 … /pids/{PID_COUNT - 1}>"


class AsyncPidUnit:
    """PID unit ``index`` (``/pids/N``) of an :class:`ftafm.aio.Instrument`: as
    :class:`PidUnit`, its calls awaitable (``await unit.configure(...)``,
    ``await unit.wait(...)``); its nodes as on the node tree (``await unit.p()``), except
    ``enable``, the action (``await unit.nodes.enable()`` reads the node)."""

    def __init__(self, client: "aio.Instrument", index: int):
        if not 0 <= index < PID_COUNT:
            raise IndexError(f"no PID unit /pids/{index}: /pids/0 … /pids/{PID_COUNT - 1}")
        self._client = client
        self.index = index
        self.path = f"/pids/{index}"

    @property
    def nodes(self) -> NodeBranch:
        """The unit's branch of the node tree (``await unit.nodes.enable()`` reads the
        node)."""
        pids = self._client.root.pids
        assert isinstance(pids, NodeBranch), "the daemon has no /pids"
        branch = pids[self.index]
        assert isinstance(branch, NodeBranch)
        return branch

    def __getattr__(self, name: str) -> NodeBranch | NodeLeaf:
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.nodes, name)  # type: ignore[no-any-return]

    async def configure(self, **settings: Any) -> float | None:
        """:meth:`PidUnit.configure`: any of the unit's nodes in one ``set_many``, all or
        nothing; the simulated time (s) it took effect (``None`` inside
        ``set_transaction``)."""
        _check_keys(settings, self.index)
        return await self._client.set_many(
            {f"{self.path}/{k}": v for k, v in settings.items()}
        )

    async def enable(self, on: bool = True) -> float | None:
        """Starts the unit (bumpless); ``enable(False)`` is :meth:`disable`."""
        return await self._client.set(f"{self.path}/enable", bool(on))

    async def disable(self) -> float | None:
        """Stops the unit; its output stays where the unit left it."""
        return await self.enable(False)

    async def advise(self, bandwidth: float, *, kind: AdviceKind = "pi") -> PidAdvice:
        """:meth:`PidUnit.advise`: the daemon's advised gains for this unit at a
        closed-loop −3 dB ``bandwidth`` (Hz), PI or PID. Sets nothing."""
        return await self._client.pid_advise(self.index, bandwidth, kind=kind)

    async def status(self, *, timeout: float | None = None) -> PidStatus:
        """The unit in the next ``status`` message."""
        return (await self._client.pid_status(timeout=timeout))[self.index]

    async def wait(
        self,
        until: Callable[[PidStatus], bool] | None = None,
        *,
        updates: int = 1,
        epoch: int | None = None,
        timeout: float = WAIT_TIMEOUT,
    ) -> PidStatus:
        """:meth:`PidUnit.wait`: message by message of ``status``, until the unit's latest
        update was made under settings epoch ``epoch`` or later (default: this client's
        last change), counts at least ``updates`` and ``until(status)`` holds."""
        want = self._client.epoch if epoch is None else epoch
        deadline = time.monotonic() + timeout
        last: PidStatus | None = None
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                raise _wait_timeout(self.path, want, updates, timeout, last)
            last = await self.status(timeout=left)
            if _satisfies(last, want, updates, until):
                return last

    def __repr__(self) -> str:
        return f"<ftafm PID unit {self.path} (asyncio)>"


class AsyncPids(_Units[AsyncPidUnit]):
    """The PID units of an :class:`ftafm.aio.Instrument`: ``inst.pids[0]``,
    ``len(inst.pids)``, iteration, and ``await`` :meth:`status` / :meth:`held`."""

    def __init__(self, client: "aio.Instrument"):
        self._client = client
        self._units = [AsyncPidUnit(client, n) for n in range(PID_COUNT)]

    async def status(self, *, timeout: float | None = None) -> list[PidStatus]:
        """Every unit in the next ``status`` message."""
        return await self._client.pid_status(timeout=timeout)

    async def held(self, *, timeout: float | None = None) -> list[str]:
        """The outputs the units hold away from their nodes in the next ``status``."""
        return await self._client.pid_held(timeout=timeout)

    def __repr__(self) -> str:
        return f"<ftafm PID units /pids/0 … /pids/{PID_COUNT - 1} (asyncio)>"
