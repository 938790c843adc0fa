"""Six-axis campaigns through the Drake diagram (olti_drake.sim.serial_station, serial_scenario):
`olti simulate` dispatch and byte-for-byte reproducibility, open-loop pan/tilt aiming hitting and
missing, plan coverage as recorded, the diagram equal to the numpy model (aiming3d), truth.json
predicting the true positions, and a small simulated campaign identified within its uncertainty.

Small plans (30 deg nodes, one pose per node and direction) keep each run to a second or two."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.sim import serial_station as ss
from olti_drake.sim.serial_scenario import load_serial_scenario, scenario_kind
from olti_calls import error_line, olti_sub

ROOT = Path(__file__).resolve().parents[2]
SIX_AXIS = ROOT / "diagrams" / "six_axis.yaml"
SCENARIOS = ROOT / "diagrams" / "scenarios.yaml"
SMALL = "{plan: {step_deg: 30.0, poses_per_node: 1}}"
EXACT = "{plan: {step_deg: 30.0, poses_per_node: 1}, interferometer: {noise: false, quantization: false}}"
MOUNTED_EXACT = ("{interferometer: {noise: false, quantization: false}, "
                 "scheme: !RobotMounted {points_per_axis: 3, n_targets: 12}}")


def _setup(text, path=SIX_AXIS, name=None):
    return ss.prepare_serial(load_serial_scenario(path, name, text))


@pytest.fixture(scope="module")
def exact():
    """A noise-free floor-tracer campaign through the diagram, with its setup."""
    setup = _setup(EXACT)
    return setup, ss.run_serial_campaign(setup)


# ------------------------------------------------------------------ scenario
def test_shipped_scenarios_load_and_are_told_apart():
    """diagrams/six_axis.yaml and the named variants are six-axis scenarios; the paper-000 ones are not;
    the mounted variant overrides only the scheme and the tool offset of its base."""
    assert scenario_kind(SIX_AXIS) == "serial" and scenario_kind(SCENARIOS, "six_axis_mounted") == "serial"
    assert scenario_kind(SCENARIOS, "paper000_scara") == "scara" and scenario_kind(None) == "scara"
    base = load_serial_scenario(SIX_AXIS)
    mounted = load_serial_scenario(SCENARIOS, "six_axis_mounted")
    assert type(base.scheme).__name__ == "FloorTracers" and type(mounted.scheme).__name__ == "RobotMounted"
    assert mounted.plan == base.plan and mounted.robot.truth == base.robot.truth
    assert mounted.robot.tool_offset_mm == [0.0, 0.0, 60.0] and base.robot.tool_offset_mm == [40.0, -25.0, 60.0]
    assert base.robot_path().endswith(os.path.join("models", "ur5.urdf")) and base.plan.poses_per_node == 28


@pytest.mark.parametrize("text, words", [
    ("{robot: {file: nowhere.urdf}}", "robot.file"),
    ("{robot: {tool_offset_mm: [1, 2]}}", "robot.tool_offset_mm"),
    ("{scheme: !FloorTracers {stations_mm: [[1, 2]]}}", "scheme.stations_mm"),
    ("{scheme: !FloorTracers {station_sigma_mm: -1}}", "scheme.station_sigma_mm"),
    ("{plan: {step_deg: 0}}", "plan.step_deg"),
    ("{scheme: !RobotMounted {box_mm: [[1, 0], [0, 1], [0, 1]]}}", "scheme.box_mm"),
    ("{period_s: 0}", "period_s"),
])
def test_bad_scenario_values_are_named(text, words):
    with pytest.raises(InputError, match=words.replace(".", r"\.")):
        load_serial_scenario(SIX_AXIS, None, text)


@pytest.mark.parametrize("text, words", [
    ("{plan: {ranges_deg: [[-10, 10], [-10, 10]]}}", "plan.ranges_deg has 2 pairs, the robot 6 joints"),
    ("{robot: {tool_frame: nope}}", "robot: tool frame 'nope' not found"),
    ("{plan: {floor_z_mm: 5000.0}}", "plan: joint shoulder_pan_joint node -90 deg direction +1 not covered"),
    ("{scheme: !RobotMounted {start_deg: [0, 0]}}", "scheme.start_deg has 2 angles, the robot 6 joints"),
])
def test_scenario_problems_found_with_the_robot_are_named(text, words):
    with pytest.raises(InputError, match=r"^scenario .*six_axis\.yaml: " + words.replace("(", r"\(").replace("+", r"\+")):
        _setup(text)


def test_simulate_refuses_bad_six_axis_input_in_one_line(tmp_path):
    """A scenario problem found with the robot is one `error:` line naming the scenario, exit 2, no output."""
    for extra in (["--scenario-text", "{robot: {tool_frame: nope}}"],):
        r = olti_sub("simulate", SIX_AXIS, *extra, "--out", tmp_path / "x")
        error_line(r.returncode, r.stderr)
        assert "six_axis.yaml" in r.stderr and not (tmp_path / "x").exists()


# ------------------------------------------------------------------ olti simulate
def test_simulate_same_seed_same_bytes_other_seed_other_noise(tmp_path):
    """`olti simulate diagrams/six_axis.yaml` runs the six-axis diagram: the same seed gives the same
    campaign.csv and truth.json byte for byte; another --seed changes the readings' noise only; a
    directory holding a campaign is refused before any work."""
    outs = {}
    for name, seed in (("a", 4), ("b", 4), ("c", 5)):
        r = olti_sub("simulate", SIX_AXIS, "--scenario-text", SMALL, "--seed", seed, "--out", tmp_path / name)
        assert r.returncode == 0, r.stderr
        assert "floor tracers" in r.stdout and "wrote" in r.stdout
        outs[name] = [(tmp_path / name / f).read_bytes() for f in ("campaign.csv", "truth.json")]
    assert outs["a"] == outs["b"]
    assert outs["a"][0] != outs["c"][0]
    lines = [ln.split(",") for ln in outs["a"][0].decode().splitlines() if not ln.startswith("#")]
    assert lines[0] == (["station"] + [f"theta{i}_deg" for i in range(1, 7)] + [f"dir{i}" for i in range(1, 7)]
                        + ["displacement_mm", "valid"])
    r = olti_sub("simulate", SIX_AXIS, "--scenario-text", SMALL, "--out", tmp_path / "a")
    error_line(r.returncode, r.stderr, "campaign.csv")
    assert (tmp_path / "a" / "campaign.csv").read_bytes() == outs["a"][0]


# ------------------------------------------------------------------ aiming
def test_pan_tilt_aiming_hits_when_errors_are_small(exact):
    """Open loop from estimates 0.05 mm off, a robot with tens of µm / a few mdeg of errors: every beam
    passes within the acceptance of the true cat's eye (misses of the robot's error at the tool, tenths
    of a mm); the only lost readings are past the ±80° viewing angle (the plan decided on the nominal
    robot), and those are NaN, valid 0."""
    setup, camp = exact
    reads = ss.numpy_readings(setup, np.flatnonzero(setup.measure), setup.scenario.interferometer)
    assert 0.05 < np.median(reads.miss_mm) and reads.miss_mm.max() < setup.scenario.interferometer.acceptance_mm
    lost = camp.columns["valid"] == 0
    assert lost.mean() < 0.05
    assert np.all(reads.viewing_deg[lost] > 79.0)
    assert np.all(np.isnan(camp.columns["displacement_mm"][lost]))
    assert np.all(np.isfinite(camp.columns["displacement_mm"][~lost]))


def test_pan_tilt_aiming_misses_when_the_station_estimate_is_far_off():
    """Station 0's estimate 3 mm off (the others exact): its beam misses the cat's eye by more than
    the 1 mm acceptance at (nearly) every pose and the readings are flagged (valid 0, no number);
    the other stations still read."""
    truth = load_serial_scenario(SIX_AXIS).scheme.stations_mm
    est = [[x + (3.0 if j == 0 else 0.0) for x in p] for j, p in enumerate(truth)]
    setup = _setup(EXACT[:-1] + f", scheme: !FloorTracers {{stations_estimate_mm: {est}}}}}")
    camp = ss.run_serial_campaign(setup)
    c = camp.columns
    reads = ss.numpy_readings(setup, np.flatnonzero(setup.measure), setup.scenario.interferometer)
    far = c["station"] == 0
    assert np.median(reads.miss_mm[far]) > 1.0
    assert c["valid"][far].mean() < 0.1 and np.all(np.isnan(c["displacement_mm"][far & (c["valid"] == 0)]))
    assert c["valid"][~far].mean() > 0.9


# ------------------------------------------------------------------ plan
def test_plan_coverage_per_joint_and_direction_as_recorded(exact):
    """Readings per (joint, node, direction) counted from the recorded campaign equal the plan's report;
    every pair is read at least poses_per_node × min_stations times; every command is on a node."""
    setup, camp = exact
    plan, rules = setup.plan, setup.scenario.plan
    c = camp.columns
    report = plan.coverage()
    for i, joint in enumerate(plan.joint_names):
        grid = plan.grids[joint]
        counts = np.zeros((grid.size, 2), int)
        for theta, d in zip(c[f"theta{i + 1}_deg"], c[f"dir{i + 1}"]):
            node = np.flatnonzero(np.abs(grid - theta) < 1e-9)
            assert node.size == 1, (joint, theta)
            counts[node[0], 0 if d > 0 else 1] += 1
        assert np.array_equal(counts, report[joint]), joint
        assert counts.min() >= rules.poses_per_node * rules.min_stations
    assert len(c["station"]) == plan.n_readings


# ------------------------------------------------------------------ diagram = numpy model
@pytest.mark.parametrize("text", [EXACT, MOUNTED_EXACT])
def test_diagram_readings_equal_the_numpy_model(exact, text):
    """Noise off: the diagram (ErrorMapJoint -> the model file's plant with the truth's location errors
    -> 3D interferometer) reads what aiming3d's numpy model reads, to 1e-9 mm, for both schemes; the
    recorded directions are the plan's (approach rows) and valid flags agree."""
    setup, camp = exact if text == EXACT else (None, None)
    if setup is None:
        setup = _setup(text, SCENARIOS, "six_axis_mounted")
        camp = ss.run_serial_campaign(setup)
    ref = ss.simulate_serial_numpy(setup)
    c = camp.columns
    assert len(c["station"]) == len(ref["station"]) > 10
    for k in ref:
        if k != "displacement_mm":
            assert np.array_equal(c[k], ref[k]) or np.abs(c[k] - ref[k]).max() < 1e-9, k
    both = ~np.isnan(ref["displacement_mm"])
    assert np.array_equal(both, ~np.isnan(c["displacement_mm"])) and both.sum() > 10
    assert np.abs(c["displacement_mm"][both] - ref["displacement_mm"][both]).max() < 1e-9


def test_robot_mounted_aim_hits_the_true_reflector():
    """IK aiming at reflector estimates 0.05 mm off on a robot with small errors: every target reached,
    every beam within the acceptance of the true reflector."""
    setup = _setup(MOUNTED_EXACT, SCENARIOS, "six_axis_mounted")
    assert all(len(v) == 0 for v in setup.unreachable.values())
    reads = ss.numpy_readings(setup, np.flatnonzero(setup.measure), setup.scenario.interferometer)
    assert np.all(reads.valid) and reads.miss_mm.max() < 0.5


# ------------------------------------------------------------------ truth.json
def test_truth_json_predicts_the_true_positions_and_readings(exact, tmp_path):
    """truth.json (serial result format, loaded by io.serial_io) gives the true tool points at the
    campaign's commands (1° maps: within 2 µm) and, with its stations and dead paths, the noise-free
    readings."""
    from olti_drake.io.serial_io import load_serial_result

    setup, camp = exact
    paths = ss.write_serial_simulation(camp, str(tmp_path / "sim"))
    data = json.loads(Path(paths[1]).read_text())
    assert len(data["robot"].pop("sha256")) == 64  # the model file's digest (issue 24)
    assert data["robot"] == {"file": "ur5", "tool_frame": "tool0", "joints": list(setup.chain.joint_names)}
    result = load_serial_result(paths[1])
    c = camp.columns
    cmd = np.column_stack([c[f"theta{i}_deg"] for i in range(1, 7)])
    dirs = np.column_stack([c[f"dir{i}"] for i in range(1, 7)])
    true_p = setup.truth.positions(cmd, dirs)
    assert np.abs(result.model.positions(cmd, dirs) - true_p).max() < 2e-3
    st = c["station"].astype(int)
    pred = np.linalg.norm(result.model.positions(cmd, dirs) - result.stations_mm[st], axis=1) - result.dead_paths_mm[st]
    ok = c["valid"] > 0
    # the cosine error of the open-loop aim (miss ≤ 0.5 mm at ~1.5 m: ≤ 0.1 µm) is below the 1° maps' 2 µm
    assert np.abs(pred[ok] - c["displacement_mm"][ok]).max() < 2e-3


# ------------------------------------------------------------------ identification
def test_small_simulated_campaign_identified_within_its_uncertainty():
    """A small noisy campaign (20° nodes, 2 poses per node and direction; the truth's harmonics made
    small so the 20° maps can represent it) identified with the serial error-map model and
    Calibration: residual RMS at the budget's reading noise, and the readings of 200 unseen poses from
    the same stations predicted within 4 of their propagated standard uncertainties (plus the maps'
    interpolation error, ≤ 0.5 µm here)."""
    from olti_drake.estimation.calibration import Calibration
    from olti_drake.estimation.calibration import SolverOptions
    from olti_drake.estimation.serial_plan import reading_uncertainty_mm
    from olti_drake.model.serial import DistanceMeasurement, build_position_model, find_gauge

    setup = _setup("{plan: {step_deg: 20.0, poses_per_node: 2}, robot: {truth: {deviation_mdeg: 1.0}}}")
    c = ss.run_serial_campaign(setup).columns
    ok = c["valid"] > 0
    cmd = np.column_stack([c[f"theta{i}_deg"] for i in range(1, 7)])[ok]
    dirs = np.column_stack([c[f"dir{i}"] for i in range(1, 7)])[ok]
    st, d = c["station"][ok].astype(int), c["displacement_mm"][ok]
    model = build_position_model(setup.chain, cmd, dirs, grids=setup.plan.grids, tool_offset_mm=setup.tool_offset_mm)
    P0 = setup.stations_estimate_mm
    p0 = model.positions(cmd, dirs)
    d0 = np.array([np.mean(np.linalg.norm(p0[st == j] - P0[j], axis=1) - d[st == j]) for j in range(len(P0))])
    meas = DistanceMeasurement(model, cmd, dirs, st, d, P0, d0)
    fit = Calibration(meas, SolverOptions(budget=setup.budget), find_gauge(meas), "six-axis test").fit()
    u = reading_uncertainty_mm(setup.budget)
    rms = np.sqrt(np.mean(fit.residuals ** 2))
    n, n_free = len(d), len(fit.x) - len(find_gauge(meas).constraints)
    # the residual of a least-squares fit: the reading noise shrunk by the parameters it absorbs
    assert 0.5 * setup.budget.combined("reading") * np.sqrt(max(n - n_free, 1) / n) < rms < 2 * u, (rms, n, n_free)
    # unseen poses: on the plan's nodes (inside the maps), random directions, read from every station
    rng = np.random.default_rng(7)
    grids = [setup.plan.grids[j] for j in setup.chain.joint_names]
    new = np.column_stack([rng.choice(g, 200) for g in grids])
    new_dirs = rng.choice([-1.0, 1.0], new.shape)
    nt = len(P0)
    new_st = np.repeat(np.arange(nt), len(new))
    truth = setup.truth
    true_d = (np.linalg.norm(np.tile(truth.positions(new, new_dirs), (nt, 1)) - truth.stations_mm[new_st], axis=1)
              - truth.dead_paths_mm[new_st])
    check = DistanceMeasurement(model, np.tile(new, (nt, 1)), np.tile(new_dirs, (nt, 1)), new_st, true_d)
    r, jac = check.residuals(fit.x)  # predicted − true
    sigma = np.sqrt(np.einsum("ij,jk,ik->i", jac.toarray(), fit.covariance, jac.toarray()))
    assert np.median(sigma) < 4 * u  # a small campaign predicts unseen readings within a few readings' u
    assert np.all(np.abs(r) < 4 * sigma + 5e-4), np.max(np.abs(r) / (sigma + 5e-4))


# ------------------------------------------------------------------ olti demo --robot six_axis
def test_six_axis_demo_simulates_identifies_and_validates(tmp_path):
    """The six-axis demo on a small plan: campaign, truth, both results, validation and figures written;
    on unseen poses measured by the simulated tracker the error-map model beats the geometric one,
    which beats the nominal; a second run into the same directory is refused (a campaign is there)."""
    from olti_drake.cli.verbs import build_parser
    from olti_drake.report.six_axis_demo import RESULTS, run_six_axis_demo

    assert build_parser().parse_args(["demo", "--robot", "six_axis"]).robot == "six_axis"
    text = "{plan: {step_deg: 20.0, poses_per_node: 3}}"
    lines = run_six_axis_demo(tmp_path, scenario_text=text)
    for name in RESULTS + ("campaign.csv", "truth.json"):
        assert (tmp_path / name).stat().st_size > 100, name
    v = json.loads((tmp_path / "validation.json").read_text())["models"]
    assert v["errormap"]["rms_mm"] < v["dh"]["rms_mm"] < v["nominal"]["rms_mm"]
    assert any(ln.startswith("  errormap") for ln in lines)
    with pytest.raises(ValueError, match="campaign.csv"):
        run_six_axis_demo(tmp_path, force=True, scenario_text=text)


def test_six_axis_diagram_offers_the_scara_station_ports():
    """The committed six-axis wiring (olti diagrams) is the code's; its station takes and gives the SCARA
    station's ports (plus the head command of the floor tracers) and the error map feeds the interferometer."""
    from olti_drake.report.diagram_pictures import DIAGRAMS_DIR, campaign_diagram, read_wiring, wiring_lines

    with campaign_diagram(DIAGRAMS_DIR / "six_axis.yaml") as diagram:
        lines = wiring_lines(diagram)
        names = {diagram.station.get_output_port(i).get_name() for i in range(diagram.station.num_output_ports())}
    assert read_wiring(DIAGRAMS_DIR / "six_axis.wiring.txt") == lines
    assert names >= {"displacement", "valid", "miss", "status", "direction", "measured_position", "true_position"}
    inputs = {ln.split(" -> ")[1] for ln in lines if " -> station." in ln and "/" not in ln}
    assert inputs == {"station.joint_command", "station.reflector", "station.head_command"}
    assert "station/error_map_joint.position -> station/serial_laser_interferometer.position" in lines
