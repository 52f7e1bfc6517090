"""The asyncio client: ``async with ftafm.aio.Instrument(url) as inst: ...``.

One WebSocket connection; a reader task hands each reply to the request waiting for it
(matched by id) and each data message to the streams being read. Every call of the
synchronous :class:`ftafm.Instrument` is one of these coroutines. The node tree is here
too, its calls awaitable (``await inst.sample.youngs_modulus(116.1e9)``, built from
``list`` on connect, :mod:`ftafm.tree`), and ``async with inst.set_transaction():``
batches sets into one ``set_many``.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import math
import os
import struct
from dataclasses import dataclass
from typing import (
    Any,
    AsyncGenerator,
    AsyncIterator,
    Callable,
    Iterable,
    Mapping,
    Sequence,
    cast,
)

import websockets
from websockets.asyncio.client import ClientConnection

from . import data, pids, tree
from .errors import ConnectionLost, InstrumentError, NoDaemon

#: The requests that change the settings (their replies carry the change's epoch).
_CHANGES = frozenset({"set", "preset", "load_settings"})

#: Streams whose messages are derived from a model of the settings: they carry the epoch
#: they reflect and ``stale`` while the model of newer settings is being built.
_DERIVED = frozenset({"force", "image"})

#: Where ``ftafm serve`` listens by default.
DEFAULT_URL = "ws://127.0.0.1:8700/ws"

#: Default longest wait (s) for one sweep point: beyond the daemon's own 60 s wait for its
#: force estimator, which a busy machine can starve (it is built at a lower priority).
SWEEP_POINT_TIMEOUT = 120.0

#: What ``sweep`` sets when the call does not say, as ``config/default.toml`` does: each call
#: stands on its own, whatever an earlier sweep left in ``/sweeper/*``.
SWEEP_DEFAULTS: dict[str, Any] = {
    "scale": "linear",
    "direction": "up",
    "settling": 0.0,
    "averaging": 4,
}

#: A sweep's progress callback: ``progress(done, total)``, points measured and to measure.
Progress = Callable[[int, int], None]


#: A frame of streamed samples' header (docs/protocol.md, "Streaming samples in"): magic,
#: sample type (1 int16, 2 float32, 3 float64), reserved, id, sample rate (Hz), scale (m per
#: unit), index of the frame's first sample in the writer's count; little-endian.
_FRAME_HEADER = struct.Struct("<4sHHQddQ")


@dataclass
class StreamReceipt:
    """What became of streamed samples (:meth:`Instrument.stream_samples`)."""

    #: Frames the daemon took.
    frames: int = 0
    #: Samples that entered the chain.
    accepted: int = 0
    #: Samples dropped for want of room in the daemon's feed (the chain behind the writer).
    dropped: int = 0
    #: Samples skipped by a jump in the frames' indices.
    gap: int = 0
    #: The writer's index of the next sample: ``first_index`` for a call that goes on.
    next_index: int = 0


@dataclass(frozen=True)
class Node:
    """One node of the settings tree, as ``list`` describes it."""

    path: str
    value: Any
    unit: str
    writable: bool
    type: str
    min: Any
    max: Any
    description: str
    allowed: tuple[str, ...] | None = None
    warning: str | None = None
    #: Whether ``min`` / ``max`` themselves are accepted (``0 < value ≤ 1e13``: False,
    #: True); None for a node without a range (or a daemon too old to say).
    min_inclusive: bool | None = None
    max_inclusive: bool | None = None

    @classmethod
    def from_json(cls, n: Mapping[str, Any]) -> "Node":
        allowed = n.get("allowed")
        return cls(
            path=n["path"],
            value=n["value"],
            unit=n["unit"],
            writable=n["writable"],
            type=n.get("type", ""),
            min=n.get("min"),
            max=n.get("max"),
            description=n.get("description", ""),
            allowed=tuple(allowed) if allowed is not None else None,
            warning=n.get("warning"),
            min_inclusive=n.get("min_inclusive"),
            max_inclusive=n.get("max_inclusive"),
        )


def _check_finite(value: Any, where: str) -> None:
    """JSON has no NaN or infinity: refuse them here, with the node's name."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{where} = {value!r}: values must be finite numbers")
    if isinstance(value, (list, tuple)):
        for v in value:
            _check_finite(v, where)


def _plain(value: Any) -> Any:
    """numpy scalars and arrays as the JSON types they stand for."""
    if hasattr(value, "tolist"):
        return value.tolist()
    return value


class Instrument:
    """A connection to an ftafm daemon (asyncio).

    ``url`` is the daemon's WebSocket endpoint (default ``ws://127.0.0.1:8700/ws``, or the
    ``FTAFM_URL`` environment variable); ``timeout`` bounds each request's wait for its
    reply, in seconds.
    """

    def __init__(self, url: str | None = None, *, timeout: float = 10.0):
        self.url = url or os.environ.get("FTAFM_URL", DEFAULT_URL)
        self.timeout = timeout
        self._ws: ClientConnection | None = None
        self._reader: asyncio.Task[None] | None = None
        self._ids = itertools.count(1)
        self._pending: dict[int, asyncio.Future[dict[str, Any]]] = {}
        self._readers: dict[str, list[asyncio.Queue[dict[str, Any] | None]]] = {}
        self._closed: str | None = None
        self._epoch = 0
        self.hello: dict[str, Any] = {}
        self._batch = tree.Batching()
        self._tree: tree.NodeBranch | None = None
        #: The ``list`` reply the node tree was built from, on connect.
        self.node_list: list[Node] = []

    @property
    def epoch(self) -> int:
        """The settings epoch of this client's last change (``set``, ``set_many``,
        ``preset``, ``load_settings``): the daemon counts every committed change, and stamps
        each force estimate, image line and sweep message with the epoch it reflects."""
        return self._epoch

    # -- connection ----------------------------------------------------------------------

    async def connect(self) -> "Instrument":
        """Opens the connection and greets the daemon (``hello``); raises
        :class:`ftafm.NoDaemon` when no daemon answers at the URL."""
        try:
            self._ws = await websockets.connect(
                self.url, max_size=None, open_timeout=self.timeout
            )
        except (OSError, asyncio.TimeoutError, websockets.InvalidHandshake) as e:
            raise NoDaemon(self.url, str(e) or type(e).__name__) from e
        self._closed = None
        self._reader = asyncio.create_task(self._read())
        self.hello = await self.request("hello")
        # The node tree needs the node list before any attribute is looked up, and an
        # attribute lookup cannot await: one `list` now.
        self.node_list = await self.nodes()
        self._tree = tree.build(self, self.node_list)
        return self

    async def close(self) -> None:
        """Closes the connection; waiting requests and streams end with ConnectionLost."""
        if self._ws is not None:
            await self._ws.close()
        if self._reader is not None:
            await asyncio.gather(self._reader, return_exceptions=True)
        self._ws = None

    async def __aenter__(self) -> "Instrument":
        return await self.connect()

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    async def _read(self) -> None:
        assert self._ws is not None
        reason = "the daemon closed the connection"
        try:
            async for frame in self._ws:
                if isinstance(frame, bytes):
                    continue  # this client subscribes in JSON only
                msg = json.loads(frame)
                if "ok" in msg:
                    fut = self._pending.pop(msg.get("id"), None)
                    if fut is not None and not fut.done():
                        fut.set_result(msg)
                    continue
                for queue in self._readers.get(msg.get("stream", ""), []):
                    queue.put_nowait(msg)
        except websockets.ConnectionClosed as e:
            reason = f"the connection closed ({e})"
        finally:
            self._closed = reason
            for fut in self._pending.values():
                if not fut.done():
                    fut.set_exception(ConnectionLost(reason))
            self._pending.clear()
            for queues in self._readers.values():
                for q in queues:
                    q.put_nowait(None)

    # -- requests ------------------------------------------------------------------------

    async def request(self, op: str, **fields: Any) -> dict[str, Any]:
        """Sends one request and returns its reply; raises InstrumentError on a refusal."""
        if self._ws is None or self._closed is not None:
            raise ConnectionLost(self._closed or "not connected: use `async with` or connect()")
        rid = next(self._ids)
        fut: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._pending[rid] = fut
        request = {"id": rid, "op": op, **fields}
        await self._ws.send(json.dumps(request, allow_nan=False))
        try:
            reply = await asyncio.wait_for(fut, self.timeout)
        except asyncio.TimeoutError:
            self._pending.pop(rid, None)
            raise InstrumentError(
                "timeout", f"no reply to {op} within {self.timeout} s", request
            ) from None
        if not reply.get("ok"):
            err = reply.get("error", {})
            raise InstrumentError(err.get("code", "internal"), err.get("message", ""), request)
        if op in _CHANGES and isinstance(reply.get("epoch"), int):
            self._epoch = max(self._epoch, reply["epoch"])
        return reply

    async def stream_samples(
        self,
        samples: Any,
        sample_rate: float | None = None,
        *,
        scale: float = 1.0,
        first_index: int = 0,
        frame_samples: int = 1 << 18,
        window: int = 4,
        realtime: bool = False,
    ) -> StreamReceipt:
        """Streams ``samples`` (a 1-D numpy array of int16, float32 or float64, or anything
        ``numpy.asarray`` makes one of) into the chain as its photodiode signal, while
        ``/source/kind`` is ``"stream"`` (set it first): the same lock-in bank, spectrum and
        force inversion as the synthesiser's signal, on a reference at ``/drive/frequency``
        with phase 0 at the writer's sample 0 (``first_index`` is the index of
        ``samples[0]`` in that count; a later call that goes on where this one ended
        continues the stream, one that skips ahead leaves a gap the daemon counts).

        ``scale`` is metres per unit of the samples (an InvOLS in m/V times volts per
        code); ``sample_rate`` must be the daemon's ``/synth/sample_rate`` (the default).
        Frames of ``frame_samples`` go out with at most ``window`` unanswered, so the
        daemon's feed sets the pace; ``realtime=True`` paces them by the wall clock too,
        as a digitiser would deliver them. Returns what became of the samples; raises
        :class:`InstrumentError` on a frame the daemon refuses (its message names why).
        """
        import time

        import numpy as np

        if self._ws is None or self._closed is not None:
            raise ConnectionLost(self._closed or "not connected: use `async with` or connect()")
        data = np.asarray(samples)
        codes = {np.dtype("<i2"): 1, np.dtype("<f4"): 2, np.dtype("<f8"): 3}
        dtype = data.dtype.newbyteorder("<")
        if data.ndim != 1 or dtype not in codes:
            raise ValueError(
                f"samples must be a 1-D array of int16, float32 or float64, not "
                f"{data.ndim}-D {data.dtype}"
            )
        data = data.astype(dtype, copy=False)
        rate = float(sample_rate if sample_rate is not None else self.hello["sample_rate"])
        if not (math.isfinite(scale) and scale != 0.0):
            raise ValueError(f"scale = {scale!r}: metres per unit must be finite and non-zero")
        if frame_samples < 1 or window < 1:
            raise ValueError("frame_samples and window must be at least 1")
        loop = asyncio.get_running_loop()
        receipt = StreamReceipt()
        unanswered: list[tuple[dict[str, Any], asyncio.Future[dict[str, Any]]]] = []

        async def settle(fut: asyncio.Future[dict[str, Any]], frame: dict[str, Any]) -> None:
            reply = await asyncio.wait_for(fut, self.timeout)
            if not reply.get("ok"):
                err = reply.get("error", {})
                raise InstrumentError(err.get("code", "internal"), err.get("message", ""), frame)
            receipt.frames += 1
            receipt.accepted += reply["accepted"]
            receipt.dropped += reply["dropped"]
            receipt.gap += reply["gap"]
            receipt.next_index = reply["next_index"]

        start = time.monotonic()
        try:
            for offset in range(0, len(data), frame_samples):
                part = data[offset : offset + frame_samples]
                if realtime:
                    due = start + offset / rate
                    await asyncio.sleep(max(0.0, due - time.monotonic()))
                rid = next(self._ids)
                header = _FRAME_HEADER.pack(
                    b"FTS1", codes[dtype], 0, rid, rate, scale, first_index + offset
                )
                fut: asyncio.Future[dict[str, Any]] = loop.create_future()
                self._pending[rid] = fut
                frame = {"id": rid, "first_index": first_index + offset, "samples": len(part)}
                await self._ws.send(header + part.tobytes())
                unanswered.append((frame, fut))
                if len(unanswered) >= window:
                    frame0, fut0 = unanswered.pop(0)
                    await settle(fut0, frame0)
            while unanswered:
                frame0, fut0 = unanswered.pop(0)
                await settle(fut0, frame0)
        finally:
            for frame0, fut0 in unanswered:
                self._pending.pop(frame0["id"], None)
                fut0.cancel()
        return receipt

    async def info(self) -> dict[str, Any]:
        """Server name, version, protocol version and sample rate (Hz), and the warnings now
        (from ``status``: the operating point's, and the chain's if it fell behind real
        time in the last interval)."""
        info = {k: v for k, v in self.hello.items() if k not in ("id", "ok")}
        status = await self.next("status")
        info["warnings"] = status.get("warnings", [])
        info["realtime_factor"] = status.get("realtime_factor")
        return info

    async def pid_status(self, *, timeout: float | None = None) -> list[pids.PidStatus]:
        """The PID units ``/pids/0`` … ``/pids/3`` in the next ``status`` message (every
        0.5 s of wall time): each one's settings in force and latest update
        (:class:`ftafm.pids.PidStatus`); ``timeout`` (s, default: the client's) bounds the
        wait."""
        return pids.from_status(await self.next("status", timeout=timeout))

    async def pid_held(self, *, timeout: float | None = None) -> list[str]:
        """The outputs a PID unit holds away from their nodes in the next ``status``
        message (``"surface_distance"``, ``"drive_frequency"``, ``"drive_amplitude"``,
        ``"drive2_frequency"``, ``"drive2_amplitude"``): one runs on it, or one ran and left
        it where it put it; a write of the node (``/surface/distance``,
        ``/drive/frequency``, ``/drive/free_amplitude``, ``/drive2/frequency``,
        ``/drive2/free_amplitude``), even of its present value, or a load of settings
        takes it back, and ``/drive2/enable`` false lets go of
        the second excitation's."""
        return pids.held_from_status(await self.next("status", timeout=timeout))

    async def pid_advise(
        self, unit: int, bandwidth: float, *, kind: pids.AdviceKind = "pi"
    ) -> pids.PidAdvice:
        """Gains for PID unit ``unit`` (``/pids/N``) from the closed loop's target −3 dB
        ``bandwidth`` (Hz, > 0): the daemon's PID advisor (``pid_advise``) on the unit's
        loop at the settings in force, a PI (``kind="pi"``, D = 0) or a PID (``"pid"``);
        the gains and the loop they predict (:class:`ftafm.pids.PidAdvice`). Nothing is
        set (``await inst.pids[unit].configure(**advice.gains)`` sets them). Modelled: a
        PLL (input ``"phase"``, harmonic 1, output ``"drive_frequency"``) and an
        amplitude loop (``"r"``, harmonic 1, ``"drive_amplitude"``), and the same two on
        ``"drive2"``; the unit need not be enabled. Raises :class:`ftafm.InstrumentError`
        naming the field: ``bad_request`` for a bad ``unit``, ``bandwidth`` or ``kind``,
        ``invalid_value`` for a bandwidth beyond the loop's reach (the message gives the
        reach) or a unit the advisor does not model; :class:`ValueError` for a NaN or
        infinite ``bandwidth``, before anything is sent."""
        bandwidth = _plain(bandwidth)
        _check_finite(bandwidth, 'field "bandwidth" of op "pid_advise"')
        reply = await self.request("pid_advise", unit=_plain(unit), bandwidth=bandwidth, kind=kind)
        return pids.PidAdvice.from_json(reply)

    @property
    def pids(self) -> pids.AsyncPids:
        """The PID units ``/pids/0`` … ``/pids/3``: ``await inst.pids[0].configure(...)``,
        ``.enable()``, ``.disable()``, ``.status()``, ``.wait(...)``
        (:class:`ftafm.pids.AsyncPidUnit`); their nodes as on the node tree
        (``await inst.pids[0].p()``)."""
        return pids.AsyncPids(self)

    async def nodes(self, path: str | None = None) -> list[Node]:
        """Every node (or those under ``path``) with its value, unit, type and range."""
        fields = {"path": path} if path else {}
        reply = await self.request("list", **fields)
        return [Node.from_json(n) for n in reply["nodes"]]

    async def get(self, path: str) -> Any:
        """The value of the node at ``path`` (or a measured value: ``/demods/N/sample``)."""
        return (await self.request("get", path=path))["value"]

    async def get_many(self, paths: Sequence[str]) -> dict[str, Any]:
        """The values at ``paths`` (nodes and measured values mixed), read in one request
        from one version of the settings: path → value, ``None`` for a measured value that
        does not exist now (a disabled demodulator's ``/demods/N/sample``)."""
        if not paths:
            return {}
        reply = await self.request("get", paths=list(paths))
        return cast(dict[str, Any], reply["values"])

    async def set(self, path: str, value: Any) -> float | None:
        """Sets one node; returns the simulated time (s) at which the change took effect.
        Inside :meth:`set_transaction`, queues it instead and returns ``None``."""
        if self._batch.queue({path: value}):
            return None
        value = _plain(value)
        _check_finite(value, path)
        return (await self.request("set", path=path, value=value)).get("t")

    async def set_many(self, values: Mapping[str, Any]) -> float | None:
        """Sets several nodes together, at one sample boundary, all or nothing; returns the
        simulated time (s) at which they took effect. Inside :meth:`set_transaction`,
        queues them instead and returns ``None``."""
        if self._batch.queue(values):
            return None
        plain = {p: _plain(v) for p, v in values.items()}
        for p, v in plain.items():
            _check_finite(v, p)
        return (await self.request("set", values=plain)).get("t")

    async def read_sample(self, demod: int = 0) -> dict[str, float]:
        """The newest output of demodulator ``demod``: ``t`` (s), ``harmonic``, ``x``,
        ``y``, ``r`` (m), ``phase`` (rad); what ``await inst.sample(demod)`` returns."""
        return cast(dict[str, float], await self.get(f"/demods/{demod}/sample"))

    @property
    def sample(self) -> tree.SampleBranch:
        """Called, ``await sample(demod=0)`` is the newest output of demodulator ``demod``
        (:meth:`read_sample`); as a branch, the ``/sample`` nodes
        (``await inst.sample.youngs_modulus()``)."""
        return tree.SampleBranch(self.read_sample, lambda: self.root)

    @contextlib.asynccontextmanager
    async def set_transaction(self) -> AsyncIterator[tree.Transaction]:
        """Batches every ``set`` and ``set_many`` (and node-tree set) on this Instrument
        inside the ``async with`` into one ``set_many`` at its end: one change at one sample
        boundary, all or nothing (as zhinst-toolkit's ``set_transaction``). Nothing is sent
        if the block raises. The transaction's ``t`` is the simulated time the change took
        effect."""
        with self._batch.opened() as transaction:
            yield transaction
        if transaction.values:
            transaction.t = await self.set_many(transaction.values)

    @property
    def root(self) -> tree.NodeBranch:
        """The node tree, built from ``list`` on connect: ``inst.root.drive`` is
        ``inst.drive``; see :mod:`ftafm.tree`."""
        if self._tree is None:
            raise ConnectionLost("not connected: the node tree is built on connect()")
        return self._tree

    def __getattr__(self, name: str) -> Any:
        # Only names that are not attributes come here: the node tree's top-level branches.
        if name.startswith("_") or self.__dict__.get("_tree") is None:
            raise AttributeError(name)
        return getattr(self._tree, name)

    def __dir__(self) -> list[str]:
        names = set(super().__dir__())
        if self.__dict__.get("_tree") is not None:
            names.update(self.__dict__["_tree"].__dir__())
        return sorted(names)

    async def presets(self) -> list[dict[str, str]]:
        """The presets (real cantilevers and samples): name, kind, summary."""
        return cast(list[dict[str, str]], (await self.request("presets"))["presets"])

    async def preset(self, name: str) -> float | None:
        """Loads a preset; returns the simulated time (s) it took effect."""
        return (await self.request("preset", name=name)).get("t")

    async def settings_toml(self) -> str:
        """The running settings as a config file (TOML)."""
        return str((await self.request("settings"))["toml"])

    async def save_settings(self, file: str | os.PathLike[str]) -> None:
        """Writes the running settings to ``file``, a config ``ftafm --config`` accepts."""
        text = await self.settings_toml()
        with open(file, "w", encoding="utf-8") as f:
            f.write(text)

    async def load_settings(self, file: str | os.PathLike[str]) -> float | None:
        """Lays the config in ``file`` (whole or partial) over the running settings as one
        change; returns the simulated time (s) it took effect."""
        with open(file, encoding="utf-8") as f:
            text = f.read()
        return (await self.request("load_settings", toml=text)).get("t")

    # -- streams -------------------------------------------------------------------------

    async def _subscribe(
        self, stream: str, queue: asyncio.Queue[dict[str, Any] | None] | None = None
    ) -> asyncio.Queue[dict[str, Any] | None]:
        if stream not in data.STREAMS:
            raise ValueError(f"unknown stream {stream!r}; streams: {', '.join(data.STREAMS)}")
        if queue is None:
            queue = asyncio.Queue()
        readers = self._readers.setdefault(stream, [])
        readers.append(queue)
        if len(readers) == 1:
            try:
                await self.request("subscribe", stream=stream)
            except BaseException:
                readers.remove(queue)
                raise
        return queue

    async def _unsubscribe(self, stream: str, queue: asyncio.Queue[Any]) -> None:
        readers = self._readers.get(stream, [])
        if queue in readers:
            readers.remove(queue)
        if not readers and self._closed is None:
            try:
                await self.request("unsubscribe", stream=stream)
            except ConnectionLost:
                pass

    async def messages(
        self, stream: str, *, timeout: float | None = None
    ) -> AsyncGenerator[dict[str, Any], None]:
        """The messages of ``stream`` as they come (subscribed while iterating). Raises
        InstrumentError ``timeout`` when none comes for ``timeout`` s (default: the
        client's)."""
        queue = await self._subscribe(stream)
        wait = self.timeout if timeout is None else timeout
        try:
            while True:
                try:
                    msg = await asyncio.wait_for(queue.get(), wait)
                except asyncio.TimeoutError:
                    raise InstrumentError(
                        "timeout", f"no {stream} message within {wait} s"
                    ) from None
                if msg is None:
                    raise ConnectionLost(self._closed or "connection closed")
                yield msg
        finally:
            await self._unsubscribe(stream, queue)

    async def next(self, stream: str, *, timeout: float | None = None) -> dict[str, Any]:
        """The next message of ``stream``; ``timeout`` (s, default: the client's) bounds the
        wait."""
        gen = self.messages(stream, timeout=timeout)
        try:
            return await gen.__anext__()
        finally:
            await gen.aclose()

    async def poll(
        self,
        stream: str,
        seconds: float,
        *,
        timeout: float | None = None,
        include_stale: bool = False,
    ) -> data.StreamData:
        """The messages of ``stream`` over ``seconds`` of simulated time, as arrays.

        Collects from the first message on until one reflects samples ``seconds`` later
        (that one excluded). Simulated time runs with the wall clock in real time and
        faster when free-running. ``timeout`` (s) bounds the wait for each message.

        ``force`` and ``image`` messages of settings older than this client's last change
        (:attr:`epoch`), or marked ``stale`` (made by the model of older settings while
        the new one is built), are left out unless ``include_stale``: after a ``set``,
        ``poll("force", ...)`` returns estimates of the new settings only.
        """
        rows: list[dict[str, Any]] = []
        gen = self.messages(stream, timeout=timeout)
        try:
            async for msg in gen:
                if (
                    stream in _DERIVED
                    and not include_stale
                    and (msg.get("stale") or msg.get("epoch", 0) < self._epoch)
                ):
                    continue
                if rows and msg["t"] >= rows[0]["t"] + seconds:
                    break
                rows.append(msg)
        finally:
            await gen.aclose()
        return data.from_messages(stream, rows)

    async def sweep(
        self,
        path: str,
        start: float,
        stop: float,
        points: int = 121,
        *,
        scale: str = SWEEP_DEFAULTS["scale"],
        direction: str = SWEEP_DEFAULTS["direction"],
        settling: float = SWEEP_DEFAULTS["settling"],
        averaging: int = SWEEP_DEFAULTS["averaging"],
        timeout: float | None = None,
        progress: bool | Progress | None = None,
    ) -> data.SweepResult:
        """Sweeps the node at ``path`` from ``start`` to ``stop`` in ``points`` points with
        the daemon's sweeper (``/sweeper/*``; docs/sweeper.md) and returns every point.

        ``scale`` ``"linear"``/``"log"``, ``direction`` ``"up"``/``"down"``/``"both"``,
        ``settling`` (s, 0 automatic) and ``averaging`` (frames) are this call's own
        (:data:`SWEEP_DEFAULTS` when not given), never what an earlier sweep left in
        ``/sweeper``. A frequency sweep holds the base amplitude constant (a tune); the swept
        node is restored afterwards. ``timeout`` (s) bounds the wait for each point; by
        default the larger of the client's timeout and :data:`SWEEP_POINT_TIMEOUT`, since a
        point may wait up to 60 s for the daemon's force estimator on a busy machine.

        ``progress``: ``True`` shows a tqdm bar (``pip install tqdm``), or a callable
        ``progress(done, total)`` is called with the points measured so far and the total,
        once at the start (0) and after every point (in the client's event loop thread:
        keep it short).
        """
        values: dict[str, Any] = {
            "/sweeper/parameter": path,
            "/sweeper/start": _plain(start),
            "/sweeper/stop": _plain(stop),
            "/sweeper/points": _plain(points),
            "/sweeper/scale": scale,
            "/sweeper/direction": direction,
            "/sweeper/settling": _plain(settling),
            "/sweeper/averaging": _plain(averaging),
            "/sweeper/enable": True,
        }
        for key, value in values.items():
            _check_finite(value, key)
        total = int(points) * (2 if direction == "both" else 1)
        queue: asyncio.Queue[dict[str, Any] | None] = asyncio.Queue()
        wait = max(self.timeout, SWEEP_POINT_TIMEOUT) if timeout is None else timeout
        report, finish = _progress(progress, total, path)
        try:
            await self._subscribe("sweep", queue)
        except BaseException:
            finish()
            raise
        rows: list[dict[str, Any]] = []
        finished = False
        try:
            # The epoch of the change that asks for the sweep is its request: every message
            # of this sweep carries it, and no other sweep's does.
            request = (await self.request("set", values=values))["epoch"]
            report(0)
            while True:
                try:
                    msg = await asyncio.wait_for(queue.get(), wait)
                except asyncio.TimeoutError:
                    raise InstrumentError(
                        "timeout", f"no sweep point within {wait} s"
                    ) from None
                if msg is None:
                    raise ConnectionLost(self._closed or "connection closed")
                if msg.get("request") != request:
                    continue
                if msg.get("done"):
                    finished = True
                    return data.SweepResult.from_messages(rows, msg)
                rows.append(msg)
                report(len(rows))
        finally:
            finish()
            if not finished and self._closed is None:
                # Interrupted, timed out or cancelled: the sweep is this call's, so it
                # ends with it (the daemon restores the swept node).
                try:
                    await asyncio.shield(self.request("set", path="/sweeper/enable", value=False))
                except (InstrumentError, ConnectionLost, asyncio.CancelledError):
                    pass
            await self._unsubscribe("sweep", queue)

    async def wait_until(self, t: float, *, timeout: float | None = None) -> float:
        """Waits until the instrument has processed its signal up to simulated time ``t``
        (s), e.g. a ``set``'s return value plus a settling time; returns the time reached.
        ``timeout`` (s, default: the client's) bounds the wait for each status message."""
        # The demodulators' frames (1 kHz) say it soonest; status (2 Hz) also while none
        # is enabled.
        queue: asyncio.Queue[dict[str, Any] | None] = asyncio.Queue()
        wait = self.timeout if timeout is None else timeout
        subscribed = []
        try:
            for stream in ("demods", "status"):
                await self._subscribe(stream, queue)
                subscribed.append(stream)
            while True:
                try:
                    msg = await asyncio.wait_for(queue.get(), wait)
                except asyncio.TimeoutError:
                    raise InstrumentError(
                        "timeout", f"simulated time {t} s not reached: no data within {wait} s"
                    ) from None
                if msg is None:
                    raise ConnectionLost(self._closed or "connection closed")
                if msg["t"] >= t:
                    return float(msg["t"])
        finally:
            for stream in subscribed:
                await self._unsubscribe(stream, queue)

    async def record(
        self,
        file: str | os.PathLike[str],
        streams: Iterable[str] = ("demods",),
        seconds: float = 1.0,
    ) -> dict[str, int]:
        """Records ``streams`` for ``seconds`` of simulated time into the HDF5 ``file``
        (needs ``pip install ftafm[hdf5]``); returns the messages recorded per stream. See
        :mod:`ftafm.record` for the layout."""
        from .record import record

        return await record(self, file, list(streams), seconds)


def _progress(
    progress: bool | Progress | None, total: int, path: str
) -> tuple[Callable[[int], None], Callable[[], None]]:
    """A sweep's ``report(done)`` and ``finish()`` for its ``progress`` argument."""
    if progress is None or progress is False:
        return (lambda done: None), (lambda: None)
    if progress is True:
        try:
            from tqdm.auto import tqdm  # type: ignore[import-untyped]
        except ImportError as e:
            raise ImportError("progress=True shows a tqdm bar: pip install tqdm") from e
        bar = tqdm(total=total, desc=f"sweep {path}", unit="point")

        def advance(done: int) -> None:
            bar.update(done - bar.n)

        return advance, bar.close
    callback = progress
    return (lambda done: callback(done, total)), (lambda: None)


async def connect(url: str | None = None, *, timeout: float = 10.0) -> Instrument:
    """An open :class:`Instrument` (close it with ``await inst.close()``)."""
    return await Instrument(url, timeout=timeout).connect()
