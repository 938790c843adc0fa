"""How fast is the serial position model's sparse Jacobian, against a dense one built in the same run?

    python benchmarks/bench_serial_model.py

On the shipped UR5-class arm (``olti_drake/models/ur5.urdf``, tool0, a tool
offset of (40, -25, 60) mm), seeded synthetic distance campaigns with 4
stations, directions on every joint (``olti_drake.model.serial``):

1. 700 poses × 4 stations = 2800 readings, 15° bidirectional maps on every
   joint over ±90° (≈ 200 unknowns): the residuals and their sparse Jacobian
   (``DistanceMeasurement.residuals``: FK, Eq. (10) in 3D, ∂r/∂x as CSR), best
   of 5, against the dense baseline — the same Jacobian as a dense (M, P)
   array, map columns as ∂p/∂θ_i times the dense Eq. (7) weight matrix — and
   the gauge analysis (``find_gauge``).
2. 25 000 poses × 4 stations = 100 000 readings, 1° maps on six joints over
   ±170° (≈ 4 100 unknowns): the same, with the peak memory of the call
   (tracemalloc: numpy's allocations). The dense baseline would need a
   100 000 × P float64 array (printed); it is measured on the first 10 000
   readings and scaled by 10 (time is linear in the readings). For the solver
   integration, what one Gauss-Newton step would cost on top (J^T J, a dense
   KKT solve with the gauge rows) is printed for information.

Both Jacobians must agree (1e-9); exits 1 when they do not, or the targets
(2800 readings < 0.1 s; 100 000 readings < 10 s and < 2 GiB; identification
budgets: < 3 s and < 60 s / 4 GiB in all) are missed.

Units: mm, deg; times in ms or s.
"""

import sys
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import best_of, cpu_busy  # noqa: E402

import olti_drake  # noqa: E402
from olti_drake.model.chain import load_serial_chain  # noqa: E402
from olti_drake.model.serial import (DistanceMeasurement, build_position_model, find_gauge,  # noqa: E402
                                     synthetic_campaign, synthetic_truth)

TOOL = (40.0, -25.0, 60.0)


def problem(chain, truth, n_poses, step_deg, half_range_deg, seed):
    ranges = np.tile([-half_range_deg, half_range_deg], (chain.n_joints, 1))
    camp = synthetic_campaign(truth, n_poses, seed, ranges_deg=ranges, noise_mm=0.0005)
    model = build_position_model(chain, camp.commands, camp.dirs, kind="errormap",
                                 grid_step_deg=step_deg, tool_offset_mm=TOOL)
    return DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station,
                               camp.displacement_mm, truth.stations_mm, truth.dead_paths_mm)


def dense_jacobian(prob, x, rows=None):
    """The baseline: the same ∂r/∂x as a dense array (map columns through dense weight matrices),
    from the same FK of the distinct poses."""
    model = prob.model
    sel = slice(None) if rows is None else slice(0, rows)
    commands, dirs, station = prob.commands[sel], prob.dirs[sel], prob.station[sel]
    xm, P = x[:model.n_params], x[model.n_params:]
    nt = len(prob.labels)
    # the same FK as the sparse path: each distinct pose once (the ratio is sparse vs dense only)
    first, inverse = prob._poses
    keep = inverse[sel]
    p, jac = model.chain.jacobian(model.actual_angles(prob.commands[first], prob.dirs[first], xm),
                                  model.chain_parameters(xm))
    p, jac = p[keep], jac[keep]
    diff = p - P[:3 * nt].reshape(nt, 3)[station]
    u = diff / np.linalg.norm(diff, axis=1)[:, None]
    out = np.zeros((len(p), len(prob.names)))
    n = model.chain.n_joints
    out[:, :model.n_dense] = np.einsum("mc,mcd->md", u, np.concatenate(
        [jac[:, :, n + model._chain_cols], jac[:, :, model.offset_joints]], axis=2))
    for start, j, m in zip(model.map_starts, model.map_joints, model.maps):
        weights = m.emap.weights(commands[:, j], dirs[:, j]).toarray()
        out[:, start:start + m.n_values] = np.einsum("mc,mc->m", u, jac[:, :, j])[:, None] * weights
    for c in range(3):
        out[np.arange(len(p)), model.n_params + 3 * station + c] = -u[:, c]
    out[np.arange(len(p)), model.n_params + 3 * nt + station] = -1.0
    return out


def gauss_newton_step(prob, x):
    """Seconds for J^T J (sparse product), the dense KKT solve of one step with the gauge rows,
    and the gauge analysis: what the solver integration will pay per iteration."""
    import time

    import scipy.linalg

    r, jac = prob.residuals(x)
    t0 = time.perf_counter()
    normal = (jac.T @ jac).toarray()
    t1 = time.perf_counter()
    gauge = find_gauge(prob)
    t2 = time.perf_counter()
    k = len(gauge.b)
    kkt = np.block([[normal, gauge.A.T], [gauge.A, np.zeros((k, k))]])
    scipy.linalg.solve(kkt, np.concatenate([-(jac.T @ r), np.zeros(k)]), assume_a="sym")
    t3 = time.perf_counter()
    return t1 - t0, t3 - t2, t2 - t1


def peak_memory(fn):
    """(peak bytes allocated during fn(), result), by tracemalloc."""
    tracemalloc.start()
    out = fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak, out


def main() -> int:
    busy = cpu_busy()
    print(f"machine busy (others): {busy:.0%}" if busy is not None else "machine busy: unknown")
    chain = load_serial_chain(Path(olti_drake.__file__).parent / "models" / "ur5.urdf", "tool0")
    truth = synthetic_truth(chain, seed=0, tool_offset_mm=TOOL)
    ok = True

    small = problem(chain, truth, 700, 15.0, 90.0, seed=1)
    x = small.start_vector()
    t_sparse, (_, jac) = best_of(lambda: small.residuals(x), 5)
    t_dense, dense = best_of(lambda: dense_jacobian(small, x), 5)
    t_gauge, gauge = best_of(lambda: find_gauge(small), 2)
    err = np.abs(jac.toarray() - dense).max()
    print(f"UR5, {len(small.station)} readings, 15 deg maps, {len(small.names)} unknowns "
          f"({jac.nnz / jac.shape[0]:.0f} non-zeros per row)")
    print(f"  sparse Jacobian (FK + residuals) : {t_sparse * 1e3:8.1f} ms")
    print(f"  dense baseline                   : {t_dense * 1e3:8.1f} ms   ({t_dense / t_sparse:.1f}x)")
    print(f"  gauge analysis ({gauge.null_dimension} constraints)     : {t_gauge * 1e3:8.1f} ms")
    print(f"  largest difference sparse - dense: {err:.1e}")
    ok &= err < 1e-9 and t_sparse < 0.1

    big = problem(chain, truth, 25_000, 1.0, 170.0, seed=2)
    x = big.start_vector()
    t_big, (_, jac) = best_of(lambda: big.residuals(x), 2)
    peak, _ = peak_memory(lambda: big.residuals(x))
    rows = 10_000
    t_dense, dense = best_of(lambda: dense_jacobian(big, x, rows), 1)
    err = np.abs(jac[:rows].toarray() - dense).max()
    del dense
    scale = len(big.station) / rows
    dense_bytes = len(big.station) * len(big.names) * 8
    print(f"UR5, {len(big.station)} readings, 1 deg maps, {len(big.names)} unknowns "
          f"({jac.nnz / jac.shape[0]:.0f} non-zeros per row, CSR {jac.data.nbytes * 1.5 / 2**20:.0f} MiB)")
    print(f"  sparse Jacobian (FK + residuals) : {t_big:8.2f} s, peak memory {peak / 2**30:.2f} GiB")
    print(f"  dense baseline (10 000 rows x {scale:.0f}) : {t_dense * scale:8.2f} s   "
          f"({t_dense * scale / t_big:.1f}x), its matrix alone {dense_bytes / 2**30:.2f} GiB")
    print(f"  largest difference sparse - dense: {err:.1e}")
    t_step = gauss_newton_step(big, x)
    print(f"  for the solver (information): one Gauss-Newton step with the gauge: J^T J (sparse) "
          f"{t_step[0]:.2f} s, dense KKT solve {t_step[1]:.2f} s, gauge analysis {t_step[2]:.2f} s")
    ok &= err < 1e-9 and t_big < 10.0 and peak < 2 * 2**30
    print("OK" if ok else "FAILED (targets: agree to 1e-9; 2800 readings < 0.1 s; 1e5 < 10 s and < 2 GiB)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
