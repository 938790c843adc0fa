"""How long does a 5-fold cross-validation of a six-axis campaign take, against one plain identification?

    python benchmarks/bench_validate.py [--quick]

Issue 23's benchmark: "the automatic smoothing choice and a 5-fold validation on a six-axis campaign (~2 800
readings) in < 5 s". The shipped UR5-class arm (``olti_drake/models/ur5.urdf``, tool0, a tool offset of
(40, -25, 60) mm given as the start), a seeded synthetic truth *not* in the model family
(``olti_drake.model.serial.synthetic_truth``: harmonic joint deviations with backlash, joint-origin errors), a
random-pose distance campaign of 700 poses x 4 stations = 2 800 readings over +-90 deg on every joint, random
approach directions, 0.5 um reading noise, read as ``olti validate`` reads it (a SerialCampaign).

* baseline: one plain identification of the error-map model (15 deg grid) with the default options (the
  automatic smoothing choice included, where the engine has it): ``identify_serial``, uncertainty included --
  what ``olti identify`` does;
* validation: :func:`olti_drake.estimation.validation.cross_validate` with 5 folds by pose of ``dh`` and
  ``errormap:15`` (10 fits, each on 4/5 of the poses, and the held-out predictions) -- what ``olti validate
  --models dh,errormap:15`` does after reading the file.

The fastest of ``REPEATS`` runs each (one with ``--quick``), wall clock, both in this process after a warm-up of
the baseline. Target: the validation < ``TARGET_S`` s. Prints the held-out RMS per model (mm) and the recommended
model. Exits 1 when the target is missed. Units: mm, deg; times in s.
"""

import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from timing import best_of, cpu_busy  # noqa: E402

from olti_drake.estimation.serial_identification import SerialIdentificationOptions, identify_serial  # noqa: E402
from olti_drake.estimation.validation import cross_validate  # noqa: E402
from olti_drake.io.serial_io import SerialCampaign, load_robot  # noqa: E402
from olti_drake.model.serial import synthetic_campaign, synthetic_truth  # noqa: E402

TOOL = (40.0, -25.0, 60.0)
NOISE_MM = 0.0005
N_POSES, HALF_RANGE_DEG, GRID_STEP_DEG = 700, 90.0, 15.0
FOLDS, MODELS = 5, "dh,errormap:15"
TARGET_S = 5.0
REPEATS = 3


def campaign(chain):
    """The 2 800-reading distance campaign (module doc) as a SerialCampaign (file lines 2.., as written)."""
    truth = synthetic_truth(chain, seed=0, tool_offset_mm=TOOL)
    ranges = np.tile([-HALF_RANGE_DEG, HALF_RANGE_DEG], (chain.n_joints, 1))
    camp = synthetic_campaign(truth, N_POSES, seed=1, ranges_deg=ranges, noise_mm=NOISE_MM)
    m = len(camp.station)
    return SerialCampaign("distance", camp.distance_commands, camp.distance_dirs, np.arange(m) + 2, "benchmark",
                          station=camp.station, displacement_mm=camp.displacement_mm)


def main(argv) -> int:
    repeats = 1 if "--quick" in argv else REPEATS
    busy = cpu_busy()
    print(f"bench_validate: {os.cpu_count()} CPUs; " +
          (f"CPU use by other processes just before the run: {100 * busy:.0f}%" if busy is not None else ""))
    chain = load_robot("ur5", "tool0")
    data = campaign(chain)
    options = SerialIdentificationOptions(model="errormap", grid_step_deg=GRID_STEP_DEG, tool_offset_mm=TOOL)
    identify_serial(chain, data, options)  # warm-up: first-call costs (Drake, imports)
    t_one, ident = best_of(lambda: identify_serial(chain, data, options), repeats)
    t0 = time.perf_counter()
    t_cv, cv = best_of(lambda: cross_validate(chain, data, options, folds=FOLDS, models=MODELS, seed=0), repeats)
    total = time.perf_counter() - t0
    smoothing = getattr(ident.fit, "smoothing", None)
    print(f"campaign: {len(data)} distance readings, {cv['campaign']['poses']} poses, {len(ident.fit.names)} "
          f"unknowns (errormap {GRID_STEP_DEG:g} deg)" + (f"; smoothing: {smoothing.get('method')}, weight "
                                                          f"{smoothing.get('weight', float('nan')):.3g}"
                                                          if isinstance(smoothing, dict) else ""))
    print(f"{'':34s}{'s':>8s}{'x one':>8s}")
    print(f"{'one identification (baseline)':34s}{t_one:8.2f}{1.0:8.2f}")
    print(f"{f'{FOLDS}-fold validation of {MODELS}':34s}{t_cv:8.2f}{t_cv / t_one:8.2f}   (best of {repeats}, "
          f"{total:.1f} s in all)")
    for m in cv["models"]:
        mean = "refused" if m["mean_rms_mm"] is None else f"{1e3 * m['mean_rms_mm']:.2f} +- {1e3 * m['std_rms_mm']:.2f} um"
        print(f"  {m['name']:14s} held-out RMS {mean} ({m['parameters']} unknowns, {m['n_refused']} folds refused, "
              f"{m['seconds']:.2f} s)")
    print(f"  recommended: {cv['recommended']}")
    ok = t_cv < TARGET_S
    print("OK" if ok else f"FAILED (target: the {FOLDS}-fold validation < {TARGET_S:g} s)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
