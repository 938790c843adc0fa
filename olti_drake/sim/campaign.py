"""The simulated open-loop tracking interferometer campaign (000 §2, §4.1).

``AddSimulatedStation`` adds the simulated *station* -- the robot and its instrument:
ErrorMapJoint -> SCARA MultibodyPlant (through SceneGraph) -> LaserInterferometer
-- as one Drake Diagram with named ports, so a hardware station with the same
ports can stand in for it (``geometry=False``: the kinematic station, no SceneGraph, which
converts with ``ToAutoDiffXd()``: readings differentiable with respect to the map nodes).
``build_campaign_diagram`` wires the measurement procedure around it: PlanSequencer ->
BeamSteering -> station -> CampaignRecorder.

Units: mm and degrees in files and in :class:`Campaign`; SI on Drake ports.
"""

import os
from dataclasses import dataclass
from typing import Optional

import numpy as np

from olti_drake.formats import result_header
from olti_drake.io.csvio import write_table
from olti_drake.model.errormap import approach_directions, sample_map
from olti_drake.model.instrument import beam_geometry, simulate_readings
from olti_drake.model.plan import Plan
from olti_drake.sim.scenario import SEED_STREAMS, ExactEstimate, PerturbedEstimate, Scenario, as_plain
from olti_drake.sim.scenario import stream_rng, stream_seed  # stream_seed re-exported (machine_station)
from olti_drake.model.instrument import (SearchData, beam_command_deg, default_search_positions_mm, fit_reflectors,
                       simulate_search)

#: Keys of the independent random streams derived from the scenario seed (sim.scenario.SEED_STREAMS).
STREAM_LASER, STREAM_ESTIMATE = SEED_STREAMS["laser"], SEED_STREAMS["reflector_estimate"]


@dataclass
class Setup:
    """What the campaign needs before the diagram runs, all from the scenario.

    ``reflectors_estimate_mm``/``theta40_estimate_deg`` steer the beam (Eq. 1);
    ``dead_paths_mm`` is the counter zero of each reflector's run: the true
    optical length at the run's first measured pose (000 Eq. 5: d0_j).
    """

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "scara"

    scenario: Scenario
    plan: Plan
    budget: object
    robot: object
    reflectors_mm: np.ndarray
    reflectors_estimate_mm: np.ndarray
    theta40_estimate_deg: float
    search: Optional[SearchData]
    dead_paths_mm: np.ndarray


def prepare(scenario: Scenario) -> Setup:
    """Validate the scenario (one-line InputError naming the field, before anything is built), estimate the
    reflectors (as the scenario says) and fix the counter zeros."""
    source = getattr(scenario, "source_file", None)
    scenario.validate(f"scenario {source}" if source else "scenario")
    plan = scenario.load_plan()
    robot = scenario.robot.true_robot()
    P = np.asarray(scenario.reflectors_mm, dtype=float)
    P_est, theta40_est, search = _estimate(scenario, robot, P)
    return Setup(scenario, plan, scenario.load_budget(), robot, P, P_est, theta40_est, search,
                 _dead_paths(scenario, plan, robot, P, P_est, theta40_est))


def _estimate(scenario: Scenario, robot, P):
    est = scenario.reflector_estimate
    rng = stream_rng(scenario.seed, "reflector_estimate")
    if isinstance(est, ExactEstimate):
        return P.copy(), robot.theta40_deg, None
    if isinstance(est, PerturbedEstimate):
        return (P + est.sigma_mm * rng.standard_normal(P.shape),
                robot.theta40_deg + 1e-3 * est.theta40_sigma_mdeg * rng.standard_normal(), None)
    r = scenario.robot
    xy = (np.asarray(est.positions_mm, dtype=float) if est.positions_mm
          else default_search_positions_mm(r.nominal_L1_mm, r.nominal_L2_mm))

    def actual_pose(t1, t2, t4):
        # The operator approaches each search pose in the positive direction.
        return robot.laser_beam(t1, t2, t4, 1.0, 1.0, 1.0)

    data = simulate_search(xy, P, actual_pose, None, rng,
                           None if est.angle_noise_mdeg < 0 else est.angle_noise_mdeg,
                           L1_mm=r.nominal_L1_mm, L2_mm=r.nominal_L2_mm)
    fit = fit_reflectors(*data, r.nominal_L1_mm, r.nominal_L2_mm)
    return fit.reflectors_mm, fit.theta40_deg, data


def campaign_commands(plan: Plan, P_est, theta40_est, L1_mm, L2_mm):
    """Every commanded row of the campaign, as the diagram will execute it.

    The plan is repeated once per reflector; θ4* comes from the open-loop
    steering (Eq. 1 of 000); directions run over the whole campaign, since run
    j starts where run j-1 ended (the plan's first rows re-approach).

    Returns dict of (K,) arrays: theta1/2/4 (deg), dir1/2/4 (±1), reflector, plan_row.
    """
    n_t = len(P_est)
    t1, t2 = np.tile(plan.theta1_deg, n_t), np.tile(plan.theta2_deg, n_t)
    j = np.repeat(np.arange(n_t), len(plan))
    t4 = beam_command_deg(t1, t2, np.asarray(P_est)[j], L1_mm, L2_mm, theta40_est)
    d = approach_directions(np.column_stack([t1, t2, t4]))
    return {"theta1": t1, "theta2": t2, "theta4": t4, "dir1": d[:, 0], "dir2": d[:, 1],
            "dir4": d[:, 2], "reflector": j, "plan_row": np.tile(np.arange(len(plan)), n_t)}


def _dead_paths(scenario, plan, robot, P, P_est, theta40_est):
    r = scenario.robot
    c = campaign_commands(plan, P_est, theta40_est, r.nominal_L1_mm, r.nominal_L2_mm)
    measured = plan.measure[c["plan_row"]]
    first = np.array([np.flatnonzero((c["reflector"] == k) & measured)[0] for k in range(len(P))])
    origin, angle = robot.laser_beam(*(c[k][first] for k in ("theta1", "theta2", "theta4",
                                                              "dir1", "dir2", "dir4")))
    along, miss = beam_geometry(origin, angle, P)
    return along if scenario.interferometer.cosine_error else np.hypot(along, miss)


def AddSimulatedStation(builder, setup: Setup, name: str = "station", geometry: bool = True):
    """Add the simulated station (a Diagram) to ``builder`` and return it.

    Ports -- inputs: ``joint_command`` (4: θ1*, θ2* rad, J3 m, θ4* rad),
    ``reflector`` (1); outputs: ``displacement`` (1, m), ``valid`` (1),
    ``miss`` (1, m), ``status`` (:class:`~olti_drake.sim.systems.ReadStatus`),
    ``direction`` (4, ±1), ``measured_position`` (4, rad/m: what the encoders
    read, here the commanded positions: a perfect servo, the error map is what
    encoders do not see), ``true_position`` (4, rad/m: the actual positions
    through the error map; simulation only, for diagnostics) and
    ``query_object`` (SceneGraph, for visualization).

    Which station a scenario uses (simulated, emulated, hardware) is decided
    above this module, by :func:`olti_drake.hardware.station.AddStation`.

    ``geometry=False``: the kinematic station, without SceneGraph (no ``query_object``): the
    :class:`~olti_drake.sim.systems.KinematicLaserInterferometer` takes the actual positions and
    computes the laser head pose with the plant's own kinematics, so the station converts with
    ``ToAutoDiffXd()`` and a reading is differentiable with respect to the map nodes (the
    ErrorMapJoint Parameters); same readings as the geometry station.
    """
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import PassThrough

    from olti_drake.sim.plant import AddScaraPlant, make_scara_plant
    from olti_drake.sim.systems import ErrorMapJoint, KinematicLaserInterferometer, LaserInterferometer

    s, r = setup.scenario, setup.scenario.robot
    inner = DiagramBuilder()
    plant_args = (r.L1_mm, r.L2_mm, setup.reflectors_mm, r.theta40_deg, tuple(r.beam_offset_mm))
    plant = AddScaraPlant(inner, *plant_args) if geometry else make_scara_plant(*plant_args)
    joints = inner.AddSystem(ErrorMapJoint([r.J1, r.J2, None, r.J4], revolute=[True, True, False, True]))
    noise = (s.interferometer, setup.budget)
    seeding = dict(seed=stream_seed(s.seed, "laser"), period_s=s.period_s)
    if geometry:
        laser = inner.AddSystem(LaserInterferometer(
            plant.flange_frame_id, plant.laser_head_in_flange, plant.reflector_frame_ids, setup.dead_paths_mm,
            *noise, **seeding))
    else:
        laser = inner.AddSystem(KinematicLaserInterferometer(
            plant.plant, plant.reflector_positions_m()[:, :2] * 1e3, setup.dead_paths_mm, *noise, **seeding))
    command = inner.AddNamedSystem("joint_command", PassThrough(4))
    inner.Connect(command.get_output_port(), joints.GetInputPort("command"))
    if geometry:
        inner.Connect(joints.GetOutputPort("position"), plant.position_input)
        inner.Connect(plant.query_output, laser.GetInputPort("geometry_query"))
    else:
        inner.Connect(joints.GetOutputPort("position"), laser.GetInputPort("position"))
    inner.ExportInput(command.get_input_port(), "joint_command")
    inner.ExportInput(laser.GetInputPort("reflector"), "reflector")
    for port in ("displacement", "valid", "miss", "status"):
        inner.ExportOutput(laser.GetOutputPort(port), port)
    inner.ExportOutput(joints.GetOutputPort("direction"), "direction")
    inner.ExportOutput(command.get_output_port(), "measured_position")
    inner.ExportOutput(joints.GetOutputPort("position"), "true_position")
    if geometry:
        inner.ExportOutput(plant.query_output, "query_object")
    station = builder.AddNamedSystem(name, inner.Build())
    station.plant = plant  # keeps the plant (referenced by MultibodyPositionToGeometryPose and the laser) alive
    return station


def build_campaign_diagram(setup: Setup, station_factory=None, extend=None, sink=None):
    """The whole campaign as a Diagram; returns (diagram, recorder, sequencer).

    ``sink(row, status)``: called with every recorded reading (``CampaignRecorder``;
    ``olti run`` writes it to disk).

    ``station_factory(builder, setup)`` adds the station (default
    :func:`AddSimulatedStation`; :func:`olti_drake.hardware.station.AddStation`
    adds the scenario's, simulated, emulated or hardware); ``extend(builder, setup=, station=,
    sequencer=, steering=, recorder=)``, if given, adds more systems (e.g. the
    Meshcat view of :mod:`olti_drake.sim.meshcat_view`) before the diagram is built.
    """
    from pydrake.systems.framework import DiagramBuilder

    from olti_drake.sim.systems import BeamSteering, CampaignRecorder, PlanSequencer

    s, r = setup.scenario, setup.scenario.robot
    builder = DiagramBuilder()
    station = (station_factory or AddSimulatedStation)(builder, setup)
    seq = builder.AddNamedSystem("plan_sequencer", PlanSequencer(
        setup.plan.theta1_deg, setup.plan.theta2_deg, setup.plan.measure, len(setup.reflectors_mm),
        s.period_s))
    steer = builder.AddNamedSystem("beam_steering", BeamSteering(
        r.nominal_L1_mm, r.nominal_L2_mm, setup.reflectors_estimate_mm, setup.theta40_estimate_deg))
    rec = builder.AddNamedSystem("campaign_recorder", CampaignRecorder(s.period_s, sink))
    builder.Connect(seq.GetOutputPort("arm_command"), steer.GetInputPort("arm_command"))
    builder.Connect(seq.GetOutputPort("reflector"), steer.GetInputPort("reflector"))
    builder.Connect(steer.GetOutputPort("joint_command"), station.GetInputPort("joint_command"))
    builder.Connect(seq.GetOutputPort("reflector"), station.GetInputPort("reflector"))
    builder.Connect(steer.GetOutputPort("joint_command"), rec.GetInputPort("joint_command"))
    for port in ("direction", "displacement", "valid", "status"):
        builder.Connect(station.GetOutputPort(port), rec.GetInputPort(port))
    for port in ("reflector", "measure", "row"):
        builder.Connect(seq.GetOutputPort(port), rec.GetInputPort(port))
    if extend is not None:
        extend(builder, setup=setup, station=station, sequencer=seq, steering=steer, recorder=rec)
    diagram = builder.Build()
    diagram.station = station
    return diagram, rec, seq


@dataclass
class Campaign:
    """Readings (columns of ``CampaignRecorder.COLUMNS``, mm/deg) and the truth dict."""

    columns: dict
    truth: dict

    @property
    def n_readings(self) -> int:
        return len(self.columns["reflector"])

    @classmethod
    def from_recorder(cls, setup: Setup, recorder, root_context) -> "Campaign":
        """The recorder's rows (mm/deg) kept in ``root_context`` as columns, with the simulated truth."""
        names = type(recorder).COLUMNS
        rows = np.array(recorder.GetReadings(root_context), dtype=float).reshape(-1, len(names))
        columns = {c: rows[:, i] for i, c in enumerate(names)}
        return cls(columns, truth_result(setup, columns))


def run_campaign(setup: Setup, progress=None, extend=None, realtime_rate: float = 0.0,
                 station_factory=None) -> Campaign:
    """Simulate the diagram through the whole plan and collect the readings.

    ``progress(fraction)``, if given, is called as the simulation advances.
    ``extend`` as in :func:`build_campaign_diagram` (e.g. a Meshcat view);
    ``realtime_rate`` > 0 paces the simulation for a viewer (0: as fast as possible);
    ``station_factory`` as in :func:`build_campaign_diagram`.
    """
    from pydrake.systems.analysis import Simulator

    diagram, rec, seq = build_campaign_diagram(setup, station_factory, extend=extend)
    try:
        simulator = Simulator(diagram)
        simulator.set_target_realtime_rate(realtime_rate)
        chunks = 50 if progress else 1
        for k in range(1, chunks + 1):
            simulator.AdvanceTo(seq.duration_s * k / chunks)
            if progress:
                progress(k / chunks)
    finally:
        close = getattr(diagram.station, "close", None)  # an emulated or hardware station's ports
        if close is not None:
            close()
    return Campaign.from_recorder(setup, rec, simulator.get_context())


def simulate_vectorized(setup: Setup, rng: np.random.Generator) -> Campaign:
    """The same campaign computed in one vectorized pass, without Drake (the numpy twin).

    Same commands, truth and interferometer model as the diagram; the noise
    comes from ``rng`` for all readings at once, so it equals the diagram's
    readings only with the noise off. For many independent campaigns fast
    (uncertainty checks, benchmarks' baseline).
    """
    s, r = setup.scenario, setup.scenario.robot
    c = campaign_commands(setup.plan, setup.reflectors_estimate_mm, setup.theta40_estimate_deg,
                          r.nominal_L1_mm, r.nominal_L2_mm)
    keep = setup.plan.measure[c["plan_row"]]
    c = {k: v[keep] for k, v in c.items()}
    j = c["reflector"]
    origin, angle = setup.robot.laser_beam(*(c[k] for k in ("theta1", "theta2", "theta4", "dir1", "dir2", "dir4")))
    reading, valid, _ = simulate_readings(origin, angle, setup.reflectors_mm[j], setup.dead_paths_mm[j],
                                          s.interferometer, setup.budget, rng)
    columns = {"reflector": j.astype(float), "theta1_deg": c["theta1"], "theta2_deg": c["theta2"],
               "dir1": c["dir1"], "dir2": c["dir2"], "displacement_mm": np.where(valid, reading, np.nan),
               "theta4_deg": c["theta4"], "valid": valid.astype(float), "plan_row": c["plan_row"].astype(float)}
    return Campaign(columns, truth_result(setup, columns))


def simulate(scenario: Scenario) -> Campaign:
    """Prepare and run the scenario's campaign (``olti simulate``)."""
    return run_campaign(prepare(scenario))


def truth_result(setup: Setup, columns: dict) -> dict:
    """The simulated truth in the result format (formats.md), model ``errormap``.

    The continuous truth is sampled at the distinct measured command angles;
    ``truth`` keeps the exact deviation functions, θ40, the laser mount and
    the steering's estimates for anyone who wants more than the samples.
    """
    r = setup.scenario.robot
    grids = {a: np.unique(columns[f"theta{a[1]}_deg"]) for a in ("J1", "J2")}
    # The identifier's frame (formats.md): X along the arm at theta1* = 0, both approach directions averaged.
    # The truth's base frame has X along the arm at the actual theta1 = 0, i.e. rotated from it by -g.
    at = float(np.clip(0.0, grids["J1"][0], grids["J1"][-1]))
    g = float(0.5 * (r.J1(np.array([at]), 1.0)[0] + r.J1(np.array([at]), -1.0)[0]))
    return {
        **result_header("scara"),
        "model": "errormap",
        "L1_mm": r.L1_mm,
        "L2_mm": r.L2_mm,
        "reflectors_mm": setup.reflectors_mm.tolist(),
        "dead_paths_mm": setup.dead_paths_mm.tolist(),
        "error_map": {a: sample_map(getattr(r, a), g, a).to_dict() for a, g in grids.items()},
        "gauge": (f"simulation truth in the robot base frame: origin on the J1 axis, X along the arm at the actual "
                  f"theta1 = theta2 = 0, not at the commanded theta1* = 0. The frame of formats.md and of identified "
                  f"results (X along the arm at theta1* = {at:g} deg, mean of both approach directions) is this one "
                  f"rotated by the J1 deviation there, {1e3 * g:.3f} mdeg, about J1: subtract it from the J1 map "
                  f"and rotate the reflectors by minus it to compare (truth.formats_frame_rotation_deg)"),
        "residual_rms_mm": 0.0,
        "n_readings": int(np.sum(columns["valid"] > 0)),
        "truth": {
            "robot": as_plain(r),
            "reflectors_estimate_mm": setup.reflectors_estimate_mm.tolist(),
            "theta40_estimate_deg": setup.theta40_estimate_deg,
            "seed": setup.scenario.seed,
            "formats_frame_rotation_deg": g,
        },
    }


CAMPAIGN_FORMATS = {"reflector": "%d", "theta1_deg": "%.12g", "theta2_deg": "%.12g", "dir1": "%d",
                    "dir2": "%d", "displacement_mm": "%.9f", "theta4_deg": "%.9f", "valid": "%d"}


def write_campaign(campaign: Campaign, out_dir: str, comments=()) -> tuple:
    """Write ``campaign.csv`` (formats.md SCARA campaign) and ``truth.json``; returns both paths."""
    from olti_drake.io.outputs import make_dir, write_json

    make_dir(out_dir)
    csv_path, truth_path = os.path.join(out_dir, "campaign.csv"), os.path.join(out_dir, "truth.json")
    cols = {c: campaign.columns[c] for c in CAMPAIGN_FORMATS}
    # Measurements: never replacing an existing file (outputs.writing).
    write_table(csv_path, cols, CAMPAIGN_FORMATS, comments=list(comments) + [
        "olti_drake SCARA campaign (shared/spec/formats.md): mm and degrees; "
        "dir = approach direction; valid 0 = beam lost (no reading)"], measurement=True)
    write_json(truth_path, campaign.truth, measurement=True)
    return csv_path, truth_path
