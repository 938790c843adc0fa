"""How fast is the vectorized serial-chain model, against Drake one pose at a time?

    python benchmarks/bench_chain.py

On the shipped UR5-class arm (``olti_drake/models/ur5.urdf``, tool frame
``tool0``, a tool offset of (40, -25, 60) mm), for 2800 seeded random poses
within the joint limits (≈ 700 poses × 4 stations, the scale of a 3D
campaign):

- vectorized: ``SerialChain.jacobian`` — the tool point and its analytic
  Jacobian w.r.t. the 6 joint angles, the 36 joint-frame location errors and
  the 3 tool-offset components (45 columns), numpy over all poses (best of 5);
- Drake: ``drake_kinematics`` — a Python loop over the poses calling
  ``CalcPointsPositions`` and ``CalcJacobianTranslationalVelocity`` on the
  plant (joint-angle columns only; best of 2);
- the vectorized model at 100 000 poses (the 1° map benchmark's reading count).

The two must agree (1e-9 mm); exits 1 when they do not or when the vectorized
model takes 0.1 s or more for the 2800 poses (target).

Units: mm, deg; times in ms.
"""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import best_of, cpu_busy  # noqa: E402

import olti_drake  # noqa: E402
from olti_drake.model.chain import drake_kinematics, load_serial_chain  # noqa: E402

TARGET_S = 0.1


def main() -> int:
    busy = cpu_busy()
    chain = load_serial_chain(Path(olti_drake.__file__).parent / "models" / "ur5.urdf", "tool0")
    params = chain.nominal_parameters((40.0, -25.0, 60.0))
    theta = chain.random_angles(2800, seed=0)
    t_vec, (p, jac) = best_of(lambda: chain.jacobian(theta, params), 5)
    t_drake, (p_d, jac_d) = best_of(lambda: drake_kinematics(chain, theta, params[-3:]), 2)
    big = chain.random_angles(100_000, seed=1)
    t_big, _ = best_of(lambda: chain.jacobian(big, params), 2)
    err = max(np.abs(p - p_d).max(), np.abs(jac[:, :, :6] - jac_d).max())
    print(f"machine busy (others): {busy:.0%}" if busy is not None else "machine busy: unknown")
    print(f"UR5, 2800 poses, FK + Jacobian ({jac.shape[2]} columns vectorized, 6 by Drake)")
    print(f"  vectorized numpy : {t_vec * 1e3:8.1f} ms")
    print(f"  Drake per pose   : {t_drake * 1e3:8.1f} ms   ({t_drake / t_vec:.0f}x the vectorized time)")
    print(f"  largest difference: {err:.1e} mm (or mm/deg)")
    print(f"UR5, 100000 poses, vectorized: {t_big * 1e3:8.1f} ms")
    ok = err < 1e-9 and t_vec < TARGET_S
    print("OK" if ok else f"FAILED (target: agree to 1e-9, vectorized < {TARGET_S} s)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
