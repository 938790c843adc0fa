"""How fast is 3D self-calibrating multilateration (001 Eq. 2-6 in R^3) at issue 15's size?

    python benchmarks/bench_multilateration3d.py

A simulated 3D campaign (``model.machine.simulate_machine_campaign_3d``): 600
targets (a 10 x 10 x 6 grid over the default 400 x 300 x 250 mm travel) read
from 5 pan/tilt heads, 3000 readings, 3 * 600 + 4 * 5 = 1820 unknowns.

- ours: ``multilaterate`` -- the shared least-squares program (LM steps as
  Drake programs, the 6 gauge constraints exact, the sparse Jacobian: a reading
  touches one target and one station, 7 non-zeros per row), including the
  identifiability check and the covariance; best of 2;
- baseline, in the same run: ``scipy.optimize.least_squares`` ('trf', dense:
  no ``jac_sparsity``) on the same residuals, with the same analytic Jacobian
  handed over dense and the gauge as 6 heavily weighted residual rows; 1 run,
  on one BLAS thread as ours.

Prints both times, the ratio and the largest difference of the two solutions
(µm). Exits 1 when ours takes 5 s or more (issue 15 target) or the two
disagree by more than 0.01 µm.
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import best_of, cpu_busy  # noqa: E402

from olti_drake.estimation.multilateration import Multilateration, machine_campaign, multilaterate  # noqa: E402
from olti_drake.model.machine import Machine3DScenario, simulate_machine_campaign_3d  # noqa: E402
from olti_drake.threads import single_thread_blas  # noqa: E402

TARGET_S = 5.0


def scipy_dense(ml: Multilateration):
    """The same problem by scipy's dense trust-region reflective solver: residuals, then the gauge rows."""
    from scipy.optimize import least_squares

    A, b = ml._equality_rows()
    w = 1e3 * np.sqrt(len(ml.data))  # the gauge rows weigh far more than all readings together

    def fun(x):
        return np.concatenate([ml.residuals(x)[0], w * (A @ x - b)])

    def jac(x):
        return np.vstack([ml.residuals(x)[1].toarray(), w * A])

    return least_squares(fun, ml.x0, jac=jac, method="trf", x_scale="jac", xtol=1e-15, ftol=1e-15, gtol=1e-12)


def main() -> int:
    busy = cpu_busy()
    cols, _ = simulate_machine_campaign_3d(Machine3DScenario(seed=7, grid=(10, 10, 6)))
    data = machine_campaign(cols)
    t_ours, res = best_of(lambda: multilaterate(data), 2)
    ml = Multilateration(data)
    t0 = time.perf_counter()
    with single_thread_blas():  # as ours (Multilateration.solve): the same BLAS on both sides
        base = scipy_dense(ml)
    t_base = time.perf_counter() - t0
    diff_um = 1e3 * float(np.abs(base.x[:3 * data.n_targets] - res.targets_mm.ravel()).max())
    print(f"3D multilateration: {data.n_targets} targets x {data.n_stations} stations, {len(data)} readings, "
          f"{len(ml.names)} unknowns, J {ml.residuals(ml.x0)[1].nnz} non-zeros"
          f"{'' if busy is None else f'; CPUs {100 * busy:.0f}% busy with other work'}")
    print(f"  ours (LM on the Drake program, sparse J) {t_ours:8.2f} s, {res.fit.iterations} iterations "
          f"(target < {TARGET_S:.0f} s)")
    print(f"  scipy least_squares trf, dense J        {t_base:8.2f} s, {base.nfev} evaluations")
    print(f"  ratio baseline / ours                   {t_base / t_ours:8.1f}x; largest target difference "
          f"{diff_um:.2e} um")
    ok = t_ours < TARGET_S and diff_um < 0.01
    if not ok:
        print("FAILED: " + ("too slow" if t_ours >= TARGET_S else "the two solutions disagree"))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
