"""olti plan: a six-axis plan and its predicted quality before any measurement (issue 14 item 2)."""

import json
import re

from olti_calls import error_line, olti_sub
from tests.sim.test_six_axis import SIX_AXIS

SMALL = "{plan: {step_deg: 30.0, poses_per_node: 2}}"


def test_plan_report_predicts_what_the_campaign_then_identifies(tmp_path):
    """Per joint the report states the nodes covered in both directions and the predicted node u (linear, the
    budget); the campaign simulated from the same scenario, identified and propagated with the same budget,
    gives map-node uncertainties within 25 % of the prediction (the plan is evaluated at the station estimates,
    the identification at the identified stations). The plan CSV has the poses, directions and stations."""
    run = olti_sub("plan", SIX_AXIS, "--scenario-text", SMALL, "--out", tmp_path / "plan.csv")
    assert run.returncode == 0, run.stderr
    predicted = {}
    for joint, plus, minus, umax in re.findall(r"  (\w+): \d+ nodes, readings per node \+1 min (\d+) / -1 min (\d+); "
                                               r"u\(node\) max ([0-9.]+) mdeg", run.stdout):
        assert int(plus) >= 1 and int(minus) >= 1
        predicted[joint] = float(umax)
    assert len(predicted) == 6 and "identifies every parameter" in run.stdout
    head = [ln for ln in (tmp_path / "plan.csv").read_text().splitlines() if not ln.startswith("#")][0].split(",")
    assert head[:2] == ["pose", "theta1_deg"] and "dir6" in head and "station_3" in head
    sim = olti_sub("simulate", SIX_AXIS, "--scenario-text", SMALL, "--out", tmp_path / "sim")
    assert sim.returncode == 0, sim.stderr
    c = tmp_path / "sim" / "campaign.csv"
    ident = olti_sub("identify", c, "--robot", "ur5", "--tool-frame", "tool0", "--tool-offset-mm", "40,-25,60",
                  "--model", "errormap", "--grid-step-deg", "30", "--smoothing", "off",
                  "--out", tmp_path / "r.json")  # (the plan predicts the maps' u without the smoothness prior)
    assert ident.returncode == 0, ident.stderr
    unc = olti_sub("uncertainty", tmp_path / "r.json", c, "--method", "linear", "--out", tmp_path / "u.json")
    assert unc.returncode == 0, unc.stderr
    u = json.loads((tmp_path / "u.json").read_text())["error_map"]
    for joint, umax in predicted.items():
        got = 1e3 * max(max(u[joint]["forward_deg"]), max(u[joint]["reverse_deg"]))
        assert abs(got - umax) < 0.25 * umax, (joint, got, umax)


def test_plan_refuses_a_scara_scenario_in_one_line(tmp_path):
    run = olti_sub("plan", SIX_AXIS.parent / "paper000_scara.yaml")
    error_line(run.returncode, run.stderr, "six-axis")
