"""How long does ``olti run`` of the emulated paper campaign take, and how much is protocol?

    python benchmarks/bench_run.py

Runs the paper-000 campaign (1056 readings) in-process with ``runner.run`` on

(a) the simulated station (no devices: the baseline, same diagram, same log), and
(b) the emulated station at ``fast`` speed: pyserial over the emulator's two
    pseudo-terminals, every reading on disk (fsync) as it arrives;

and splits (b) into the time spent inside protocol round trips (every
``Transport.request``: framing, CRC, the pty, the emulator thread answering
it) and the rest. The issue's target: the emulated campaign in < 120 s at
full speed; exits 1 if the best repeat misses it. Also prints what the
``realistic`` speed would take (the emulator's move model, computed, not run).
Times in s.
"""

import os
import sys
import tempfile
import time

import numpy as np

from olti_drake.hardware import protocol
from olti_drake.hardware.emulator import DEFAULT_SETTLE_S, DEFAULT_SPEEDS
from olti_drake.hardware.runner import _plan, run
from olti_drake.sim.campaign import prepare
from olti_drake.sim.scenario import Emulated, Scenario

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from timing import cpu_busy  # noqa: E402

TARGET_S = 120.0
REPEATS = 3


def _timed_requests():
    """Wrap Transport.request to add up its wall time and count round trips."""
    stats = {"s": 0.0, "n": 0}
    original = protocol.Transport.request

    def request(self, *a, **kw):
        t0 = time.perf_counter()
        try:
            return original(self, *a, **kw)
        finally:
            stats["s"] += time.perf_counter() - t0
            stats["n"] += 1
    protocol.Transport.request = request
    return stats, lambda: setattr(protocol.Transport, "request", original)


def _run(scenario, tmp, name):
    out = os.path.join(tmp, name)
    t0 = time.perf_counter()
    summary = run(scenario, out)
    assert summary.complete and summary.on_disk == 1056
    return time.perf_counter() - t0


def realistic_estimate_s(scenario) -> float:
    """Move + settle time of the whole command sequence at the emulator's realistic speeds (s)."""
    c, _ = _plan(prepare(scenario))
    q = np.column_stack([c["theta1"], c["theta2"], np.zeros_like(c["theta1"]), c["theta4"]])
    step = np.abs(np.diff(q, axis=0)) / np.asarray(DEFAULT_SPEEDS)
    moving = step.max(axis=1) > 0
    return float(step.max(axis=1).sum() + DEFAULT_SETTLE_S * moving.sum())


def main() -> int:
    busy = cpu_busy()
    sim, emu = Scenario(), Scenario(station=Emulated(speed="fast"))
    with tempfile.TemporaryDirectory() as tmp:
        t_sim = min(_run(sim, tmp, f"sim{k}") for k in range(REPEATS))
        best = None
        for k in range(REPEATS):
            stats, restore = _timed_requests()
            try:
                t = _run(emu, tmp, f"emu{k}")
            finally:
                restore()
            if best is None or t < best[0]:
                best = (t, stats["s"], stats["n"])
    t_emu, t_proto, n = best
    print(f"machine busy before the run: {100 * busy:.0f} %" if busy is not None else "")
    print(f"simulated station, olti run (log + fsync):   {t_sim:6.2f} s  (baseline)")
    print(f"emulated station, fast, through the ptys:    {t_emu:6.2f} s  = {t_emu / t_sim:4.2f}x baseline "
          f"(target < {TARGET_S:.0f} s)")
    print(f"  protocol round trips: {n} ({n / 1056:.2f} per reading), {t_proto:.2f} s "
          f"= {100 * t_proto / t_emu:.0f} % of the run, {1e3 * t_proto / n:.3f} ms each")
    print(f"  the rest (diagram, log, fsync): {t_emu - t_proto:.2f} s")
    print(f"realistic speed (moves at {DEFAULT_SPEEDS[:2]} deg/s, settle {DEFAULT_SETTLE_S} s), computed: "
          f"{realistic_estimate_s(sim) / 60:.1f} min of motion")
    return 0 if t_emu < TARGET_S else 1


if __name__ == "__main__":
    sys.exit(main())
