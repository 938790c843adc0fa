"""How long does the identification of a five-axis campaign of ~2 000 readings take, against scipy on the same
residuals (issue 25)?

    python benchmarks/bench_five_axis_identify.py [--poses N]

The shipped scenario (``diagrams/machine_5axis.yaml``: the A/C trunnion, 3 tracking interferometers on the bed and
2 riding on the table, 2 tools, 3 R-test nests; ``tracking_plan``) with 200 poses per station set-up and tool:
2 000 distance readings and the R-test paths (the valid ones are counted when printed), simulated by the numpy
twin of the diagram (``simulate_five_axis_campaign``; the truth's linear axes perfect, as the model's), written
and read back as ``olti identify --machine`` does, identified with

* ``geometric``: the rotary axes' location errors and tool 1's offset, the stations, dead paths and nest zeros;
* ``errormap``: plus the six bidirectional error motions of A and C every 15 deg, with their gauge (grid mean 0,
  no rotating first harmonic: the program's linear equalities), smoothing off (a prior scipy would not have).

"ours" is the whole identification (:class:`olti_drake.estimation.five_axis.FiveAxisIdentification`: the program's
setup -- separability, station starts --, the identifiability check, LM, acceptance and the covariance), the
fastest of ``REPEATS``. The baseline is ``scipy.optimize.least_squares`` (``method='trf'``, ``x_scale='jac'``) on
the engine's own residuals and analytic Jacobian (``Calibration.residuals``), from the same start, the gauge
eliminated exactly (``bench_identify.scipy_solve`` / ``gauge_elimination``), its program set up inside its timing
as ours, without rank check or covariance. scipy's default tolerances stop short of the minimum by more than the
1e-6 the costs must agree to, so they are tightened (``SCIPY_VARIANTS``): ``tr_solver='exact'`` (J dense) and
``'lsmr'`` (J sparse); the faster that reaches our cost (½ Σ r², relative difference <= 1e-6) counts. Printed:
the totals (setup included) and the solve alone. The setup (reading the campaign, the program: separability,
station starts) is the same code for both, so the target is on the solve: ours (identifiability check, LM,
covariance) / scipy's <= 1 for each model; exits 1 when missed.

Units: readings in mm, times in s.
"""

import argparse
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # the benchmarks' own helpers
from bench_identify import ScipyTimeout, scipy_solve  # noqa: E402
from timing import cpu_busy  # noqa: E402

from olti_drake.estimation.five_axis import FiveAxisIdentification, FiveAxisOptions  # noqa: E402
from olti_drake.io.five_axis_io import read_five_axis_campaign, write_five_axis_campaign  # noqa: E402
from olti_drake.sim.five_axis_station import (load_five_axis_scenario, prepare_five_axis,  # noqa: E402
                                              simulate_five_axis_campaign)

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
YAML = os.path.join(ROOT, "diagrams", "machine_5axis.yaml")
REPEATS = 3
MODELS = ("geometric", "errormap")
#: Largest relative difference of the two costs.
COST_RTOL = 1e-6
#: scipy's variants (tr_solver, ftol = xtol = gtol): its default tolerances (1e-8) stop the error-map problem 7e-6
#: of the cost short of the minimum ours reaches; 'exact' reaches it at 1e-12, 'lsmr' does not converge there (its
#: inexact steps) and is run at 1e-10. The fastest variant within COST_RTOL of our cost is the baseline.
SCIPY_VARIANTS = (("exact", 1e-12), ("lsmr", 1e-10))
#: A scipy run longer than this (s) is stopped and not counted.
SCIPY_TIME_LIMIT_S = 120.0


def campaign(poses: int, directory: str):
    """(machine, campaign path): the scenario's campaign with ``poses`` per set-up and tool, written as a file."""
    doc = load_five_axis_scenario(YAML, text=f"{{tracking: {{poses: {poses}}}, truth: {{linear: false}}}}")
    run = prepare_five_axis(doc)
    cols, _ = simulate_five_axis_campaign(run)
    path = os.path.join(directory, "campaign.csv")
    write_five_axis_campaign(path, {k: v for k, v in cols.items() if k != "time_s"})
    return run.machine, path


def program(machine, path, model: str) -> FiveAxisIdentification:
    tools = [[0.0, 0.0, 0.0], [0.0, 60.0, 30.0]]
    return FiveAxisIdentification(read_five_axis_campaign(path, machine), machine,
                                  FiveAxisOptions(model=model, smoothing="off", tool_offsets_mm=tools,
                                                  linear="perfect"))  # (the truth's, as the docstring says)


def cost(ident, x) -> float:
    r = ident.residuals(x)[0]
    return 0.5 * float(r @ r)


def ours(machine, path, model):
    """(seconds, cost, iterations, unknowns, seconds of the solve alone): the whole identification."""
    t0 = time.perf_counter()
    ident = program(machine, path, model)
    t1 = time.perf_counter()
    fit = ident.fit()
    t = time.perf_counter()
    return t - t0, cost(ident, fit.x), fit.iterations, len(ident.names), t - t1


def scipy_run(machine, path, model, tr_solver, tol):
    """(seconds, cost, function evaluations, seconds of the solve alone) or None past :data:`SCIPY_TIME_LIMIT_S`:
    setup included, as in ours."""
    t0 = time.perf_counter()
    ident = program(machine, path, model)
    t1 = time.perf_counter()
    try:
        out = scipy_solve(ident, tr_solver, time_limit_s=SCIPY_TIME_LIMIT_S, ftol=tol, xtol=tol, gtol=tol)
    except ScipyTimeout:
        return None
    t = time.perf_counter()
    return t - t0, cost(ident, out["x"]), out["nfev"], t - t1


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=200, help="poses per station set-up and tool (default 200)")
    args = ap.parse_args(argv)
    busy = cpu_busy()
    with tempfile.TemporaryDirectory() as d:
        machine, path = campaign(args.poses, d)
        kinds = read_five_axis_campaign(path, machine).kind
        n = len(kinds)
        by = ", ".join(f"{int(np.sum(kinds == k))} {k}" for k in np.unique(kinds))
        print(f"five-axis campaign: {n} valid readings ({by}; {os.path.basename(YAML)}, {args.poses} poses per set-up "
              f"and tool), "
              f"{os.cpu_count()} CPUs, others' load {'?' if busy is None else f'{100 * busy:.0f}%'}, "
              f"best of {REPEATS}")
        print(f"{'model':10s}{'unknowns':>9s}{'ours s':>9s}{'scipy s':>9s}{'ours/scipy':>11s}{'cost ours':>14s}"
              f"{'cost scipy':>14s}{'rel diff':>10s}  scipy variant")
        ok = True
        for model in MODELS:
            runs = [ours(machine, path, model) for _ in range(REPEATS)]
            t_ours, c_ours, iterations, unknowns, solve_ours = min(runs)
            best = None
            for tr, tol in SCIPY_VARIANTS:
                runs = [scipy_run(machine, path, model, tr, tol) for _ in range(REPEATS)]
                if any(r is None for r in runs):
                    print(f"{'':10s}scipy trf {tr} tol {tol:g}: over {SCIPY_TIME_LIMIT_S:g} s, not counted")
                    continue
                t_s, c_s, nfev, solve_s = min(runs)
                rel = abs(c_ours - c_s) / max(abs(c_s), 1e-300)
                print(f"{'':10s}scipy trf {tr} tol {tol:g}: {t_s:.3f} s, cost {c_s:.10g} (rel diff {rel:.1e}), "
                      f"{nfev} evaluations")
                if rel <= COST_RTOL and (best is None or t_s < best[0]):
                    best = (t_s, c_s, nfev, f"trf {tr} tol {tol:g}", solve_s)
            if best is None:
                print(f"{model:10s}: no scipy variant reached our cost within {COST_RTOL:g}  MISSED")
                ok = False
                continue
            t_s, c_s, nfev, tr, solve_s = best
            rel = abs(c_ours - c_s) / max(abs(c_s), 1e-300)
            good = solve_ours <= solve_s
            ok &= good
            print(f"{model:10s}{unknowns:9d}{t_ours:9.3f}{t_s:9.3f}{t_ours / t_s:11.2f}{c_ours:14.8g}{c_s:14.8g}"
                  f"{rel:10.1e}  {tr} ({nfev} evaluations; ours {iterations} LM steps)")
            print(f"{'':10s}the solve alone (after the program's setup, the same code for both): ours "
                  f"{solve_ours:.3f} s (identifiability, LM, covariance), scipy {solve_s:.3f} s, ratio "
                  f"{solve_ours / solve_s:.2f}"
                  + ("" if good else "  MISSED"))
    print(f"target: our solve <= scipy's and the same cost (rel <= {COST_RTOL:g}) for every model: "
          f"{'met' if ok else 'MISSED'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
