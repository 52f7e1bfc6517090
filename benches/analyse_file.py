"""`ftafm analyse` on a long int16 recording: speed against real time, and peak memory.

    python3 benches/analyse_file.py [--seconds S] [--rate HZ] [--dir DIR] [--keep] [-- FLAGS…]

Writes S seconds (default 600: 12 GB at 10 MS/s) of int16 codes of three tones of a 100 kHz
drive plus Gaussian noise to DIR/analyse-bench.npy (a buffer of whole drive periods written
again and again, so writing it is bound by the disk, not by numpy), then runs
``$FTAFM_BIN analyse`` on it under ``/usr/bin/time -v`` with ``[inversion] averaging = 10``
(FLAGS after ``--`` go before ``analyse``, e.g. ``-- --config other.toml``), and prints the
analysis's speed and the process's peak resident memory. The file is deleted afterwards
unless ``--keep``. Needs numpy and about S × rate × 2 bytes of free disk.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile

import numpy as np


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--rate", type=float, default=10e6)
    ap.add_argument("--dir", default=tempfile.gettempdir())
    ap.add_argument("--keep", action="store_true")
    ap.add_argument("flags", nargs="*")
    args = ap.parse_args()
    exe = os.environ.get("FTAFM_BIN") or shutil.which("ftafm") or "target/release/ftafm"
    rate, f = args.rate, 1e5
    period = rate / f
    if abs(period - round(period)) > 1e-9:
        raise SystemExit(f"{rate} Hz is not a whole number of samples per 100 kHz period")
    p = int(round(period))
    n_buf = (1 << 20) // p * p
    n = int(args.seconds * rate) // n_buf * n_buf
    rng = np.random.default_rng(1)
    theta = 2 * np.pi * f / rate * np.arange(n_buf)
    x = 12000 * np.cos(theta + 0.3) + 300 * np.cos(2 * theta - 1) + 60 * np.cos(17 * theta + 0.5)
    buf = np.round(x + rng.normal(0, 30, n_buf)).astype("<i2")
    path = os.path.join(args.dir, "analyse-bench.npy")
    out_dir = os.path.join(args.dir, "analyse-bench-out")
    conf = os.path.join(args.dir, "analyse-bench.toml")
    with open(conf, "w") as c:
        c.write("[inversion]\naveraging = 10\n")
    m = np.lib.format.open_memmap(path, mode="w+", dtype="<i2", shape=(n,))
    for s in range(0, n, n_buf):
        m[s : s + n_buf] = buf
    m.flush()
    del m
    cmd = ["/usr/bin/time", "-v", exe, "--config", conf, *args.flags, "analyse", path,
           "--sample-rate", str(rate), "--drive-frequency", str(f), "--invols", "1e-12",
           "--out", out_dir]
    try:
        run = subprocess.run(cmd, capture_output=True, text=True)
    finally:
        if not args.keep:
            os.remove(path)
        shutil.rmtree(out_dir, ignore_errors=True)
        os.remove(conf)
    if run.returncode != 0:
        print(run.stdout, run.stderr, sep="\n", file=sys.stderr)
        return run.returncode
    speed = re.search(r"^speed: .*$", run.stdout, re.M)
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", run.stderr)
    cpu = re.search(r"Percent of CPU this job got: (\d+)%", run.stderr)
    print(f"file: {n} int16 samples ({n / rate:.1f} s at {rate:g} Hz, {2 * n / 1e9:.1f} GB)")
    print(speed.group(0) if speed else run.stdout)
    if rss:
        print(f"peak resident memory: {int(rss.group(1)) / 1024:.1f} MB")
    if cpu:
        print(f"CPU: {cpu.group(1)} % of one core")
    return 0


if __name__ == "__main__":
    sys.exit(main())
