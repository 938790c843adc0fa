"""The six-axis (N-joint) campaign as a Drake diagram (issue "Six-axis campaigns end to end", item 3).

The serial counterpart of :mod:`olti_drake.sim.campaign`, one code path for any N:

    RowSequencer (joint_command N, reflector, measure, row)
      -> [PanTiltSteering: head_command (2), floor tracers only]
      -> station: ErrorMapJoint (N axes: θ = θ* + Δθ(θ*, dir), 000 Eq. 7)
                  -> SerialLaserInterferometer (the MultibodyPlant of the model file, its joint frames
                     moved by the truth's location errors; 3D beam, cosine error, acceptance, noise)
      -> SerialCampaignRecorder

The station's ports follow the SCARA station's contract (:func:`~olti_drake.sim.campaign.AddSimulatedStation`):
inputs ``joint_command`` (N, rad), ``reflector`` (1: the station index j) and, for floor tracers,
``head_command`` (2, rad: pan, tilt); outputs ``displacement`` (1, m), ``valid``, ``miss`` (1, m),
``status``, ``direction`` (N), ``measured_position`` (N, rad: the commands; the encoders do not see
the error map) and ``true_position`` (N, rad; simulation only).

The systems are public in :mod:`olti_drake.sim.systems` (importable from here too, pydrake loaded on first
use): :class:`~olti_drake.sim.systems.PanTiltSteering`, :class:`~olti_drake.sim.systems.SerialLaserInterferometer`
and :class:`~olti_drake.sim.systems.SerialCampaignRecorder`. :func:`AddSerialStation` builds the station from
a chain (the model file's plant) and a truth without a scenario, :func:`AddSimulatedSerialStation` from a
scenario's setup. What the identification estimates are numeric Parameters of the Context -- the map nodes
(``ErrorMapJoint``), the location errors and tool offset, the stations and dead paths (the interferometer)
-- and the station converts with ``ToAutoDiffXd()``: a reading's derivative with respect to them is the
Jacobian entry of :class:`~olti_drake.model.serial.DistanceMeasurement` (tests/sim/test_drake_native_serial_machine.py).

What is decided before the run (:func:`prepare_serial`, open loop: the aim uses commands and estimates
only): the plan (``serial_plan.generate_plan`` on the ESTIMATED stations) or, robot-mounted, the IK
aim of every tool point at every ESTIMATED reflector (``aiming3d.RobotAimer``); the row sequence
(per station run: approach pose q − overrun·dir, then q, so every joint arrives from the planned
side; formats.md's direction rule); the dead paths (the true optical length at each run's first
measured pose, 000 Eq. 5). :func:`simulate_serial_numpy` computes the same readings with the numpy
model of :mod:`olti_drake.model.aiming3d` (the test reference and the benchmark's baseline).

Units: mm and degrees everywhere but the Drake ports (rad, m).
"""

import dataclasses
import os
import time
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model import aiming3d as a3
from olti_drake.model.errormap import approach_directions
from olti_drake.sim.scenario import stream_rng, stream_seed
from olti_drake.sim.serial_scenario import SHIPPED_MODELS, FloorTracers, SerialScenario, load_serial_scenario

M_TO_MM = 1e3
#: Truth error maps in truth.json: nodes every TRUTH_GRID_DEG over each joint's commanded range.
TRUTH_GRID_DEG = 1.0


@dataclass
class SerialSetup:
    """Everything the run needs, from the scenario (mm, deg). One row per sequencer step:
    ``commands_deg`` (K, N), ``dirs`` (K, N) (formats.md rule over the whole sequence),
    ``reflector`` (K,) station index, ``measure`` (K,) bool, ``row`` (K,) the pose's index in the
    plan (tracers) or the tool-point raster (robot-mounted). ``truth``: the true robot
    (``SyntheticTruth``; its ``stations_mm`` and ``dead_paths_mm`` are the true stations/reflectors
    and counter zeros). ``timings`` (s): plan, aiming."""

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "serial"

    scenario: SerialScenario
    chain: object
    truth: object
    budget: object
    tool_offset_mm: np.ndarray
    stations_estimate_mm: np.ndarray
    commands_deg: np.ndarray
    dirs: np.ndarray
    reflector: np.ndarray
    measure: np.ndarray
    row: np.ndarray
    heads_true: Optional[a3.PanTiltHeads] = None
    heads_est: Optional[a3.PanTiltHeads] = None
    head_errors: tuple = ()
    laser_true: Optional[a3.LaserOnTool] = None
    plan: object = None
    unreachable: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)

    @property
    def tracers(self) -> bool:
        return isinstance(self.scenario.scheme, FloorTracers)

    @property
    def stations_mm(self) -> np.ndarray:
        return self.truth.stations_mm

    @property
    def n_joints(self) -> int:
        return self.chain.n_joints


# ------------------------------------------------------------------ preparation
def prepare_serial(scenario: SerialScenario) -> SerialSetup:
    """Validate the scenario, load the model, draw the truth and the estimates, plan (or aim), fix
    the row sequence and the dead paths (module doc)."""
    from olti_drake.model.chain import load_serial_chain
    from olti_drake.model.serial import synthetic_truth

    source = getattr(scenario, "source_file", None)
    where = f"scenario {source}" if source else "scenario"
    scenario.validate(where)
    r, s = scenario.robot, scenario.scheme
    try:
        chain = load_serial_chain(scenario.robot_path(), r.tool_frame)
    except ValueError as e:
        raise InputError(f"{where}: robot: {e}") from None
    _check_joints(scenario, chain, where)
    tool = np.asarray(r.tool_offset_mm, float)
    true_points = np.asarray(s.stations_mm if scenario_is_tracers(scenario) else s.reflectors_mm, float)
    t = r.truth
    truth = synthetic_truth(chain, t.seed, tool_offset_mm=tool + np.asarray(t.tool_offset_error_mm, float),
                            n_stations=len(true_points), location_mm=t.location_mm, location_deg=t.location_deg,
                            deviation_mdeg=t.deviation_mdeg, backlash_mdeg=t.backlash_mdeg)
    truth = dataclasses.replace(truth, stations_mm=true_points, dead_paths_mm=np.zeros(len(true_points)))
    rng = stream_rng(scenario.seed, "reflector_estimate")
    build = _prepare_tracers if scenario_is_tracers(scenario) else _prepare_mounted
    try:
        setup = build(scenario, chain, truth, tool, rng)
    except ValueError as e:  # e.g. a (joint, node, direction) no readable pose covers: name the scenario
        raise InputError(f"{where}: {e}") from None
    dead = _dead_paths(setup)
    setup.truth = dataclasses.replace(setup.truth, dead_paths_mm=dead)
    return setup


def scenario_is_tracers(scenario) -> bool:
    return isinstance(scenario.scheme, FloorTracers)


def _check_joints(scenario, chain, where):
    n = chain.n_joints
    if scenario.plan.ranges_deg and len(scenario.plan.ranges_deg) != n:
        raise InputError(f"{where}: plan.ranges_deg has {len(scenario.plan.ranges_deg)} pairs, the robot "
                         f"{n} joints ({', '.join(chain.joint_names)})")
    if not scenario_is_tracers(scenario) and len(scenario.scheme.start_deg) != n:
        raise InputError(f"{where}: scheme.start_deg has {len(scenario.scheme.start_deg)} angles, the robot "
                         f"{n} joints")


def _estimate(given, truth, sigma, rng):
    """The operator's estimate: as given, else the truth + seeded normal errors (same unit)."""
    if given:
        return np.asarray(given, float)
    return truth + sigma * rng.standard_normal(truth.shape)


def _prepare_tracers(scenario, chain, truth, tool, rng) -> SerialSetup:
    from olti_drake.estimation.serial_plan import generate_plan

    s = scenario.scheme
    P = truth.stations_mm
    zeros = np.asarray(s.zeros_deg, float) if s.zeros_deg else np.zeros((len(P), 2))
    P_est = _estimate(s.stations_estimate_mm, P, s.station_sigma_mm, rng)
    z_est = _estimate(s.zeros_estimate_deg, zeros, 1e-3 * s.zero_sigma_mdeg, rng)
    errors = tuple(a3.harmonic_head_error(stream_seed(scenario.seed, "head_error", j), s.head_error_mdeg)
                   if s.head_error_mdeg > 0 else None for j in range(len(P)))
    t0 = time.perf_counter()
    plan = generate_plan(chain, P_est, scenario.plan.rules(s.catseye_axis_tool), tool_offset_mm=tool,
                         seed=scenario.plan.seed)
    runs = [(np.flatnonzero(plan.visible[:, j]), plan.commands_deg, plan.dirs) for j in range(len(P))]
    seq = _sequence(runs, scenario.plan.overrun_deg)
    return SerialSetup(scenario, chain, truth, scenario.load_budget(), tool, P_est, *seq,
                       heads_true=a3.PanTiltHeads(P, zeros), heads_est=a3.PanTiltHeads(P_est, z_est),
                       head_errors=errors, plan=plan, timings={"plan": time.perf_counter() - t0})


def serpentine_points(box_mm, per_axis: int) -> np.ndarray:
    """Tool points on a ``per_axis``³ serpentine raster through ``box_mm`` [[x0, x1], [y0, y1], [z0, z1]]
    (consecutive points neighbours, so the IK's nearest-to-previous pose moves little), mm."""
    box = np.asarray(box_mm, float)
    g = [np.linspace(lo, hi, per_axis) for lo, hi in box]
    pts = []
    for i, x in enumerate(g[0]):
        for j, y in enumerate(g[1] if i % 2 == 0 else g[1][::-1]):
            zs = g[2] if (i * per_axis + j) % 2 == 0 else g[2][::-1]
            pts += [(x, y, z) for z in zs]
    return np.array(pts)


def _prepare_mounted(scenario, chain, truth, tool, rng) -> SerialSetup:
    s = scenario.scheme
    P = truth.stations_mm
    P_est = _estimate(s.reflectors_estimate_mm, P, s.reflector_sigma_mm, rng)
    targets = serpentine_points(s.box_mm, s.points_per_axis)[:s.n_targets]
    direction = tuple(np.asarray(s.laser_direction, float))
    aimer = a3.RobotAimer(chain, a3.LaserOnTool(tuple(tool), direction), tool, seed=scenario.plan.seed)
    q0 = _plant_start(chain, s.start_deg)
    t0 = time.perf_counter()
    runs, unreachable = [], {}
    for j in range(len(P)):
        aim = aimer.aim(targets, P_est[j], q0)
        ok = np.flatnonzero(aim.success)
        unreachable[j] = aim.unreachable
        dirs = np.random.default_rng([scenario.plan.seed, j]).choice([-1.0, 1.0], size=(len(targets), chain.n_joints))
        runs.append((ok, aim.commands_deg, dirs))
    t_aim = time.perf_counter() - t0
    seq = _sequence(runs, scenario.plan.overrun_deg)
    laser = a3.LaserOnTool(tuple(truth.chain_params[6 * chain.n_joints:]), direction)
    return SerialSetup(scenario, chain, truth, scenario.load_budget(), tool, P_est, *seq, laser_true=laser,
                       unreachable=unreachable, timings={"aiming": t_aim})


def _plant_start(chain, start_deg) -> np.ndarray:
    """Chain-order start angles (deg) as the plant's position vector (deg), for ``RobotAimer.aim``."""
    plant = chain.plant
    q = np.zeros(plant.num_positions())
    for name, v in zip(chain.joint_names, start_deg):
        q[plant.GetJointByName(name).position_start()] = v
    return q


def _sequence(runs, overrun_deg):
    """The sequencer rows of station runs [(pose indices, commands (M, N), dirs (M, N)), ...]: per
    measured pose q the approach pose q − overrun·dir (not measured), then q. Returns commands,
    dirs (formats.md rule over the whole sequence, from +1), station, measure, row."""
    cmd, station, measure, row = [], [], [], []
    for j, (poses, commands, dirs) in enumerate(runs):
        q = commands[poses]
        both = np.empty((2 * len(q), q.shape[1]))
        both[0::2], both[1::2] = q - overrun_deg * dirs[poses], q
        cmd.append(both)
        station.append(np.full(len(both), j))
        measure.append(np.tile([False, True], len(q)))
        row.append(np.repeat(poses, 2))
    cmd = np.vstack(cmd)
    measure = np.concatenate(measure)
    dirs = approach_directions(cmd, last_direction=1.0)
    want = np.vstack([d[p] for p, _, d in runs])
    assert np.array_equal(dirs[measure], want), "approach rows must give the planned directions"
    return cmd, dirs, np.concatenate(station), measure, np.concatenate(row)


def _dead_paths(setup: SerialSetup) -> np.ndarray:
    """Counter zero of each station's run: the true optical length at its first measured pose (000 Eq. 5)."""
    exact = dataclasses.replace(setup.scenario.interferometer, noise=False, quantization=False)
    n = len(setup.stations_mm)
    first = np.array([np.flatnonzero(setup.measure & (setup.reflector == j))[0] for j in range(n)])
    return numpy_readings(setup, first, exact, dead_paths_mm=np.zeros(n)).reading_mm


# ------------------------------------------------------------ the numpy model
def numpy_readings(setup: SerialSetup, rows, options, dead_paths_mm=None, rng=None) -> a3.BeamReadings:
    """The readings of sequencer ``rows`` by the numpy model (:mod:`olti_drake.model.aiming3d`):
    pan/tilt heads aimed at the nominal tool point of the commands from the estimates, or the
    robot-mounted beam of the true robot; noise from ``rng`` for all rows at once."""
    rows = np.asarray(rows, int)
    cmd, dirs, st = setup.commands_deg[rows], setup.dirs[rows], setup.reflector[rows]
    dead = setup.truth.dead_paths_mm if dead_paths_mm is None else np.asarray(dead_paths_mm, float)
    s = setup.scenario.scheme
    rng = np.random.default_rng(rng)
    out = {k: np.empty(len(rows)) for k in ("reading_mm", "miss_mm", "viewing_deg", "along_mm")}
    out["valid"] = np.zeros(len(rows), bool)
    for j in np.unique(st):
        sel = st == j
        if setup.tracers:
            commanded = setup.chain.positions(cmd[sel], setup.chain.nominal_parameters(setup.tool_offset_mm))
            r = a3.pan_tilt_readings(setup.truth, cmd[sel], dirs[sel], st[sel], commanded, setup.heads_true,
                                     setup.heads_est, dead, catseye_axis_tool=s.catseye_axis_tool,
                                     head_error=setup.head_errors[j], options=options, budget=setup.budget, rng=rng)
        else:
            r = a3.robot_beam_readings(setup.truth, cmd[sel], dirs[sel], setup.laser_true, setup.stations_mm[j],
                                       dead[j], reflector_axis=s.reflector_axis, options=options,
                                       budget=setup.budget, rng=rng)
        for k in out:
            out[k][sel] = getattr(r, k)
    return a3.BeamReadings(**out)


def simulate_serial_numpy(setup: SerialSetup, rng=None, options=None) -> dict:
    """The campaign's columns computed by :func:`numpy_readings` without Drake (the diagram's twin:
    equal readings with the noise off)."""
    rows = np.flatnonzero(setup.measure)
    reads = numpy_readings(setup, rows, options or setup.scenario.interferometer, rng=rng)
    return _columns(setup, setup.reflector[rows], setup.commands_deg[rows], setup.dirs[rows],
                    np.where(reads.valid, reads.reading_mm, np.nan), reads.valid, setup.row[rows])


def _columns(setup, station, commands, dirs, displacement, valid, row) -> dict:
    cols = {"station": np.asarray(station, float)}
    n = setup.n_joints
    cols.update({f"theta{i + 1}_deg": commands[:, i] for i in range(n)})
    cols.update({f"dir{i + 1}": dirs[:, i] for i in range(n)})
    cols.update(displacement_mm=np.asarray(displacement, float), valid=np.asarray(valid, float),
                plan_row=np.asarray(row, float))
    return cols


# --------------------------------------------------------------- Drake systems
#: The Drake systems of this diagram, public in :mod:`olti_drake.sim.systems` (which imports pydrake) and
#: importable from here too: this module stays free of pydrake until one of them is used.
_SYSTEMS = ("PanTiltSteering", "SerialLaserInterferometer", "SerialLaserInterferometer_", "SerialCampaignRecorder",
            "AddPanTiltSteering", "AddSerialInterferometer")


def __getattr__(name):
    if name in _SYSTEMS:
        from olti_drake.sim import systems

        return getattr(systems, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _systems():
    """(PanTiltSteering, SerialLaserInterferometer, SerialCampaignRecorder) of :mod:`olti_drake.sim.systems`.

    A thin alias kept for callers of the former private factory; use the public names.
    (The interferometer is now built from a chain, not a setup: :func:`AddSerialInterferometer`.)"""
    from olti_drake.sim.systems import PanTiltSteering, SerialCampaignRecorder, SerialLaserInterferometer

    return PanTiltSteering, SerialLaserInterferometer, SerialCampaignRecorder


def AddSerialStation(builder, chain, deviations, chain_params, stations_mm, dead_paths_mm, options, *,
                     budget=None, seed: int = 0, period_s: float = 1.0, name: str = "station", **beam):
    """Add a simulated N-joint station of ``chain`` (a :class:`~olti_drake.model.chain.SerialChain`: the model
    file's plant, joints and tool frame) to ``builder``; return it (a Diagram, ports in the module doc).

    Inside: :class:`~olti_drake.sim.systems.ErrorMapJoint` with one ``deviations`` entry per joint (an
    ErrorMap -- its nodes a Parameter --, a tabulated or continuous truth, or None; deg, 000 Eq. 7) feeding a
    :class:`~olti_drake.sim.systems.SerialLaserInterferometer` whose Parameters default to ``chain_params``
    (6N + 3 location errors and tool offset; mm, deg), ``stations_mm`` (Nt, 3) and ``dead_paths_mm`` (Nt,).
    ``beam``: the interferometer's scheme arguments (``laser_direction`` for a robot-mounted laser, else
    floor tracers with ``head_zeros_deg``, ``head_errors``; ``catseye_axis``). The whole station converts
    with ``ToAutoDiffXd()``."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import PassThrough

    from olti_drake.sim.systems import AddSerialInterferometer, ErrorMapJoint

    n = chain.n_joints
    if len(deviations) != n:
        raise ValueError(f"{name}: {len(deviations)} deviations given, the chain has {n} joints "
                         f"({', '.join(chain.joint_names)})")
    inner = DiagramBuilder()
    joints = inner.AddSystem(ErrorMapJoint(list(deviations), revolute=[True] * n))
    laser = AddSerialInterferometer(inner, chain, chain_params, stations_mm, dead_paths_mm, options, budget=budget,
                                    seed=seed, period_s=period_s, **beam)
    command = inner.AddNamedSystem("joint_command", PassThrough(n))
    inner.Connect(command.get_output_port(), joints.GetInputPort("command"))
    inner.Connect(joints.GetOutputPort("position"), laser.GetInputPort("position"))
    inner.ExportInput(command.get_input_port(), "joint_command")
    inner.ExportInput(laser.GetInputPort("reflector"), "reflector")
    if laser.tracers:
        inner.ExportInput(laser.GetInputPort("head_command"), "head_command")
    for port in ("displacement", "valid", "miss", "status"):
        inner.ExportOutput(laser.GetOutputPort(port), port)
    inner.ExportOutput(joints.GetOutputPort("direction"), "direction")
    inner.ExportOutput(command.get_output_port(), "measured_position")
    inner.ExportOutput(joints.GetOutputPort("position"), "true_position")
    return builder.AddNamedSystem(name, inner.Build())


def AddSimulatedSerialStation(builder, setup: SerialSetup, name: str = "station"):
    """Add the simulated N-joint station of a scenario's setup (:func:`AddSerialStation` with the truth's
    deviations, location errors, tool offset, stations and dead paths, the scheme's beam) to ``builder``."""
    s = setup.scenario
    t = setup.truth
    beam = (dict(head_zeros_deg=setup.heads_true.zeros_deg, head_errors=setup.head_errors,
                 catseye_axis=s.scheme.catseye_axis_tool) if setup.tracers else
            dict(laser_direction=setup.laser_true.direction, catseye_axis=s.scheme.reflector_axis))
    return AddSerialStation(builder, setup.chain, t.deviations, t.chain_params, setup.stations_mm, t.dead_paths_mm,
                            s.interferometer, budget=setup.budget, seed=stream_seed(s.seed, "laser"),
                            period_s=s.period_s, name=name, **beam)


def build_serial_diagram(setup: SerialSetup, station_factory=None, extend=None):
    """The whole six-axis campaign as a Diagram; returns (diagram, recorder, sequencer).

    ``station_factory(builder, setup)`` adds the station (default :func:`AddSimulatedSerialStation`;
    ``olti run`` passes :func:`olti_drake.hardware.station.AddStation`: the scenario's station).
    ``extend(builder, setup, station, sequencer)`` adds more (e.g. :func:`olti_drake.sim.serial_view.add_serial_view`)."""
    from pydrake.systems.framework import DiagramBuilder

    from olti_drake.sim.systems import AddPanTiltSteering, RowSequencer, SerialCampaignRecorder

    s = setup.scenario
    builder = DiagramBuilder()
    station = (station_factory or AddSimulatedSerialStation)(builder, setup)
    seq = builder.AddNamedSystem("plan_sequencer", RowSequencer({
        "joint_command": np.radians(setup.commands_deg), "reflector": setup.reflector.astype(float),
        "measure": setup.measure.astype(float), "row": setup.row.astype(float)}, s.period_s))
    rec = builder.AddNamedSystem("campaign_recorder", SerialCampaignRecorder(setup.n_joints, s.period_s))
    for port in ("joint_command", "reflector"):
        builder.Connect(seq.GetOutputPort(port), station.GetInputPort(port))
    if setup.tracers:
        steer = AddPanTiltSteering(builder, setup.chain, setup.tool_offset_mm, setup.heads_est)
        for port in ("joint_command", "reflector"):
            builder.Connect(seq.GetOutputPort(port), steer.GetInputPort(port))
        builder.Connect(steer.GetOutputPort("head_command"), station.GetInputPort("head_command"))
    for port in ("joint_command", "reflector", "measure", "row"):
        builder.Connect(seq.GetOutputPort(port), rec.GetInputPort(port))
    for port in ("direction", "displacement", "valid", "status"):
        builder.Connect(station.GetOutputPort(port), rec.GetInputPort(port))
    if extend is not None:
        extend(builder, setup, station, seq)
    diagram = builder.Build()
    diagram.station = station
    return diagram, rec, seq


@dataclass
class SerialCampaign:
    """The recorded columns (mm, deg; ``station``, ``theta<i>_deg``, ``dir<i>``, ``displacement_mm``,
    ``valid``, ``plan_row``) and the truth in the result format."""

    columns: dict
    truth: dict

    @property
    def n_readings(self) -> int:
        return len(self.columns["station"])


def run_serial_campaign(setup: SerialSetup, progress=None, extend=None, realtime_rate: float = 0.0) -> SerialCampaign:
    """Simulate the diagram through every row; ``setup.timings`` gets ``build`` and ``stepping`` (s).
    ``extend``: as :func:`build_serial_diagram`'s (a live view); ``realtime_rate`` > 0 paces the run."""
    from pydrake.systems.analysis import Simulator

    t0 = time.perf_counter()
    diagram, rec, seq = build_serial_diagram(setup, extend=extend)
    simulator = Simulator(diagram)
    if realtime_rate > 0:
        simulator.set_target_realtime_rate(realtime_rate)
    t1 = time.perf_counter()
    chunks = 50 if progress else 1
    for k in range(1, chunks + 1):
        simulator.AdvanceTo(seq.duration_s * k / chunks)
        if progress:
            progress(k / chunks)
    setup.timings.update(build=t1 - t0, stepping=time.perf_counter() - t1)
    n = setup.n_joints
    rows = np.array(rec.GetReadings(simulator.get_context()), dtype=float).reshape(-1, 2 * n + 4)
    cols = _columns(setup, rows[:, 0], rows[:, 1:1 + n], rows[:, 1 + n:1 + 2 * n], rows[:, 1 + 2 * n],
                    rows[:, 2 + 2 * n], rows[:, 3 + 2 * n])
    return SerialCampaign(cols, serial_truth_result(setup, cols))


# ---------------------------------------------------------------- the truth
def serial_truth_result(setup: SerialSetup, columns: dict) -> dict:
    """The simulated truth in the serial result format (formats.md, *Serial robots*;
    :func:`olti_drake.io.serial_io.serial_truth_dict`): the robot (its shipped name, else the model
    path), every joint frame's location errors by name, the tool offset, the joint deviations
    sampled every ``TRUTH_GRID_DEG`` over each joint's commanded range (forward = direction +1,
    reverse = −1; linear interpolation between 1° nodes is within ~0.03 mdeg of the harmonics),
    the true stations (or floor reflectors) and dead paths, so ``olti predict truth.json`` gives
    true positions; ``simulation`` keeps the scheme's estimates and the seeds."""
    from olti_drake.io.serial_io import serial_truth_dict

    chain, s = setup.chain, setup.scenario
    n = chain.n_joints
    th = np.column_stack([columns[f"theta{i + 1}_deg"] for i in range(n)])
    ranges = (np.column_stack([np.floor(th.min(axis=0)), np.ceil(th.max(axis=0))]) if len(th)
              else np.zeros((n, 2)))
    out = serial_truth_dict(setup.truth, s.robot.file if s.robot.file in SHIPPED_MODELS else chain.path,
                            grid_step_deg=TRUTH_GRID_DEG, ranges_deg=ranges)
    out.pop("tracker_frame", None)  # a distance campaign: no tracker
    out["gauge"] = ("simulation truth in the robot's root frame: every joint frame's location errors and the full "
                    "joint deviations (zero offsets included); an identified result fixes the unseen freedoms by "
                    "its own gauge, so compare predicted positions or readings, not parameters")
    out["residual_rms_mm"] = 0.0
    out["n_readings"] = int(np.sum(columns["valid"] > 0))
    extra = ({"heads_zeros_deg": setup.heads_true.zeros_deg.tolist(),
              "heads_zeros_estimate_deg": setup.heads_est.zeros_deg.tolist()} if setup.tracers else
             {"laser_direction_tool": list(setup.laser_true.direction),
              "unreachable_targets": {str(j): v.tolist() for j, v in setup.unreachable.items()}})
    out["simulation"] = {"scheme": type(s.scheme).__name__, "stations_estimate_mm": setup.stations_estimate_mm.tolist(),
                         "seed": s.seed, "truth_seed": s.robot.truth.seed, "plan_seed": s.plan.seed,
                         "nominal_tool_offset_mm": setup.tool_offset_mm.tolist(), **extra}
    return out


# ------------------------------------------------------------------ writing
CAMPAIGN_COMMENT = ("olti_drake six-axis distance campaign (olti simulate): dir = approach direction; "
                    "valid 0 = beam lost (no reading)")


def write_serial_simulation(campaign: SerialCampaign, out_dir: str, comments=()) -> tuple:
    """Write ``campaign.csv`` (N-joint distance campaign, :func:`olti_drake.io.serial_io.write_serial_campaign`)
    and ``truth.json`` (measurements: never replacing a file); returns both paths."""
    from olti_drake.io.outputs import make_dir, write_json
    from olti_drake.io.serial_io import write_serial_campaign

    make_dir(out_dir)
    csv_path, truth_path = os.path.join(out_dir, "campaign.csv"), os.path.join(out_dir, "truth.json")
    c = campaign.columns
    n = sum(k.startswith("theta") for k in c)
    write_serial_campaign(csv_path, np.column_stack([c[f"theta{i + 1}_deg"] for i in range(n)]),
                          np.column_stack([c[f"dir{i + 1}"] for i in range(n)]), station=c["station"],
                          displacement_mm=c["displacement_mm"], valid=c["valid"],
                          comments=list(comments) + [CAMPAIGN_COMMENT])
    write_json(truth_path, campaign.truth, measurement=True)
    return csv_path, truth_path


def simulate_serial_command(path, name, text, out_dir, seed=None, progress=None, view=None) -> str:
    """``olti simulate SCENARIO.yaml --out DIR`` for a six-axis scenario: load, check the outputs before
    any work (never replacing a campaign), prepare, run the diagram, write; returns the summary.
    ``view()``: (extend, realtime rate) of a live view, started once the outputs are known good."""
    from olti_drake.io.outputs import preflight

    t0 = time.perf_counter()
    scenario = load_serial_scenario(path, name, text)
    if seed is not None:
        scenario.seed = seed
    inputs = [path, scenario.robot_path()] + ([scenario.resolve(scenario.budget)] if scenario.budget else [])
    preflight([], inputs, measurements=[os.path.join(out_dir, n) for n in ("campaign.csv", "truth.json")],
              dirs=[out_dir], create_dirs=True)
    setup = prepare_serial(scenario)
    extend, rate = view() if view else (None, 0.0)
    campaign = run_serial_campaign(setup, progress, extend, rate)
    paths = write_serial_simulation(campaign, out_dir, [f"scenario: {path}" + (f" ({name})" if name else "")
                                                        + f"; seed {scenario.seed}"])
    return "\n".join(serial_summary(setup, campaign, time.perf_counter() - t0) + [f"wrote {paths[0]} and {paths[1]}"])


def plan_command(path, name, text, out=None) -> str:
    """``olti plan SCENARIO.yaml [--out PLAN.csv]``: the six-axis scenario's plan and its predicted quality
    before any measurement (issue "six-axis campaigns", item 2): per joint the nodes covered in each approach
    direction, the rank with the gauge, the condition number, the predicted standard uncertainty of the map
    nodes (linear method, the scenario's budget and station estimates) and what the plan cannot identify, by
    name (:func:`olti_drake.estimation.serial_plan.plan_report`). ``out``: the plan as CSV (pose order,
    joint commands, approach directions, ``station_<j>`` 1 where station j reads the pose)."""
    from olti_drake.estimation.serial_plan import plan_report, reading_uncertainty_mm
    from olti_drake.io.csvio import write_table
    from olti_drake.io.outputs import preflight

    scenario = load_serial_scenario(path, name, text)
    inputs = [path, scenario.robot_path()] + ([scenario.resolve(scenario.budget)] if scenario.budget else [])
    preflight([out] if out else [], inputs)
    setup = prepare_serial(scenario)
    plan = setup.plan
    if plan is None:
        raise InputError(f"scenario {path}: a robot-mounted scheme aims at a raster of tool points, not a joint "
                         f"plan: olti plan reports floor-tracer plans")
    u = reading_uncertainty_mm(setup.budget)
    report = plan_report(setup.chain, plan, setup.stations_estimate_mm, u, tool_offset_mm=setup.tool_offset_mm,
                         seed=scenario.plan.seed)
    lines = [f"plan of {path}" + (f" ({name})" if name else "") + f": {len(plan.commands_deg)} poses, "
             f"{plan.n_readings} readings from {plan.visible.shape[1]} stations, travel {plan.travel_deg():.0f} deg; "
             f"linear prediction with the budget's u(reading) = {1e3 * u:.2f} um and the station estimates"]
    lines += ["  " + ln for ln in report.lines()]
    lines.append("  the plan identifies every parameter of the model" if report.identifiable else
                 "  the plan does NOT identify every parameter: see 'unidentifiable' above")
    if out:
        n = setup.n_joints
        cols = {"pose": np.arange(len(plan.commands_deg))}
        cols.update({f"theta{i + 1}_deg": plan.commands_deg[:, i] for i in range(n)})
        cols.update({f"dir{i + 1}": plan.dirs[:, i] for i in range(n)})
        cols.update({f"station_{j}": plan.visible[:, j].astype(int) for j in range(plan.visible.shape[1])})
        fmt = {c: "%d" for c in cols if not c.startswith("theta")}
        fmt.update({c: "%.6f" for c in cols if c.startswith("theta")})
        write_table(out, cols, fmt, comments=[f"olti plan: {path}; poses in order; station_<j> = 1: station j "
                                             f"reads the pose; mm and degrees"])
        lines.append(f"wrote {out}")
    return "\n".join(lines)


def serial_summary(setup: SerialSetup, campaign: SerialCampaign, elapsed_s: float) -> list:
    c = campaign.columns
    valid = c["valid"] > 0
    kind = "floor tracers (pan/tilt heads)" if setup.tracers else "robot-mounted laser (IK aiming)"
    lines = [f"{os.path.basename(setup.chain.path)} ({setup.n_joints} joints, tool frame {setup.chain.tool_frame}), "
             f"{kind}: {campaign.n_readings} readings ({int(valid.sum())} valid, {int((~valid).sum())} beam lost) "
             f"from {len(setup.stations_mm)} stations",
             f"simulated in {elapsed_s:.2f} s (" + ", ".join(f"{k} {v:.2f} s" for k, v in setup.timings.items()) + ")"]
    if setup.plan is not None:
        lines.append(f"plan: {len(setup.plan.commands_deg)} poses, nodes every {setup.scenario.plan.step_deg:g} deg, "
                     f"travel {setup.plan.travel_deg():.0f} deg")
    for j, (p, e, d0) in enumerate(zip(setup.stations_mm, setup.stations_estimate_mm - setup.stations_mm,
                                       setup.truth.dead_paths_mm)):
        sel = c["station"] == j
        lines.append(f"  station {j}: true ({p[0]:.1f}, {p[1]:.1f}, {p[2]:.1f}) mm, estimate off by "
                     f"{np.linalg.norm(e):.3f} mm, dead path {d0:.3f} mm, {int(sel.sum())} readings "
                     f"({int((valid & sel).sum())} valid)")
    return lines
