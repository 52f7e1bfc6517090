"""A streamed source fed from a second process in real time: how much the daemon lost.

    python3 benches/stream_feed.py [--seconds S] [--url ws://HOST:PORT/ws] [--json]

Connects to a running daemon (``--url``; default: starts ``$FTAFM_BIN serve`` on port 0
with its defaults), sets ``/source/kind`` to ``"stream"`` and streams int16 codes of three
tones at the daemon's ``/synth/sample_rate`` (10 MS/s at the defaults: 20 MB/s over
loopback), paced by the wall clock as a digitiser delivers them, for S seconds (default 60;
the goal's run is 600). Then it reports what the daemon took, dropped and skipped (its
replies and ``status``'s counters), the chain's overruns, the demodulator latency
percentiles, and each tone's amplitude as the lock-in read it against the one sent.
Exit status 1 on any loss. Needs the Python package (``pip install ./python``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

import ftafm
from ftafm.testing import Daemon


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--url")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()

    daemon = None if args.url else Daemon()
    url = args.url or daemon.url  # type: ignore[union-attr]
    try:
        with ftafm.Instrument(url, timeout=30.0) as inst:
            return run(inst, args.seconds, args.json)
    finally:
        if daemon is not None:
            daemon.stop()


def run(inst: ftafm.Instrument, seconds: float, as_json: bool) -> int:
    rate = float(inst.hello["sample_rate"])
    f = float(inst.get("/drive/frequency"))
    inst.set("/source/kind", "stream")
    scale = 1e-12  # m per code
    tones = [(1, 12000.0, 0.3), (2, 3000.0, -1.0), (17, 400.0, 2.0)]
    # One buffer of whole drive periods (at a drive that is a whole number of samples a
    # period, as at the defaults), sent again and again: the tones stay continuous.
    period = rate / f
    periods = max(1, int(round((1 << 18) / period)))
    n = int(round(periods * period))
    if abs(n - periods * period) > 1e-6:
        raise SystemExit(f"the drive period {period} samples is not whole: pick another drive")
    theta = 2 * np.pi * f / rate * np.arange(n)
    buf = np.round(sum(a * np.cos(k * theta + p) for k, a, p in tones)).astype(np.int16)

    total = int(seconds * rate) // n * n
    start = time.monotonic()
    got = ftafm.StreamReceipt()
    for first in range(0, total, n):
        due = start + first / rate
        wait = due - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        r = inst.stream_samples(buf, scale=scale, first_index=first, frame_samples=n, window=1)
        got.frames += r.frames
        got.accepted += r.accepted
        got.dropped += r.dropped
        got.gap += r.gap
    wall = time.monotonic() - start
    # Until the chain has taken it all (an event), then the counters and the tones.
    for _ in range(60):
        status = inst.next("status")
        c = status["counters"]
        if status["stream_fill"] == 0 and c["samples_processed"] == c["samples_synthesized"]:
            break
    read = {}
    for demod, (k, a, _) in enumerate([t for t in tones if t[0] <= 2]):
        s = inst.sample(demod)
        read[f"H{k}"] = s["r"] / (a * scale) - 1
    c = status["counters"]
    report = {
        "machine_cpus": __import__("os").cpu_count(),
        "seconds_streamed": total / rate,
        "wall_seconds": wall,
        "sample_rate": rate,
        "frames": got.frames,
        "accepted": got.accepted,
        "dropped": got.dropped,
        "gap": got.gap,
        "overrun_samples": c["overrun_samples"],
        "late_blocks": c["late_blocks"],
        "stream_dropped_samples": c["stream_dropped_samples"],
        "stream_gap_samples": c["stream_gap_samples"],
        "discontinuities": c["discontinuities"],
        "latency_synth_to_dsp": status["latency_synth_to_dsp"],
        "amplitude_error": read,
    }
    inst.set("/source/kind", "synth")
    if as_json:
        print(json.dumps(report))
    else:
        for key, value in report.items():
            print(f"{key}: {value}")
    lost = got.dropped + got.gap + c["overrun_samples"] + c["stream_dropped_samples"]
    return 1 if lost else 0


if __name__ == "__main__":
    sys.exit(main())
