#!/usr/bin/env python3
"""The Rust lock-in bank against a straightforward NumPy/SciPy lock-in, on the same samples.

Runs the Rust half first (benches/lockin_compare.rs, through cargo): it synthesises
photodiode samples with the default configuration (10 MS/s, 5 modes, noise on), writes them
to a file and times the lock-in bank on them (32 demodulators at harmonics 1-32, 4th-order
low-pass, 1 kHz output). Then it times what a user would write in Python on the same
samples: for each harmonic k, mix with exp(-i k theta), low-pass with scipy.signal.lfilter
(the same 4th-order filter: four identical first-order RC sections, as one transfer
function b/a), take every (sample rate / output rate)-th sample. It times the same with
scipy.signal.sosfilt (the four sections kept apart), checks the amplitudes against the Rust
bank and prints the throughputs, their medians and the ratios.

The plain lfilter version is numerically wrong here: a 4-fold pole at 1 - 2e-4 (tau =
500 us at 10 MS/s) does not survive rounding the expanded polynomial's coefficients, and its
DC gain comes out about 1.2 instead of 1 (all amplitudes 20 % high). sosfilt is exact and
as fast; it is the one checked against the Rust bank.

    pip install numpy scipy
    python3 benches/lockin_numpy.py [--samples N] [--repeats R] [--rust-repeats R] [--json]

Not part of CI. Needs cargo and the repository (run it from anywhere inside it).
"""

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

try:
    import numpy as np
    import scipy
    from scipy import signal
except ImportError:  # pragma: no cover
    sys.exit("benches/lockin_numpy.py needs NumPy and SciPy: pip install numpy scipy")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run_rust(path, samples, repeats):
    """Runs the Rust half; returns its JSON object."""
    env = dict(os.environ)
    env.update(
        FTAFM_LOCKIN_SAMPLES=path,
        FTAFM_LOCKIN_LEN=str(samples),
        FTAFM_LOCKIN_REPEATS=str(repeats),
    )
    cmd = [
        "cargo", "test", "--release", "--quiet", "--bench", "lockin_compare",
        "--", "--ignored", "--nocapture", "--test-threads=1",
    ]
    out = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
    for line in out.stdout.splitlines():
        if line.startswith("LOCKIN_RUST "):
            return json.loads(line[len("LOCKIN_RUST "):])
    sys.stderr.write(out.stdout + out.stderr)
    sys.exit(f"the Rust half failed (exit {out.returncode}): {' '.join(cmd)}")


def drive_phase(n, phase0, word):
    """Drive phase theta[m] (rad) of samples 0..n-1 from the synthesiser's 64-bit phase
    words, exactly as the instrument counts it (wrapping uint64 arithmetic)."""
    m = np.arange(n, dtype=np.uint64)
    with np.errstate(over="ignore"):
        words = np.uint64(phase0) + m * np.uint64(word)
    return words.astype(np.float64) * (2.0 * np.pi / 2.0**64)


def rc_cascade(order, tau, fs):
    """lfilter coefficients of `order` identical first-order sections
    y[m] = y[m-1] + alpha (x[m] - y[m-1]), alpha = 1 - exp(-1/(tau fs))."""
    alpha = -np.expm1(-1.0 / (tau * fs))
    b = np.array([alpha**order])
    a = np.array([1.0])
    for _ in range(order):
        a = np.convolve(a, [1.0, -(1.0 - alpha)])
    return b, a


def rc_sections(order, tau, fs):
    """The same filter as `order` first-order sections for sosfilt."""
    alpha = -np.expm1(-1.0 / (tau * fs))
    return np.tile([alpha, 0.0, 0.0, 1.0, -(1.0 - alpha), 0.0], (order, 1))


def numpy_lockin(x, theta, demods, fs, sos=False):
    """What a user would write: one harmonic at a time, full rate, then decimate, with
    lfilter (b/a) or, with `sos`, sosfilt. Returns {harmonic: (complex outputs at the output
    rate, X + iY in peak amplitude; index of the first output's sample)}."""
    out = {}
    for d in demods:
        k = d["harmonic"]
        mixed = 2.0 * x * np.exp(-1j * k * theta)
        if sos:
            filtered = signal.sosfilt(rc_sections(d["order"], d["time_constant"], fs), mixed)
        else:
            b, a = rc_cascade(d["order"], d["time_constant"], fs)
            filtered = signal.lfilter(b, a, mixed)
        step = int(round(fs / d["rate"]))
        out[k] = filtered[step - 1 :: step]
    return out


def timed(x, rust, demods, fs, repeats, sos):
    """Median and minimum seconds of `repeats` passes (phase, mixing, filter, decimation),
    and the last pass's outputs."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        theta = drive_phase(len(x), int(rust["phase0"]), int(rust["frequency_word"]))
        result = numpy_lockin(x, theta, demods, fs, sos)
        times.append(time.perf_counter() - start)
    return statistics.median(times), min(times), result


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--samples", type=int, default=1 << 21, help="samples (default 2^21 = 0.21 s at 10 MS/s)")
    p.add_argument("--repeats", type=int, default=5, help="timed NumPy passes (default 5)")
    p.add_argument("--rust-repeats", type=int, default=20, help="timed Rust passes (default 20)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "samples.f64")
        rust = run_rust(path, args.samples, args.rust_repeats)
        x = np.fromfile(path, dtype="<f8")
    assert len(x) == args.samples, (len(x), args.samples)
    fs = rust["sample_rate"]
    demods = rust["demods"]

    numpy_median, numpy_min, result_tf = timed(x, rust, demods, fs, args.repeats, False)
    sos_median, sos_min, result = timed(x, rust, demods, fs, args.repeats, True)

    # Cross-check: the outputs on the same 1 kHz grid (sample 9999, 19999, ...) after the
    # filters have settled (from 0.1 s on), amplitudes R = |X + iY|. Both bank and script
    # start from zero; the bank's pre-decimator adds a fixed group delay of a few samples.
    rust_r = {}
    for demod, harmonic, index, xr, yr in rust["outputs"]:
        rust_r.setdefault(harmonic, {})[index] = abs(complex(xr, yr))
    step = int(round(fs / demods[0]["rate"]))
    h1 = abs(result[1][-1])

    def worst_of(res):
        worst = 0.0
        for k, z in res.items():
            for j, v in enumerate(z):
                index = (j + 1) * step - 1
                if index < fs * 0.1 or index not in rust_r[k]:
                    continue
                # relative to the harmonic itself, floored at 1e-3 of the fundamental
                worst = max(worst, abs(abs(v) - rust_r[k][index]) / max(abs(v), 1e-3 * h1))
        return worst

    worst = worst_of(result)
    worst_tf = worst_of(result_tf)

    rust_rate = rust["samples_per_s_median"]
    numpy_rate = len(x) / numpy_median
    sos_rate = len(x) / sos_median
    report = {
        "samples": len(x),
        "sample_rate": fs,
        "demodulators": len(demods),
        "rust": {
            "kernel": rust["kernel"],
            "repeats": rust["repeats"],
            "seconds_median": rust["seconds_median"],
            "samples_per_s_median": rust_rate,
        },
        "numpy": {
            "numpy": np.__version__,
            "scipy": scipy.__version__,
            "python": platform.python_version(),
            "repeats": args.repeats,
            "lfilter_seconds_median": numpy_median,
            "lfilter_seconds_min": numpy_min,
            "lfilter_samples_per_s_median": numpy_rate,
            "sosfilt_seconds_median": sos_median,
            "sosfilt_seconds_min": sos_min,
            "sosfilt_samples_per_s_median": sos_rate,
        },
        "ratio_rust_over_numpy_lfilter": rust_rate / numpy_rate,
        "ratio_rust_over_numpy_sosfilt": rust_rate / sos_rate,
        "amplitude_max_relative_difference_sosfilt": worst,
        "amplitude_max_relative_difference_lfilter": worst_tf,
    }
    if args.json:
        print(json.dumps(report))
        return
    print(f"{len(x)} samples at {fs / 1e6:g} MS/s, {len(demods)} demodulators "
          f"(order {demods[0]['order']}, tau {demods[0]['time_constant'] * 1e6:g} us, "
          f"{demods[0]['rate']:g} Hz)")
    print(f"Rust lock-in bank ({rust['kernel']}): median {rust['seconds_median'] * 1e3:.1f} ms "
          f"of {rust['repeats']} = {rust_rate / 1e6:.1f} MS/s")
    print(f"NumPy {np.__version__} / SciPy {scipy.__version__}, lfilter (b/a): median "
          f"{numpy_median:.2f} s of {args.repeats} = {numpy_rate / 1e6:.3f} MS/s; "
          f"the Rust bank is {rust_rate / numpy_rate:.0f}x faster")
    print(f"NumPy {np.__version__} / SciPy {scipy.__version__}, sosfilt: median "
          f"{sos_median:.2f} s of {args.repeats} = {sos_rate / 1e6:.3f} MS/s; "
          f"the Rust bank is {rust_rate / sos_rate:.0f}x faster")
    print(f"amplitudes vs the Rust bank, largest relative difference after 0.1 s: sosfilt "
          f"{worst:.1e}, lfilter {worst_tf:.1e}")


if __name__ == "__main__":
    main()
