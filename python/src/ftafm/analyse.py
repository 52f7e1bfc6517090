"""Offline analysis of a recorded photodiode signal: ``ftafm analyse`` from Python.

:func:`analyse` runs the ``ftafm`` binary (``$FTAFM_BIN``, else ``ftafm`` on the PATH) on a
numpy array, a file, or an h5py dataset (streamed to the binary's standard input in
pieces, never loaded whole), and returns an :class:`Analysis` with every demodulator's
x/y/r/phase against time, the spectra and the force estimates with their standard
deviations as numpy arrays. :meth:`Analysis.save_hdf5` writes them in the recordings'
layout (:mod:`ftafm.record`).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: Element types the binary reads from .npy files; others are converted to float64.
_NPY_TYPES = {np.dtype("<i2"), np.dtype("<i4"), np.dtype("<f4"), np.dtype("<f8")}
#: Sample times per piece streamed from an h5py dataset.
_PIECE = 1 << 18


class AnalysisError(RuntimeError):
    """``ftafm analyse`` refused the input or failed; the message is its own sentence."""


@dataclass
class Analysis:
    """What ``ftafm analyse`` produced.

    ``demods``: a structured array, one row per demodulator frame: ``sample_index``,
    ``t`` (s), and ``x``, ``y``, ``r`` (m), ``phase`` (rad), ``harmonic`` as frames ×
    demodulators (NaN where a demodulator gave no output in that frame).
    ``spectrum``: ``sample_index``, ``t`` (s), ``magnitudes`` (m, peak) per spectrum.
    ``force``: ``t`` (s), ``max_force`` (N), ``youngs_modulus`` (Pa),
    ``contact_time_ratio`` and each one's ``*_sigma``, ``pulse_phase`` (rad),
    ``waveform`` (N over one period); ``None`` without estimates.
    ``summary``: the binary's summary (sample rate, reference, scale, speed, ...).
    """

    demods: np.ndarray
    spectrum: np.ndarray | None
    force: np.ndarray | None
    summary: dict[str, Any]

    @property
    def frequency(self) -> np.ndarray:
        """The spectrum bins' centres (Hz)."""
        bins = 0 if self.spectrum is None else self.spectrum["magnitudes"].shape[1]
        return np.arange(bins) * float(self.summary["bin_width"])

    def save_hdf5(self, path: str | os.PathLike[str]) -> None:
        """Writes the outputs as HDF5 in the layout of :mod:`ftafm.record` (NeXus
        ``NXdata`` groups ``demods``, ``spectrum``, ``force`` with SI ``units``)."""
        import h5py  # type: ignore[import-untyped]  # the hdf5 extra

        units = {
            "t": "s",
            "x": "m",
            "y": "m",
            "r": "m",
            "phase": "rad",
            "magnitudes": "m",
            "frequency": "Hz",
            "max_force": "N",
            "max_force_sigma": "N",
            "youngs_modulus": "Pa",
            "youngs_modulus_sigma": "Pa",
            "pulse_phase": "rad",
            "waveform": "N",
        }
        with h5py.File(path, "w") as f:
            f.attrs["NX_class"] = "NXroot"
            f.attrs["default"] = "demods"
            f.attrs["sample_rate"] = float(self.summary["sample_rate"])
            f.attrs["seconds"] = float(self.summary["seconds"])
            f.attrs["source"] = str(self.summary["file"])
            f.attrs["analysis"] = json.dumps(self.summary)
            groups: list[tuple[str, np.ndarray | None, str, list[str], list[str]]] = [
                ("demods", self.demods, "r", ["t", "."], ["x", "y", "phase"]),
                ("spectrum", self.spectrum, "magnitudes", ["t", "frequency"], []),
                (
                    "force",
                    self.force,
                    "max_force",
                    ["t"],
                    ["contact_time_ratio", "youngs_modulus", "pulse_phase"],
                ),
            ]
            for name, arr, signal, axes, aux in groups:
                if arr is None:
                    continue
                g = f.create_group(name)
                g.attrs["NX_class"] = "NXdata"
                g.attrs["signal"] = signal
                g.attrs["axes"] = axes
                g.attrs["auxiliary_signals"] = aux
                g.attrs["messages"] = len(arr)
                for field in arr.dtype.names or ():
                    d = g.create_dataset(field, data=arr[field])
                    d.attrs["units"] = units.get(field, "")
                if name == "spectrum":
                    d = g.create_dataset("frequency", data=self.frequency)
                    d.attrs["units"] = "Hz"


def _binary(binary: str | None) -> str:
    exe = binary or os.environ.get("FTAFM_BIN") or shutil.which("ftafm")
    if not exe:
        raise AnalysisError(
            "no ftafm binary: set FTAFM_BIN or put ftafm on the PATH (cargo install --path .)"
        )
    return exe


def _load(path: Path) -> np.ndarray | None:
    return np.load(path) if path.exists() else None


def analyse(
    data: Any,
    sample_rate: float | None = None,
    *,
    invols: float | None = None,
    units: str | None = None,
    drive_frequency: float | None = None,
    reference_channel: int | None = None,
    drive2_frequency: float | None = None,
    reference2_channel: int | None = None,
    signal_channel: int = 0,
    preset: Sequence[str] = (),
    config: str | os.PathLike[str] | None = None,
    binary: str | None = None,
    timeout: float | None = None,
) -> Analysis:
    """Runs ``ftafm analyse`` on ``data`` and returns its outputs.

    ``data``: a numpy array (1-D, or samples × channels), a path to a .npy, .wav or raw
    file, or an h5py dataset (1-D or samples × channels; streamed as float32 to the
    binary's standard input). ``sample_rate`` (Hz) is needed unless the file has one (a
    WAV, or a ``record-signal`` file). The scale to metres: ``invols`` (m/V) or
    ``units="m"``. The reference: ``reference_channel`` (a channel holding the
    excitation) or ``drive_frequency`` (Hz, refined from the signal); the demodulators on
    ``drive2``'s: ``reference2_channel`` or ``drive2_frequency`` alike. ``preset`` and
    ``config`` give the lever and the lock-in bank, as for every ``ftafm`` command.
    Raises :class:`AnalysisError` with the binary's message when it refuses the input.
    """
    exe = _binary(binary)
    with tempfile.TemporaryDirectory(prefix="ftafm-analyse-") as tmp:
        tmpdir = Path(tmp)
        out = tmpdir / "out"
        stdin_source = None
        extra: list[str] = []
        if isinstance(data, (str, os.PathLike)):
            file = str(data)
        elif hasattr(data, "id") and hasattr(data, "shape") and hasattr(data, "dtype"):
            # An h5py dataset: streamed in pieces.
            if data.ndim not in (1, 2):
                raise AnalysisError(f"dataset {data.name}: {data.ndim}-D, not 1-D or 2-D")
            file = "-"
            channels = 1 if data.ndim == 1 else int(data.shape[1])
            extra += ["--format", "raw-f32", "--channels", str(channels)]
            stdin_source = data
        else:
            arr = np.asarray(data)
            if arr.ndim not in (1, 2):
                raise AnalysisError(f"a {arr.ndim}-D array: give 1-D or samples × channels")
            if arr.dtype.newbyteorder("<") not in _NPY_TYPES or arr.dtype.byteorder == ">":
                arr = arr.astype("<f8")
            file = str(tmpdir / "signal.npy")
            np.save(file, np.ascontiguousarray(arr))
        args = [exe, "analyse", file, "--json", "--out", str(out)]
        for p in preset:
            args += ["--preset", p]
        if config is not None:
            args += ["--config", str(config)]
        for flag, value in [
            ("--sample-rate", sample_rate),
            ("--invols", invols),
            ("--units", units),
            ("--drive-frequency", drive_frequency),
            ("--reference-channel", reference_channel),
            ("--drive2-frequency", drive2_frequency),
            ("--reference2-channel", reference2_channel),
        ]:
            if value is not None:
                args += [flag, repr(value) if isinstance(value, float) else str(value)]
        args += ["--signal-channel", str(signal_channel), *extra]
        proc = subprocess.Popen(
            args,
            stdin=subprocess.PIPE if stdin_source is not None else subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        if stdin_source is not None:
            assert proc.stdin is not None
            try:
                for lo in range(0, stdin_source.shape[0], _PIECE):
                    piece = np.asarray(stdin_source[lo : lo + _PIECE], dtype="<f4")
                    proc.stdin.write(piece.tobytes())
            except BrokenPipeError:
                pass  # the binary stopped early: its message says why
            finally:
                proc.stdin.close()
                # Closed: communicate() must not flush it. The binary writes little to
                # stdout and stderr (one JSON object; a message), so it never blocks on
                # them while the samples are written.
                proc.stdin = None
        stdout, stderr = proc.communicate(timeout=timeout)
        if proc.returncode != 0:
            msg = stderr.decode(errors="replace").strip()
            raise AnalysisError(msg or f"ftafm analyse exited with {proc.returncode}")
        summary = json.loads(stdout.decode())
        demods = np.load(out / "demods.npy")
        return Analysis(
            demods=demods,
            spectrum=_load(out / "spectrum.npy"),
            force=_load(out / "force.npy"),
            summary=summary,
        )
