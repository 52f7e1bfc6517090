"""The synchronous client: ``with ftafm.Instrument(url) as inst: inst.set(...)``.

Each method runs the coroutine of the same name of :class:`ftafm.aio.Instrument` on a
private event loop in a background thread, so it works in scripts, notebooks (whose own
loop it leaves alone) and QCoDeS alike. Beside the methods, the node tree is there as
attributes (``inst.sample.youngs_modulus(116.1e9)``, :mod:`ftafm.tree`), and
``with inst.set_transaction():`` batches sets into one ``set_many``.
"""

from __future__ import annotations

import asyncio
import os
import threading
from contextlib import contextmanager
from typing import Any, Coroutine, Iterable, Iterator, Mapping, Sequence, TypeVar

from . import aio, data, tree
from .pids import AdviceKind, PidAdvice, PidStatus, Pids

T = TypeVar("T")


class Instrument:
    """A connection to an ftafm daemon.

    ``url`` is its WebSocket endpoint (default ``ws://127.0.0.1:8700/ws``, or the
    ``FTAFM_URL`` environment variable); ``timeout`` bounds each request's wait for its
    reply, in seconds. Use it as a context manager, or call :meth:`close`.
    """

    def __init__(self, url: str | None = None, *, timeout: float = 10.0):
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(
            target=self._loop.run_forever, name="ftafm-client", daemon=True
        )
        self._thread.start()
        self._async = aio.Instrument(url, timeout=timeout)
        self._tree: tree.NodeBranch | None = None
        try:
            self._run(self._async.connect())
        except BaseException:
            self._stop_loop()
            raise

    def _run(self, coro: Coroutine[Any, Any, T]) -> T:
        future = asyncio.run_coroutine_threadsafe(coro, self._loop)
        try:
            return future.result()
        except BaseException:
            # Ctrl-C (or any exception) in the caller's thread: cancel the coroutine too, so
            # its clean-up runs (a sweep is aborted) instead of it running on unseen.
            future.cancel()
            raise

    def _stop_loop(self) -> None:
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join()
        self._loop.close()

    @property
    def url(self) -> str:
        """The daemon's WebSocket endpoint."""
        return self._async.url

    @property
    def epoch(self) -> int:
        """The settings epoch of this client's last change (see
        :attr:`ftafm.aio.Instrument.epoch`)."""
        return self._async.epoch

    @property
    def hello(self) -> dict[str, Any]:
        """The daemon's ``hello``: server, version, protocol, sample_rate (Hz)."""
        return self._async.hello

    def close(self) -> None:
        """Closes the connection."""
        if self._loop.is_closed():
            return
        try:
            self._run(self._async.close())
        finally:
            self._stop_loop()

    def __enter__(self) -> "Instrument":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def info(self) -> dict[str, Any]:
        """Server, version, protocol, sample rate (Hz), warnings and real-time factor."""
        return self._run(self._async.info())

    def nodes(self, path: str | None = None) -> list[aio.Node]:
        """Every node (or those under ``path``) with value, unit, type and range."""
        return self._run(self._async.nodes(path))

    def get(self, path: str) -> Any:
        """The value of the node at ``path`` (or a measured value: ``/demods/N/sample``)."""
        return self._run(self._async.get(path))

    def get_many(self, paths: Sequence[str]) -> dict[str, Any]:
        """The values at ``paths`` in one request, from one version of the settings: path →
        value (``None`` for a measured value that does not exist now)."""
        return self._run(self._async.get_many(paths))

    def set(self, path: str, value: Any) -> float | None:
        """Sets one node; returns the simulated time (s) at which it took effect. Inside
        :meth:`set_transaction`, queues it instead and returns ``None``."""
        return self._run(self._async.set(path, value))

    def set_many(self, values: Mapping[str, Any]) -> float | None:
        """Sets several nodes together at one sample boundary, all or nothing; returns the
        simulated time (s) at which they took effect. Inside :meth:`set_transaction`,
        queues them instead and returns ``None``."""
        return self._run(self._async.set_many(values))

    @contextmanager
    def set_transaction(self) -> Iterator[tree.Transaction]:
        """Batches every ``set`` (and node-tree set) inside the ``with`` into one
        ``set_many`` at its end: one change at one sample boundary, all or nothing (as
        zhinst-toolkit's ``set_transaction``). Nothing is sent if the block raises. The
        transaction's ``t`` is the simulated time the change took effect. The asyncio
        client's transaction, so sets through either queue in it."""
        with self._async._batch.opened() as transaction:
            yield transaction
        if transaction.values:
            transaction.t = self._run(self._async.set_many(transaction.values))

    @property
    def root(self) -> tree.NodeBranch:
        """The node tree (built from ``list`` on first use): ``inst.root.sample`` is
        ``inst.sample``; see :mod:`ftafm.tree`."""
        if self._tree is None:
            # The list the asyncio client read on connect: no second request.
            self._tree = tree.build(self, self._async.node_list)
        return self._tree

    def __getattr__(self, name: str) -> Any:
        # Only names that are not methods come here: the node tree's top-level branches.
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.root, name)

    def __dir__(self) -> list[str]:
        names = set(super().__dir__())
        if self._tree is not None:
            names.update(self._tree.__dir__())
        return sorted(names)

    @property
    def sample(self) -> tree.SampleBranch:
        """Called, ``sample(demod=0)`` is the newest output of demodulator ``demod`` (t,
        harmonic, x, y, r, phase); as a branch, the ``/sample`` nodes
        (``inst.sample.youngs_modulus()``)."""
        return tree.SampleBranch(
            lambda demod: self._run(self._async.read_sample(demod)), lambda: self.root
        )

    @property
    def pids(self) -> Pids:
        """The PID units ``/pids/0`` … ``/pids/3``: ``inst.pids[0].configure(...)``,
        ``.enable()``, ``.disable()``, ``.status()``, ``.wait(...)``
        (:mod:`ftafm.pids`); their nodes as on the node tree (``inst.pids[0].p()``)."""
        return Pids(self)

    def pid_status(self, *, timeout: float | None = None) -> list[PidStatus]:
        """Every PID unit in the next ``status`` message: settings in force and latest
        update (:class:`ftafm.pids.PidStatus`, ``latest`` a
        :class:`ftafm.pids.PidUpdate` or ``None`` before the first)."""
        return self._run(self._async.pid_status(timeout=timeout))

    def pid_held(self, *, timeout: float | None = None) -> list[str]:
        """The outputs a PID unit holds away from their nodes in the next ``status``
        message (``["drive_frequency"]`` while a PLL runs; see
        :meth:`ftafm.aio.Instrument.pid_held`)."""
        return self._run(self._async.pid_held(timeout=timeout))

    def pid_advise(
        self, unit: int, bandwidth: float, *, kind: AdviceKind = "pi"
    ) -> PidAdvice:
        """Gains for PID unit ``unit`` from the closed loop's target −3 dB ``bandwidth``
        (Hz), a PI or (``kind="pid"``) a PID, and the loop they predict
        (:class:`ftafm.pids.PidAdvice`): the daemon's PID advisor at the settings in
        force. Nothing is set: ``inst.pids[unit].configure(**advice.gains)`` sets them.
        Refusals raise :class:`ftafm.InstrumentError` naming the field (see
        :meth:`ftafm.aio.Instrument.pid_advise`)."""
        return self._run(self._async.pid_advise(unit, bandwidth, kind=kind))

    def wait_until(self, t: float, *, timeout: float | None = None) -> float:
        """Waits until the signal is processed up to simulated time ``t`` (s)."""
        return self._run(self._async.wait_until(t, timeout=timeout))

    def poll(self, stream: str, seconds: float, *, timeout: float | None = None) -> data.StreamData:
        """``stream``'s messages over ``seconds`` of simulated time, as numpy arrays."""
        return self._run(self._async.poll(stream, seconds, timeout=timeout))

    def sweep(
        self,
        path: str,
        start: float,
        stop: float,
        points: int = 121,
        **options: Any,
    ) -> data.SweepResult:
        """Sweeps ``path`` from ``start`` to ``stop`` with the daemon's sweeper and returns
        every point (options: ``scale`` ``"linear"``, ``direction`` ``"up"``, ``settling``
        0 (automatic), ``averaging`` 4 unless given, whatever an earlier sweep left;
        ``timeout``; ``progress`` ``True`` for a tqdm bar or ``progress(done, total)``; see
        :meth:`ftafm.aio.Instrument.sweep`)."""
        return self._run(self._async.sweep(path, start, stop, points, **options))

    def next(self, stream: str, *, timeout: float | None = None) -> dict[str, Any]:
        """The next message of ``stream``, as the daemon sent it; ``timeout`` (s, default:
        the client's) bounds the wait."""
        return self._run(self._async.next(stream, timeout=timeout))

    def record(
        self,
        file: str | os.PathLike[str],
        streams: Iterable[str] = ("demods",),
        seconds: float = 1.0,
    ) -> dict[str, int]:
        """Records ``streams`` for ``seconds`` of simulated time to HDF5 ``file``."""
        return self._run(self._async.record(file, streams, seconds))

    def stream_samples(
        self,
        samples: Any,
        sample_rate: float | None = None,
        *,
        scale: float = 1.0,
        first_index: int = 0,
        frame_samples: int = 1 << 18,
        window: int = 4,
        realtime: bool = False,
    ) -> aio.StreamReceipt:
        """Streams ``samples`` into the chain while ``/source/kind`` is ``"stream"``
        (:meth:`ftafm.aio.Instrument.stream_samples`)."""
        return self._run(
            self._async.stream_samples(
                samples,
                sample_rate,
                scale=scale,
                first_index=first_index,
                frame_samples=frame_samples,
                window=window,
                realtime=realtime,
            )
        )

    def presets(self) -> list[dict[str, str]]:
        """The presets: name, kind, summary."""
        return self._run(self._async.presets())

    def preset(self, name: str) -> float | None:
        """Loads a preset; returns the simulated time (s) it took effect."""
        return self._run(self._async.preset(name))

    def settings_toml(self) -> str:
        """The running settings as a config file (TOML)."""
        return self._run(self._async.settings_toml())

    def save_settings(self, file: str | os.PathLike[str]) -> None:
        """Writes the running settings to ``file`` (``ftafm --config`` accepts it)."""
        self._run(self._async.save_settings(file))

    def load_settings(self, file: str | os.PathLike[str]) -> float | None:
        """Lays the config in ``file`` over the running settings as one change."""
        return self._run(self._async.load_settings(file))
