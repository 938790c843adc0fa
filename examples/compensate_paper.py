"""Compensation proved by simulation on the paper-000 set-up (000 §4, Fig. 11 style).

1. Simulates the paper campaign through the Drake diagram (352 bidirectional
   poses x 3 reflectors, Table 2 budget, the scenario's seed) and identifies
   the error-map model (000 Eq. 6-10) and, for comparison, the D-H model.
2. Compensates target positions the identification never saw (the grid of
   Cartesian paths of Fig. 11, random targets with random approach
   directions, the X = 200 mm path of Figs. 9-10) and runs the commands
   through the simulated truth robot (continuous joint deviations with
   backlash) -- and, for the grid, through the Drake ``ErrorMapJoint`` and
   ``MultibodyPlant``.
3. Prints the positioning errors before (an uncompensated controller:
   inverse kinematics with the *nominal* lengths 325/225 mm, no map) and
   after, overall and per (dir1, dir2) approach combination, and writes the
   before/after error-vector figure.

Errors are actual − target in the result's frame (its gauge: X along the arm
at θ1* = 0, mean of both directions, realized in the truth by
``compensation.frame_rotation_deg``); "registered" adds a best-fit rotation
about J1 per model and set, as the validation of 000 §4.3 does.

    python examples/compensate_paper.py [SCENARIO.yaml] [--out DIR]

Units: mm and degrees; errors printed in µm.
"""

import argparse
import os
import sys
import time

import numpy as np

from olti_drake.estimation import compensation as comp
from olti_drake.sim.compensation_check import drake_end_effector
from olti_drake.report import validation as v
from olti_drake.sim.campaign import prepare, run_campaign
from olti_drake.estimation.identification import IdentificationOptions, identify
from olti_drake.model.scara import ScaraModel
from olti_drake.sim.scenario import load_scenario

#: Margin (deg) kept from the identified map range when drawing unseen targets, so their compensated
#: commands stay inside the grid; θ2 starts at 2° so the nominal targets lie within the true reach.
MARGIN_DEG = 1.0
THETA2_MIN_DEG = 2.0


def target_sets(model: ScaraModel, L1_mm, L2_mm, seed):
    """name -> (CommandSet, given directions or None): targets not used in the identification (000 §4.3)."""
    g1, g2 = model.map1.grid_deg, model.map2.grid_deg
    r1 = (g1[0] + MARGIN_DEG, g1[-1] - MARGIN_DEG)
    r2 = (max(g2[0], THETA2_MIN_DEG), g2[-1] - MARGIN_DEG)
    rnd = v.random_commands(500, [seed, v.STREAM_RANDOM_COMMANDS], r1, r2, L1_mm, L2_mm)
    return {"grid paths (Fig. 11)": (v.grid_paths(L1_mm, L2_mm, r1, r2), None),
            "random targets (random dirs)": (rnd, (rnd.commands.dir1, rnd.commands.dir2)),
            "X = 200 mm path (Figs. 9-10)": (v.x200_path(L1_mm, L2_mm), None)}


def print_table(name, res):
    print(f"\n{name}: {len(next(iter(res.values()))['errors'])} targets; positioning error actual - target, um")
    print(f"  {'commands':26s} {'RMS':>7s} {'max':>7s} {'RMS reg.':>8s}   "
          + "  ".join(f"{f'RMS {a:+d}{b:+d}':>10s}" for a, b in comp.DIRECTION_COMBOS))
    for label, r in res.items():
        per = "  ".join(f"{1e3 * r[f'rms_{a:+d}{b:+d}_mm']:6.1f} ({r[f'n_{a:+d}{b:+d}']:3d})"
                        for a, b in comp.DIRECTION_COMBOS)
        print(f"  {label:26s} {1e3 * r['rms_mm']:7.1f} {1e3 * r['max_mm']:7.1f} {1e3 * r['rms_registered_mm']:8.1f}"
              f"   {per}")


def plot_before_after(targets, before, after, path, magnification=1000.0, scale_um=200.0):
    """Fig. 11 style: error vectors from the targets, magnified, before and after compensation (µm).

    ``before``/``after``: (errors (N, 2) mm, dir1 (N,)); red/blue: J1 approached +1/−1.
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 7), sharex=True, sharey=True)
    for ax, (title, (e, dir1)) in zip(axes, (("before: nominal inverse kinematics", before),
                                             ("after: error-map compensation", after))):
        tip = targets + magnification * e
        for d, color in ((1, "tab:red"), (-1, "tab:blue")):
            s = dir1 == d
            ax.plot(np.stack([targets[s, 0], tip[s, 0]]), np.stack([targets[s, 1], tip[s, 1]]), "-", color=color,
                    lw=0.8)
            ax.plot(tip[s, 0], tip[s, 1], "o", color=color, ms=2.5, mfc="none", label=f"J1 approach {d:+d}")
        ax.plot(targets[:, 0], targets[:, 1], ".", color="k", ms=4, label="targets")
        rms = 1e3 * np.sqrt(np.mean(np.sum(e ** 2, axis=1)))
        ax.set_title(f"{title}\nRMS {rms:.1f} µm, max {1e3 * np.max(np.hypot(*e.T)):.1f} µm", fontsize=10)
        ax.set_aspect("equal")
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("X, mm")
    x0, y0 = targets[:, 0].min(), targets[:, 1].max() + 80
    axes[0].plot([x0, x0 + magnification * scale_um * 1e-3], [y0, y0], "k-", lw=2.5)
    axes[0].annotate(f"error scale: {scale_um:g} µm (x{magnification:g})", (x0, y0), textcoords="offset points",
                     xytext=(0, 5), fontsize=8)
    axes[0].set_ylabel("Y, mm")
    axes[0].legend(fontsize=8, loc="lower left")
    fig.suptitle("Positioning error of the simulated robot on paths not used in the identification")
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default=None, help="scenario YAML (default: paper 000)")
    parser.add_argument("--out", default="compensate_out", help="directory of the figure (default compensate_out)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()

    # 1. The campaign through the Drake diagram, then both identifications (000 §4.2).
    scenario = load_scenario(args.scenario)
    r = scenario.robot
    setup = prepare(scenario)
    data = v.campaign_data(run_campaign(setup))
    idents = {kind: identify(data, IdentificationOptions(model=kind, nominal_L1_mm=r.nominal_L1_mm,
                                                         nominal_L2_mm=r.nominal_L2_mm)) for kind in ("errormap", "dh")}
    em = idents["errormap"].model
    print(f"simulated and identified in {time.perf_counter() - t0:.2f} s: {data.commands.theta1_deg.size} readings, "
          f"error-map residual RMS {1e3 * idents['errormap'].residual_rms_mm:.2f} um")
    truth = setup.robot
    print(f"result frame in the truth frame (gauge at theta1* = 0): {1e3 * comp.frame_rotation_deg(truth):.2f} mdeg")

    # 2-3. Compensate unseen targets and run them through the truth robot.
    models = {"before (nominal IK)": ScaraModel(r.nominal_L1_mm, r.nominal_L2_mm, 0.0),
              "D-H identified": idents["dh"].model, "after (error map)": em}
    results = {}
    for name, (cs, dirs) in target_sets(em, r.nominal_L1_mm, r.nominal_L2_mm, scenario.seed).items():
        clamp = "X = 200" in name  # needs θ2* up to 142.6°, beyond the J2 map [0, 140]°: hold the end values
        ms = {k: v.holding_map_ends(m) for k, m in models.items()} if clamp else models
        t = time.perf_counter()
        results[name] = res = comp.compare_compensation(ms, truth, cs.xy_cmd_mm, *(dirs or (None, None)))
        dt = time.perf_counter() - t
        print_table(name, res)
        c = res["after (error map)"]["compensation"]
        print(f"  compensation: {c.iterations} Newton iteration(s), max model residual {c.residual_mm.max():.1e} mm, "
              f"{int(c.needs_approach.any(axis=1).sum())} target(s) needing an overrun approach, "
              f"{1e3 * dt:.1f} ms for the three models")
        if clamp:
            out = v.outside_map(em, c.commands)
            print(f"  {int(out.sum())} of {len(out)} compensated commands lie beyond the identified map range; "
                  f"there the map holds its end values")

    # The same commands through the Drake diagram: ErrorMapJoint derives the directions from the sequence.
    grid_name = next(iter(results))
    after = results[grid_name]["after (error map)"]
    c = after["compensation"].commands
    p_drake, d_drake = drake_end_effector(truth, c)
    p_numpy = truth.end_effector(c.theta1_deg, c.theta2_deg, c.dir1, c.dir2)
    same = np.array_equal(d_drake, np.column_stack([c.dir1, c.dir2]))
    print(f"\nDrake diagram on the grid commands: max |plant - numpy truth| {np.abs(p_drake - p_numpy).max():.1e} mm, "
          f"directions derived by ErrorMapJoint {'equal' if same else 'DIFFER from'} those of commands.csv")

    os.makedirs(args.out, exist_ok=True)
    grid = results[grid_name]
    before = grid["before (nominal IK)"]
    path = plot_before_after(after["compensation"].targets_mm,
                             (before["errors"], before["compensation"].commands.dir1), (after["errors"], c.dir1),
                             os.path.join(args.out, "compensation_before_after.png"))
    print(f"wrote {path}")
    ratio = {k: res["before (nominal IK)"]["rms_mm"] / res["after (error map)"]["rms_mm"] for k, res in results.items()}
    print("RMS improvement before/after: " + "; ".join(f"{k} {q:.1f}x" for k, q in ratio.items()))
    print(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
