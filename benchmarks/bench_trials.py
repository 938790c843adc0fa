"""Parallel efficiency of the Monte Carlo trials (issue 26 item 5): the same trials on 1 and 2 workers, one run.

    python benchmarks/bench_trials.py [--trials 4000] [--dask]

On the paper-scale problem -- the shipped campaign ``data/paper000/campaign.csv``, the error-map model
identified first (49 unknowns), the budget of 000 Table 2 -- ``monte_carlo`` runs the same seeded trials

* with ``workers=2`` (joblib loky): the first call, which starts the worker processes (each imports numpy, scipy
  and the package and builds the problem once);
* then, alternated (the others' load drifts alike over both), ``workers=1`` (in this process) and ``workers=2`` on
  the started workers, best of 2 each;
* with ``--dask``: ``backend="dask"`` on a local cluster of 2 single-threaded worker processes (made and closed
  by the call: its start included).

Prints the times, the speed-up t1 / t2 and the parallel efficiency t1 / (2 t2) (1 = perfect on 2 cores), warm
and with the workers' start, and the others' CPU use just before (a shared machine's timings are unreliable).
Exits 1 when the samples differ, bit for bit, between any two runs (they must not: seeds per block of trials).
Units: s.
"""

import argparse
import os
import sys

import numpy as np

from olti_drake.estimation.identification import Identifier
from olti_drake.estimation.uncertainty import BATCH, monte_carlo
from olti_drake.io.budget import load_budget
from olti_drake.io.csvio import load_campaign
from olti_drake.model.budget import ReadingErrors

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the benchmarks' own helpers
from timing import best_of, machine_header  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PAPER_CAMPAIGN = os.path.join(ROOT, "data", "paper000", "campaign.csv")
PAPER_BUDGET = os.path.join(ROOT, "data", "budget_paper000.yaml")
REPEATS = 2


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=4000, help="Monte Carlo trials (default 4000: 16 blocks)")
    ap.add_argument("--dask", action="store_true", help="also on a local Dask cluster of 2 workers")
    a = ap.parse_args(argv)
    machine_header("bench_trials")
    data = load_campaign(PAPER_CAMPAIGN)
    errors = ReadingErrors(load_budget(PAPER_BUDGET))
    ident = Identifier(data)
    x = ident.solve().x
    print(f"problem: {len(data)} readings, {len(x)} unknowns; {a.trials} trials in blocks of {BATCH}")

    def run(workers, backend="loky"):
        return monte_carlo(ident, x, errors, trials=a.trials, seed=0, workers=workers, backend=backend).samples

    t2_cold, s2_cold = best_of(lambda: run(2), 1)
    t1 = t2 = np.inf
    for _ in range(REPEATS):  # alternated: the others' load drifts alike over both
        t, s1 = best_of(lambda: run(1), 1)
        t1 = min(t1, t)
        t, s2 = best_of(lambda: run(2), 1)
        t2 = min(t2, t)
    rows = [("workers=1 (in process), best of 2", t1, s1),
            ("workers=2 loky, first call (starts the workers)", t2_cold, s2_cold),
            ("workers=2 loky, started workers, best of 2", t2, s2)]
    if a.dask:
        td, sd = best_of(lambda: run(2, "dask"), 1)
        rows.append(("workers=2 dask LocalCluster (its start included)", td, sd))
    print(f"\n  {'run':52s}{'time s':>9s}{'speed-up':>10s}{'efficiency':>12s}")
    for label, t, _ in rows:
        print(f"  {label:52s}{t:9.2f}{t1 / t:10.2f}{t1 / (2 * t) if 'workers=1' not in label else 1.0:12.2f}")
    same = all(np.array_equal(s1, s) for _, _, s in rows)
    print(f"\nsamples identical bit for bit across the {len(rows)} runs: {'yes' if same else 'NO'}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
