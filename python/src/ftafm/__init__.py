"""ftafm: the Python client of the ftafm virtual FT-AFM instrument.

>>> import ftafm
>>> with ftafm.Instrument("ws://127.0.0.1:8700/ws") as inst:   # doctest: +SKIP
...     t = inst.set("/surface/distance", 15e-9)
...     inst.wait_until(t + 0.05)
...     print(inst.sample(0)["r"])

- :class:`Instrument` (synchronous) and :mod:`ftafm.aio` (asyncio): get, get_many, set,
  set_many, sample, poll, sweep, wait_until, record (HDF5), save_settings, load_settings,
  presets, stream_samples (a real signal into the chain); the synchronous one also the node tree as attributes
  (``inst.sample.youngs_modulus(116.1e9)``, :mod:`ftafm.tree`) and ``set_transaction``.
- :mod:`ftafm.data`: stream messages as numpy arrays.
- :mod:`ftafm.fm`: FM-AFM offline: the Sader–Jarvis inversion of a Δf(z) curve to the force
  (``fm.invert``, ``ftafm fm-invert``'s numbers) and the forward model (``fm.frequency_shift``).
- :mod:`ftafm.pids`: the live PID units (``inst.pids[0].configure(...)``, ``pid_status()``)
  and the daemon's PID advisor (``inst.pids[0].advise(bandwidth)``, ``pid_advise``).
- :mod:`ftafm.qcodes`: the QCoDeS driver (``pip install ftafm[qcodes]``).
- :mod:`ftafm.testing`: a daemon on port 0 for test suites, and pytest fixtures.
"""

from .aio import DEFAULT_URL, Node, StreamReceipt
from .analyse import Analysis, AnalysisError, analyse
from .client import Instrument
from .data import (
    DemodData,
    ForceData,
    ImageData,
    ScopeData,
    SpectrumData,
    StatusData,
    StreamData,
    SweepResult,
)
from .errors import ConnectionLost, InstrumentError, NoDaemon
from . import fm
from .fm import FmError, ForceCurve
from .pids import AsyncPids, AsyncPidUnit, PidAdvice, PidStatus, PidUnit, PidUpdate, Pids

__version__ = "0.1.0"

__all__ = [
    "Analysis",
    "AnalysisError",
    "analyse",
    "AsyncPids",
    "AsyncPidUnit",
    "DEFAULT_URL",
    "ConnectionLost",
    "DemodData",
    "fm",
    "FmError",
    "ForceCurve",
    "ForceData",
    "ImageData",
    "Instrument",
    "InstrumentError",
    "NoDaemon",
    "Node",
    "PidAdvice",
    "PidStatus",
    "PidUnit",
    "PidUpdate",
    "Pids",
    "ScopeData",
    "SpectrumData",
    "StreamReceipt",
    "StatusData",
    "StreamData",
    "SweepResult",
    "__version__",
]
