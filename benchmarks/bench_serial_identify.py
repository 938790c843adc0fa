"""How long does the identification of a six-axis robot take, against scipy on the same residuals?

    python benchmarks/bench_serial_identify.py [--quick]

The shipped UR5-class arm (``olti_drake/models/ur5.urdf``, tool0, a tool offset of (40, -25, 60) mm), a seeded
synthetic truth *not* in the model family (``olti_drake.model.serial.synthetic_truth``: harmonic joint
deviations with backlash, joint-origin errors), distance campaigns from 4 stations with random approach
directions and 0.5 um reading noise, bidirectional error maps on every joint (``build_position_model``, the
gauge of ``find_gauge``), identified by :class:`olti_drake.estimation.calibration.Calibration` (LM, the
default), at three scales:

* ``six-axis``: 700 poses x 4 stations, 15 deg maps over +-90 deg (~200 unknowns): target < 3 s;
* ``5 deg``: 5 000 poses x 4 stations, 5 deg maps over +-170 deg (~850 unknowns), in between;
* ``1 deg``: 25 000 poses x 4 stations = 10^5 readings, 1 deg maps over +-170 deg (~4 100 unknowns):
  target < 60 s and peak memory < 4 GiB.

"ours" is the whole identification: the program's setup, the identifiability check (rank and condition
within the gauge), LM, the fit's acceptance and the covariance (standard uncertainties of every parameter;
the full covariance matrix is formed only when asked for, and is not asked for here), the fastest of
``REPEATS_BELOW_1S`` runs (two at 1 deg). Ours runs its BLAS on one thread; above
``calibration.REUSE_ABOVE`` unknowns (the 1 deg scale) the check's Cholesky runs on every BLAS thread, JᵀWJ
and the metric change's sparse products on two cores, and one helper thread computes the check's rank and
condition (Lanczos) and the variances (triangular inverse in single precision, checked against double on
sampled rows) beside LM, through BLAS/LAPACK calls that release the GIL (``olti_drake.threads``); the
covariance reuses the check's factorization when the normal matrix at the solution is within
``REUSE_TOLERANCE`` of it in its metric (estimated; the fit's notes state the bound, printed below). The
normal matrix of the 1 deg problem fills to 97 % under fill-reducing orderings (SuperLU's MMD and COLAMD),
so its factorization is dense: one Cholesky of it is the floor of the check and the covariance, which scipy does not compute. The baseline is
``scipy.optimize.least_squares`` with its best variant for sparse problems (``method='trf'``,
``tr_solver='lsmr'``, ``x_scale='jac'``, default tolerances) on the same residuals and the same analytic
sparse Jacobian, the gauge eliminated exactly (``bench_identify.gauge_elimination``), from the same start,
without any rank check or covariance; timed with OpenBLAS's default threads and with one thread (ours runs on
one), half as many runs each as ours, the fastest counts. Target: ours/scipy <= 1 at every scale; both
must reach the same cost (residual RMS within 1e-6 relative).

Peak memory: the peak resident set of a fresh process that runs only our identification of the 1 deg
problem (``resource.getrusage``, ru_maxrss, the interpreter and pydrake included), and numpy's peak
allocation during it (tracemalloc).

Monte Carlo: 1 000 trials of the six-axis problem (``olti_drake.estimation.uncertainty.monte_carlo``, the
budget of 000 Table 2, both cores): target < 60 s.

Exits 1 when a target is missed. ``--quick`` skips the 1 deg scale. Units: mm, deg; times in s.
"""

import importlib.util
import os
import resource
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from timing import cpu_busy  # noqa: E402

import olti_drake  # noqa: E402
from olti_drake.estimation.calibration import Calibration  # noqa: E402
from olti_drake.estimation.calibration import SolverOptions  # noqa: E402
from olti_drake.model.chain import load_serial_chain  # noqa: E402
from olti_drake.model.serial import (DistanceMeasurement, build_position_model, find_gauge,  # noqa: E402
                                     synthetic_campaign, synthetic_truth)
from olti_drake.threads import single_thread_blas  # noqa: E402

_spec = importlib.util.spec_from_file_location("bench_identify", HERE / "bench_identify.py")
bench_identify = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_identify)

TOOL = (40.0, -25.0, 60.0)
NOISE_MM = 0.0005
#: name: (poses, map step deg, half range deg, campaign seed, target s or None)
SCALES = {"six-axis": (700, 15.0, 90.0, 1, 3.0), "5 deg": (5_000, 5.0, 170.0, 2, None),
          "1 deg": (25_000, 1.0, 170.0, 3, 60.0)}
MEMORY_TARGET = 4 * 2 ** 30
MC_TRIALS, MC_TARGET_S = 1000, 60.0
SAME_COST_RTOL = 1e-6
#: Runs per timing below the 1 deg scale (ours; scipy half as many with each thread setting, the fastest counts).
REPEATS_BELOW_1S = 4


def chain_and_truth():
    chain = load_serial_chain(Path(olti_drake.__file__).parent / "models" / "ur5.urdf", "tool0")
    return chain, synthetic_truth(chain, seed=0, tool_offset_mm=TOOL)


def problem(scale: str):
    """(measurement, gauge) of a scale of :data:`SCALES`: seeded, the start at the nominal model."""
    n_poses, step, half, seed, _ = SCALES[scale]
    chain, truth = chain_and_truth()
    ranges = np.tile([-half, half], (chain.n_joints, 1))
    camp = synthetic_campaign(truth, n_poses, seed, ranges_deg=ranges, noise_mm=NOISE_MM)
    model = build_position_model(chain, camp.commands, camp.dirs, kind="errormap", grid_step_deg=step,
                                 tool_offset_mm=TOOL)
    meas = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station,
                               camp.displacement_mm, truth.stations_mm, truth.dead_paths_mm)
    return meas, find_gauge(meas)


def ours(meas, gauge):
    """(seconds, fit): the whole identification, setup to standard uncertainties."""
    t0 = time.perf_counter()
    fit = Calibration(meas, SolverOptions(), gauge, "benchmark").fit()
    return time.perf_counter() - t0, fit


def scipy_lsmr(meas, gauge, repeats: int = 1):
    """(seconds, result dict of ``bench_identify.scipy_solve``): setup (the program for the gauge rows and
    the start) included, as in ours; the fastest of ``repeats`` runs with OpenBLAS's default threads and
    ``repeats`` with one thread (ours runs on one: on a shared machine that is much faster, so scipy gets the
    same chance)."""
    def run():
        t0 = time.perf_counter()
        out = bench_identify.scipy_solve(Calibration(meas, SolverOptions(), gauge, "benchmark"), "lsmr")
        return time.perf_counter() - t0, out

    runs = [run() for _ in range(repeats)]
    with single_thread_blas():
        runs += [run() for _ in range(repeats)]
    return min(runs, key=lambda t: t[0])


def rms(v) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


def memory_child(scale: str) -> int:
    """Run in a fresh process: our identification of ``scale``; print peak RSS and numpy's peak, bytes."""
    meas, gauge = problem(scale)
    tracemalloc.start()
    ours(meas, gauge)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, peak)
    return 0


def peak_memory(scale: str):
    """(peak RSS, numpy's peak allocation) bytes of our identification of ``scale`` in a fresh process."""
    out = subprocess.run([sys.executable, __file__, "--memory-child", scale], capture_output=True, text=True,
                         check=True)
    rss, peak = out.stdout.split()[-2:]
    return int(rss), int(peak)


def monte_carlo_timing(meas, gauge, fit):
    """(seconds, MonteCarlo) of :data:`MC_TRIALS` trials on both cores, 000 Table 2 budget."""
    from olti_drake.estimation.uncertainty import ReadingErrors, monte_carlo
    from olti_drake.io.budget import default_budget

    cal = Calibration(meas, SolverOptions(), gauge, "benchmark")
    t0 = time.perf_counter()
    mc = monte_carlo(cal, fit.x, ReadingErrors(default_budget("scara")), trials=MC_TRIALS, seed=1, workers=2)
    return time.perf_counter() - t0, mc


def main(argv) -> int:
    if argv[:1] == ["--memory-child"]:
        return memory_child(argv[1])
    quick = "--quick" in argv
    busy = cpu_busy()
    print(f"bench_serial_identify: {os.cpu_count()} CPUs; " +
          (f"CPU use by other processes just before the run: {100 * busy:.0f}%" if busy is not None else ""))
    ok = True
    print(f"{'scale':10s}{'unknowns':>9s}{'readings':>9s}{'ours s':>9s}{'scipy s':>9s}{'ours/scipy':>11s}"
          f"{'it/fev':>8s}{'RMS ours mm':>15s}{'RMS scipy mm':>15s}")
    six = None
    for scale, (*_, target) in SCALES.items():
        if quick and scale == "1 deg":
            continue
        meas, gauge = problem(scale)
        ours(meas, gauge) if scale == "six-axis" else None  # warm-up: first-call costs
        # Sub-second runs on a shared machine vary by +-30 %: the fastest of more runs, for both alike.
        repeats = REPEATS_BELOW_1S if scale != "1 deg" else 2
        t_ours, fit = min((ours(meas, gauge) for _ in range(repeats)), key=lambda t: t[0])
        t_sci, sci = scipy_lsmr(meas, gauge, max(1, repeats // 2))
        same = abs(rms(fit.residuals) - sci["rms_mm"]) <= SAME_COST_RTOL * sci["rms_mm"]
        print(f"{scale:10s}{len(meas.names):9d}{len(meas.station):9d}{t_ours:9.2f}{t_sci:9.2f}{t_ours / t_sci:11.2f}"
              f"{str(fit.iterations) + '/' + str(sci['nfev']):>8s}{rms(fit.residuals):15.10f}{sci['rms_mm']:15.10f}"
              + ("" if same else "  NOT the same cost"))
        ok &= same and t_ours <= t_sci and (target is None or t_ours < target)
        for note in fit.notes:
            if "identifiability check's factorization" in note:
                print(f"{'':10s}note: {note}")
        if scale == "six-axis":
            six = (meas, gauge, fit)
    if not quick:
        rss, peak = peak_memory("1 deg")
        print(f"1 deg, ours in a fresh process: peak RSS {rss / 2 ** 30:.2f} GiB (numpy's own peak "
              f"{peak / 2 ** 30:.2f} GiB); target < {MEMORY_TARGET / 2 ** 30:g} GiB")
        ok &= rss < MEMORY_TARGET
    t_mc, mc = monte_carlo_timing(*six)
    print(f"Monte Carlo, six-axis, {len(mc.samples)} trials on 2 workers: {t_mc:.2f} s (target < {MC_TARGET_S:g} s)")
    ok &= t_mc < MC_TARGET_S
    print("OK" if ok else "FAILED (targets: ours/scipy <= 1 and the same cost at every scale; six-axis < 3 s; "
          "1 deg < 60 s, < 4 GiB; 1000 Monte Carlo trials < 60 s)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
