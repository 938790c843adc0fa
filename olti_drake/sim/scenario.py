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

from olti_drake.io.csvio import InputError, read_yaml
from olti_drake.model.errormap import ErrorMap, Harmonic, HarmonicDeviation, NoDeviation
from olti_drake.model.interferometer import InterferometerOptions
from olti_drake.model.scara import PAPER_L1_MM, PAPER_L2_MM
from olti_drake.model.plan import BidirectionalGrid, Plan, load_plan
from olti_drake.model.truth import TrueRobot


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
class Emulated:
    """The station is the in-process device emulator (docs/emulator.md), driven over its pseudo-terminals.

    ``speed``: ``fast`` or ``realistic``; the fault fields are those of
    :class:`olti_drake.hardware.emulator.Faults`; ``timeout_s`` and ``retries`` are the
    host transport's (docs/protocol.md); ``policy`` what the station does on
    beam loss and alarms.
    """

    speed: str = "fast"
    drop: float = 0.0
    garble: float = 0.0
    nak_crc: float = 0.0
    bad_crc: float = 0.0
    partial: float = 0.0
    latency_s: float = 0.0
    beam_loss: float = 0.0
    alarm_at: Optional[int] = None
    disconnect_after: Optional[int] = None
    latch_beam_loss: bool = False
    timeout_s: float = 1.0
    retries: int = 2
    policy: RunPolicy = field(default_factory=RunPolicy)

    def faults(self):
        """The fault fields as the emulator's :class:`~olti_drake.hardware.emulator.Faults`, validated by it."""
        from olti_drake.hardware.emulator import Faults

        return Faults(**{f.name: getattr(self, f.name) for f in fields(Faults) if hasattr(self, f.name)}).validate()


@dataclass
class Hardware:
    """The real robot controller and interferometer counter on two serial ports (docs/protocol.md).

    ``robot_driver``, ``counter_driver``: ``olti`` (the olti serial protocol) or
    ``package.module:Class`` -- a driver of another device (:mod:`olti_drake.hardware.drivers`).
    """

    robot_port: str = ""
    counter_port: str = ""
    baud: int = 115200
    robot_driver: str = "olti"
    counter_driver: str = "olti"
    timeout_s: float = 1.0
    retries: int = 2
    policy: RunPolicy = field(default_factory=RunPolicy)


def _paper_reflectors() -> list[list[float]]:
    # Nearly collinear, outside the reach (like 000 Fig. 5; the paper gives no numbers).
    return [[650.0, -450.0], [700.0, -50.0], [650.0, 350.0]]


@dataclass
class Scenario:
    """A simulated open-loop tracking interferometer campaign (000 §2, §4.1).

    ``budget`` is a budget YAML path (relative to the scenario file); empty
    means 000 Table 2. ``period_s`` is the simulated time per plan row (move,
    settle, read). ``seed`` makes every random draw reproducible.
    """

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

    def resolve(self, path: str) -> str:
        """A path from the scenario, relative to the scenario file's directory."""
        return path if os.path.isabs(path) else os.path.join(getattr(self, "base_dir", ""), path)

    def load_plan(self) -> Plan:
        if isinstance(self.plan, PlanFile):
            return load_plan(self.resolve(self.plan.path))
        return self.plan.plan()

    def load_budget(self):
        from olti_drake.io.budget import load_budget, paper000_budget
        return load_budget(self.resolve(self.budget)) if self.budget else paper000_budget()

    def validate(self, where: str = "scenario") -> "Scenario":
        """Check every value; raise one-line InputError naming the field."""
        r = self.robot
        for key in ("L1_mm", "L2_mm", "nominal_L1_mm", "nominal_L2_mm"):
            _positive(f"{where}: robot.{key}", getattr(r, key))
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
        _check_station(f"{where}: station", self.station)
        if isinstance(self.station, Hardware) and not isinstance(self.reflector_estimate, ExactEstimate):
            raise InputError(f"{where}: a !Hardware station needs reflector_estimate: !ExactEstimate {{}} with "
                             f"reflectors_mm and robot.theta40_deg from your Eq. (2) search (a simulated search "
                             f"cannot aim a real robot)")
        return self


def _check_station(name, st):
    if isinstance(st, Emulated):
        if st.speed not in ("fast", "realistic"):
            raise InputError(f"{name}.speed must be fast or realistic, got {st.speed!r}")
        try:
            st.faults()
        except ValueError as e:
            raise InputError(f"{name}: {e}") from None
    if isinstance(st, Hardware):
        for key in ("robot_port", "counter_port"):
            if not getattr(st, key):
                raise InputError(f"{name}.{key} is empty")
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


def load_scenario(path=None) -> Scenario:
    """Load a scenario YAML (paths inside it relative to it); None gives the paper default."""
    if path is None:
        return Scenario().validate("default scenario")
    from pydrake.common.yaml import yaml_load_typed  # lazy: keeps `olti --help` fast

    name = os.fspath(path)
    if not os.path.isfile(name):
        raise InputError(f"{name}: " + ("is a directory, expected a scenario YAML file" if os.path.isdir(name)
                                        else "scenario file not found"))
    read_yaml(name, "scenario")  # refuses duplicate keys and non-UTF-8 bytes, naming the line
    try:
        scenario = yaml_load_typed(schema=Scenario, filename=name)
    except Exception as e:  # pydrake's messages are multi-line and may not name the key
        where = _locate_bad_field(Scenario, name)
        raise InputError(f"scenario {name}: {where + ': ' if where else ''}{_first_line(e)}") from None
    scenario.base_dir = os.path.dirname(os.path.abspath(name))
    return scenario.validate(f"scenario {name}")


def _locate_bad_field(schema, filename: str) -> str:
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
