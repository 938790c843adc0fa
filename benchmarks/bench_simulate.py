"""How long does ``olti simulate`` of the paper campaign take, and where does it go?

    python benchmarks/bench_simulate.py

Times, on this machine:

(a) ``olti simulate`` as a subprocess, start-up (imports) included: the
    issue's target is < 5 s on the 2-core machine; exits 1 when the best of
    the repeats misses it;
(b) the Drake diagram alone: ``prepare`` and ``run_campaign`` in-process;
(c) a numpy-only baseline of the same readings (no Drake): the package's
    vectorized model -- ``campaign.simulate_vectorized``: ``TrueRobot.laser_beam``,
    ``simulate_readings`` -- which bounds what the diagram's per-reading
    Python events cost.

Units: readings in mm, times in s.
"""

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from olti_drake.sim.campaign import STREAM_LASER, build_campaign_diagram, prepare, run_campaign, simulate_vectorized
from olti_drake.sim.scenario import Scenario

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the benchmarks' own helpers
from timing import best_of  # noqa: E402

#: The issue's target for ``olti simulate`` of the paper campaign, start-up included (s).
TARGET_S = 5.0
REPEATS = 3
#: The baseline takes ~1 ms: more repeats for a stable best.
BASELINE_REPEATS = 20


def numpy_baseline(setup, rng=None) -> dict:
    """The campaign's measured readings computed vectorized, without Drake (columns, mm/deg)."""
    if rng is None:
        rng = np.random.default_rng([setup.scenario.seed, STREAM_LASER])
    return simulate_vectorized(setup, rng).columns


def olti_command() -> list:
    """The installed ``olti`` script, or the module when it is not on PATH."""
    exe = shutil.which("olti")
    return [exe] if exe else [sys.executable, "-m", "olti_drake.cli"]


def time_cli(repeats: int = REPEATS) -> list:
    """Wall times (s) of ``olti simulate --out TMP``, each a fresh process."""
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(repeats):
            t0 = time.perf_counter()
            # A fresh directory each run: olti simulate never replaces a campaign (measured data).
            subprocess.run(olti_command() + ["simulate", "--out", os.path.join(tmp, f"run{i}")], check=True,
                           stdout=subprocess.DEVNULL)
            times.append(time.perf_counter() - t0)
    return times




def main() -> int:
    cli = time_cli()
    t_prep, setup = best_of(lambda: prepare(Scenario()), REPEATS)
    t_build, _ = best_of(lambda: build_campaign_diagram(setup), REPEATS)
    t_diag, campaign = best_of(lambda: run_campaign(setup), REPEATS)
    t_base, base = best_of(lambda: numpy_baseline(setup), repeats=BASELINE_REPEATS)
    n = campaign.n_readings
    if len(base["valid"]) != n:
        sys.exit(f"error: the baseline has {len(base['valid'])} readings, the diagram {n}")

    rows = [("(a) olti simulate, subprocess, best", min(cli)),
            ("    olti simulate, subprocess, median", statistics.median(cli)),
            ("(b) prepare (Eq. 2 search, counter zeros)", t_prep),
            ("    build_campaign_diagram (in run_campaign)", t_build),
            ("    run_campaign (build + simulate diagram)", t_diag),
            ("(c) numpy baseline (vectorized, no Drake)", t_base)]
    print(f"paper-000 campaign: {n} readings, {os.cpu_count()} CPUs, Python {sys.version.split()[0]}, "
          f"best of {REPEATS} (baseline: of {BASELINE_REPEATS})")
    print(f"{'':46s}{'time ms':>10s}{'readings/s':>12s}")
    for name, t in rows:
        rate = "" if "prepare" in name or "build_" in name else f"{n / t:.0f}"
        print(f"{name:46s}{1e3 * t:10.2f}{rate:>12s}")
    print(f"diagram / baseline: {t_diag / t_base:.0f}x; "
          f"Python-event overhead {1e3 * (t_diag - t_build - t_base) / n:.3f} ms per reading "
          f"(simulation minus build minus baseline)")
    ok = min(cli) <= TARGET_S
    print(f"target: olti simulate < {TARGET_S:g} s, start-up included: "
          f"{'met' if ok else 'MISSED'} (best {min(cli):.2f} s)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
