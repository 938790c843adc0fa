"""Timing helpers shared by the benchmarks (wall clock; the machines are shared and noisy)."""

import os
import sys
import time

import numpy as np


def best_of(fn, repeats: int):
    """(best wall time in s, last result) of ``repeats`` calls of ``fn()``."""
    best, out = np.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def cpu_busy(seconds: float = 0.5):
    """Fraction of all CPUs busy over ``seconds`` (Linux /proc/stat; None elsewhere) -- others' load."""
    def sample():
        with open("/proc/stat") as f:
            v = [float(x) for x in f.readline().split()[1:]]
        return sum(v), v[3] + v[4]  # total, idle + iowait
    try:
        t0, i0 = sample()
        time.sleep(seconds)
        t1, i1 = sample()
    except (OSError, ValueError, IndexError):
        return None
    return 1.0 - (i1 - i0) / max(t1 - t0, 1e-9)


def machine_header(name: str, extra: str = "", why: str = "") -> float:
    """Print the benchmark's machine line and, when others use the CPUs, a warning (their share; ``why``: what
    that does to this benchmark). Returns the busy share (None off Linux)."""
    print(f"{name}: {os.cpu_count()} CPUs, Python {sys.version.split()[0]}, numpy {np.__version__}{extra}")
    busy = cpu_busy()
    if busy is not None:
        print(f"CPU use by other processes just before the run: {100 * busy:.0f}% of {os.cpu_count()} CPUs")
        if busy > 0.25:
            print(f"warning: the CPUs are shared right now -- {why}timings are unreliable, re-run on an idle machine")
    return busy
