"""CPU use of every thread on the machine over an interval, as % of one core.

Reads utime + stime of /proc/*/task/*/stat before and after SECONDS and prints the threads
(by process and thread name) that used more than 0.5 % of a core, busiest first. Used for
the per-thread figures in docs/benchmarks.md, e.g. while `ftafm soak` runs against
`ftafm serve`:

    python3 benches/thread_cpu.py 20
"""
import os
import sys
import time


def snapshot():
    ticks = {}
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            comm = open(f"/proc/{pid}/comm").read().strip()
            for tid in os.listdir(f"/proc/{pid}/task"):
                stat = open(f"/proc/{pid}/task/{tid}/stat").read()
                name = stat[stat.index("(") + 1 : stat.rindex(")")]
                fields = stat[stat.rindex(")") + 2 :].split()
                ticks[(pid, tid)] = (comm, name, int(fields[11]) + int(fields[12]))
        except OSError:
            pass  # the thread ended meanwhile
    return ticks


def main():
    seconds = float(sys.argv[1])
    before, t0 = snapshot(), time.time()
    time.sleep(seconds)
    after, dt = snapshot(), time.time() - t0
    hz = os.sysconf("SC_CLK_TCK")
    by_name = {}
    for key, (comm, name, t) in after.items():
        # Keyed by ids: a kernel worker's name changes with its work. A thread born
        # meanwhile counts from its start.
        used = (t - before.get(key, ("", "", 0))[2]) / hz / dt * 100
        # Kernel workers' names carry their current work after a dash; group them.
        if comm.startswith("kworker"):
            comm = name = comm.split("-")[0]
        group = (comm, name)
        by_name[group] = by_name.get(group, 0.0) + used
    for (comm, name), pct in sorted(by_name.items(), key=lambda kv: -kv[1]):
        if pct > 0.5:
            print(f"{pct:6.1f} %  {comm} / {name}")
    print(f"total {sum(by_name.values()):.1f} % of one core")


if __name__ == "__main__":
    main()
