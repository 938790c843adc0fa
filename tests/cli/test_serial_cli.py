"""N-joint serial robots through the command line (``python -m olti_drake.cli``): identify, predict,
compensate on campaigns of a seeded synthetic truth that is NOT in the model family (harmonic joint
deviations with backlash, joint-origin location errors, a tool offset off the last axis; see
``model.serial.synthetic_truth``); every malformed input one line, exit 2, no traceback, nothing written."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from olti_drake.io.serial_io import load_robot, serial_truth_dict, write_serial_campaign
from olti_drake.model.serial import synthetic_campaign, synthetic_truth
from olti_calls import olti_sub

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).resolve().parents[1] / "data"
TOOL = (40.0, -25.0, 60.0)
TOOL_ARG = "--tool-offset-mm=40,-25,60"
RANGES = np.array([[-100.0, 80.0], [-170.0, -10.0], [-120.0, 120.0], [-90.0, 90.0], [-60.0, 150.0],
                   [-180.0, 180.0]])
NOISE_MM = 0.0005


def write_distance(path, camp, dirs=True):
    write_serial_campaign(path, camp.distance_commands, camp.distance_dirs if dirs else None, station=camp.station,
                          displacement_mm=camp.displacement_mm)
    return path


@pytest.fixture(scope="module")
def ur5():
    return load_robot("ur5", "tool0")


@pytest.fixture(scope="module")
def truth(ur5):
    return synthetic_truth(ur5, seed=3, tool_offset_mm=TOOL)


@pytest.fixture(scope="module")
def files(tmp_path_factory, truth):
    """Training distance campaign (300 poses x 4 stations), a held-out one (60 poses), the truth file."""
    d = tmp_path_factory.mktemp("ur5")
    train = synthetic_campaign(truth, 300, seed=4, ranges_deg=RANGES, noise_mm=NOISE_MM)
    held = synthetic_campaign(truth, 60, seed=5, ranges_deg=RANGES - np.array([-10.0, 10.0]), noise_mm=NOISE_MM)
    write_distance(d / "campaign.csv", train)
    write_distance(d / "held_out.csv", held)
    (d / "truth.json").write_text(json.dumps(serial_truth_dict(truth, "ur5", grid_step_deg=0.1, ranges_deg=RANGES)))
    return d, train, held


@pytest.fixture(scope="module")
def errormap_result(files):
    d, _, _ = files
    out = olti_sub("identify", d / "campaign.csv", "--robot", "ur5", "--tool-frame", "tool0", TOOL_ARG,
                   "--model", "errormap", "--grid-step-deg", 10, "--out", d / "result.json", expect=0)
    return d / "result.json", out.stdout


def test_identify_errormap_recovers_the_backlash_of_a_truth_outside_the_model(errormap_result, truth, ur5):
    """Criterion: the identified backlash (forward - reverse) at every map node is within 3 stated standard
    uncertainties sqrt(u_f^2 + u_r^2) of the truth's at >= 90 % of the nodes and within 5 at all of them.
    Backlash is what the gauge (map levels, rigid motion) and the base-set trades (constant levels) cannot
    move, so it is comparable node by node; the remaining misses are the piecewise-linear map's
    interpolation error of the harmonic truth (not in the model family), which the residual-based u only
    partly covers."""
    path, stdout = errormap_result
    res = json.loads(path.read_text())
    assert res["model"] == "errormap" and res["robot"]["joints"] == list(ur5.joint_names)
    assert "wrote" in stdout and "residual RMS" in stdout
    z = []
    for j, joint in enumerate(ur5.joint_names):
        m, u = res["error_map"][joint], res["uncertainty"]["error_map"][joint]
        g = np.array(m["grid_deg"])
        back = np.array(m["forward_deg"]) - np.array(m["reverse_deg"])
        true_back = truth.deviations[j](g, 1.0) - truth.deviations[j](g, -1.0)
        z += list(np.abs(back - true_back) / np.hypot(u["forward_deg"], u["reverse_deg"]))
    z = np.array(z)
    assert np.mean(z < 3) >= 0.9 and z.max() < 5, (np.mean(z < 3), z.max())
    assert len(res["stations_mm"]) == 4 and res["campaign"]["readings"] == 1200
    assert res["residual_rms_mm"] < 0.01
    assert any("trades with" in d["reason"] for d in res["dropped"])
    assert "rigid motion of the robot together with the stations" in res["gauge"]


@pytest.fixture(scope="module")
def arm7(tmp_path_factory):
    """The 7-joint arm (floating root welded, finger joints ignored, a continuous joint): its own truth, a dh
    result from 80 one-directional poses x 4 stations."""
    d = tmp_path_factory.mktemp("arm7")
    chain = load_robot(DATA / "arm7_floating.urdf", "tcp")
    truth = synthetic_truth(chain, seed=7, tool_offset_mm=(20.0, 10.0, 30.0))
    camp = synthetic_campaign(truth, 80, seed=8, noise_mm=NOISE_MM, directions=False)
    write_distance(d / "c.csv", camp, dirs=False)
    olti_sub("identify", d / "c.csv", "--robot", DATA / "arm7_floating.urdf", "--tool-frame", "tcp",
             "--tool-offset-mm=20,10,30", "--model", "dh", "--out", d / "r.json", expect=0)
    return d, chain


def test_seven_joint_floating_root_with_fingers(arm7):
    """The result names the 7 chain joints only (no finger), the model file relative to itself, a tool offset
    near the truth's, and fits the harmonic truth as a dh model can (< 0.2 mm RMS)."""
    d, _ = arm7
    res = json.loads((d / "r.json").read_text())
    assert res["robot"]["joints"] == ["j1", "j2", "j3", "j4", "j5", "j6", "j7"]
    assert res["robot"]["file"] == os.path.relpath(DATA / "arm7_floating.urdf", d)
    assert np.abs(np.array(res["tool_offset_mm"]) - (20.0, 10.0, 30.0)).max() < 1.0
    assert {k.split("_")[0] for k in res if k.endswith(("_dx_mm", "_drx_deg", "_offset_deg"))} <= set(
        res["robot"]["joints"])
    assert res["residual_rms_mm"] < 0.2


def test_missing_meshes_are_noted_once_and_identified(tmp_path):
    """A model whose meshes cannot be found identifies (kinematics only) and says so once, in the output and
    the result's notes."""
    chain = load_robot(DATA / "missing_mesh.urdf", "tool")
    truth = synthetic_truth(chain, seed=2, tool_offset_mm=(10.0, 5.0, 0.0))
    camp = synthetic_campaign(truth, 40, seed=3, noise_mm=NOISE_MM, directions=False)
    write_distance(tmp_path / "c.csv", camp, dirs=False)
    out = olti_sub("identify", tmp_path / "c.csv", "--robot", DATA / "missing_mesh.urdf", "--tool-frame", "tool",
                   "--tool-offset-mm=10,5,0", "--model", "dh", "--out", tmp_path / "r.json", expect=0).stdout
    assert out.count("mesh file(s) cannot be found") == 1
    res = json.loads((tmp_path / "r.json").read_text())
    assert sum("cannot be found" in n for n in res["notes"]) == 1 and res["robot"]["joints"] == ["j1", "j2"]


def test_point_campaign_identifies_the_tracker_frame(tmp_path, truth):
    """A tracker campaign: the tracker frame is estimated (its rotation within 0.05 deg of the truth's: the
    gauge holds J1's location errors at 0, which moves the frame by their size only)."""
    camp = synthetic_campaign(truth, 120, seed=9, ranges_deg=RANGES, noise_mm=NOISE_MM)
    write_serial_campaign(tmp_path / "p.csv", camp.commands, camp.dirs, points_mm=camp.points_mm)
    olti_sub("identify", tmp_path / "p.csv", "--robot", "ur5", "--tool-frame", "tool0", TOOL_ARG, "--model",
             "errormap", "--grid-step-deg", 30, "--out", tmp_path / "r.json", expect=0)
    res = json.loads((tmp_path / "r.json").read_text())
    frame = res["tracker_frame"]
    assert np.abs(np.array(frame["rotation_deg"]) - truth.frame[3:]).max() < 0.05
    assert "stations_mm" not in res and res["residual_rms_mm"] < 0.1
    assert "rigid motion of the robot relative to the unknown tracker frame" in res["gauge"]


def test_one_station_without_directions_refused_by_name_then_regularized(tmp_path, ur5):
    """One station and no directions: 40 readings cannot identify 30-degree maps on six joints; refused
    before solving, naming the parameters, nothing written; --regularize states its prior in the notes."""
    truth = synthetic_truth(ur5, seed=3, tool_offset_mm=TOOL, n_stations=1)
    camp = synthetic_campaign(truth, 40, seed=4, ranges_deg=RANGES, noise_mm=NOISE_MM, directions=False)
    write_distance(tmp_path / "c.csv", camp, dirs=False)
    args = ["identify", tmp_path / "c.csv", "--robot", "ur5", "--tool-frame", "tool0", TOOL_ARG, "--model",
            "errormap", "--grid-step-deg", 30, "--out", tmp_path / "r.json"]
    # The default smoothness prior holds the maps straight where the readings cannot shape them, and says so.
    olti_sub(*args, expect=0)
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["smoothing"]["method"] == "restricted maximum likelihood"
    assert any("the prior outweighs the readings at" in n for n in res["notes"])
    (tmp_path / "r.json").unlink()
    args += ["--smoothing", "off"]
    err = olti_sub(*args, expect=2).stderr
    assert "not identifiable: shoulder_lift_joint_dx_mm" in err and "--regularize" in err
    assert not (tmp_path / "r.json").exists()
    olti_sub(*args, "--regularize", expect=0)
    res = json.loads((tmp_path / "r.json").read_text())
    assert any(n.startswith("regularized: the readings cannot identify") and "sigma 1 mm or 1 deg" in n
               for n in res["notes"])
    assert "reverse_deg" not in res["error_map"]["elbow_joint"]


def test_bad_inputs_are_one_line_and_write_nothing(tmp_path, files):
    d, _, _ = files
    (tmp_path / "broken.urdf").write_text("<robot name='x'><link name='a'></robot>")
    (tmp_path / "five.csv").write_text("station,theta1_deg,theta2_deg,theta3_deg,theta4_deg,theta5_deg,"
                                       "displacement_mm\n" + "".join(f"0,{i},1,2,3,4,{i}.5\n" for i in range(6)))
    nan = (d / "campaign.csv").read_text().splitlines()
    k = next(i for i, line in enumerate(nan) if line and line[0].isdigit())  # first data row (0-based)
    nan[k + 2] = nan[k + 2].rsplit(",", 1)[0] + ",nan"
    (tmp_path / "nan.csv").write_text("\n".join(nan) + "\n")
    out = tmp_path / "r.json"
    base = ["--model", "dh", "--out", out]
    cases = [
        (["identify", d / "campaign.csv", "--robot", tmp_path / "broken.urdf", "--tool-frame", "a"], "broken.urdf"),
        (["identify", d / "campaign.csv", "--robot", "ur5", "--tool-frame", "flange"],
         "tool frame 'flange' not found in"),
        (["identify", d / "campaign.csv", "--robot", "ur5"], "--tool-frame"),
        (["identify", tmp_path / "five.csv", "--robot", "ur5", "--tool-frame", "tool0"],
         "5 joint columns (theta1_deg .. theta5_deg) but the robot ur5 has 6 joints"),
        (["identify", tmp_path / "nan.csv", "--robot", "ur5", "--tool-frame", "tool0"],
         f"nan.csv:{k + 3}: column 'displacement_mm': nan is not finite"),
        (["identify", d / "campaign.csv", "--robot", "ur5", "--tool-frame", "tool0", "--grid1-deg", "0:10:5"],
         "--grid1-deg is a SCARA option"),
        (["identify", d / "campaign.csv", "--grid-step-deg", "5"], "--grid-step-deg needs --robot FILE"),
        (["uncertainty", d / "truth.json", d / "campaign.csv", "--method", "linear"],
         "a simulation truth, not an identified result"),
    ]
    for args, expect in cases:
        err = olti_sub(*args, *(base if args[0] == "identify" else base[2:]), expect=2).stderr
        assert expect in err, (args, err)
        assert not out.exists()


def _read_csv(path):
    lines = [ln for ln in Path(path).read_text().splitlines() if not ln.startswith("#")]
    head = lines[0].split(",")
    vals = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    return {c: vals[:, i] for i, c in enumerate(head)}


def _rigid_residual(a, b):
    """b - (R a + t) for the best rigid fit (Kabsch), mm: what is left after the gauge's rigid motion."""
    ac, bc = a - a.mean(axis=0), b - b.mean(axis=0)
    u, _, vt = np.linalg.svd(bc.T @ ac)
    rot = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))]) @ vt
    return bc - ac @ rot.T


def test_predict_cross_validates_on_held_out_readings(errormap_result, files, ur5):
    """On 240 held-out readings (poses never used): the identified model's predicted_displacement_mm matches
    the readings within 3 x its own identification residual RMS (316 unknowns from 1200 readings); the truth file (maps sampled every 0.1 deg)
    predicts them at the noise level; the predicted tool points equal the truth's up to the gauge's rigid
    motion within 0.05 mm (RMS 0.015 mm; the nominal model misses by over 10 times more)."""
    d, _, held = files
    result, _ = errormap_result
    rms = json.loads(result.read_text())["residual_rms_mm"]
    olti_sub("predict", result, d / "held_out.csv", "--out", d / "pred.csv", expect=0)
    olti_sub("predict", d / "truth.json", d / "held_out.csv", "--out", d / "pred_truth.csv", expect=0)
    pred, true = _read_csv(d / "pred.csv"), _read_csv(d / "pred_truth.csv")
    assert np.abs(pred["theta6_deg"] - held.distance_commands[:, 5]).max() < 1e-9
    assert np.array_equal(pred["dir3"], held.distance_dirs[:, 2])
    miss = pred["predicted_displacement_mm"] - pred["displacement_mm"]
    assert np.sqrt(np.mean(miss ** 2)) < 3 * rms
    assert np.sqrt(np.mean((true["predicted_displacement_mm"] - true["displacement_mm"]) ** 2)) < 3 * NOISE_MM
    pts = [np.column_stack([t[c] for c in ("x_mm", "y_mm", "z_mm")]) for t in (pred, true)]
    err = np.linalg.norm(_rigid_residual(*pts), axis=1)
    nominal = ur5.positions(held.distance_commands, ur5.nominal_parameters(TOOL))
    assert err.max() < 0.05 and np.sqrt(np.mean(err ** 2)) < 0.015
    assert np.linalg.norm(_rigid_residual(nominal, pts[1]), axis=1).max() > 10 * err.max()
    # commands outside the map grid: refused naming the line, or clamped
    text = (d / "held_out.csv").read_text().splitlines()
    k = next(i for i, line in enumerate(text) if line and line[0].isdigit())
    row = text[k].split(",")
    row[1] = "150"  # theta1 beyond the identified grid
    text[k] = ",".join(row)
    (d / "outside.csv").write_text("\n".join(text) + "\n")
    err = olti_sub("predict", result, d / "outside.csv", "--out", d / "p2.csv", expect=2).stderr
    assert f"outside.csv:{k + 1}:" in err and "--outside clamp" in err and not (d / "p2.csv").exists()
    olti_sub("predict", result, d / "outside.csv", "--out", d / "p2.csv", "--outside", "clamp", expect=0)


def _targets(path, chain, commands, dirs=None, tool=TOOL, shift=None):
    """targets.csv: the nominal chain's tool points at the nominal poses (what the program means), the poses
    and their directions."""
    from olti_drake.io.csvio import write_table

    t = chain.positions(commands, chain.nominal_parameters(tool)) + (0.0 if shift is None else shift)
    cols = {"x_mm": t[:, 0], "y_mm": t[:, 1], "z_mm": t[:, 2]}
    cols.update({f"theta{i + 1}_deg": commands[:, i] for i in range(commands.shape[1])})
    if dirs is not None:
        cols.update({f"dir{i + 1}": dirs[:, i] for i in range(commands.shape[1])})
    write_table(path, cols, {f"dir{i + 1}": "%d" for i in range(commands.shape[1])})
    return t


def test_compensate_puts_the_true_tool_point_on_the_targets(errormap_result, files, truth, ur5):
    """Targets = the nominal chain's tool points at 30 nominal poses (elbow kept 15 deg off the stretched
    singularity and inside the identified grids). Executed on the truth with their directions, the
    compensated commands hit the targets within 0.05 mm once the base placement (a rigid motion: the gauge,
    which distances cannot see) is registered, 10 x better than the uncompensated commands; by the model the
    residual is below 1e-6 mm and the tool orientation stays the nominal pose's; directions are unchanged;
    a target out of reach is refused naming its line, nothing written. --urdf-out: Drake's FK of the written
    URDF at the commands equals the identified model's geometric part to 1e-6 mm."""
    d, _, _ = files
    result, _ = errormap_result
    ranges = RANGES.copy()
    ranges[2] = (30.0, 120.0)
    camp = synthetic_campaign(truth, 30, seed=11, ranges_deg=ranges - np.array([-15.0, 15.0]))
    targets = _targets(d / "targets.csv", ur5, camp.commands, camp.dirs)
    olti_sub("compensate", result, d / "targets.csv", "--out", d / "commands.csv", "--tables", d / "tables",
             "--urdf-out", d / "identified.urdf", expect=0)
    c = _read_csv(d / "commands.csv")
    cmd = np.column_stack([c[f"theta{i}_deg"] for i in range(1, 7)])
    dirs = np.column_stack([c[f"dir{i}"] for i in range(1, 7)])
    assert np.array_equal(dirs, camp.dirs) and c["residual_mm"].max() < 1e-6
    assert c["orientation_change_deg"].max() < 1e-4
    hit = np.linalg.norm(_rigid_residual(truth.positions(cmd, dirs), targets), axis=1)
    plain = np.linalg.norm(_rigid_residual(truth.positions(camp.commands, camp.dirs), targets), axis=1)
    assert hit.max() < 0.05 and plain.max() > 10 * hit.max(), (hit.max(), plain.max())
    table = _read_csv(d / "tables" / "elbow_joint_compensation.csv")
    assert set(table) >= {"angle_deg", "forward_command_deg", "reverse_command_deg"}
    # the identified URDF, loaded by Drake
    from olti_drake.io.serial_io import load_serial_result
    from olti_drake.model.chain import drake_kinematics

    model = load_serial_result(result).model
    written = load_robot(d / "identified.urdf", "tool0_tool_point")
    p_drake, _ = drake_kinematics(written, cmd, jacobian=False)
    assert np.abs(p_drake - model.chain.positions(cmd, model.chain_parameters(model.start_vector()))).max() < 1e-6
    # out of reach: refused, naming the line
    _targets(d / "far.csv", ur5, camp.commands[:3], camp.dirs[:3], shift=np.array([0.0, 0.0, 5000.0]))
    err = olti_sub("compensate", result, d / "far.csv", "--out", d / "far_cmd.csv", expect=2).stderr
    assert "far.csv:2: target" in err and "cannot be reached" in err and not (d / "far_cmd.csv").exists()


def test_compensate_seven_joints_keeps_the_nominal_null_space_choice(arm7):
    """A dh result of the 7-joint arm: compensated commands stay near the nominal poses (median largest joint
    change < 0.3 deg, all < 2 deg: the redundant joint is not wandered off), hit the targets by the model, and
    the URDF round trip holds with the dh offsets folded into the joint origins."""
    from olti_drake.io.serial_io import load_serial_result
    from olti_drake.model.chain import drake_kinematics

    tmp_path, chain = arm7
    poses = chain.random_angles(10, seed=21) * 0.5
    _targets(tmp_path / "t.csv", chain, poses, tool=(20.0, 10.0, 30.0))
    olti_sub("compensate", tmp_path / "r.json", tmp_path / "t.csv", "--out", tmp_path / "cmd.csv", "--urdf-out",
             tmp_path / "arm7_identified.urdf", expect=0)
    c = _read_csv(tmp_path / "cmd.csv")
    cmd = np.column_stack([c[f"theta{i}_deg"] for i in range(1, 8)])
    moved = np.abs(cmd - poses).max(axis=1)
    assert np.median(moved) < 0.3 and moved.max() < 2.0 and c["residual_mm"].max() < 1e-6
    model = load_serial_result(tmp_path / "r.json").model
    p_drake, _ = drake_kinematics(load_robot(tmp_path / "arm7_identified.urdf", "tcp_tool_point"), cmd, jacobian=False)
    assert np.abs(p_drake - model.positions(cmd)).max() < 1e-6
