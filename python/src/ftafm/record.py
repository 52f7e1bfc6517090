"""Recording streams to HDF5 (``pip install ftafm[hdf5]``).

Layout, readable with h5py alone (and into pandas with ``pd.DataFrame``), following the
NeXus conventions so that h5web, silx and other NeXus viewers plot it without code:

- root attributes: ``NX_class`` ``NXroot``, ``default`` (the first stream recorded),
  ``ftafm_version``, ``protocol``, ``sample_rate`` (Hz), ``created`` (UTC, ISO 8601),
  ``url``, ``settings`` (the running settings as a config file, TOML, taken when the
  recording started: ``ftafm --config`` accepts it) and ``seconds``.
- one group per stream (``/demods``, ``/force``, ...) with a dataset per array of
  :mod:`ftafm.data` (``t``, ``seq``, ``t_synth_ns``, then the stream's own: ``x``, ``y``,
  ``r``, ``phase``, ``harmonic`` as frames × 32 demodulators; ``magnitudes`` as spectra ×
  bins and ``frequency`` once, the bins' centres; ...), each with its SI ``units``
  attribute; image channels under ``channels/``.
- each stream group is an ``NXdata`` (``NX_class``) whose ``signal`` attribute names the
  dataset to plot (:data:`SIGNALS`: ``r`` for demods, ``magnitudes`` for the spectrum,
  ...), ``axes`` the dataset along each of its dimensions (``t``, ``frequency``, or ``.``
  for a plain index such as the demodulator number) and ``auxiliary_signals`` the others
  of the same shape; an image's ``channels`` group is the ``NXdata`` (its lines × pixels).
- each group's attributes: ``messages`` recorded, ``gaps`` (messages the daemon dropped for
  this client in between, from ``seq``), ``skipped`` (messages whose shape changed mid-way,
  e.g. a new ``/spectrum/size``: not stored, counted), and for status the whole messages
  as JSON text in the ``messages_json`` dataset.

Data is appended as it arrives (every 0.25 s of wall time), so a long recording does not
grow in memory.
"""

from __future__ import annotations

import asyncio
import datetime as _dt
import json
import os
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from . import data

if TYPE_CHECKING:
    from .aio import Instrument

_FLUSH_EVERY = 0.25

#: What NeXus viewers plot of each stream: its ``signal`` dataset, the ``axes`` along each
#: of its dimensions and the ``auxiliary_signals`` shown with it.
SIGNALS: dict[str, tuple[str, list[str], list[str]]] = {
    "demods": ("r", ["t", "."], ["x", "y", "phase"]),
    "spectrum": ("magnitudes", ["t", "frequency"], []),
    "scope": ("samples", ["t", "."], []),
    "force": ("max_force", ["t"], ["contact_time_ratio", "youngs_modulus", "pulse_phase"]),
    "status": ("realtime_factor", ["t"], ["ring_fill", "messages_dropped"]),
}

#: Arrays the same in every message (an axis, not a row per message): written once.
_ONCE = {"spectrum": {"frequency"}}


class _StreamWriter:
    def __init__(self, h5: Any, stream: str):
        self.group = h5.create_group(stream)
        self.stream = stream
        self.rows: list[dict[str, Any]] = []
        self.count = 0
        self.skipped = 0
        self.last_seq: int | None = None
        self.gaps = 0

    def add(self, msg: dict[str, Any]) -> None:
        self.rows.append(msg)

    def flush(self) -> None:
        if not self.rows:
            return
        rows, self.rows = self.rows, []
        batch = data.from_messages(self.stream, rows)
        if self.last_seq is not None and len(batch.seq):
            step = int(batch.seq[0]) - self.last_seq
            self.gaps += max(step - 1, 0)
        self.gaps += batch.gaps
        if len(batch.seq):
            self.last_seq = int(batch.seq[-1])
        arrays = batch.arrays()
        for name in _ONCE.get(self.stream, ()):
            axis = arrays.pop(name)
            if name not in self.group:
                self.group.create_dataset(name, data=axis)
                self.group[name].attrs["units"] = data.unit(self.stream, name)
        keep = np.ones(len(batch), dtype=bool)
        # A row whose width differs from what the file holds (a new spectrum size, scope
        # length or raster) cannot be appended: skip it, counted.
        for name, arr in arrays.items():
            if arr.ndim == 2 and name in self.group:
                width = self.group[name].shape[1]
                if arr.shape[1] != width:
                    keep &= False
        if not keep.any():
            self.skipped += len(batch)
            return
        for name, arr in arrays.items():
            if arr.dtype.kind == "f":
                arr = arr.astype(np.float64)
            if name not in self.group:
                self.group.create_dataset(
                    name,
                    data=arr,
                    maxshape=(None, *arr.shape[1:]),
                    chunks=True,
                )
                leaf = name.split("/")[-1]
                unit = (
                    batch.units.get(leaf, "")
                    if isinstance(batch, data.ImageData) and name.startswith("channels/")
                    else data.unit(self.stream, leaf)
                )
                self.group[name].attrs["units"] = unit
            else:
                ds = self.group[name]
                n = ds.shape[0]
                ds.resize(n + arr.shape[0], axis=0)
                ds[n:] = arr
        if isinstance(batch, data.StatusData):
            text = np.array([json.dumps(m) for m in batch.messages], dtype=object)
            import h5py  # type: ignore[import-untyped]

            if "messages_json" not in self.group:
                self.group.create_dataset(
                    "messages_json",
                    data=text,
                    maxshape=(None,),
                    chunks=True,
                    dtype=h5py.string_dtype(),
                )
            else:
                ds = self.group["messages_json"]
                n = ds.shape[0]
                ds.resize(n + len(text), axis=0)
                ds[n:] = text
        self.count += len(batch)

    def close(self) -> None:
        self.flush()
        self.group.attrs["messages"] = self.count
        self.group.attrs["gaps"] = self.gaps
        self.group.attrs["skipped"] = self.skipped
        self.describe()

    def describe(self) -> None:
        """The NeXus attributes: what a viewer plots (only of datasets the file holds)."""
        if self.stream in SIGNALS and SIGNALS[self.stream][0] in self.group:
            signal, axes, auxiliary = SIGNALS[self.stream]
            _nxdata(self.group, signal, axes, [a for a in auxiliary if a in self.group])
        elif self.stream == "image" and "channels" in self.group:
            self.group.attrs["NX_class"] = "NXcollection"
            self.group.attrs["default"] = "channels"
            channels = sorted(self.group["channels"])
            _nxdata(self.group["channels"], channels[0], [".", "."], channels[1:])
        else:
            self.group.attrs["NX_class"] = "NXcollection"

    @property
    def plottable(self) -> bool:
        """Whether :meth:`describe` made this stream's group (or its channels) an NXdata."""
        return (
            self.stream in SIGNALS and SIGNALS[self.stream][0] in self.group
        ) or (self.stream == "image" and "channels" in self.group)


def _nxdata(group: Any, signal: str, axes: list[str], auxiliary: list[str]) -> None:
    group.attrs["NX_class"] = "NXdata"
    group.attrs["signal"] = signal
    group.attrs["axes"] = axes
    if auxiliary:
        group.attrs["auxiliary_signals"] = auxiliary


async def record(
    inst: "Instrument",
    file: str | os.PathLike[str],
    streams: list[str],
    seconds: float,
) -> dict[str, int]:
    """Records ``streams`` over ``seconds`` of simulated time into ``file`` (see the module
    documentation); returns the messages recorded per stream."""
    try:
        import h5py
    except ImportError as e:  # pragma: no cover - depends on the extra
        raise ImportError("recording needs h5py: pip install 'ftafm[hdf5]'") from e
    for s in streams:
        if s not in data.STREAMS:
            raise ValueError(f"unknown stream {s!r}; streams: {', '.join(data.STREAMS)}")
    if not streams:
        raise ValueError("give at least one stream to record")
    settings = await inst.settings_toml()
    queue: asyncio.Queue[dict[str, Any] | None] = asyncio.Queue()
    with h5py.File(file, "w") as h5:
        h5.attrs["NX_class"] = "NXroot"
        h5.attrs["ftafm_version"] = str(inst.hello.get("version", ""))
        h5.attrs["protocol"] = int(inst.hello.get("protocol", 0))
        h5.attrs["sample_rate"] = float(inst.hello.get("sample_rate", 0.0))
        h5.attrs["created"] = _dt.datetime.now(_dt.timezone.utc).isoformat()
        h5.attrs["url"] = inst.url
        h5.attrs["settings"] = settings
        h5.attrs["seconds"] = float(seconds)
        writers = {s: _StreamWriter(h5, s) for s in streams}
        subscribed: list[str] = []
        try:
            for s in streams:
                await inst._subscribe(s, queue)
                subscribed.append(s)
            start: float | None = None
            last_flush = time.monotonic()
            while True:
                try:
                    msg = await asyncio.wait_for(queue.get(), inst.timeout)
                except asyncio.TimeoutError:
                    from .errors import InstrumentError

                    raise InstrumentError(
                        "timeout", f"no data from {', '.join(streams)} within {inst.timeout} s"
                    ) from None
                if msg is None:
                    from .errors import ConnectionLost

                    raise ConnectionLost("the connection closed during the recording")
                if start is None:
                    start = msg["t"]
                if msg["t"] >= start + seconds:
                    break
                writers[msg["stream"]].add(msg)
                if time.monotonic() - last_flush > _FLUSH_EVERY:
                    for w in writers.values():
                        w.flush()
                    last_flush = time.monotonic()
        finally:
            for s in subscribed:
                await inst._unsubscribe(s, queue)
            for w in writers.values():
                w.close()
            shown = [s for s, w in writers.items() if w.plottable]
            if shown:
                h5.attrs["default"] = shown[0]
        return {s: w.count for s, w in writers.items()}
