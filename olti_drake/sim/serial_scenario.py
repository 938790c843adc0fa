"""Scenario of a six-axis (N-joint) campaign: everything that decides it, as typed YAML.

The serial-robot counterpart of :mod:`olti_drake.sim.scenario` (issue "Six-axis campaigns end to
end", docs/six_axis_campaign.md), loaded by the same :func:`~olti_drake.sim.scenario.load_scenario`
(``yaml_load_typed`` layers: ``base:`` files and named scenarios, ``--scenario-text`` overrides,
relative paths relative to the file that gives them) with :class:`SerialScenario` as the schema.
A scenario file is a six-axis one when it (or a base it names) has the top-level key ``scheme``
(:func:`scenario_kind`); ``olti simulate`` dispatches on that.

* ``robot``: the model file (``ur5`` = the shipped ``olti_drake/models/ur5.urdf``; else a URDF/SDF
  path), the tool frame, the nominal tool-point offset and the seeded truth
  (:func:`olti_drake.model.serial.synthetic_truth`: harmonic joint deviations with backlash,
  joint-frame location errors; the true tool point = nominal + ``tool_offset_error_mm``).
* ``scheme``: ``!FloorTracers`` (a cat's eye on the tool, a pan/tilt head per station aimed at
  the commanded tool point from the estimated station, 001 Eq. (1) in 3D) or ``!RobotMounted``
  (the laser on the tool, floor reflectors, the robot aimed by Drake IK at the estimated one).
* ``plan``: :class:`~olti_drake.estimation.serial_plan.PlanRules` for the floor tracers
  (``generate_plan``); the robot-mounted scheme measures a raster of tool points instead.

Units: mm and degrees (mdeg where the field name says so).
"""

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Optional, Union

import numpy as np

from olti_drake.errors import InputError
from olti_drake.io.csvio import read_yaml
from olti_drake.limits import check_allocation
from olti_drake.model.instrument import InterferometerOptions
# the SCARA scenario's station kinds, run policy and field checks
from olti_drake.sim.scenario import Emulated, Hardware, RunPolicy, ScenarioPaths, Simulated, _nonnegative, _positive

#: Working float64 values a plan pose or raster point carries (commands, FK, IK, readings): an estimate for the
#: allocation guards of ``plan.step_deg`` and ``points_per_axis`` (:func:`olti_drake.limits.check_allocation`).
VALUES_PER_POSE = 64
MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
#: Robot models shipped with the package, by the short name a scenario may give as ``robot.file``.
SHIPPED_MODELS = {"ur5": MODELS_DIR / "ur5.urdf"}


@dataclass
class SerialTruth:
    """The simulated robot's errors, seeded (``synthetic_truth``): location errors ~N(0, ``location_mm``
    / ``location_deg``) per joint frame, per joint an offset, trend and two harmonics of amplitude
    ~``deviation_mdeg`` and a backlash ~``backlash_mdeg``; the true tool point is the nominal one plus
    ``tool_offset_error_mm`` (tool frame)."""

    seed: int = 3
    location_mm: float = 0.05
    location_deg: float = 0.005
    deviation_mdeg: float = 10.0
    backlash_mdeg: float = 5.0
    tool_offset_error_mm: List[float] = field(default_factory=lambda: [0.3, -0.2, 0.4])


@dataclass
class SerialRobot:
    """The robot: model ``file`` (``ur5`` or a path relative to the scenario file), ``tool_frame``,
    the nominal tool-point offset in the tool frame (mm; the cat's-eye centre, or the laser's beam
    origin when the laser is on the tool) and the ``truth``."""

    file: str = "ur5"
    tool_frame: str = "tool0"
    tool_offset_mm: List[float] = field(default_factory=lambda: [40.0, -25.0, 60.0])
    truth: SerialTruth = field(default_factory=SerialTruth)


def _tracer_stations() -> list:
    # Four heads around the robot at 1.3 m, below the base (as tests/model/test_serial_plan.py).
    return [[1300.0, 0.0, -300.0], [0.0, 1300.0, -300.0], [-1300.0, 0.0, -300.0], [0.0, -1300.0, -300.0]]


@dataclass
class FloorTracers:
    """001's scheme in 3D: a pan/tilt head at each station (``stations_mm``: the true centres, the
    intersection of pan and tilt axes; ``zeros_deg``: their true zero angles [azimuth, elevation],
    empty = 0), a cat's eye on the tool (axis ``catseye_axis_tool`` in the tool frame, ±80°).
    The heads aim from the estimates: ``stations_estimate_mm`` / ``zeros_estimate_deg`` when given
    (e.g. the 001 §2.2 fit of ``aiming3d.estimate_pan_tilt_station``), else the truth plus seeded
    normal errors of ``station_sigma_mm`` per coordinate and ``zero_sigma_mdeg`` per angle. Each
    head turns with its own angular positioning error, harmonics up to ``head_error_mdeg``."""

    stations_mm: list[list[float]] = field(default_factory=_tracer_stations)
    zeros_deg: list[list[float]] = field(default_factory=list)
    stations_estimate_mm: list[list[float]] = field(default_factory=list)
    zeros_estimate_deg: list[list[float]] = field(default_factory=list)
    station_sigma_mm: float = 0.05
    zero_sigma_mdeg: float = 1.0
    head_error_mdeg: float = 2.0
    catseye_axis_tool: List[float] = field(default_factory=lambda: [0.0, 0.0, 1.0])


def _floor_reflectors() -> list:
    return [[600.0, 300.0, -300.0], [600.0, -300.0, -300.0], [-300.0, 500.0, -300.0], [-300.0, -500.0, -300.0]]


@dataclass
class RobotMounted:
    """000's scheme in 3D: the laser on the tool (beam origin the tool point, direction
    ``laser_direction`` in the tool frame), cat's eyes on the floor (``reflectors_mm``, axis
    ``reflector_axis``, world). At each commanded tool point the robot aims the beam at the
    estimated reflector by Drake IK (``aiming3d.RobotAimer``: nearest to the previous pose, from
    ``start_deg``). The tool points: a serpentine raster of ``points_per_axis``³ points in the box
    ``box_mm`` [[x0, x1], [y0, y1], [z0, z1]], the first ``n_targets``. Estimates as the tracers'."""

    reflectors_mm: list[list[float]] = field(default_factory=_floor_reflectors)
    reflectors_estimate_mm: list[list[float]] = field(default_factory=list)
    reflector_sigma_mm: float = 0.05
    reflector_axis: List[float] = field(default_factory=lambda: [0.0, 0.0, 1.0])
    laser_direction: List[float] = field(default_factory=lambda: [0.0, 0.0, 1.0])
    box_mm: list[list[float]] = field(default_factory=lambda: [[250.0, 550.0], [-150.0, 150.0], [100.0, 400.0]])
    points_per_axis: int = 9
    n_targets: int = 700
    start_deg: List[float] = field(default_factory=lambda: [0.0, -90.0, 90.0, -90.0, -90.0, 0.0])


@dataclass
class Tracker:
    """A laser tracker over emScon TCP measuring the cat's eye on the tool open loop (docs/tracker.md).

    ``host`` empty: ``olti run`` starts the tracker emulator (a local TCP port) and the N-joint robot emulator
    in-process; else the tracker at ``host``:``port`` (a real one: port 700) and the robot controller on
    ``robot_port`` (olti protocol, ``robot_driver``). ``position_mm`` / ``rotation_deg``: the tracker's nominal
    placement in the robot base frame (tracker point m = R (p - position), R = Rx Ry Rz), what the station points
    with; the emulated tracker stands ``emulator_offset_mm`` / ``emulator_rotation_deg`` off it (its truth).
    The emulator's ``capture_mm``, noise (``u_const_um`` + ``u_per_m_um`` per m, coverage ``coverage_k``),
    ``beam_break`` / ``reflector_lost`` probabilities per measurement, ``environment`` [°C, hPa, %RH] and its
    ``drift`` per measurement; ``policy.rereads``: re-pointings after a beam interruption."""

    host: str = ""
    port: int = 700
    robot_port: str = ""
    robot_driver: str = "olti"
    baud: int = 115200
    timeout_s: float = 5.0
    retries: int = 2
    position_mm: List[float] = field(default_factory=lambda: [1300.0, 0.0, -300.0])
    rotation_deg: List[float] = field(default_factory=lambda: [0.0, 0.0, 180.0])
    emulator_offset_mm: List[float] = field(default_factory=lambda: [0.05, -0.04, 0.03])
    emulator_rotation_deg: List[float] = field(default_factory=lambda: [0.0, 0.0, 0.002])
    capture_mm: float = 5.0
    u_const_um: float = 15.0
    u_per_m_um: float = 6.0
    coverage_k: float = 2.0
    beam_break: float = 0.0
    reflector_lost: float = 0.0
    environment: List[float] = field(default_factory=lambda: [20.0, 1013.25, 45.0])
    drift: List[float] = field(default_factory=lambda: [0.01, 0.05, 0.1])
    policy: RunPolicy = field(default_factory=RunPolicy)

    def validate(self, where: str) -> None:
        for key in ("position_mm", "rotation_deg", "emulator_offset_mm", "emulator_rotation_deg", "environment",
                    "drift"):
            _vector(f"{where}.{key}", getattr(self, key), 3)
        for key in ("capture_mm", "timeout_s", "coverage_k"):
            _positive(f"{where}.{key}", getattr(self, key))
        for key in ("u_const_um", "u_per_m_um"):
            _nonnegative(f"{where}.{key}", getattr(self, key))
        _nonnegative(f"{where}.policy.reread_delay_s", self.policy.reread_delay_s)
        for key in ("beam_break", "reflector_lost"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                raise InputError(f"{where}.{key}: a probability 0..1, got {getattr(self, key)!r}")
        if not 0 < self.port < 65536:
            raise InputError(f"{where}.port must be 1..65535, got {self.port!r}")
        if self.host and not self.robot_port:
            raise InputError(f"{where}.robot_port is empty: a tracker at {self.host} needs the robot controller's port")
        if self.retries < 0 or self.policy.rereads < 0:
            raise InputError(f"{where}: retries and policy.rereads must be >= 0")


@dataclass
class SerialPlanRules:
    """The plan (:class:`~olti_drake.estimation.serial_plan.PlanRules`, mm and deg; ``ranges_deg``
    empty = the joint limits) and its ``seed``. Robot-mounted: ``overrun_deg`` is the approach
    overrun and ``seed`` draws the approach directions (±1 per joint and pose)."""

    step_deg: float = 15.0
    ranges_deg: list[list[float]] = field(default_factory=list)
    overrun_deg: float = 1.0
    poses_per_node: int = 2
    min_stations: int = 2
    link_radius_mm: float = 45.0
    clearance_mm: float = 60.0
    floor_z_mm: Optional[float] = None
    max_batches: int = 200
    batch: int = 256
    seed: int = 0

    def rules(self, catseye_axis_tool):
        """The :class:`PlanRules` of these fields, with the cat's eye's axis (tool frame)."""
        from olti_drake.estimation.serial_plan import PlanRules
        return PlanRules(step_deg=self.step_deg,
                         ranges_deg=np.asarray(self.ranges_deg, float) if self.ranges_deg else None,
                         overrun_deg=self.overrun_deg, poses_per_node=self.poses_per_node,
                         min_stations=self.min_stations, link_radius_mm=self.link_radius_mm,
                         clearance_mm=self.clearance_mm, catseye_axis_tool=tuple(catseye_axis_tool),
                         floor_z_mm=self.floor_z_mm, max_batches=self.max_batches, batch=self.batch)


@dataclass
class SerialScenario(ScenarioPaths):
    """A simulated six-axis campaign (module doc). ``budget``: a budget YAML path (empty: 000
    Table 2); ``period_s``: simulated time per sequencer row (move, settle, read); ``seed``: the
    readings' noise, the estimates and the heads' errors (``sim.scenario.SEED_STREAMS``); the truth
    and the plan have their own seeds. ``base`` as :class:`~olti_drake.sim.scenario.Scenario`'s."""

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "serial"

    robot: SerialRobot = field(default_factory=SerialRobot)
    scheme: Union[FloorTracers, RobotMounted] = field(default_factory=FloorTracers)
    plan: SerialPlanRules = field(default_factory=SerialPlanRules)
    interferometer: InterferometerOptions = field(default_factory=InterferometerOptions)
    budget: str = ""
    seed: int = 0
    period_s: float = 1.0
    #: The station ``olti run`` takes the campaign on: ``!Simulated`` (``olti simulate``), ``!Emulated``
    #: (the N-joint device emulator, docs/emulator.md; floor tracers only), ``!Hardware``, ``!Tracker`` (an
    #: emScon laser tracker or its emulator, docs/tracker.md).
    station: Union[Simulated, Emulated, Hardware, Tracker] = field(default_factory=Simulated)
    base: str = ""

    def robot_path(self) -> str:
        """The model file: a shipped name (``ur5``) or a path relative to the scenario file."""
        shipped = SHIPPED_MODELS.get(self.robot.file)
        return str(shipped) if shipped is not None else self.resolve(self.robot.file)

    def load_budget(self):
        from olti_drake.io.budget import load_budget
        from olti_drake.model.budget import paper000_budget
        return load_budget(self.resolve(self.budget)) if self.budget else paper000_budget()

    def validate(self, where: str = "scenario") -> "SerialScenario":
        """Check every value; raise a one-line InputError naming the field."""
        r = self.robot
        if not r.file:
            raise InputError(f"{where}: robot.file is empty (a URDF/SDF path, or one of {', '.join(SHIPPED_MODELS)})")
        if not os.path.isfile(self.robot_path()):
            raise InputError(f"{where}: robot.file: {self.robot_path()}: model file not found")
        if not r.tool_frame:
            raise InputError(f"{where}: robot.tool_frame is empty")
        _vector(f"{where}: robot.tool_offset_mm", r.tool_offset_mm, 3)
        _vector(f"{where}: robot.truth.tool_offset_error_mm", r.truth.tool_offset_error_mm, 3)
        for key in ("location_mm", "location_deg", "deviation_mdeg", "backlash_mdeg"):
            _nonnegative(f"{where}: robot.truth.{key}", getattr(r.truth, key))
        s = self.scheme
        if isinstance(s, FloorTracers):
            self._validate_tracers(f"{where}: scheme", s)
        else:
            self._validate_mounted(f"{where}: scheme", s)
        p = self.plan
        for key in ("step_deg", "overrun_deg", "link_radius_mm", "clearance_mm"):
            _positive(f"{where}: plan.{key}", getattr(p, key))
        for key in ("poses_per_node", "min_stations", "max_batches", "batch"):
            if getattr(p, key) < 1:
                raise InputError(f"{where}: plan.{key} must be >= 1, got {getattr(p, key)!r}")
        # the plan's nodes per joint (at most two turns, 720 deg) x poses per node (olti_drake.limits)
        check_allocation(f"{where}: plan.step_deg", f"{p.step_deg:g} deg", [720.0 / p.step_deg + 1, p.poses_per_node,
                                                                          VALUES_PER_POSE],
                         what="values (nodes per joint x poses per node x values per pose)",
                         hint="use a coarser plan.step_deg")
        if p.ranges_deg and any(len(x) != 2 or not x[0] <= x[1] for x in p.ranges_deg):
            raise InputError(f"{where}: plan.ranges_deg must be a list of [low, high] pairs, one per joint")
        if p.seed < 0 or self.seed < 0 or r.truth.seed < 0:
            raise InputError(f"{where}: seeds must be >= 0 (seed, plan.seed, robot.truth.seed)")
        try:
            self.interferometer.validate(f"{where}: interferometer")
        except ValueError as e:
            raise InputError(str(e)) from None
        _positive(f"{where}: period_s", self.period_s)
        if isinstance(self.station, Tracker):
            if not isinstance(s, FloorTracers):
                raise InputError(f"{where}: station !Tracker measures a cat's eye on the tool: scheme !FloorTracers")
            self.station.validate(f"{where}: station")
        return self

    @staticmethod
    def _validate_tracers(where, s: FloorTracers):
        n = _points(f"{where}.stations_mm", s.stations_mm)
        for key, size in (("zeros_deg", 2), ("stations_estimate_mm", 3), ("zeros_estimate_deg", 2)):
            value = getattr(s, key)
            if value and (len(value) != n or any(len(v) != size for v in value)
                          or not np.all(np.isfinite(np.asarray(value, float)))):
                raise InputError(f"{where}.{key}: {n} finite [{'x, y, z' if size == 3 else 'azimuth, elevation'}] "
                                 f"entries, one per station, or empty")
        for key in ("station_sigma_mm", "zero_sigma_mdeg", "head_error_mdeg"):
            _nonnegative(f"{where}.{key}", getattr(s, key))
        _vector(f"{where}.catseye_axis_tool", s.catseye_axis_tool, 3, nonzero=True)

    @staticmethod
    def _validate_mounted(where, s: RobotMounted):
        n = _points(f"{where}.reflectors_mm", s.reflectors_mm)
        if s.reflectors_estimate_mm and (len(s.reflectors_estimate_mm) != n or _points(
                f"{where}.reflectors_estimate_mm", s.reflectors_estimate_mm) != n):
            raise InputError(f"{where}.reflectors_estimate_mm: one [x, y, z] per reflector ({n}), or empty")
        _nonnegative(f"{where}.reflector_sigma_mm", s.reflector_sigma_mm)
        _vector(f"{where}.reflector_axis", s.reflector_axis, 3, nonzero=True)
        _vector(f"{where}.laser_direction", s.laser_direction, 3, nonzero=True)
        box = np.asarray(s.box_mm, float)
        if box.shape != (3, 2) or not np.all(np.isfinite(box)) or np.any(box[:, 0] > box[:, 1]):
            raise InputError(f"{where}.box_mm must be [[x0, x1], [y0, y1], [z0, z1]] mm, low <= high")
        if s.points_per_axis < 1 or s.n_targets < 1:
            raise InputError(f"{where}: points_per_axis and n_targets must be >= 1")
        k = float(s.points_per_axis)
        check_allocation(f"{where}.points_per_axis", s.points_per_axis, [k, k, k, VALUES_PER_POSE],
                         what="values (raster points x values per pose)", hint="use fewer points_per_axis")
        if not np.all(np.isfinite(np.asarray(s.start_deg, float))):
            raise InputError(f"{where}.start_deg must be finite joint angles (deg)")


def _points(name, pts) -> int:
    a = np.asarray(pts, float) if pts else np.zeros((0, 3))
    if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0 or not np.all(np.isfinite(a)):
        raise InputError(f"{name} must be a non-empty list of finite [x, y, z] points (mm)")
    return len(a)


def _vector(name, v, size, nonzero=False):
    a = np.asarray(v, float)
    if a.shape != (size,) or not np.all(np.isfinite(a)) or (nonzero and not np.any(a)):
        raise InputError(f"{name} must be {size} finite numbers" + (", not all zero" if nonzero else ""))


#: What differs by scenario kind (:func:`scenario_kind`), the one table: its loader ((path, name, text) -> the
#: scenario document) and its ``olti simulate`` body ((path, name, text, out_dir, seed, meshcat) -> the summary;
#: None: the SCARA's and the six-axis robot's, which the command line runs with their live views), as
#: "module:function", imported when asked (:func:`scenario_function`: ``olti --help`` stays fast).
SCENARIO_TYPES = {
    "scara": {"load": "olti_drake.sim.scenario:load_scenario", "simulate": None},
    "serial": {"load": "olti_drake.sim.serial_scenario:load_serial_scenario", "simulate": None},
    "machine3d": {"load": "olti_drake.sim.machine3d_station:load_machine3d_scenario",
                  "simulate": "olti_drake.sim.machine3d_station:simulate_machine3d_command"},
    "machine5": {"load": "olti_drake.sim.five_axis_station:load_five_axis_scenario",
                 "simulate": "olti_drake.sim.five_axis_station:simulate_five_axis_command"},
}
#: The kinds of scenario (:func:`scenario_kind`).
SCENARIO_KINDS = tuple(SCENARIO_TYPES)


def scenario_function(kind: str, role: str):
    """The function of ``role`` (``load``, ``simulate``) for scenarios of ``kind`` (:data:`SCENARIO_TYPES`), or
    None when the kind has none."""
    from olti_drake.named import resolve

    where = SCENARIO_TYPES[kind][role]
    return None if where is None else resolve(where)


def load_any_scenario(path, name: Optional[str] = None, text: Optional[str] = None):
    """The scenario document of the file ``path`` (its scenario ``name``, overrides ``text``), loaded as its kind
    (:func:`scenario_kind`) says."""
    return scenario_function(scenario_kind(path, name), "load")(path, name, text)


def scenario_kind(scenario, name: Optional[str] = None) -> str:
    """The kind of a scenario -- ``"scara"``, ``"serial"`` (an N-joint robot), ``"machine3d"`` (a 3D machine
    tool) or ``"machine5"`` (a five-axis machine tool) -- the one place that tells them apart: ``olti simulate``,
    ``plan``, ``run``, ``diagrams``, the emulator and the stations dispatch on it.

    ``scenario``: a YAML file -- ``"serial"`` when it (its named scenario ``name``, or a base it names) has the
    top-level key ``scheme``, ``"machine3d"`` when it has ``heads_mm`` (:mod:`olti_drake.sim.machine3d_station`),
    ``"machine5"`` when it has ``machine_model`` (:mod:`olti_drake.sim.five_axis_station`), else ``"scara"``; a
    file or name that cannot be read is left to the loader, which names the problem --;
    None (the default scenario, the SCARA's); or a loaded scenario or campaign setup (the ``KIND`` its class
    declares: ``Scenario``, ``campaign.Setup``; ``SerialScenario``, ``SerialSetup``; ``Machine3DScenarioFile``,
    ``Machine3DSetup``, ``Machine3DCampaignSetup``; ``FiveAxisScenarioFile``, ``FiveAxisRun``)."""
    if scenario is None:
        return "scara"
    if not isinstance(scenario, (str, os.PathLike)):
        kind = getattr(type(scenario), "KIND", None)
        if kind not in SCENARIO_KINDS:
            raise TypeError(f"{type(scenario).__name__} is not a scenario or a campaign setup (no KIND)")
        return kind
    for kind, key in (("serial", "scheme"), ("machine3d", "heads_mm"), ("machine5", "machine_model")):
        if _has_key(os.fspath(scenario), name, key, set()):
            return kind
    return "scara"


def _has_key(path: str, child: Optional[str], top_key: str, seen: set) -> bool:
    key = (os.path.abspath(path), child)
    if key in seen or not os.path.isfile(path):
        return False
    try:
        raw = read_yaml(path, "scenario")
    except ValueError:
        return False
    if child is not None:
        raw = raw.get(child) if isinstance(raw, dict) else None
    if not isinstance(raw, dict):
        return False
    if top_key in raw:
        return True
    base = raw.get("base")
    if not isinstance(base, str) or not base:
        return False
    file, _, base_child = base.partition("#")
    file = os.path.join(os.path.dirname(os.path.abspath(path)), file) if file else path
    return _has_key(file, base_child or None, top_key, seen | {key})


def load_serial_scenario(path=None, name: Optional[str] = None, text: Optional[str] = None) -> SerialScenario:
    """A six-axis scenario: ``load_scenario`` with :class:`SerialScenario` defaults (layers, overrides,
    validation naming the field)."""
    from olti_drake.sim.scenario import load_scenario
    return load_scenario(path, name, text, defaults=SerialScenario())
