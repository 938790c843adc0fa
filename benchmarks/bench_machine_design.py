"""How fast is ``olti design`` on a 3D machine-tool result (issue 24, class 5: > 22 min, without output)?

    python benchmarks/bench_machine_design.py

On the machine_3d walk-through's size (the numpy twin of diagrams/machine_3d.yaml: a 6 x 5 x 4 command grid x 3
tools = 360 targets, 5 pan/tilt heads, 001 Table 4 noise), multilaterated:

- baseline in the same run: the dense evaluation of one layout -- the per-station sandwiches of
  ``MachineStationInformation`` summed and ``position_u`` (the (3 N_i)² = 1080² matrices, an eigendecomposition
  per layout), as the design evaluated every candidate before (best of 2);
- ours: ``LayoutCosts.u`` of a batch of layouts (four stations + each of the candidates), per layout (best of
  3); the two must agree to 1e-9;
- the default design (``design_machine_stations``: 3 starts, <= 5 sweeps, candidates on the default step of
  the three boxes of tests/estimation/test_machine_design.py, ~100 candidates) end to end, and the dense evaluation's time
  for the same number of layouts (extrapolated: it is what the design ran before).

Exits 1 when the two evaluations disagree, the ratio (dense per layout / ours per layout) is below 20, or the
default design takes 60 s or more. Times in s; the machine is shared (its load is printed).
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from timing import best_of, cpu_busy  # noqa: E402

from olti_drake.estimation.machine_design import (LayoutCosts, MachineStationInformation,  # noqa: E402
                                                  default_step_mm, design_machine_stations)
from olti_drake.estimation.multilateration import machine_campaign, multilaterate  # noqa: E402
from olti_drake.estimation.serial_design import candidate_points  # noqa: E402
from olti_drake.io.budget import default_budget  # noqa: E402
from olti_drake.model.budget import ReadingErrors  # noqa: E402
from olti_drake.model.machine import Machine3DScenario, simulate_machine_campaign_3d  # noqa: E402
from olti_drake.model.volumetric3d import MachineConfig  # noqa: E402
from olti_drake.threads import single_thread_blas  # noqa: E402

BOXES = [[[-400, -200], [-300, 600], [0, 400]], [[600, 800], [-300, 600], [0, 400]], [[0, 400], [-400, -300], [0, 400]]]
MIN_RATIO = 20.0
MAX_DESIGN_S = 60.0


def main() -> int:
    cfg = MachineConfig(tool_offsets_mm=((0, 0, 100), (80, 0, 100), (0, 80, 140)), knot_spacing_mm=50.0)
    cols, _ = simulate_machine_campaign_3d(Machine3DScenario(config=cfg, grid=(6, 5, 4), tools=(0, 1, 2)))
    res = multilaterate(machine_campaign(cols, "machine_3d twin"))
    errors = ReadingErrors(default_budget("machine"))
    info = MachineStationInformation(res.targets_mm, res.nominal_mm, "best-fit", errors)
    step = default_step_mm(np.asarray(BOXES, float), res.targets_mm)
    cand = candidate_points(np.asarray(BOXES, float), step)
    busy = cpu_busy()
    print(f"{len(res.targets_mm)} targets, {len(cand)} candidates on a {step:g} mm grid; machine busy "
          f"{'?' if busy is None else f'{100 * busy:.0f} %'}")
    layout = np.vstack([res.stations_mm[:4], cand[:1]])
    with single_thread_blas():
        t_dense, u_dense = best_of(lambda: info.position_u(sum(info.block(s)[0] for s in layout)), 2)
        costs = LayoutCosts(info.targets_mm, info.nominal_mm, "best-fit", errors, np.vstack([layout, cand]))
        t_batch, u_batch = best_of(lambda: costs.u([0, 1, 2, 3], np.arange(5, 5 + len(cand))), 3)
    ours = t_batch / len(cand)
    agree = np.allclose(u_batch[0], u_dense, rtol=1e-9, atol=0)
    ratio = t_dense / ours
    print(f"one layout: dense {t_dense:.3f} s, ours {1e3 * ours:.2f} ms (batch of {len(cand)}); ratio {ratio:.0f}x; "
          f"agree to 1e-9: {agree}")
    t0 = time.perf_counter()
    d = design_machine_stations(info, cand, 5)
    t_design = time.perf_counter() - t0
    print(f"default design: {t_design:.1f} s, {d.evaluations} layouts evaluated (dense, as before: ~"
          f"{d.evaluations * t_dense / 60:.0f} min), max u {1e3 * d.cost_mm:.3f} um")
    ok = agree and ratio >= MIN_RATIO and t_design < MAX_DESIGN_S
    print("ok" if ok else "FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
