"""Scenario: everything that decides a simulated campaign, as typed YAML.

Loaded with ``pydrake.common.yaml.yaml_load_typed`` into these dataclasses;
``typing.Union`` fields choose their alternative by YAML tag, e.g.
``J1: !HarmonicDeviation {...}`` or ``plan: !PlanFile {path: plan.csv}``.

The dataclass **defaults are the paper-000 experiment** (§4.1): the
RH-3FRH-5515 arm, three nearly collinear reflector positions, the Table 2
budget and the Eq. (11)-(12) plan. ``diagrams/paper000_scara.yaml`` is the
same scenario written out (a test keeps them equal).

Units: mm and degrees (mdeg where the field name says so).
"""


import os
from dataclasses import dataclass, field, fields, is_dataclass
from typing import List, Optional, Union

import numpy as np

from olti_drake.errors import InputError
from olti_drake.io.csvio import read_yaml
from olti_drake.io.plan_io import load_plan
from olti_drake.model.errormap import ErrorMap, Harmonic, HarmonicDeviation, NoDeviation
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.model.scara import PAPER_L1_MM, PAPER_L2_MM
from olti_drake.model.plan import BidirectionalGrid, Plan
from olti_drake.model.scara import ScaraPositionModel, TrueRobot
from olti_drake.units import UNIT_BOUNDS


#: Every random source of a scenario, by name, and its stream key under the scenario ``seed``: each
#: draws from ``numpy.random.default_rng([seed, key, *sub])`` (:func:`stream_rng`) or from a generator
#: seeded :func:`stream_seed`\ ``(seed, name, *sub)``, so no source shifts another however many numbers
#: it draws. The ONE place that lists them (docs/runner.md, "Seeds"); keys are never renumbered (a
#: campaign's bytes depend on them). Sources: ``laser`` -- the simulated counter's noise, one generator
#: per sample ``n`` (``[stream_seed(seed, "laser"), n]``); ``reflector_estimate`` -- the Eq. (2) search
#: or the perturbed estimate; ``emulator_session`` -- the emulator's seed in resumed session ``k``
#: (``stream_seed(seed, "emulator_session", k)``); ``emulator_noise`` -- the emulator counter's noise;
#: ``emulator_faults`` -- the emulator's fault draws on line ``k`` (0 robot, 1 counter); ``head_error`` --
#: the angular positioning error of the pan/tilt head at station ``j`` (``stream_seed(seed, "head_error", j)``,
#: six-axis scenarios, :mod:`olti_drake.sim.serial_scenario`); ``emulator_truth`` -- the N-joint emulator's own
#: synthetic robot and heads (``hardware.serial_emulator``, when no scenario gives them).
SEED_STREAMS = {"laser": 0, "reflector_estimate": 1, "emulator_session": 2,
                "emulator_noise": 10, "emulator_faults": 11, "emulator_truth": 12, "head_error": 20,
                "rtest": 30,  # rtest: the five-axis R-test device's noise (sim/five_axis_station.py)
                "tracker": 40}  # tracker: the emScon tracker emulator of session k (hardware/tracker_station.py)


def stream_key(name) -> int:
    """The stream key of a named random source (an int key passes through: older callers)."""
    if isinstance(name, (int, np.integer)):
        return int(name)
    try:
        return SEED_STREAMS[name]
    except KeyError:
        raise KeyError(f"random stream {name!r}: not one of {', '.join(SEED_STREAMS)}") from None


def stream_rng(seed: int, name, *sub: int) -> np.random.Generator:
    """The generator of one named random source under the scenario ``seed`` (``sub``: e.g. a line)."""
    return np.random.default_rng([int(seed), stream_key(name), *sub])


def stream_seed(seed: int, name, *sub: int) -> int:
    """An independent, reproducible seed for one named random source of a scenario seeded ``seed``."""
    return int(np.random.SeedSequence([int(seed), stream_key(name), *sub]).generate_state(1)[0])


@dataclass
class MapTable:
    """A deviation given as a table (deg), linearly interpolated like an identified map."""

    grid_deg: List[float] = field(default_factory=list)
    forward_deg: List[float] = field(default_factory=list)
    reverse_deg: List[float] = field(default_factory=list)
    outside: str = "clamp"

    def __call__(self, theta_deg, direction):
        return ErrorMap(self.grid_deg, self.forward_deg, self.reverse_deg, outside=self.outside)(
            theta_deg, direction)


DeviationSpec = Union[HarmonicDeviation, MapTable, NoDeviation]


def _paper_j1() -> HarmonicDeviation:
    # Tens of mdeg of pitch error, ~10 mdeg backlash: 000 Fig. 6a's magnitude.
    return HarmonicDeviation(offset_mdeg=0.0, slope_mdeg_per_deg=0.04, harmonics=[
        Harmonic(12.0, 360.0, 30.0), Harmonic(6.0, 120.0, 75.0), Harmonic(2.5, 45.0, 10.0)],
        backlash_mdeg=10.0, backlash_slope_mdeg_per_deg=0.01)


def _paper_j2() -> HarmonicDeviation:
    # Offset = θ20 of 000 Table 1 (-5.55 mdeg); backlash ~14 mdeg (Fig. 6b).
    return HarmonicDeviation(offset_mdeg=-5.55, slope_mdeg_per_deg=-0.03, harmonics=[
        Harmonic(15.0, 360.0, -40.0), Harmonic(7.0, 90.0, 20.0), Harmonic(2.0, 35.0, 0.0)],
        backlash_mdeg=14.0)


def _paper_j4() -> HarmonicDeviation:
    return HarmonicDeviation(harmonics=[Harmonic(5.0, 360.0, 0.0)], backlash_mdeg=4.0)


@dataclass
class Robot:
    """The simulated SCARA: true and nominal link lengths (mm), joint deviations, laser mount.

    ``J2`` includes the offset θ20. ``theta40_deg`` is the beam's true angle in
    the J4 frame; ``beam_offset_mm`` = (along, lateral) offset of the beam
    origin from the J4 axis (000 §2 Remark 2).
    """

    L1_mm: float = 324.97
    L2_mm: float = 225.004
    nominal_L1_mm: float = PAPER_L1_MM
    nominal_L2_mm: float = PAPER_L2_MM
    theta40_deg: float = 0.8
    beam_offset_mm: List[float] = field(default_factory=lambda: [0.0, 0.0])
    J1: DeviationSpec = field(default_factory=_paper_j1)
    J2: DeviationSpec = field(default_factory=_paper_j2)
    J4: DeviationSpec = field(default_factory=_paper_j4)

    def true_robot(self) -> TrueRobot:
        return TrueRobot(self.L1_mm, self.L2_mm, {"J1": self.J1, "J2": self.J2, "J4": self.J4},
                         self.theta40_deg, tuple(self.beam_offset_mm))


@dataclass
class SearchEstimate:
    """Reflector positions and θ40 from the simulated manual J4 search (000 §2 Remark 1, Eq. 2).

    Empty ``positions_mm`` uses the default search positions; a negative
    ``angle_noise_mdeg`` uses the default search imprecision.
    """

    positions_mm: list[list[float]] = field(default_factory=list)
    angle_noise_mdeg: float = -1.0


@dataclass
class PerturbedEstimate:
    """Reflector estimates = truth + Gaussian error (mm, per coordinate), θ40 likewise (mdeg)."""

    sigma_mm: float = 0.3
    theta40_sigma_mdeg: float = 10.0


@dataclass
class ExactEstimate:
    """The steering uses ``reflectors_mm`` and ``robot.theta40_deg`` as given: in simulation the truth
    (noise-free tests); on hardware the operator's Eq. (2) search result, which is all it knows."""


@dataclass
class PlanFile:
    """A plan file (CSV or YAML), relative to the scenario file."""

    path: str = ""


@dataclass
class Simulated:
    """The station is simulated in the Drake diagram (the default)."""


@dataclass
class RunPolicy:
    """What a device station does when a reading or a move fails (``olti run``; docs/runner.md).

    ``rereads``: READs repeated after an invalid one (a transient beam interruption), each after
    ``reread_delay_s`` seconds. ``rezeros``: then, re-zeroings of the counter at the run's reference
    pose, each followed by a READ at the pose (a counter that lost its count stays invalid until
    zeroed; zeroing where the run was zeroed, approached the same way, keeps the dead path of the
    run). ``approach_overrun_deg``: a re-approach to a pose (after a resume, an alarm or to re-zero)
    starts this far before it on the side of its approach direction, on J1, J2 and J4 (deg; the
    plan's overrun), so every axis arrives from the planned side. ``clear_alarms``: controller
    alarms the station may clear (``ALRM,CLR``) and then re-approach; beyond that the run stops with
    the alarm codes (an operator should look first).
    """

    rereads: int = 2
    reread_delay_s: float = 0.0
    rezeros: int = 1
    approach_overrun_deg: float = 2.0
    clear_alarms: int = 0


@dataclass
class Faults:
    """The device emulator's fault injection switches (:mod:`olti_drake.hardware.emulator` re-exports
    this class; it lives here so the scenario layer never imports the hardware layer); all random choices come from the emulator's seeded generator.

    ``latency_s``: delay before every reply. ``drop``: probability that a frame is lost, drawn
    separately for the request (not executed) and for its reply (executed, not answered).
    ``garble``: probability that one byte of a reply is changed. ``nak_crc``: probability that a
    request is taken as corrupted on the line (``NAK,CRC``, not executed). ``bad_crc``: probability
    that a reply goes out with a wrong checksum. ``partial``: probability that only the first half of
    a reply is written; the rest follows after ``partial_delay_s`` seconds, or never if None.
    ``beam_loss``: probability that a READ reports no beam (valid 0). ``alarm_at``: the N-th MOVJ
    (1-based, retries not counted) raises an alarm: it and every MOVJ/WAIT after it get
    ``NAK,ALARM`` until ``ALRM,CLR``. ``disconnect_after``: close both pseudo-terminals after
    answering N request frames (both lines, retries included).
    """

    latency_s: float = 0.0
    drop: float = 0.0
    garble: float = 0.0
    nak_crc: float = 0.0
    bad_crc: float = 0.0
    partial: float = 0.0
    partial_delay_s: Optional[float] = None
    beam_loss: float = 0.0
    alarm_at: Optional[int] = None
    disconnect_after: Optional[int] = None

    def validate(self) -> "Faults":
        for key in ("drop", "garble", "nak_crc", "bad_crc", "partial", "beam_loss"):
            p = getattr(self, key)
            if not (isinstance(p, (int, float)) and 0.0 <= p <= 1.0):
                raise ValueError(f"fault {key}: a probability 0..1, got {p!r}")
        for key in ("latency_s", "partial_delay_s"):
            v = getattr(self, key)
            if v is not None and not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ValueError(f"fault {key}: seconds >= 0, got {v!r}")
        for key in ("alarm_at", "disconnect_after"):
            v = getattr(self, key)
            if v is not None and not (isinstance(v, int) and v >= 1):
                raise ValueError(f"fault {key}: an integer >= 1 or None, got {v!r}")
        return self


@dataclass
class Emulated(Faults):
    """The station is the in-process device emulator (docs/emulator.md), driven over its pseudo-terminals.

    ``speed``: ``fast`` or ``realistic``; the fault switches are the fields it takes from
    :class:`Faults` (flat in the YAML: ``!Emulated {beam_loss: 0.02}``); ``timeout_s`` and ``retries``
    are the host transport's (docs/protocol.md); ``policy`` what the station does on beam loss and
    alarms.
    """

    speed: str = "fast"
    latch_beam_loss: bool = False
    timeout_s: float = 1.0
    retries: int = 2
    policy: RunPolicy = field(default_factory=RunPolicy)

    def faults(self):
        """The fault fields as the emulator's :class:`Faults`, validated by it."""
        return Faults(**{f.name: getattr(self, f.name) for f in fields(Faults)}).validate()


@dataclass
class Hardware:
    """The real robot controller and interferometer counter on two serial ports (docs/protocol.md).

    ``robot_driver``, ``counter_driver``: ``olti`` (the olti serial protocol; the operator is prompted to
    set up each reflector), ``bench`` (the counter sets each reflector with ``REFL``, as the emulator
    does: an unattended bench) or ``package.module:Class`` -- a driver of another device
    (:mod:`olti_drake.hardware.drivers`). A six-axis floor-tracer campaign names one port per tracer
    head in ``head_ports`` (station order; the heads are the counter, ``counter_port`` unused), as does
    a 3D machine-tool campaign (one per pan/tilt head, in the order of ``heads_mm``; ``robot_port`` is
    the machine's controller).
    """

    robot_port: str = ""
    counter_port: str = ""
    head_ports: list[str] = field(default_factory=list)
    baud: int = 115200
    robot_driver: str = "olti"
    counter_driver: str = "olti"
    timeout_s: float = 1.0
    retries: int = 2
    policy: RunPolicy = field(default_factory=RunPolicy)


def _paper_reflectors() -> list[list[float]]:
    # Nearly collinear, outside the reach (like 000 Fig. 5; the paper gives no numbers).
    return [[650.0, -450.0], [700.0, -50.0], [650.0, 350.0]]


class ScenarioPaths:
    """What every scenario file does with its paths (a mixin of the scenario dataclasses: no fields)."""

    def at(self, base_dir):
        """This scenario, its relative paths resolved against ``base_dir`` (returns self)."""
        self.base_dir = os.path.abspath(os.fspath(base_dir))
        return self

    def resolve(self, path: str) -> str:
        """A path from the scenario: relative to ``base_dir`` (the YAML file's folder when loaded from a
        file; the current directory for a scenario built in Python unless :meth:`at` set it)."""
        path = os.fspath(path)
        return path if os.path.isabs(path) else os.path.join(getattr(self, "base_dir", os.getcwd()), path)


@dataclass
class Scenario(ScenarioPaths):
    """A simulated open-loop tracking interferometer campaign (000 §2, §4.1).

    ``budget`` is a budget YAML path, or (from Python) a :class:`~olti_drake.io.budget.Budget`;
    empty means 000 Table 2. ``plan`` is a plan generator, a ``!PlanFile``, or (from Python) a
    :class:`~olti_drake.model.plan.Plan`. ``period_s`` is the simulated time per plan row (move,
    settle, read). ``seed`` makes every random draw reproducible.

    ``base``: a scenario this one overrides (``FILE``, ``FILE#NAME`` or ``#NAME`` for a named
    scenario of the same file): every field this one does not give is the base's
    (:func:`load_scenario`).

    Relative paths (``budget``, ``plan.path``, ``base``) have ONE rule: relative to the folder of
    the YAML file that gives them; a scenario built in Python resolves them against its
    ``base_dir`` attribute, the current directory unless set (``Scenario(...).at(folder)``).
    """

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "scara"

    robot: Robot = field(default_factory=Robot)
    reflectors_mm: list[list[float]] = field(default_factory=_paper_reflectors)
    reflector_estimate: Union[SearchEstimate, PerturbedEstimate, ExactEstimate] = field(
        default_factory=SearchEstimate)
    interferometer: InterferometerOptions = field(default_factory=InterferometerOptions)
    budget: str = ""
    plan: Union[BidirectionalGrid, PlanFile] = field(default_factory=BidirectionalGrid)
    seed: int = 0
    period_s: float = 1.0
    station: Union[Simulated, Emulated, Hardware] = field(default_factory=Simulated)
    base: str = ""


    def load_plan(self) -> Plan:
        if isinstance(self.plan, Plan):
            return self.plan
        if isinstance(self.plan, PlanFile):
            return load_plan(self.resolve(self.plan.path))
        return self.plan.plan()

    def load_budget(self):
        from olti_drake.io.budget import load_budget
        from olti_drake.model.budget import Budget, paper000_budget
        if isinstance(self.budget, Budget):
            return self.budget
        return load_budget(self.resolve(self.budget)) if self.budget else paper000_budget()

    def validate(self, where: str = "scenario") -> "Scenario":
        """Check every value; raise one-line InputError naming the field."""
        r = self.robot
        for key in ("L1_mm", "L2_mm", "nominal_L1_mm", "nominal_L2_mm"):
            _positive(f"{where}: robot.{key}", getattr(r, key))
            if not getattr(r, key) <= UNIT_BOUNDS["_mm"]:
                raise InputError(f"{where}: robot.{key} = {getattr(r, key):g} mm is beyond {UNIT_BOUNDS['_mm']:g} mm "
                                 f"(olti_drake.units.UNIT_BOUNDS): no link of a robot (a length in other units?)")
        # A true link more than LENGTH_FACTOR x off its nominal is no manufacturing error but a unit slip (0.325 for
        # 325): the identification refuses such a solution (ScaraPositionModel.implausible), so the scenario too.
        f = ScaraPositionModel.LENGTH_FACTOR
        for key in ("L1_mm", "L2_mm"):
            true, nominal = getattr(r, key), getattr(r, f"nominal_{key}")
            if not nominal / f <= true <= nominal * f:
                raise InputError(f"{where}: robot.{key} = {true:g} mm is more than {f:g} x off robot.nominal_{key} = "
                                 f"{nominal:g} mm: both in mm?")
        _finite(f"{where}: robot.theta40_deg", r.theta40_deg)
        if len(r.beam_offset_mm) != 2 or not np.all(np.isfinite(r.beam_offset_mm)):
            raise InputError(f"{where}: robot.beam_offset_mm must be two finite numbers [along, lateral]")
        for axis in ("J1", "J2", "J4"):
            _check_deviation(f"{where}: robot.{axis}", getattr(r, axis))
        P = self.reflectors_mm
        if not P or any(len(p) != 2 for p in P) or not np.all(np.isfinite(np.asarray(P, dtype=float))):
            raise InputError(f"{where}: reflectors_mm must be a non-empty list of finite [x, y] pairs")
        if isinstance(self.reflector_estimate, PerturbedEstimate):
            for key in ("sigma_mm", "theta40_sigma_mdeg"):
                _nonnegative(f"{where}: reflector_estimate.{key}", getattr(self.reflector_estimate, key))
        if isinstance(self.reflector_estimate, SearchEstimate):
            pos = self.reflector_estimate.positions_mm
            if any(len(p) != 2 for p in pos):
                raise InputError(f"{where}: reflector_estimate.positions_mm must be a list of [x, y] pairs")
        try:
            self.interferometer.validate(f"{where}: interferometer")
        except ValueError as e:
            raise InputError(str(e)) from None
        _positive(f"{where}: period_s", self.period_s)
        if self.seed < 0:
            raise InputError(f"{where}: seed must be >= 0, got {self.seed}")
        if isinstance(self.plan, PlanFile) and not self.plan.path:
            raise InputError(f"{where}: plan.path is empty")
        _check_object(f"{where}: plan", self.plan, (Plan, BidirectionalGrid, PlanFile))
        from olti_drake.model.budget import Budget
        _check_object(f"{where}: budget", self.budget, (Budget, str, os.PathLike))
        _check_station(f"{where}: station", self.station)
        if isinstance(self.station, Hardware) and not isinstance(self.reflector_estimate, ExactEstimate):
            raise InputError(f"{where}: a !Hardware station needs reflector_estimate: !ExactEstimate {{}} with "
                             f"reflectors_mm and robot.theta40_deg from your Eq. (2) search (a simulated search "
                             f"cannot aim a real robot)")
        return self


def _check_station(name, st, heads: Optional[int] = None):
    """Check a station's fields (one line naming ``name`` and the field). ``heads``: a campaign whose
    counters are pan/tilt heads (the 3D machine tool): a ``!Hardware`` station then names the
    controller's ``robot_port`` and one of ``head_ports`` per head, in order, not ``counter_port``."""
    if isinstance(st, Emulated):
        if st.speed not in ("fast", "realistic"):
            raise InputError(f"{name}.speed must be fast or realistic, got {st.speed!r}")
        try:
            st.faults()
        except ValueError as e:
            raise InputError(f"{name}: {e}") from None
    if isinstance(st, Hardware):
        for key in ("robot_port",) if heads is not None else ("robot_port", "counter_port"):
            if not getattr(st, key):
                raise InputError(f"{name}.{key} is empty")
        if heads is not None and (len(st.head_ports) != heads or not all(st.head_ports)):
            raise InputError(f"{name}.head_ports: one serial port per pan/tilt head, {heads} in the order of "
                             f"heads_mm (got {len(st.head_ports)})")
        if st.baud <= 0:
            raise InputError(f"{name}.baud must be > 0, got {st.baud!r}")
    if isinstance(st, (Emulated, Hardware)):
        _positive(f"{name}.timeout_s", st.timeout_s)
        if st.retries < 0:
            raise InputError(f"{name}.retries must be >= 0, got {st.retries!r}")
        pol = st.policy
        for key in ("rereads", "rezeros", "clear_alarms"):
            if getattr(pol, key) < 0:
                raise InputError(f"{name}.policy.{key} must be >= 0, got {getattr(pol, key)!r}")
        _nonnegative(f"{name}.policy.reread_delay_s", pol.reread_delay_s)
        _positive(f"{name}.policy.approach_overrun_deg", pol.approach_overrun_deg)


def _check_object(name, value, kinds):
    if not isinstance(value, kinds):
        raise InputError(f"{name} must be one of {', '.join(k.__name__ for k in kinds)}, "
                         f"got {type(value).__name__}")


def _finite(name, v):
    if not np.isfinite(v):
        raise InputError(f"{name} must be finite, got {v!r}")


def _positive(name, v):
    if not (np.isfinite(v) and v > 0):
        raise InputError(f"{name} must be finite and > 0, got {v!r}")


def _nonnegative(name, v):
    if not (np.isfinite(v) and v >= 0):
        raise InputError(f"{name} must be finite and >= 0, got {v!r}")


def _check_deviation(name, dev):
    if isinstance(dev, HarmonicDeviation):
        for i, h in enumerate(dev.harmonics):
            _positive(f"{name}.harmonics[{i}].period_deg", h.period_deg)
    elif isinstance(dev, MapTable):
        try:
            ErrorMap(dev.grid_deg, dev.forward_deg, dev.reverse_deg, axis=name, outside=dev.outside)
        except ValueError as e:
            raise InputError(str(e)) from None


def load_scenario(path=None, name: Optional[str] = None, text: Optional[str] = None, *,
                  defaults: Optional[Scenario] = None) -> Scenario:
    """Load a scenario: a YAML file, optionally one named scenario of it, then overrides.

    The layers, each over the one before (as Drake's ``hardware_sim`` loads its scenarios with
    ``yaml_load_typed(..., child_name=..., defaults=...)``): ``defaults`` (the paper-000 default
    when None; its type is the schema, e.g. a six-axis ``SerialScenario``); the scenario's ``base`` (``FILE``, ``FILE#NAME`` or ``#NAME``), loaded the same
    way; the file itself (``path``), or its top-level key ``name`` when the file holds several
    named scenarios; then ``text``, YAML overrides such as ``{seed: 3}`` (``--scenario-text``).
    Relative paths are relative to the file that gives them; ``text``'s to the file's folder
    (the current directory without a file). Every value is validated, errors naming the field.
    """
    scenario = defaults if defaults is not None else Scenario()
    where = "default scenario"
    if path is not None:
        scenario = _load_layer(os.fspath(path), name, scenario, set())
        where = f"scenario {os.fspath(path)}" + (f" ({name})" if name else "")
    elif name:
        raise InputError(f"scenario name {name!r} given without a scenario file")
    if text:
        scenario = _load_text(text, scenario, where)
        where += f" + scenario text {text!r}"
    return scenario.validate(where)


def _load_layer(name: str, child: Optional[str], defaults: Scenario, seen: set) -> Scenario:
    """``name`` (its key ``child`` if given) over ``defaults``, after its own ``base`` if it names one."""
    import copy

    from pydrake.common.yaml import yaml_load_typed  # lazy: keeps `olti --help` fast

    if not os.path.isfile(name):
        raise InputError(f"{name}: " + ("is a directory, expected a scenario YAML file" if os.path.isdir(name)
                                        else "scenario file not found"))
    key = (os.path.abspath(name), child)
    if key in seen:
        raise InputError(f"scenario {name}: base: {child or name} is its own base (a cycle)")
    seen = seen | {key}
    raw = read_yaml(name, "scenario")  # refuses duplicate keys and non-UTF-8 bytes, naming the line
    label = f"scenario {name}" + (f" ({child})" if child else "")
    if child is not None:
        if not isinstance(raw, dict) or child not in raw:
            names = ", ".join(str(k) for k in raw) if isinstance(raw, dict) else "none"
            raise InputError(f"scenario {name}: no scenario named {child!r} (names: {names})")
        raw = raw[child]
    base = raw.get("base") if isinstance(raw, dict) else None
    folder = os.path.dirname(os.path.abspath(name))
    if base:
        if not isinstance(base, str):
            raise InputError(f"{label}: base must be FILE, FILE#NAME or #NAME, got {base!r}")
        file, _, base_child = base.partition("#")
        file = os.path.join(folder, file) if file else name
        if not os.path.isfile(file):
            raise InputError(f"{label}: base: {file}: scenario file not found (relative to the file that names it)")
        defaults = _rebase(_load_layer(file, base_child or None, defaults, seen), folder)
    try:
        scenario = yaml_load_typed(schema=type(defaults), filename=name, child_name=child,
                                   defaults=copy.deepcopy(defaults))
    except Exception as e:  # pydrake's messages are multi-line and may not name the key
        where = _locate_bad_field(type(defaults), name, child)
        raise InputError(f"{label}: {where + ': ' if where else ''}{_first_line(e)}") from None
    scenario.base_dir, scenario.source_file, scenario.base = folder, name, ""
    return scenario


def _load_text(text: str, defaults: Scenario, where: str) -> Scenario:
    """YAML overrides (``{seed: 3}``) over a loaded scenario; paths in them relative to its folder."""
    import copy

    from pydrake.common.yaml import yaml_load_typed

    try:
        scenario = yaml_load_typed(schema=type(defaults), data=text, defaults=copy.deepcopy(defaults))
    except Exception as e:
        raise InputError(f"{where}: scenario text {text!r}: {_first_line(e)}") from None
    for attr in ("base_dir", "source_file"):
        if hasattr(defaults, attr):
            setattr(scenario, attr, getattr(defaults, attr))
    if scenario.base:
        raise InputError(f"{where}: scenario text: base is for scenario files, not overrides")
    return scenario


def _rebase(scenario: Scenario, folder: str) -> Scenario:
    """The scenario with its relative file paths made relative to ``folder`` (a base's paths keep
    naming the files next to the base when a file in another folder overrides it)."""
    def rel(path):
        return path if os.path.isabs(path) else os.path.relpath(scenario.resolve(path), folder)

    if isinstance(scenario.budget, str) and scenario.budget:
        scenario.budget = rel(scenario.budget)
    if isinstance(getattr(scenario, "plan", None), PlanFile) and scenario.plan.path:
        scenario.plan = PlanFile(rel(scenario.plan.path))
    return scenario


def _locate_bad_field(schema, filename: str, child_name: Optional[str] = None) -> str:
    """Dotted path of the innermost field that does not load on its own ('' if none found).

    pydrake reports e.g. a non-integer seed without naming it; this retries the
    document field by field (tagged sub-trees such as ``J1: !HarmonicDeviation``
    keep their tags and are entered as the class the tag names) to name the culprit,
    e.g. ``seed`` or ``robot.J1.harmonics[0].amplitude_mdeg``.
    """
    import typing

    import yaml
    from pydrake.common.yaml import yaml_load_typed

    class _Tagged:
        def __init__(self, tag, value):
            self.tag, self.value = tag, value

    class _Loader(yaml.SafeLoader):
        pass

    class _Dumper(yaml.SafeDumper):
        pass

    def construct(loader, suffix, node):
        if isinstance(node, yaml.MappingNode):
            return _Tagged(suffix, loader.construct_mapping(node, deep=True))
        if isinstance(node, yaml.SequenceNode):
            return _Tagged(suffix, loader.construct_sequence(node, deep=True))
        return _Tagged(suffix, loader.construct_scalar(node))

    def represent(dumper, t):
        tag = "!" + t.tag
        if isinstance(t.value, dict):
            return dumper.represent_mapping(tag, t.value)
        if isinstance(t.value, list):
            return dumper.represent_sequence(tag, t.value)
        return dumper.represent_scalar(tag, str(t.value))

    _Loader.add_multi_constructor("!", construct)
    _Dumper.add_representer(_Tagged, represent)
    try:
        with open(filename, encoding="utf-8") as f:
            raw = yaml.load(f, Loader=_Loader)
    except (yaml.YAMLError, UnicodeDecodeError):
        return ""
    if child_name is not None:
        raw = raw.get(child_name) if isinstance(raw, dict) else None

    def loads(cls, key, value) -> bool:
        try:
            yaml_load_typed(schema=cls, data=yaml.dump({key: value}, Dumper=_Dumper))
            return True
        except Exception:  # pydrake raises RuntimeError/ValueError/TypeError by case
            return False

    def members(hint):
        """The dataclasses a field's type hint may hold (Union/Optional/List members, recursively)."""
        if is_dataclass(hint):
            return [hint]
        return [c for a in typing.get_args(hint) for c in members(a)]

    def enter(hint, value, where):
        """The innermost bad field inside ``value`` of type ``hint`` ('' if none is found)."""
        if isinstance(value, _Tagged):
            cls = next((c for c in members(hint) if c.__name__ == value.tag), None)
            return walk(cls, value.value, where + ".") if cls is not None else ""
        if isinstance(value, list):
            for i, item in enumerate(value):
                found = enter(hint, item, f"{where}[{i}]")
                if found:
                    return found
            return ""
        cls = next(iter(members(hint)), None)
        return walk(cls, value, where + ".") if cls is not None else ""

    def walk(cls, data, prefix):
        if not isinstance(data, dict):
            return ""
        hints = typing.get_type_hints(cls)
        for key, value in data.items():
            if key not in hints or loads(cls, key, value):
                continue
            return enter(hints[key], value, f"{prefix}{key}") or f"{prefix}{key}"
        return ""

    return walk(schema, raw, "")


def _first_line(e: Exception) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__


def dump_scenario(scenario: Scenario) -> str:
    """The scenario as YAML text (the inverse of :func:`load_scenario`)."""
    from pydrake.common.yaml import yaml_dump_typed
    return yaml_dump_typed(scenario)


def as_plain(obj):
    """Dataclass tree -> plain dict/list (for truth.json provenance)."""
    if is_dataclass(obj):
        out = {f.name: as_plain(getattr(obj, f.name)) for f in fields(obj)}
        out["_type"] = type(obj).__name__
        return out
    if isinstance(obj, (list, tuple)):
        return [as_plain(v) for v in obj]
    return obj
