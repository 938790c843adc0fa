"""The machine-tool campaign of paper 001 as a Drake diagram, the twin of
:func:`~olti_drake.model.machine.simulate_machine_campaign`.

One ``MultibodyPlant`` holds the XY(Z) machine (``models/xy_machine.sdf``: a
gantry whose spindle carries the cat's-eye ``target``) and one rotary table
(``models/rotary_table.sdf``, C axis, laser head frame with the beam along
+x) per station j, each welded at its station with the beam at the target's
height. The plant is kinematic, as for the SCARA (:mod:`olti_drake.sim.plant`):
``MultibodyPositionToGeometryPose`` poses the geometry in SceneGraph and the
instrument reads the poses from the QueryObject.

Diagram (one clock: :class:`MachineSequencer` moves every ``period_s``,
:class:`MachineRecorder` reads half a period later)::

    MachineSequencer --target_command, station--> TableSteering --table_command--+
          |                                                                      v
          +--target_command--> station: VolumetricErrorAxes -> plant (machine + tables)
                                        -> LaserInterferometer per table -> StationSelector
                                        --displacement, valid--> MachineRecorder

* :class:`VolumetricErrorAxes` -- command -> actual axis positions through
  :meth:`VolumetricError.actual <olti_drake.model.machine.VolumetricError.actual>`,
  tracking approach directions as :class:`~olti_drake.sim.systems.ErrorMapJoint` does.
* :class:`TableSteering` -- Eq. (1) of 001: the active table turns its beam
  toward the *command* target from the *estimated* station position.
* :class:`~olti_drake.sim.systems.LaserInterferometer` (reused as is) -- one per
  table: its laser frame is that table's ``laser_head``, its only "reflector"
  (index 0) the machine's target, its counter zero the station's dead path.

Units: mm, deg and µm at the API (like :mod:`olti_drake.model.machine`); SI on the
Drake ports (m, rad).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
from pydrake.geometry import SceneGraph
from pydrake.math import RigidTransform
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import BasicVector, DiagramBuilder, LeafSystem
from pydrake.systems.primitives import ConstantVectorSource, MatrixGain, Multiplexer
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

from olti_drake.formats import result_header
from olti_drake.model.budget import paper001_budget
from olti_drake.model.machine import MachineScenario, VolumetricError, machine_run
from olti_drake.sim.campaign import stream_seed
from olti_drake.sim.systems import (ApproachErrorSystem, LaserInterferometer, ReadingRecorder, RowSequencer,
                                   set_default_name)

MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
MACHINE_SDF_PATH = MODELS_DIR / "xy_machine.sdf"
TABLE_SDF_PATH = MODELS_DIR / "rotary_table.sdf"
AXIS_NAMES = ("X", "Y", "Z")
TABLE_JOINT = "C"
MM, M_TO_MM = 1e-3, 1e3
#: Simulated time per (station, target) row: move, settle, read.
PERIOD_S = 1.0
#: Margin of the drawn machine table around the workspace and the stations, mm.
BED_MARGIN_MM = 100.0
#: Seed stream of the interferometers' noise (the estimates use the twin's own generator).
STREAM_LASER = 0


# --------------------------------------------------------------------------------------------
# Models and plant
# --------------------------------------------------------------------------------------------

def _set_xy(elem: ET.Element, x: float, y: float) -> None:
    values = elem.text.split()
    values[0], values[1] = repr(float(x)), repr(float(y))
    elem.text = " ".join(values)


def machine_sdf_text(cover_mm=None) -> str:
    """The shipped machine SDF; with ``cover_mm`` (K, 2) the bed's ``table`` visual is resized
    (pose and box size, m) to cover those points plus :data:`BED_MARGIN_MM` -- visual only."""
    root = ET.parse(MACHINE_SDF_PATH).getroot()
    if cover_mm is not None:
        pts = np.asarray(cover_mm, dtype=float).reshape(-1, 2)
        visual = root.find("./model/link[@name='bed']/visual[@name='table']")
        if visual is None:
            raise ValueError("xy_machine.sdf: no visual 'table' on link 'bed'")
        lo, hi = pts.min(axis=0) - BED_MARGIN_MM, pts.max(axis=0) + BED_MARGIN_MM
        _set_xy(visual.find("pose"), *(0.5 * (lo + hi) * MM))
        _set_xy(visual.find("geometry/box/size"), *((hi - lo) * MM))
    return ET.tostring(root, encoding="unicode")


def rotary_table_sdf_text(name: str) -> str:
    """The shipped rotary-table SDF with its model renamed (one model instance per station)."""
    root = ET.parse(TABLE_SDF_PATH).getroot()
    root.find("./model").set("name", name)
    return ET.tostring(root, encoding="unicode")


def _pose_at_zero(sdf_text: str, frame: str, base: str) -> RigidTransform:
    """Pose of ``frame`` in the ``base`` body frame with every joint at zero (a throwaway plant)."""
    plant = MultibodyPlant(time_step=0.0)
    (model,) = Parser(plant).AddModelsFromString(sdf_text, "sdf")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName(base, model))
    plant.Finalize()
    ctx = plant.CreateDefaultContext()
    plant.SetPositions(ctx, np.zeros(plant.num_positions()))
    return plant.GetFrameByName(frame, model).CalcPoseInWorld(ctx)


@dataclass
class MachinePlant:
    """A finalized plant with the machine and the rotary tables, and the handles a diagram needs.

    ``axes_input`` (3: X, Y, Z in m), ``tables_input`` (N_j: C angles in rad),
    ``query_output`` and ``to_pose`` are set only by :func:`AddMachinePlant`.
    """

    plant: MultibodyPlant
    scene_graph: SceneGraph
    machine: object
    target: object
    axes: list
    tables: list
    table_joints: list
    laser_heads: list
    stations_mm: np.ndarray
    beam_height_m: float
    axes_input: object = None
    tables_input: object = None
    query_output: object = None
    to_pose: Optional[MultibodyPositionToGeometryPose] = None

    @property
    def n_stations(self) -> int:
        return len(self.tables)

    @property
    def position_selector(self) -> np.ndarray:
        """S (nq, 3 + N_j): plant q = S @ [X, Y, Z, C_0, ..., C_{N_j-1}] (SI)."""
        joints = list(self.axes) + list(self.table_joints)
        S = np.zeros((self.plant.num_positions(), len(joints)))
        for k, joint in enumerate(joints):
            S[joint.position_start(), k] = 1.0
        return S

    def positions(self, xyz_m, c_rad=None) -> np.ndarray:
        """Plant position vector q (SI) from the axis positions (3,) m and table angles (N_j,) rad."""
        c = np.zeros(self.n_stations) if c_rad is None else np.asarray(c_rad, dtype=float)
        return self.position_selector @ np.concatenate([np.asarray(xyz_m, dtype=float), c])

    @property
    def target_frame_id(self):
        """SceneGraph FrameId of the target (cat's eye) body."""
        return self.plant.GetBodyFrameIdOrThrow(self.target.index())

    @property
    def laser_frame_ids(self) -> list:
        """SceneGraph FrameIds of the turntable bodies carrying the laser heads, index j = station j."""
        return [self.plant.GetBodyFrameIdOrThrow(f.body().index()) for f in self.laser_heads]

    @property
    def lasers_in_body(self) -> list:
        """X_FL of each laser head (beam along +x) in its turntable body frame, m."""
        return [f.GetFixedPoseInBodyFrame() for f in self.laser_heads]


def make_machine_plant(stations_mm, scene_graph=None, cover_mm=None) -> MachinePlant:
    """Build and finalize the machine with one rotary table per station.

    Args:
        stations_mm: (N_j, 2) station positions (the C axes) in the machine
            frame, mm; table j is the model instance ``rotary_table_<j>``,
            welded upright with its C axis through the station and its laser
            head at the target's height (X = Y = Z = 0), so the beam is
            horizontal and C = 0 points it along machine +X.
        scene_graph: SceneGraph to register the geometry with; a new one if None.
        cover_mm: extra points (e.g. the targets) the drawn table must cover.
    """
    P = np.asarray(stations_mm, dtype=float).reshape(-1, 2)
    if not len(P) or not np.all(np.isfinite(P)):
        raise ValueError(f"stations_mm must be a non-empty list of finite [x, y] pairs, got {stations_mm!r}")
    cover = P if cover_mm is None else np.vstack([P, np.asarray(cover_mm, dtype=float).reshape(-1, 2)])
    machine_text = machine_sdf_text(cover)
    beam_height_m = float(_pose_at_zero(machine_text, "target", "bed").translation()[2])
    head_in_base = _pose_at_zero(rotary_table_sdf_text("rotary_table"), "laser_head", "base").translation()

    if scene_graph is None:
        scene_graph = SceneGraph()
    plant = MultibodyPlant(time_step=0.0)
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    parser = Parser(plant)
    (machine,) = parser.AddModelsFromString(machine_text, "sdf")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("bed", machine))
    tables, heads = [], []
    for j, (x, y) in enumerate(P):
        (table,) = parser.AddModelsFromString(rotary_table_sdf_text(f"rotary_table_{j}"), "sdf")
        # The base origin is on the C axis: put the axis on the station, the head at the beam height.
        plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base", table),
                         RigidTransform([x * MM, y * MM, beam_height_m - head_in_base[2]]))
        tables.append(table)
        heads.append(plant.GetFrameByName("laser_head", table))
    plant.Finalize()
    return MachinePlant(plant, scene_graph, machine, plant.GetBodyByName("target", machine),
                        [plant.GetJointByName(a, machine) for a in AXIS_NAMES], tables,
                        [plant.GetJointByName(TABLE_JOINT, t) for t in tables], heads, P, beam_height_m)


def AddMachinePlant(builder, stations_mm, cover_mm=None, name="plant") -> MachinePlant:
    """Add the kinematic machine + tables (SceneGraph, position-to-pose) to ``builder``.

    Like :func:`olti_drake.sim.plant.AddScaraPlant`: ``MultibodyPositionToGeometryPose``
    (named ``name``) poses the geometry; its q is assembled from
    ``axes_input`` (3, m) and ``tables_input`` (N_j, rad) by a Multiplexer and
    a MatrixGain holding :attr:`MachinePlant.position_selector`.
    """
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    mp = make_machine_plant(stations_mm, scene_graph=scene_graph, cover_mm=cover_mm)
    mux = builder.AddNamedSystem(f"{name}_axes_and_tables", Multiplexer([len(AXIS_NAMES), mp.n_stations]))
    order = builder.AddNamedSystem(f"{name}_position_order", MatrixGain(mp.position_selector))
    to_pose = builder.AddNamedSystem(name, MultibodyPositionToGeometryPose(mp.plant))
    builder.Connect(mux.get_output_port(0), order.get_input_port())
    builder.Connect(order.get_output_port(), to_pose.get_input_port())
    builder.Connect(to_pose.get_output_port(), scene_graph.get_source_pose_port(mp.plant.get_source_id()))
    mp.to_pose = to_pose
    mp.axes_input, mp.tables_input = mux.get_input_port(0), mux.get_input_port(1)
    mp.query_output = scene_graph.get_query_output_port()
    return mp


# --------------------------------------------------------------------------------------------
# Systems
# --------------------------------------------------------------------------------------------

class VolumetricErrorAxes(ApproachErrorSystem):
    """Commanded -> actual machine axis positions through the volumetric error (001 §3).

    The role :class:`~olti_drake.sim.systems.ErrorMapJoint` has for the SCARA,
    with the same direction tracking (:class:`~olti_drake.sim.systems.ApproachErrorSystem`).
    Input ``command`` (3): x*, y*, z* (m); outputs ``position`` (3, m):
    (x, y) = :meth:`VolumetricError.actual` of (x*, y*) approached in
    (dir_x, dir_y), z = z* (no Z errors in the 2D model); ``direction`` (3): ±1.
    """

    def __init__(self, error: VolumetricError, initial_direction: float = 1.0):
        super().__init__([False] * len(AXIS_NAMES), initial_direction)
        self._error = error

    def actual(self, command, direction) -> np.ndarray:
        xy = self._error.actual(command[None, :2], direction[0], direction[1])[0]
        return np.append(xy, command[2])


class TableSteering(LeafSystem):
    """Open-loop C commands of the rotary tables toward the *command* target (001 Eq. 1).

    Inputs ``target_command`` (3: x*, y*, z* in m; z* is not used -- the 2D
    case) and ``station`` (1): index j of the active station.
    Output ``table_command`` (N_j, rad): the active table's C =
    atan2(y* − P̂_j,y, x* − P̂_j,x) + δ_j from the *estimated* station P̂_j
    (mm; 001 §2.2); the other tables park at C = 0 (``aim_all``: every table
    aims from its own estimate).

    ``zero_angle_errors_rad`` (N_j,) δ_j: the table zero as the operator
    aligned it (001 §2.2, Fig. 7; u41 of Table 4) lies δ_j from machine +X,
    so the operator's Eq. (1) angle turns the beam δ_j further; the plant's C
    joint angle *is* the beam's direction from +X, hence the sum.
    """

    def __init__(self, stations_estimate_mm, zero_angle_errors_rad=None, aim_all: bool = False):
        super().__init__()
        set_default_name(self)
        self._P = np.asarray(stations_estimate_mm, dtype=float).reshape(-1, 2)
        n = len(self._P)
        self._delta = np.zeros(n) if zero_angle_errors_rad is None else np.broadcast_to(
            np.asarray(zero_angle_errors_rad, dtype=float), (n,)).copy()
        self._aim_all = aim_all
        self.DeclareVectorInputPort("target_command", len(AXIS_NAMES))
        self.DeclareVectorInputPort("station", 1)
        self.DeclareVectorOutputPort("table_command", n, self._calc)

    def _calc(self, context, output: BasicVector):
        p = np.asarray(self.get_input_port(0).Eval(context)[:2], dtype=float) * M_TO_MM
        j = int(round(self.get_input_port(1).Eval(context)[0]))
        aim = np.arctan2(p[1] - self._P[:, 1], p[0] - self._P[:, 0]) + self._delta
        output.SetFromVector(aim if self._aim_all else np.where(np.arange(len(aim)) == j, aim, 0.0))


class MachineSequencer(RowSequencer):
    """Walks the targets once per station, one (station j, target i) row per period.

    Outputs ``target_command`` (3, m), ``station`` (1), ``target`` (1).
    """

    def __init__(self, commands_mm, n_stations: int, period_s: float, z_mm: float = 0.0):
        cmd = np.asarray(commands_mm, dtype=float).reshape(-1, 2)
        k = len(cmd)
        super().__init__({"target_command": np.tile(np.column_stack([cmd, np.full(k, z_mm)]) * MM, (n_stations, 1)),
                          "station": np.repeat(np.arange(n_stations, dtype=float), k),
                          "target": np.tile(np.arange(k, dtype=float), n_stations)}, period_s)


class StationSelector(LeafSystem):
    """Passes on the reading of the active station's interferometer.

    Inputs ``station`` (1) and, per station j, ``displacement_<j>``,
    ``valid_<j>``, ``miss_<j>`` (1 each); outputs ``displacement``, ``valid``,
    ``miss`` of station j (only its interferometer is evaluated).
    """

    PORTS = ("displacement", "valid", "miss")

    def __init__(self, n_stations: int):
        super().__init__()
        set_default_name(self)
        self.DeclareVectorInputPort("station", 1)
        for j in range(n_stations):
            for name in self.PORTS:
                self.DeclareVectorInputPort(f"{name}_{j}", 1)
        for name in self.PORTS:
            self.DeclareVectorOutputPort(name, 1, lambda c, o, name=name: o.SetFromVector(
                self.GetInputPort(f"{name}_{int(round(self.get_input_port(0).Eval(c)[0]))}").Eval(c)))


class MachineRecorder(ReadingRecorder):
    """Takes the reading half a period after each move (the :class:`~olti_drake.sim.systems.CampaignRecorder` clock).

    Inputs ``station``, ``target`` (1), ``target_command`` (3, m),
    ``displacement`` (1, m), ``valid`` (1), ``position`` (3, m: the actual
    axes, kept as truth). Each record, kept in the Context
    (:meth:`~olti_drake.sim.systems.ReadingRecorder.GetReadings`), is the row
    (station, target, x_cmd_mm, y_cmd_mm, displacement_mm -- NaN when the beam
    is lost --, valid) followed by the actual (x, y) mm (:meth:`GetActual`).
    """

    COLUMNS = ("station", "target", "x_cmd_mm", "y_cmd_mm", "displacement_mm", "valid")

    def __init__(self, period_s: float):
        super().__init__(period_s, 0.5 * period_s)
        for name, size in (("station", 1), ("target", 1), ("target_command", 3), ("displacement", 1),
                           ("valid", 1), ("position", 3)):
            self.DeclareVectorInputPort(name, size)

    def record(self, context):
        station, target, cmd, disp, valid, pos = (self.get_input_port(i).Eval(context)
                                                  for i in range(self.num_input_ports()))
        ok = valid[0] > 0.5
        return (int(round(station[0])), int(round(target[0])), cmd[0] * M_TO_MM, cmd[1] * M_TO_MM,
                disp[0] * M_TO_MM if ok else np.nan, int(ok), pos[0] * M_TO_MM, pos[1] * M_TO_MM)

    def GetActual(self, root_context) -> np.ndarray:
        """(K, 2) actual (x, y) mm of the kept readings (the truth)."""
        return np.array([r[6:] for r in self.GetReadings(root_context)], dtype=float).reshape(-1, 2)


# --------------------------------------------------------------------------------------------
# Campaign
# --------------------------------------------------------------------------------------------

@dataclass
class MachineSetup:
    """What the campaign diagram needs, all from the scenario (mm, rad).

    ``stations_estimate_mm`` and ``zero_angle_errors_rad`` steer the tables
    (Eq. 1 of 001); ``dead_paths_mm`` L0_j is the counter zero of station j:
    the distance from the station to the actual target at its run's first
    reading, the definition of the numpy twin; ``targets_mm`` the actual
    target positions (each target's first reading).
    """

    scenario: MachineScenario
    budget: object
    commands_mm: np.ndarray
    stations_mm: np.ndarray
    stations_estimate_mm: np.ndarray
    zero_angle_errors_rad: np.ndarray
    sequence: dict
    targets_mm: np.ndarray
    dead_paths_mm: np.ndarray
    period_s: float = PERIOD_S


def prepare_machine(scenario: MachineScenario, budget=None, period_s: float = PERIOD_S) -> MachineSetup:
    """The campaign as the numpy twin runs it (:func:`~olti_drake.model.machine.machine_run`, seeded by the
    scenario): the same sequence, steering estimates and counter zeros, so the diagram steers exactly as
    :func:`~olti_drake.model.machine.simulate_machine_campaign`. The instrument noise has its own seeded streams
    (see :class:`~olti_drake.sim.systems.LaserInterferometer`).
    """
    if not (np.isfinite(period_s) and period_s > 0):
        raise ValueError(f"period_s must be finite and > 0, got {period_s!r}")
    run = machine_run(scenario, np.random.default_rng(scenario.seed))
    return MachineSetup(scenario, budget or paper001_budget(), run.commands_mm, run.stations_mm,
                        run.stations_estimate_mm, run.zero_angle_errors_rad, run.sequence, run.targets_mm,
                        run.dead_paths_mm, period_s)


def AddMachineStation(builder, setup: MachineSetup, name: str = "station"):
    """Add the simulated station (a Diagram: machine, tables, interferometers) to ``builder``.

    Ports -- inputs: ``target_command`` (3, m), ``table_command`` (N_j, rad),
    ``station`` (1); outputs: ``displacement`` (1, m), ``valid`` (1),
    ``miss`` (1, m) of the active station, ``direction`` (3, ±1),
    ``true_position`` (3, actual axes, m; simulation only, as the SCARA station's), ``query_object`` (SceneGraph, for
    visualization). The returned system keeps the plant as ``.plant``.
    """
    s = setup.scenario
    inner = DiagramBuilder()
    mp = AddMachinePlant(inner, setup.stations_mm, cover_mm=setup.commands_mm)
    axes = inner.AddNamedSystem("volumetric_error_axes", VolumetricErrorAxes(s.error))
    select = inner.AddNamedSystem("station_selector", StationSelector(mp.n_stations))
    target_index = inner.AddNamedSystem("target_index", ConstantVectorSource([0.0]))
    inner.Connect(axes.GetOutputPort("position"), mp.axes_input)
    for j in range(mp.n_stations):
        laser = inner.AddNamedSystem(f"laser_interferometer_{j}", LaserInterferometer(
            mp.laser_frame_ids[j], mp.lasers_in_body[j], [mp.target_frame_id], [setup.dead_paths_mm[j]],
            s.interferometer, setup.budget, seed=stream_seed(s.seed, STREAM_LASER, j), period_s=setup.period_s))
        inner.Connect(mp.query_output, laser.GetInputPort("geometry_query"))
        inner.Connect(target_index.get_output_port(), laser.GetInputPort("reflector"))
        for port in StationSelector.PORTS:
            inner.Connect(laser.GetOutputPort(port), select.GetInputPort(f"{port}_{j}"))
    inner.ExportInput(axes.GetInputPort("command"), "target_command")
    inner.ExportInput(mp.tables_input, "table_command")
    inner.ExportInput(select.GetInputPort("station"), "station")
    for port in StationSelector.PORTS:
        inner.ExportOutput(select.GetOutputPort(port), port)
    inner.ExportOutput(axes.GetOutputPort("direction"), "direction")
    inner.ExportOutput(axes.GetOutputPort("position"), "true_position")
    inner.ExportOutput(mp.query_output, "query_object")
    station = builder.AddNamedSystem(name, inner.Build())
    station.plant = mp  # keeps the plant (referenced by MultibodyPositionToGeometryPose) alive
    return station


def build_machine_diagram(setup: MachineSetup, meshcat=None, aim_all: bool = False):
    """The whole campaign as a Diagram; returns (diagram, recorder, sequencer).

    ``meshcat``: a ``pydrake.geometry.Meshcat`` to draw the machine and tables in.
    """
    builder = DiagramBuilder()
    station = AddMachineStation(builder, setup)
    seq = builder.AddNamedSystem("machine_sequencer", MachineSequencer(
        setup.commands_mm, len(setup.stations_mm), setup.period_s))
    steer = builder.AddNamedSystem("table_steering", TableSteering(
        setup.stations_estimate_mm, setup.zero_angle_errors_rad, aim_all=aim_all))
    rec = builder.AddNamedSystem("machine_recorder", MachineRecorder(setup.period_s))
    for sink in (station, steer, rec):
        builder.Connect(seq.GetOutputPort("target_command"), sink.GetInputPort("target_command"))
        builder.Connect(seq.GetOutputPort("station"), sink.GetInputPort("station"))
    builder.Connect(seq.GetOutputPort("target"), rec.GetInputPort("target"))
    builder.Connect(steer.GetOutputPort("table_command"), station.GetInputPort("table_command"))
    for port in ("displacement", "valid"):
        builder.Connect(station.GetOutputPort(port), rec.GetInputPort(port))
    builder.Connect(station.GetOutputPort("true_position"), rec.GetInputPort("position"))
    if meshcat is not None:
        from pydrake.geometry import MeshcatVisualizer

        MeshcatVisualizer.AddToBuilder(builder, station.GetOutputPort("query_object"), meshcat)
    diagram = builder.Build()
    diagram.station = station
    return diagram, rec, seq


def machine_columns(recorder: MachineRecorder, root_context) -> dict:
    """The recorder's rows in ``root_context`` as the columns of the machine campaign (formats.md), twin dtypes."""
    n = len(MachineRecorder.COLUMNS)
    rows = np.array([r[:n] for r in recorder.GetReadings(root_context)], dtype=float).reshape(-1, n)
    cols = {c: rows[:, k] for k, c in enumerate(MachineRecorder.COLUMNS)}
    for c in ("station", "target", "valid"):
        cols[c] = cols[c].astype(int)
    return cols


def machine_truth(setup: MachineSetup, columns: dict) -> dict:
    """The simulated truth, laid out as :func:`~olti_drake.model.machine.simulate_machine_campaign`'s."""
    return {**result_header("multilateration"), "targets_mm": setup.targets_mm.tolist(),
            "stations_mm": setup.stations_mm.tolist(), "dead_paths_mm": setup.dead_paths_mm.tolist(),
            "commands_mm": setup.commands_mm.tolist(), "gauge": "simulation truth: the machine's command frame",
            "residual_rms_mm": 0.0, "n_readings": int(np.sum(columns["valid"])),
            "stations_estimate_mm": setup.stations_estimate_mm.tolist(), "seed": setup.scenario.seed}


def run_machine_campaign(scenario: MachineScenario, budget=None, period_s: float = PERIOD_S):
    """Simulate the diagram over every station and target: (columns, truth).

    The layout of :func:`~olti_drake.model.machine.simulate_machine_campaign`
    (formats.md machine campaign; truth in the multilateration result
    format). With the instrument noise off the readings equal the twin's.
    """
    from pydrake.systems.analysis import Simulator

    setup = prepare_machine(scenario, budget, period_s)
    diagram, rec, seq = build_machine_diagram(setup)
    simulator = Simulator(diagram)
    simulator.AdvanceTo(seq.duration_s)
    columns = machine_columns(rec, simulator.get_context())
    return columns, machine_truth(setup, columns)
