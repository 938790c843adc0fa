"""Validate the D-H and error-map models on paths not used in the identification (000 §4.3).

Identifies both models of paper 000 from a campaign and compares their
predictions with a simulated laser tracker (AT960-XR) reading the simulated
robot: on the X = 200 mm path (Figs. 9-10), a grid of paths (Fig. 11) and
random commands -- then on a path of your own, with the building blocks of
``olti_drake.report.validation``::

    python examples/validate_paper_models.py                       # simulate the paper default
    olti simulate my.yaml --out run && \\
    python examples/validate_paper_models.py my.yaml --campaign run/campaign.csv --out run

The truth the tracker measures is the scenario's robot (the one ``olti
simulate`` ran); if a ``truth.json`` lies next to the campaign, it must match.
Units: mm and degrees; errors printed in µm.
"""

import argparse
import json
import os
import sys

from olti_drake.report import validation as v
from olti_drake.sim.campaign import prepare, run_campaign
from olti_drake.io.csvio import load_campaign
from olti_drake.sim.scenario import as_plain, load_scenario


def campaign_for(scenario, campaign_path):
    """The campaign's valid readings: from the file, or simulated from the scenario."""
    if campaign_path is None:
        return v.campaign_data(run_campaign(prepare(scenario)))
    truth_path = os.path.join(os.path.dirname(os.path.abspath(campaign_path)), "truth.json")
    if os.path.isfile(truth_path):
        with open(truth_path, encoding="utf-8") as f:
            recorded = json.load(f)["truth"]["robot"]
        # JSON turns tuples into lists; as_plain does the same, so equal dicts mean the same robot.
        if recorded != json.loads(json.dumps(as_plain(scenario.robot))):
            raise SystemExit(f"error: {truth_path} was simulated with another robot than the scenario's")
    return load_campaign(campaign_path)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", default=None, help="scenario YAML (default: paper 000)")
    parser.add_argument("--campaign", help="campaign.csv from olti simulate (default: simulate the scenario)")
    parser.add_argument("--out", help="write figures (Figs. 6, 9-10, 11) into this directory")
    args = parser.parse_args(argv)

    scenario = load_scenario(args.scenario)
    robot = scenario.robot
    data = campaign_for(scenario, args.campaign)
    truth = robot.true_robot()

    # 1. Identify both models and validate them on the three unseen command sets of §4.3.
    report = v.validate_models(data, truth, (robot.nominal_L1_mm, robot.nominal_L2_mm), seed=scenario.seed)
    print(v.validation_table(report))

    # 2. Backlash shows as a difference between the passes: split the X = 200 result by pass.
    x200 = report.results["x200"].comparison
    for name, c in x200.items():
        print(f"X = 200 mm path, {name:9s}: RMS forward pass {1e3 * c['rms_fwd_mm']:6.1f} um, "
              f"return pass {1e3 * c['rms_rev_mm']:6.1f} um")

    # 3. A path of your own, with the building blocks: commands (nominal inverse kinematics),
    #    tracker readings of the true robot, and the registered comparison.
    path = v.x200_path(robot.nominal_L1_mm, robot.nominal_L2_mm, x_mm=350.0, y_start_mm=-300.0,
                       y_stop_mm=300.0, step_mm=50.0)
    measured = v.measure(truth, path.commands, seed=[scenario.seed, 99])
    models = {name: v.holding_map_ends(ident.model) for name, ident in report.identifications.items()}
    for name, c in v.compare(models, path.commands, measured, path.pass_dir).items():
        print(f"X = 350 mm path ({len(path)} points), {name:9s}: RMS {1e3 * c['rms_mm']:6.1f} um, "
              f"max {1e3 * c['max_mm']:6.1f} um")

    if args.out:
        for p in v.write_validation_figures(report, args.out, truth):
            print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
