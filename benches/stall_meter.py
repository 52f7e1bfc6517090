"""An independent check of `ftafm stalls`: the machine's own scheduling stalls.

Naps 1 ms at a time for SECONDS and records how much later than asked it woke up, and the
hypervisor's steal time (/proc/stat) per second. Nothing of ftafm is involved, so it tells
whether a latency spike could be the machine's. docs/benchmarks.md ("The machine's own
stalls") quotes it: idle, and under `chrt -f 50` (SCHED_FIFO) while a compile ran.

    python3 benches/stall_meter.py SECONDS OUT.json
    chrt -f 50 python3 benches/stall_meter.py SECONDS OUT.json

OUT.json holds `events` ([seconds since start, stall ms] for stalls over 5 ms),
`persec` (the longest stall of each second, ms) and `steal` ([second, steal ticks] of the
seconds whose steal changed).
"""
import json
import sys
import time


def steal_ticks():
    with open("/proc/stat") as f:
        return int(f.readline().split()[8])


def main():
    duration, out = float(sys.argv[1]), sys.argv[2]
    t0 = time.time()
    last = time.perf_counter()
    events, persec, steal = [], {}, []
    s0, lastsec = steal_ticks(), 0
    while time.time() - t0 < duration:
        time.sleep(0.001)
        now = time.perf_counter()
        over = (now - last - 0.001) * 1e3
        last = now
        sec = int(time.time() - t0)
        persec[sec] = max(persec.get(sec, 0.0), over)
        if over > 5:
            events.append((round(time.time() - t0, 3), round(over, 1)))
        if sec != lastsec:
            s = steal_ticks()
            if s != s0:
                steal.append((sec, s - s0))
            s0, lastsec = s, sec
    with open(out, "w") as f:
        json.dump({"events": events, "persec": persec, "steal": steal}, f)
    worst = sorted((e[1] for e in events), reverse=True)[:10]
    print(f"longest stalls (ms): {worst}; over 20 ms: {sum(1 for e in events if e[1] >= 20)}")


if __name__ == "__main__":
    main()
