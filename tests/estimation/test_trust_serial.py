"""Issue 24, classes 1 and 4 on the serial (N-joint) path: unit slips refused by name (readings in metres, a joint
column in radians, a residual far below the budget's reading u with the unit slip's signature, implausible scenario
link lengths), and the inputs a serial result is used with checked (the report's campaign and truth, the robot
model file's digest, budget contributors that leave unit, k or acts_on to a default). Each: exit 2, one line naming
the cause, nothing written; old results without the digest still load, with a note."""

from __future__ import annotations

import functools

import json
import shutil
import types
from pathlib import Path

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.io.serial_io import load_robot, serial_truth_dict, write_serial_campaign
from olti_drake.model.serial import synthetic_campaign, synthetic_truth
from olti_calls import olti_sub

olti = functools.partial(olti_sub, expect=0)  # (the CLI in a subprocess: exit 0 unless told, one error line)

ROOT = Path(__file__).resolve().parents[2]
TOOL = (40.0, -25.0, 60.0)
TOOL_ARG = "--tool-offset-mm=40,-25,60"
RANGES = np.array([[-100.0, 80.0], [-170.0, -10.0], [-120.0, 120.0], [-90.0, 90.0], [-60.0, 150.0],
                   [-180.0, 180.0]])
BUDGET = ROOT / "data" / "budget_paper000.yaml"




def identify(campaign, out, *extra, robot="ur5", expect=0, model="dh"):
    return olti("identify", campaign, "--robot", robot, "--tool-frame", "tool0", TOOL_ARG, "--model", model,
                "--out", out, *extra, expect=expect)


@pytest.fixture(scope="module")
def truth():
    return synthetic_truth(load_robot("ur5", "tool0"), seed=3, tool_offset_mm=TOOL)


@pytest.fixture(scope="module")
def camps(truth):
    return (synthetic_campaign(truth, 150, seed=4, ranges_deg=RANGES, noise_mm=0.0005),
            synthetic_campaign(truth, 150, seed=9, ranges_deg=RANGES, noise_mm=0.0005),
            synthetic_campaign(truth, 150, seed=4, ranges_deg=RANGES, noise_mm=0.0))


def write(path, camp, displacement_scale=1.0, radians_column=None):
    cmd = np.array(camp.distance_commands, dtype=float)
    if radians_column is not None:
        cmd[:, radians_column] = np.radians(cmd[:, radians_column])
    write_serial_campaign(path, cmd, camp.distance_dirs, station=camp.station,
                          displacement_mm=camp.displacement_mm * displacement_scale)
    return path


@pytest.fixture(scope="module")
def work(tmp_path_factory, camps, truth):
    """A campaign, another one of the same robot, a result of the first, a result of the second, a truth."""
    d = tmp_path_factory.mktemp("trust")
    write(d / "campaign.csv", camps[0])
    write(d / "other.csv", camps[1])
    identify(d / "campaign.csv", d / "result.json")
    identify(d / "other.csv", d / "result2.json")
    (d / "truth.json").write_text(json.dumps(serial_truth_dict(truth, "ur5", grid_step_deg=1.0, ranges_deg=RANGES)))
    return d


# -- class 1: unit slips ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def six_axis(tmp_path_factory):
    """The issue's reproduction: the six-axis scenario's campaign, its readings in metres, its elbow column in
    radians (the rows as written, only the one column rescaled)."""
    d = tmp_path_factory.mktemp("six")
    olti("simulate", ROOT / "diagrams" / "six_axis.yaml", "--out", d / "six")
    lines = (d / "six" / "campaign.csv").read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("station,"))
    columns = lines[k].split(",")
    for name, column, scale in (("m.csv", "displacement_mm", 1e-3), ("rad.csv", "theta3_deg", np.pi / 180)):
        c = columns.index(column)
        out = lines[:k + 1]
        for line in lines[k + 1:]:
            f = line.split(",")
            f[c] = f"{float(f[c]) * scale:.12g}"
            out.append(",".join(f))
        (d / name).write_text("\n".join(out) + "\n")
    return d


@pytest.mark.parametrize("model", ["dh", "errormap"])
def test_readings_in_metres_are_refused_by_the_location_errors_and_the_tool(six_axis, tmp_path, model):
    err = identify(six_axis / "m.csv", tmp_path / "r.json", model=model, expect=2).stderr
    assert "physically impossible" in err and "beyond 50 mm, no location error" in err, err
    assert "tool_offset_mm" in err and "from its nominal (40, -25, 60)" in err, err
    assert "readings in mm" in err and not (tmp_path / "r.json").exists()


def test_a_joint_column_in_radians_is_refused_by_its_map_values(six_axis, tmp_path):
    err = identify(six_axis / "rad.csv", tmp_path / "r.json", model="errormap", expect=2).stderr
    assert "elbow_joint" in err and "beyond 10 deg" in err and "radians" in err, err
    assert not (tmp_path / "r.json").exists()


def test_implausible_names_each_bound(truth, camps):
    """SerialPositionModel.implausible and the measurements' own: location errors (50 mm, 10 deg), the tool
    (100 mm from a given nominal), map values (10 deg), stations and the tracker beyond 20 reaches."""
    from olti_drake.model.serial import DistanceMeasurement, PointMeasurement, build_position_model

    camp = camps[0]
    model = build_position_model(truth.chain, camp.commands, camp.dirs, kind="errormap", tool_offset_mm=TOOL)
    dist = DistanceMeasurement(model, camp.distance_commands, camp.distance_dirs, camp.station,
                               camp.displacement_mm, truth.stations_mm, truth.dead_paths_mm)
    x = dist.start_vector()
    assert dist.implausible(x) == []
    names = list(dist.names)
    for name, value, words in (("elbow_joint_dx_mm", 60.0, "beyond 50 mm"), ("elbow_joint_drx_deg", -11.0,
                                                                               "beyond 10 deg"),
                               ("tool_z_mm", 170.0, "over 100 mm"), ("P0_x_mm", 1e6, "station 0"),
                               (next(n for n in names if "_forward_deg[" in n), 14.0, "no positioning deviation")):
        bad = x.copy()
        bad[names.index(name)] = value
        found = dist.implausible(bad)
        named = {"tool_z_mm": "tool_offset_mm", "P0_x_mm": "P0_mm"}.get(name, name)
        assert len(found) == 1 and words in found[0] and named in found[0], found
    point = PointMeasurement(model, camp.commands, camp.dirs, np.zeros((len(camp.commands), 3)),
                             np.array([1e6, 0, 0, 0, 0, 0]))
    assert "the tracker" in " ".join(point.implausible(point.start_vector()))


def _program(campaign):
    import olti_drake as od

    return od.calibration_problem(str(campaign), model="dh", robot="ur5", tool_frame="tool0", tool_offset_mm=TOOL,
                                  budget=str(BUDGET)).program


def test_residual_far_below_the_budget_is_refused_only_with_the_unit_slip_signature(tmp_path, camps):
    """The engine's check (LeastSquaresProgram.residual_warnings): a residual below u/100 with readings that
    spread 1/1000 of the motion (metres) is refused in one line; the same residual on readings in mm -- a
    noise-free simulation -- is not."""
    from olti_drake.estimation.calibration import FitRefused

    prog = _program(write(tmp_path / "m.csv", camps[0], displacement_scale=1e-3))
    fit = types.SimpleNamespace(residuals=np.full(len(camps[0].station), 1e-8), x=prog.x0)
    with pytest.raises(FitRefused) as e:
        prog.residual_warnings(fit)
    msg = str(e.value)
    assert "\n" not in msg and "below 1/100 of the reading uncertainty" in msg and "another unit" in msg, msg
    prog = _program(write(tmp_path / "mm.csv", camps[2]))
    assert prog.residual_warnings(types.SimpleNamespace(residuals=fit.residuals, x=prog.x0)) == []


def test_a_noise_free_campaign_with_a_budget_is_identified(tmp_path):
    """Exact readings of a truth inside the model family (location errors and tool only): the residual is far
    below the budget's u, the readings spread like the motion -- legitimate, identified."""
    exact = synthetic_truth(load_robot("ur5", "tool0"), seed=3, tool_offset_mm=TOOL, deviation_mdeg=0.0,
                            backlash_mdeg=0.0)
    write(tmp_path / "exact.csv", synthetic_campaign(exact, 150, seed=4, ranges_deg=RANGES, noise_mm=0.0))
    identify(tmp_path / "exact.csv", tmp_path / "r.json", "--budget", BUDGET)
    assert json.loads((tmp_path / "r.json").read_text())["residual_rms_mm"] < 1e-6


@pytest.mark.parametrize("value, words", [("1.0e+308", "beyond 100000 mm"), ("0.325", "more than 2 x off")])
def test_scenario_link_lengths_out_of_any_robot_are_refused(tmp_path, value, words):
    text = (ROOT / "diagrams" / "paper000_scara.yaml").read_text()
    assert "\n  L1_mm: 324.97\n" in text
    (tmp_path / "s.yaml").write_text(text.replace("\n  L1_mm: 324.97\n", f"\n  L1_mm: {value}\n"))
    shutil.copy(ROOT / "data" / "budget_paper000.yaml", tmp_path / "budget_paper000.yaml")
    err = olti("simulate", tmp_path / "s.yaml", "--out", tmp_path / "out", expect=2).stderr
    assert "robot.L1_mm" in err and words in err, err
    assert not (tmp_path / "out" / "campaign.csv").exists()


# -- class 4: the inputs a serial result is used with ---------------------------------------------------------------
def test_report_refuses_another_campaign_and_a_result_as_truth(work, tmp_path):
    d = work
    err = olti("report", d / "result.json", "--out", tmp_path / "a", "--campaign", d / "other.csv", expect=2).stderr
    assert "not the campaign" in err and "other.csv" in err and not (tmp_path / "a" / "report.html").exists()
    err = olti("report", d / "result.json", "--out", tmp_path / "b", "--truth", d / "result2.json", expect=2).stderr
    assert "not a simulation truth" in err and not (tmp_path / "b" / "report.html").exists()
    olti("report", d / "result.json", "--out", tmp_path / "c", "--campaign", d / "campaign.csv", "--truth",
         d / "truth.json")
    assert (tmp_path / "c" / "report.html").exists()


def test_a_robot_model_file_edited_after_identification_is_refused(work, tmp_path):
    d = work
    robot = tmp_path / "robot.urdf"
    shutil.copy(load_robot("ur5", "tool0").path, robot)
    identify(d / "campaign.csv", tmp_path / "r.json", robot=robot)
    stored = json.loads((tmp_path / "r.json").read_text())["robot"]
    assert len(stored["sha256"]) == 64 and stored["file"] == "robot.urdf"
    olti("predict", tmp_path / "r.json", d / "other.csv", "--out", tmp_path / "p.csv")
    from olti_drake.io.csvio import write_table

    chain = load_robot("ur5", "tool0")
    cmd = np.array([[0.0, -90, 90, -90, -90, 0], [10, -80, 80, -80, -90, 10]])
    t = chain.positions(cmd, chain.nominal_parameters(TOOL))
    write_table(tmp_path / "targets.csv", {"x_mm": t[:, 0], "y_mm": t[:, 1], "z_mm": t[:, 2],
                                           **{f"theta{i + 1}_deg": cmd[:, i] for i in range(6)}}, {})
    olti("compensate", tmp_path / "r.json", tmp_path / "targets.csv", "--out", tmp_path / "c.csv")
    robot.write_text(robot.read_text() + "\n<!-- edited after the identification -->\n")
    for args in (["predict", tmp_path / "r.json", d / "other.csv", "--out", tmp_path / "p2.csv"],
                 ["compensate", tmp_path / "r.json", tmp_path / "targets.csv", "--out", tmp_path / "c2.csv"],
                 ["uncertainty", tmp_path / "r.json", d / "campaign.csv", "--method", "linear", "--out",
                  tmp_path / "u.json"],
                 ["report", tmp_path / "r.json", "--out", tmp_path / "rep"]):
        err = olti(*args, expect=2).stderr
        assert "robot model file" in err and "changed since the identification" in err, err
    assert not (tmp_path / "p2.csv").exists() and not (tmp_path / "u.json").exists()
    assert not (tmp_path / "c2.csv").exists()
    assert not (tmp_path / "rep" / "report.html").exists()


def test_the_digest_check_names_both_digests(tmp_path):
    from olti_drake.io.serial_io import check_robot_digest

    robot = tmp_path / "robot.urdf"
    robot.write_text("<robot/>")
    with pytest.raises(InputError, match=r"changed since the identification \(sha256 [0-9a-f]{12}\.\.\., the "
                                         r"result's robot.sha256 000000000000"):
        check_robot_digest({"robot": {"sha256": "0" * 64}}, "r.json", robot)


def test_an_old_result_without_the_digest_loads_with_a_note(work, tmp_path):
    d = work
    data = json.loads((d / "result.json").read_text())
    del data["robot"]["sha256"]
    (tmp_path / "old.json").write_text(json.dumps(data))
    out = olti("predict", tmp_path / "old.json", d / "other.csv", "--out", tmp_path / "p.csv")
    notes = [line for line in out.stderr.splitlines() if "no digest of its robot model file" in line]
    assert len(notes) == 1 and notes[0].startswith("note: ") and (tmp_path / "p.csv").exists()


@pytest.mark.parametrize("key", ["unit", "k", "acts_on"])
def test_a_budget_contributor_must_state_unit_k_and_acts_on(tmp_path, key):
    from olti_drake.io.budget import load_budget

    entry = {"symbol": "u1", "name": "x", "value": 1.0, "unit": "um", "k": 1.0, "type": "B", "acts_on": "reading"}
    del entry[key]
    path = tmp_path / "b.yaml"
    path.write_text("name: b\ncontributors:\n- " + json.dumps(entry) + "\n")
    with pytest.raises(InputError) as e:
        load_budget(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg and "contributors[0] (u1)" in msg and f"no '{key}' given" in msg


def test_the_shipped_budgets_still_load():
    from olti_drake.io.budget import load_budget

    for name in ("budget_paper000.yaml", "budget_paper001.yaml"):
        assert load_budget(ROOT / "data" / name).contributors
