"""The 3D machine-tool campaign (formats.md "Machine tool in 3D"; paper 001 in 3D) as a Drake diagram,
the twin of :func:`~olti_drake.model.machine.simulate_machine_campaign_3d` (issue 15 item 1).

Diagram (one clock: the sequencer moves every ``period_s``, the recorder reads half a period later)::

    RowSequencer --target_command (3, m), station, tool--> PanTiltSteering --head_command (2, rad)--+
          |                                                                                      v
          +--target_command, tool--> station: XYZ MultibodyPlant (commanded axes)
                                              VolumetricTool -> tool_point (3, m)
                                              -> PanTiltInterferometer --displacement, valid, miss-->
                                                                                  Machine3DRecorder

* the XYZ plant -- a ``MultibodyPlant`` of three prismatic axes (X on the base, Y on X, Z on Y, the
  spindle reference point on Z): the NOMINAL kinematics. :class:`PanTiltSteering` of the six-axis
  diagram (reused, with its ``tool`` input) aims the active head by 001
  Eq. (1) in 3D at the commanded tool point (the plant's spindle point + the row's nominal tool
  offset) from the ESTIMATED centre and zeros -- open loop.
* :class:`VolumetricTool` -- commanded axes -> the TRUE tool point by the volumetric3d truth (the 21
  error motions composed exactly, :func:`~olti_drake.model.volumetric3d.tool_positions`), per tool.
* :class:`PanTiltInterferometer` -- the beam leaves the TRUE head centre along the TRUE angles
  (command + the head's own error + true zeros, :func:`~olti_drake.model.aiming3d.pan_tilt_beam`) and
  reads the true tool point by :func:`~olti_drake.model.aiming3d.read_beam` (cosine error, acceptance,
  budget noise with the pose term on the head, λ/64).

Station ports (the 2D :func:`~olti_drake.sim.machine_station.AddMachineStation` contract where it
applies): inputs ``target_command`` (3, m), ``tool`` (1), ``head_command`` (2, rad; the 2D station's
``table_command``), ``station`` (1); outputs ``displacement`` (1, m), ``valid`` (1), ``miss`` (1, m),
``status``, ``true_position`` (3, m: the true tool point; simulation only).

The systems are public in :mod:`olti_drake.sim.systems` (importable from here too, pydrake loaded on first
use): :class:`~olti_drake.sim.systems.VolumetricTool`, :class:`~olti_drake.sim.systems.PanTiltInterferometer`,
:class:`~olti_drake.sim.systems.Machine3DRecorder`. :func:`AddVolumetricStation` builds the station from a
machine configuration and a truth without a scenario, :func:`AddMachine3DStation` from a planned run. A
spline truth's volumetric parameters, the head centres and the dead paths are numeric Parameters of the
Context, and the station converts with ``ToAutoDiffXd()``: a reading's derivative with respect to them is
the Jacobian entry of :class:`~olti_drake.estimation.volumetric.VolumetricIdentification`
(tests/sim/test_drake_native_serial_machine.py).

Units: mm, deg, µm, µrad in files and the API; SI on the Drake ports.
"""

import os
import time
from dataclasses import dataclass, field
from typing import Union


import numpy as np

from olti_drake.errors import InputError
from olti_drake.limits import check_allocation
from olti_drake.io.csvio import write_machine_campaign
from olti_drake.model.budget import paper001_budget
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.model.machine import Machine3DRun, Machine3DScenario, _default_heads, machine3d_truth, machine_run_3d
from olti_drake.sim.scenario import Emulated, Hardware, ScenarioPaths, Simulated, stream_seed

M_TO_MM = 1e3
#: Working float64 values a reading carries through the simulation (its columns, truth, aiming, sequence): an
#: estimate for the scenario's ``grid`` guard (:func:`olti_drake.limits.check_allocation`).
VALUES_PER_READING = 64
AXES = ("X", "Y", "Z")
SPINDLE_FRAME = "spindle"


# ------------------------------------------------------------------ the scenario file
@dataclass
class MachineSpec:
    """The machine of a 3D scenario (:class:`~olti_drake.model.volumetric3d.MachineConfig`), mm."""

    tool_chain: list[str] = field(default_factory=lambda: ["X", "Y", "Z"])
    work_chain: list[str] = field(default_factory=list)
    travel_mm: dict[str, list[float]] = field(
        default_factory=lambda: {"X": [0.0, 400.0], "Y": [0.0, 300.0], "Z": [0.0, 250.0]})
    knot_spacing_mm: float = 50.0
    tool_offsets_mm: list[list[float]] = field(default_factory=lambda: [[0.0, 0.0, 100.0]])


@dataclass
class Machine3DScenarioFile(ScenarioPaths):
    """A 3D machine campaign as YAML (``diagrams/machine_3d.yaml``): the fields of
    :class:`~olti_drake.model.machine.Machine3DScenario` with the machine spelled out, plus the
    budget file (relative to the YAML; "" = 001 Table 4 built in), the sequencer period (s) and the
    station ``olti run`` takes the campaign on: ``!Simulated`` (this diagram's), ``!Emulated`` (the 3D
    machine emulator: the X, Y, Z controller and a pan/tilt head line per head, docs/emulator.md) or
    ``!Hardware {robot_port: ..., head_ports: [...]}`` (the machine's controller and one port per head,
    in the order of ``heads_mm``); ``olti simulate`` always simulates."""

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "machine3d"

    machine: MachineSpec = field(default_factory=MachineSpec)
    grid: list[int] = field(default_factory=lambda: [5, 4, 3])
    tools: list[int] = field(default_factory=lambda: [0])
    heads_mm: list[list[float]] = field(default_factory=_default_heads)
    station_estimate_sigma_um: float = 5.75
    zero_angle_sigma_urad: float = 2.8
    head_error_mdeg: float = 0.5
    catseye_axis: list[float] = field(default_factory=lambda: [0.0, 0.0, -1.0])
    truth_seed: int = 1
    interferometer: InterferometerOptions = field(default_factory=InterferometerOptions)
    budget: str = ""
    seed: int = 0
    period_s: float = 1.0
    station: Union[Simulated, Emulated, Hardware] = field(default_factory=Simulated)

    base: str = ""

    def load_budget(self):
        """The budget file's :class:`~olti_drake.io.budget.Budget`, or 001 Table 4 when ``budget`` is empty."""
        from olti_drake.io.budget import load_budget
        return load_budget(self.resolve(self.budget)) if self.budget else paper001_budget()

    def validate(self, where: str = "scenario") -> "Machine3DScenarioFile":
        from olti_drake.sim.scenario import _check_station

        self.scenario(where)
        _check_station(f"{where}: station", self.station, heads=len(self.heads_mm))
        return self

    def scenario(self, where: str = "scenario") -> Machine3DScenario:
        """The model-layer scenario; a bad value gets one line naming ``where`` and the field."""
        from olti_drake.model.volumetric3d import MachineConfig

        m = self.machine
        try:
            config = MachineConfig(tuple(m.tool_chain), tuple(m.work_chain),
                                   {k: tuple(v) for k, v in m.travel_mm.items()}, m.knot_spacing_mm,
                                   tuple(tuple(t) for t in m.tool_offsets_mm))
        except (ValueError, TypeError) as e:
            raise InputError(f"{where}: machine: {e}") from None
        heads = np.asarray(self.heads_mm, float)
        checks = [("heads_mm", heads.ndim == 2 and heads.shape[1:] == (3,) and len(heads) >= 1
                   and np.all(np.isfinite(heads)), "a list of finite [x, y, z]"),
                  ("grid", len(self.grid) == 3 and min(self.grid) >= 2, "3 counts >= 2"),
                  ("tools", len(self.tools) >= 1 and all(0 <= t < len(config.tools) for t in self.tools),
                   f"tool indices 0..{len(config.tools) - 1} (machine.tool_offsets_mm)"),
                  ("catseye_axis", len(self.catseye_axis) == 3 and np.any(self.catseye_axis)
                   and np.all(np.isfinite(self.catseye_axis)), "3 finite numbers, not all zero"),
                  ("period_s", np.isfinite(self.period_s) and self.period_s > 0, "finite and > 0")]
        checks += [(name, np.isfinite(v) and v >= 0, "finite and >= 0") for name, v in (
            ("station_estimate_sigma_um", self.station_estimate_sigma_um),
            ("zero_angle_sigma_urad", self.zero_angle_sigma_urad), ("head_error_mdeg", self.head_error_mdeg))]
        checks += [(name, v >= 0, "an integer >= 0") for name, v in (("seed", self.seed),
                                                                      ("truth_seed", self.truth_seed))]
        for name, ok, need in checks:
            if not ok:
                raise InputError(f"{where}: {name} must be {need}, got {getattr(self, name)!r}")
        # every grid point per tool is read from every head: the campaign's columns and the aiming (limits.py)
        check_allocation(f"{where}: grid", list(self.grid), [*map(float, self.grid), len(self.tools), len(heads),
                                                             VALUES_PER_READING],
                         what="values (targets x tools x heads x values per reading)", hint="use fewer grid points")
        try:
            self.interferometer.validate(f"{where}: interferometer")
        except ValueError as e:
            raise InputError(str(e)) from None
        return Machine3DScenario(config, tuple(self.grid), tuple(self.tools), heads.tolist(),
                                 self.station_estimate_sigma_um, self.zero_angle_sigma_urad, self.head_error_mdeg,
                                 tuple(self.catseye_axis), self.truth_seed, self.interferometer, self.seed)


def is_machine3d_scenario(path, name=None) -> bool:
    """Whether ``olti simulate`` runs this scenario here: it (its named scenario, or a base it names) has
    the top-level key ``heads_mm`` (:func:`~olti_drake.sim.serial_scenario.scenario_kind`)."""
    from olti_drake.sim.serial_scenario import scenario_kind

    return scenario_kind(path, name) == "machine3d"


def load_machine3d_scenario(path, name=None, text=None) -> Machine3DScenarioFile:
    """The YAML file (its named scenario ``name``, its ``base`` layers, then ``--scenario-text``
    overrides) as a validated :class:`Machine3DScenarioFile`, by the scenario loader of
    :func:`olti_drake.sim.scenario.load_scenario` (one line naming the file and the field on error)."""
    from olti_drake.sim.scenario import load_scenario

    return load_scenario(path, name, text, defaults=Machine3DScenarioFile())


# ------------------------------------------------------------------ the XYZ plant
def xyz_machine_sdf() -> str:
    """SDFormat of the nominal XYZ machine: prismatic X (on the base), Y (on X), Z (on Y), along the
    world axes, zero at the command origin; frame ``spindle`` on Z (the spindle reference point)."""
    links, joints, parent = [], [], "base"
    for k, axis in enumerate(AXES):
        child = f"carriage_{axis.lower()}"
        links.append(f'<link name="{child}"><inertial><mass>1</mass></inertial></link>')
        joints.append(f'<joint name="{axis}" type="prismatic"><parent>{parent}</parent><child>{child}</child>'
                      f'<axis><xyz>{" ".join("1" if i == k else "0" for i in range(3))}</xyz>'
                      f'<limit><lower>-10</lower><upper>10</upper></limit></axis></joint>')
        parent = child
    return ('<?xml version="1.0"?><sdf version="1.9"><model name="xyz_machine">'
            '<link name="base"><inertial><mass>1</mass></inertial></link>' + "".join(links) + "".join(joints)
            + f'<frame name="{SPINDLE_FRAME}" attached_to="{parent}"/></model></sdf>')


@dataclass
class XYZMachine:
    """The finalized nominal plant and what :class:`PanTiltSteering` reads of a chain."""

    plant: object
    tool_frame_index: object
    joint_names: tuple = AXES
    n_joints: int = 3


def make_xyz_machine() -> XYZMachine:
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    plant = MultibodyPlant(time_step=0.0)
    (model,) = Parser(plant).AddModelsFromString(xyz_machine_sdf(), "sdf")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base", model))
    plant.Finalize()
    return XYZMachine(plant, plant.GetFrameByName(SPINDLE_FRAME, model).index())


# ------------------------------------------------------------------ Drake systems
#: The Drake systems of this diagram, public in :mod:`olti_drake.sim.systems` (which imports pydrake) and
#: importable from here too: this module stays free of pydrake until one of them is used.
_SYSTEMS = ("VolumetricTool", "VolumetricTool_", "PanTiltInterferometer", "PanTiltInterferometer_",
            "Machine3DRecorder", "PanTiltSteering", "AddPanTiltSteering")


def __getattr__(name):
    if name in _SYSTEMS:
        from olti_drake.sim import systems

        return getattr(systems, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _systems():
    """(VolumetricTool, PanTiltInterferometer, Machine3DRecorder) of :mod:`olti_drake.sim.systems`: a thin
    alias kept for callers of the former private factory; use the public names."""
    from olti_drake.sim.systems import Machine3DRecorder, PanTiltInterferometer, VolumetricTool

    return VolumetricTool, PanTiltInterferometer, Machine3DRecorder


# ------------------------------------------------------------------ the campaign
COLUMNS = ("station", "target", "x_cmd_mm", "y_cmd_mm", "z_cmd_mm", "tool", "displacement_mm", "valid")


@dataclass
class Machine3DSetup:
    """What the diagram needs: the scenario, the planned run (shared with the numpy twin), the budget,
    the period (s) and the seed of the interferometer's noise stream."""

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "machine3d"

    scenario: Machine3DScenario
    run: Machine3DRun
    budget: object
    period_s: float = 1.0


def prepare_machine3d(scenario: Machine3DScenario, budget=None, period_s: float = 1.0) -> Machine3DSetup:
    """The campaign as the numpy twin plans it (:func:`~olti_drake.model.machine.machine_run_3d`)."""
    return Machine3DSetup(scenario, machine_run_3d(scenario), budget or paper001_budget(), period_s)


def AddVolumetricStation(builder, config, truth, heads_true, head_error, dead_paths_mm, catseye_axis, options,
                         budget=None, seed: int = 0, period_s: float = 1.0, name: str = "station"):
    """Add a simulated 3D machine station to ``builder``; return it (a Diagram; ports in the module doc).

    Inside: :class:`~olti_drake.sim.systems.VolumetricTool` of ``config`` (a
    :class:`~olti_drake.model.volumetric3d.MachineConfig`) and its ``truth`` (spline motions: a Parameter;
    or a continuous truth) feeding a :class:`~olti_drake.sim.systems.PanTiltInterferometer` on the TRUE heads
    ``heads_true`` (their centres a Parameter) with ``head_error``, counter zeros ``dead_paths_mm`` (a
    Parameter), cat's-eye axis ``catseye_axis`` (world), the reading ``options``, ``budget`` (None: no
    noise), ``seed`` and ``period_s``. The whole station converts with ``ToAutoDiffXd()``."""
    from pydrake.systems.framework import DiagramBuilder

    from olti_drake.sim.systems import PanTiltInterferometer, VolumetricTool

    inner = DiagramBuilder()
    tool = inner.AddNamedSystem("volumetric_tool", VolumetricTool(config, truth))
    laser = inner.AddNamedSystem("laser_interferometer", PanTiltInterferometer(
        heads_true, head_error, dead_paths_mm, catseye_axis, options, budget, seed, period_s))
    inner.Connect(tool.GetOutputPort("tool_point"), laser.GetInputPort("tool_point"))
    inner.ExportInput(tool.GetInputPort("command"), "target_command")
    inner.ExportInput(tool.GetInputPort("tool"), "tool")
    inner.ExportInput(laser.GetInputPort("head_command"), "head_command")
    inner.ExportInput(laser.GetInputPort("station"), "station")
    for port in ("displacement", "valid", "miss", "status"):
        inner.ExportOutput(laser.GetOutputPort(port), port)
    inner.ExportOutput(tool.GetOutputPort("tool_point"), "true_position")
    return builder.AddNamedSystem(name, inner.Build())


def AddMachine3DStation(builder, setup: Machine3DSetup, name: str = "station"):
    """Add the simulated 3D station of a planned run (:func:`AddVolumetricStation` with its truth, true heads,
    head error and dead paths, the scenario's cat's eye and interferometer) to ``builder``; return it."""
    s, run = setup.scenario, setup.run
    return AddVolumetricStation(builder, run.config, run.truth, run.heads_true, run.head_error, run.dead_paths_mm,
                                s.catseye_axis, s.interferometer, setup.budget, stream_seed(s.seed, "laser"),
                                setup.period_s, name)


def build_machine3d_diagram(setup: Machine3DSetup):
    """The whole 3D campaign as a Diagram; returns (diagram, recorder, sequencer)."""
    from pydrake.systems.framework import DiagramBuilder

    from olti_drake.sim.systems import AddPanTiltSteering, Machine3DRecorder, RowSequencer

    run = setup.run
    i, j = run.sequence["target"], run.sequence["station"]
    builder = DiagramBuilder()
    station = AddMachine3DStation(builder, setup)
    xyz = make_xyz_machine()
    seq = builder.AddNamedSystem("machine_sequencer", RowSequencer({
        "target_command": run.commands_mm[i] / M_TO_MM, "station": j.astype(float), "target": i.astype(float),
        "tool": run.tool[i].astype(float)}, setup.period_s))
    steer = AddPanTiltSteering(builder, xyz, run.config.tools, run.heads_est, tool_input=True)
    rec = builder.AddNamedSystem("machine_recorder", Machine3DRecorder(setup.period_s))
    builder.Connect(seq.GetOutputPort("target_command"), steer.GetInputPort("joint_command"))
    builder.Connect(seq.GetOutputPort("station"), steer.GetInputPort("reflector"))
    builder.Connect(seq.GetOutputPort("tool"), steer.GetInputPort("tool"))
    builder.Connect(steer.GetOutputPort("head_command"), station.GetInputPort("head_command"))
    for port in ("target_command", "station", "tool"):
        builder.Connect(seq.GetOutputPort(port), station.GetInputPort(port))
    for port in ("target_command", "station", "tool", "target"):
        builder.Connect(seq.GetOutputPort(port), rec.GetInputPort(port))
    for port in ("displacement", "valid"):
        builder.Connect(station.GetOutputPort(port), rec.GetInputPort(port))
    builder.Connect(station.GetOutputPort("true_position"), rec.GetInputPort("position"))
    diagram = builder.Build()
    diagram.station, diagram.xyz = station, xyz  # keep the plant the steering reads alive
    return diagram, rec, seq


def run_machine3d_campaign(scenario: Machine3DScenario, budget=None, period_s: float = 1.0):
    """Simulate the diagram over every head and target: (columns, truth), the layout of
    :func:`~olti_drake.model.machine.simulate_machine_campaign_3d` (equal readings with the noise off)."""
    from pydrake.systems.analysis import Simulator

    setup = prepare_machine3d(scenario, budget, period_s)
    diagram, rec, seq = build_machine3d_diagram(setup)
    simulator = Simulator(diagram)
    simulator.AdvanceTo(seq.duration_s)
    n = len(COLUMNS)
    rows = np.array([r[:n] for r in rec.GetReadings(simulator.get_context())], dtype=float).reshape(-1, n)
    cols = {c: rows[:, k] for k, c in enumerate(COLUMNS)}
    for c in ("station", "target", "tool", "valid"):
        cols[c] = cols[c].astype(int)
    return cols, machine3d_truth(scenario, setup.run, cols["valid"].sum())


def simulate_machine3d_command(path, name, text, out_dir, seed=None, meshcat=False) -> str:
    """``olti simulate machine_3d.yaml --out DIR``: load, check the outputs before any work (never replacing
    a campaign), run the diagram, write DIR/campaign.csv and DIR/truth.json; returns the summary."""
    from olti_drake.io.outputs import make_dir, preflight, write_json

    if meshcat:
        raise ValueError(f"--meshcat: the live view is not available for 3D machine scenarios yet ({path})")
    t0 = time.perf_counter()
    doc = load_machine3d_scenario(path, name, text)
    if seed is not None:
        doc.seed = seed
    scenario = doc.scenario(f"scenario {path}")
    csv_path, truth_path = (os.path.join(out_dir, n) for n in ("campaign.csv", "truth.json"))
    preflight([], [path] + ([doc.resolve(doc.budget)] if doc.budget else []), measurements=[csv_path, truth_path],
              dirs=[out_dir], create_dirs=True)
    cols, truth = run_machine3d_campaign(scenario, doc.load_budget(), doc.period_s)
    make_dir(out_dir)
    write_machine_campaign(cols, csv_path)
    write_json(truth_path, truth, measurement=True)
    valid = cols["valid"] > 0
    return "\n".join([f"3D machine campaign: {len(valid)} readings ({int(valid.sum())} valid, "
                      f"{int((~valid).sum())} beam lost) of {len(truth['targets_mm'])} targets "
                      f"({len(set(truth['tools']))} tools) from {len(truth['stations_mm'])} pan/tilt heads, "
                      f"simulated in {time.perf_counter() - t0:.2f} s",
                      f"wrote {csv_path} and {truth_path}"])
