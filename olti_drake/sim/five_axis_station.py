"""A five-axis machine campaign (formats.md "Five-axis machine tools"; issue 25, item 4) as a Drake diagram, and
its numpy twin :func:`simulate_five_axis_campaign` (one planned run, one kinematic model: both read the same
:class:`~olti_drake.model.five_axis_truth.FiveAxisTruth`).

Diagram (one clock: the sequencer moves every ``period_s``, the recorder reads half a period later)::

    RowSequencer --command (n, m/rad), tool--> FiveAxisNominal (the MultibodyPlant of the model file)
          |                                        --nominal tool point (base, workpiece)--> FiveAxisSteering
          |                                                                 --head_command (2, rad)--+
          +--command, direction, tool, station, nest--> station:                                     v
                  FiveAxisTruthTool (commands -> TRUE tool point, base and workpiece frames)
                  FiveAxisNominal (the cat's eye's axis in each frame)
                  FiveAxisInterferometer --displacement, valid, miss, status-->  FiveAxisRecorder
                  RTestDevice --rtest_displacement (3, m)-------------------->

* The steering is OPEN LOOP (paper 001, Eq. (1) with the rotary axes): each pan/tilt head aims from its
  ESTIMATED centre and zero angles at the COMMANDED tool point (the plant's nominal tool point of the commands,
  nominal tool offset), never at the actual one. A head on the bed (``station_frame`` ``base``) lives in the base
  frame; a head riding on the table (``workpiece``) lives in the workpiece frame, so it moves with the table: its
  pose in the base is the command's table transform, and its beam, the tool point and the cat's eye's axis are
  all taken relative to the (true) table.
* The beam leaves the TRUE head centre along the TRUE angles (command + the head's own error + true zeros,
  :func:`~olti_drake.model.aiming3d.pan_tilt_beam`) and reads the TRUE tool point by
  :func:`~olti_drake.model.aiming3d.read_beam` (cosine error, cat's-eye acceptance and ±80° viewing angle, budget
  noise with the pose term on the head, λ/64) -- the 3D machine's reading (:mod:`olti_drake.sim.machine3d_station`).
* The R-test device reads the displacement of the actual ball centre from its nest in the workpiece frame, less
  the nest set-up's own zero, plus normal noise.

Ports carry SI (m, rad); the API and files mm and deg. Noise of reading k (k = 0, 1, ...) is drawn from
``default_rng([seed, k + 1])`` in both the diagram and the twin, so they agree reading for reading with the noise on.
"""


import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Union

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model.budget import paper001_budget
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.formats import MACHINE5_TRUTH
from olti_drake.sim.scenario import Emulated, Hardware, ScenarioPaths, Simulated, _check_station, stream_seed

M_TO_MM = 1e3
MODELS_DIR = Path(__file__).resolve().parent.parent / "models"
#: Machine models shipped with the package, by the short name a scenario may give as ``machine_model.file``.
SHIPPED_MACHINES = {"trunnion_ac": MODELS_DIR / "trunnion_ac.urdf",
                    "swivel_head_bc": MODELS_DIR / "swivel_head_bc.urdf"}
#: Working float64 values one campaign row carries (commands, truth, aiming, columns): the allocation guard's.
VALUES_PER_ROW = 96
FORMAT = MACHINE5_TRUTH


# ------------------------------------------------------------------ the scenario file
@dataclass
class MachineModel:
    """The machine: model ``file`` (a shipped name, ``trunnion_ac`` / ``swivel_head_bc``, or a URDF/SDFormat path
    relative to the scenario file), its ``workpiece_frame`` and ``tool_frame``, and the nominal tool points
    (``tool_offsets_mm``: the cat's-eye / ball centre of each mounting in the tool frame, mm)."""

    file: str = "trunnion_ac"
    workpiece_frame: str = "workpiece"
    tool_frame: str = "tool"
    tool_offsets_mm: list[list[float]] = field(default_factory=lambda: [[0.0, 0.0, 0.0], [0.0, 60.0, 30.0]])


@dataclass
class TruthSpec:
    """The seeded error truth (:func:`~olti_drake.model.five_axis_truth.synthetic_truth`): location errors of
    10–50 µm / 20–100 µrad times ``location_scale``, harmonic error motions, backlash, the linear axes' errors."""

    seed: int = 1
    location: bool = True
    motions: bool = True
    backlash: bool = True
    linear: bool = True
    location_scale: float = 1.0


@dataclass
class TrackingSpec:
    """The open-loop tracking interferometer (:func:`~olti_drake.model.five_axis_plan.tracking_plan`): pan/tilt
    heads on the bed (``bed_heads_mm``, base frame) and riding on the table (``table_heads_mm``, workpiece frame),
    stations numbered bed first; ``poses`` nominal tool points in ``box_mm`` (workpiece frame), the rotary axes
    swept forward then back over ``ranges_deg`` (default their travel), read with every tool of ``tools``; the
    heads' §2.2 estimate errors, own angular error and the cat's eye's axis in the tool frame; plan ``seed``."""

    bed_heads_mm: list[list[float]] = field(default_factory=list)
    table_heads_mm: list[list[float]] = field(default_factory=list)
    poses: int = 100
    box_mm: list[list[float]] = field(default_factory=lambda: [[-100.0, 100.0], [-100.0, 100.0], [120.0, 220.0]])
    ranges_deg: dict[str, list[float]] = field(default_factory=dict)
    tools: list[int] = field(default_factory=lambda: [0])
    station_estimate_sigma_um: float = 5.75
    zero_angle_sigma_urad: float = 2.8
    head_error_mdeg: float = 0.5
    catseye_axis_tool: list[float] = field(default_factory=lambda: [0.0, 0.0, -1.0])
    seed: int = 0


@dataclass
class RTestSpec:
    """R-test nests (:func:`~olti_drake.model.five_axis_plan.rtest_plan`): spheres at ``nests_mm`` (workpiece
    frame), ``steps`` poses per sweep (forward then back) over ``ranges_deg``, the ball of tool ``tool``; each nest
    set-up's zero drawn ~N(0, ``zero_sigma_mm``) per axis; reading noise ``noise_um`` (per axis, σ)."""

    nests_mm: list[list[float]] = field(default_factory=list)
    steps: int = 24
    ranges_deg: dict[str, list[float]] = field(default_factory=dict)
    tool: int = 0
    zero_sigma_mm: float = 0.05
    noise_um: float = 0.3


@dataclass
class FiveAxisScenarioFile(ScenarioPaths):
    """A five-axis campaign as YAML (``diagrams/machine_5axis.yaml``). Its kind is told by the top-level key
    ``machine_model`` (:func:`~olti_drake.sim.serial_scenario.scenario_kind`). ``tracking`` and ``rtest`` may both
    be given (one campaign mixes them: the distance rows first). ``olti simulate`` simulates it; ``olti run`` takes its
    distance campaign (no R-test nests) on ``station``: ``!Simulated`` (this diagram's), ``!Emulated`` (the five-axis
    emulator, :mod:`olti_drake.hardware.machine5_emulator`) or ``!Hardware {robot_port: ..., head_ports: [...]}``
    (the controller and one port per pan/tilt head, station order: the bed's, then the table's).
    ``machine_model.file`` is relative to the file that gives it; a ``base`` layer's machine path is not rebased
    (give it in the file that uses it)."""

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "machine5"

    machine_model: MachineModel = field(default_factory=MachineModel)
    truth: TruthSpec = field(default_factory=TruthSpec)
    tracking: TrackingSpec = field(default_factory=TrackingSpec)
    rtest: RTestSpec = field(default_factory=RTestSpec)
    interferometer: InterferometerOptions = field(default_factory=InterferometerOptions)
    budget: str = ""
    seed: int = 0
    period_s: float = 1.0
    station: Union[Simulated, Emulated, Hardware] = field(default_factory=Simulated)
    base: str = ""

    def machine_path(self) -> str:
        f = self.machine_model.file
        return str(SHIPPED_MACHINES[f]) if f in SHIPPED_MACHINES else self.resolve(f)

    def load_budget(self):
        from olti_drake.io.budget import load_budget
        return load_budget(self.resolve(self.budget)) if self.budget else paper001_budget()

    def validate(self, where: str = "scenario") -> "FiveAxisScenarioFile":
        """Check every field (one line naming ``where`` and the field); the machine and plan are checked when
        the run is prepared (:func:`prepare_five_axis`)."""
        tr, rt = self.tracking, self.rtest
        offsets = np.asarray(self.machine_model.tool_offsets_mm, float)
        checks = [
            ("machine_model.tool_offsets_mm", offsets.ndim == 2 and offsets.shape[1:] == (3,) and len(offsets) >= 1
             and np.all(np.isfinite(offsets)), "a non-empty list of finite [x, y, z]"),
            ("tracking.catseye_axis_tool", len(tr.catseye_axis_tool) == 3 and np.any(tr.catseye_axis_tool)
             and np.all(np.isfinite(tr.catseye_axis_tool)), "3 finite numbers, not all zero"),
            ("period_s", np.isfinite(self.period_s) and self.period_s > 0, "finite and > 0"),
            ("truth.location_scale", np.isfinite(self.truth.location_scale) and self.truth.location_scale >= 0,
             "finite and >= 0")]
        for name, heads in (("tracking.bed_heads_mm", tr.bed_heads_mm), ("tracking.table_heads_mm", tr.table_heads_mm)):
            h = np.asarray(heads, float)
            checks.append((name, not len(heads) or (h.ndim == 2 and h.shape[1:] == (3,) and np.all(np.isfinite(h))),
                           "a list of finite [x, y, z]"))
        checks += [(name, np.isfinite(v) and v >= 0, "finite and >= 0") for name, v in (
            ("tracking.station_estimate_sigma_um", tr.station_estimate_sigma_um),
            ("tracking.zero_angle_sigma_urad", tr.zero_angle_sigma_urad),
            ("tracking.head_error_mdeg", tr.head_error_mdeg), ("rtest.zero_sigma_mm", rt.zero_sigma_mm),
            ("rtest.noise_um", rt.noise_um))]
        checks += [(name, v >= 0, "an integer >= 0") for name, v in (
            ("seed", self.seed), ("truth.seed", self.truth.seed), ("tracking.seed", tr.seed))]
        if not (tr.bed_heads_mm or tr.table_heads_mm or rt.nests_mm):
            raise InputError(f"{where}: no readings: give tracking.bed_heads_mm / tracking.table_heads_mm (stations) "
                             f"or rtest.nests_mm (R-test nests)")
        for name, ok, need in checks:
            if not ok:
                raise InputError(f"{where}: {name} must be {need}, got {_field(self, name)!r}")
        try:
            self.interferometer.validate(f"{where}: interferometer")
        except ValueError as e:
            raise InputError(str(e)) from None
        _check_station(f"{where}: station", self.station, heads=len(tr.bed_heads_mm) + len(tr.table_heads_mm))
        return self


def _field(obj, dotted: str):
    for part in dotted.split("."):
        obj = getattr(obj, part)
    return obj


def load_five_axis_scenario(path, name=None, text=None) -> FiveAxisScenarioFile:
    """The YAML file (its named scenario, ``base`` layers, ``--scenario-text`` overrides) as a validated
    :class:`FiveAxisScenarioFile` (:func:`olti_drake.sim.scenario.load_scenario`; one line on error)."""
    from olti_drake.sim.scenario import load_scenario

    return load_scenario(path, name, text, defaults=FiveAxisScenarioFile())


# ------------------------------------------------------------------ the planned run (shared by twin and diagram)
@dataclass
class FiveAxisRun:
    """A planned five-axis campaign, what the diagram and the twin share. ``plan``: the rows
    (:class:`~olti_drake.model.five_axis_plan.FiveAxisPlan`); ``truth``: the error truth; ``tool_offsets_mm`` the
    nominal tool points (tool frame); heads true / estimated (:class:`~olti_drake.model.aiming3d.PanTiltHeads`,
    each centre in its station's frame: ``plan.station_frames``); ``dead_paths_mm`` L0_j (001 Eq. 3: head j's
    true centre to the true tool point at its first reading); ``nest_zeros_mm`` (N_n, 3); seeds of the readings'
    noise; the options, budget and R-test noise σ (mm)."""

    scenario: FiveAxisScenarioFile
    machine: object
    plan: object
    truth: object
    tool_offsets_mm: np.ndarray
    heads_true: object
    heads_est: object
    head_error: object
    dead_paths_mm: np.ndarray
    nest_zeros_mm: np.ndarray
    catseye_axis_tool: np.ndarray
    options: InterferometerOptions
    budget: object
    laser_seed: int
    rtest_seed: int
    rtest_sigma_mm: float

    #: The kind of scenario this is (:func:`olti_drake.sim.serial_scenario.scenario_kind`).
    KIND = "machine5"


def prepare_five_axis(doc: FiveAxisScenarioFile, where: str = "", truth=None) -> FiveAxisRun:
    """Read the machine, draw the truth (or take ``truth``), plan the rows, draw the heads' zeros and estimates and
    the nests' zeros (seeded by ``doc.seed``), and zero the counters: the run both simulations read. Errors: one
    :class:`~olti_drake.errors.InputError` line naming ``where`` (default: the scenario file) and the field."""
    from olti_drake.limits import check_allocation
    from olti_drake.model import aiming3d
    from olti_drake.model import five_axis_plan as fp
    from olti_drake.model.five_axis import FiveAxisMachine
    from olti_drake.model.five_axis_truth import synthetic_truth

    mm, tr, rt = doc.machine_model, doc.tracking, doc.rtest
    where = where or (f"scenario {doc.source_file}" if getattr(doc, "source_file", "") else "scenario")
    machine = FiveAxisMachine.from_file(doc.machine_path(), mm.workpiece_frame, mm.tool_frame)
    offsets = np.asarray(mm.tool_offsets_mm, float).reshape(-1, 3)
    if truth is None:
        t = doc.truth
        truth = synthetic_truth(machine, t.seed, t.location, t.motions, t.backlash, t.linear, offsets)
        truth.location = {k: v * t.location_scale for k, v in truth.location.items()}
    frames = ["base"] * len(tr.bed_heads_mm) + ["workpiece"] * len(tr.table_heads_mm)
    n_rows = (len(frames) * len(tr.tools) * max(tr.poses, 0) + 2 * len(rt.nests_mm) * max(rt.steps, 0))
    check_allocation(f"{where}: tracking.poses", tr.poses, [float(n_rows), VALUES_PER_ROW],
                     what="values (rows x values per row)", hint="use fewer poses, stations, tools or steps")
    plans = []
    if frames:
        plans.append(fp.tracking_plan(machine, frames, tr.poses, tr.box_mm, tr.ranges_deg, tr.tools, offsets,
                                      tr.seed, f"{where}: tracking"))
    if rt.nests_mm:
        plans.append(fp.rtest_plan(machine, rt.nests_mm, rt.steps, rt.ranges_deg, rt.tool, offsets,
                                   f"{where}: rtest"))
    plan = fp.combine(*plans)
    rng = np.random.default_rng(doc.seed)
    P = np.asarray(tr.bed_heads_mm + tr.table_heads_mm, float).reshape(-1, 3)
    zeros = rng.uniform(-180.0, 180.0, (len(P), 2)) * [1.0, 0.0]  # pan zero anywhere, tilt level
    P_est = P + 1e-3 * tr.station_estimate_sigma_um * rng.standard_normal(P.shape)
    zeros_est = zeros - np.degrees(1e-6 * tr.zero_angle_sigma_urad * rng.standard_normal(zeros.shape))
    nest_zeros = rt.zero_sigma_mm * rng.standard_normal((len(rt.nests_mm), 3))
    err = aiming3d.harmonic_head_error(doc.seed + 1, tr.head_error_mdeg) if tr.head_error_mdeg else None
    run = FiveAxisRun(doc, machine, plan, truth, offsets, aiming3d.PanTiltHeads(P, zeros),
                      aiming3d.PanTiltHeads(P_est, zeros_est), err, np.zeros(len(P)), nest_zeros,
                      np.asarray(tr.catseye_axis_tool, float) / np.linalg.norm(tr.catseye_axis_tool),
                      doc.interferometer, doc.load_budget(), stream_seed(doc.seed, "laser"),
                      stream_seed(doc.seed, "rtest"), 1e-3 * rt.noise_um)
    run.dead_paths_mm = _dead_paths(run)
    return run


def true_points(run: FiveAxisRun, rows=None) -> Dict[str, np.ndarray]:
    """{'base': (K, 3), 'workpiece': (K, 3)} mm: the true tool point of ``rows`` (default all) in each frame."""
    p = run.plan
    rows = np.arange(len(p)) if rows is None else np.asarray(rows, int)
    d = p.rotary_directions(run.machine)[rows]
    return {f: run.truth.truth_positions(p.commands[rows], d, p.tool[rows], f) for f in ("base", "workpiece")}


def _dead_paths(run: FiveAxisRun) -> np.ndarray:
    p = run.plan
    out = np.zeros(len(run.heads_true.centres_mm))
    for j, frame in enumerate(p.station_frames):
        first = int(np.flatnonzero(p.station == j)[0])
        actual = true_points(run, [first])[frame][0]
        out[j] = np.linalg.norm(actual - run.heads_true.centres_mm[j])
    return out


def nominal_frames(machine, commands, offsets, catseye_axis_tool) -> Dict[str, tuple]:
    """{frame: (nominal tool points (K, 3) mm, the cat's eye's axis (K, 3))} of commands with tool offsets
    (K, 3) (tool frame), in the base and workpiece frames (the numpy twin's loop)."""
    out = {}
    for frame in ("base", "workpiece"):
        T = machine.transforms(commands, frame)
        out[frame] = (T[:, :3, 3] + np.einsum("mij,mj->mi", T[:, :3, :3], offsets),
                      T[:, :3, :3] @ catseye_axis_tool)
    return out


# ------------------------------------------------------------------ the numpy twin
def simulate_five_axis_campaign(scenario, truth=None):
    """The campaign in numpy: (columns dict per formats.md, truth dict). ``scenario``: a
    :class:`FiveAxisScenarioFile` or a prepared :class:`FiveAxisRun` (``truth`` replaces the scenario's).

    Distance rows: head j aims by 001 Eq. (1) in 3D at the COMMANDED tool point (nominal loop, nominal tool
    offset) from its estimated centre and zeros, in its station's frame; the true beam reads the true tool point in
    that frame (:func:`~olti_drake.model.aiming3d.read_beam`). R-test rows: actual − nest − nest zero + noise."""
    run = scenario if isinstance(scenario, FiveAxisRun) else prepare_five_axis(scenario, truth=truth)
    return run_columns(run, *twin_readings(run))


def twin_readings(run: FiveAxisRun):
    """(displacement_mm (K,), valid (K,), rtest_mm (K, 3)) of every row; NaN where a row is of the other kind."""
    from olti_drake.model import aiming3d

    p = run.plan
    K = len(p)
    nominal = nominal_frames(run.machine, p.commands, run.tool_offsets_mm[p.tool], run.catseye_axis_tool)
    actual = true_points(run)
    disp, valid, rtest = np.full(K, np.nan), np.ones(K, int), np.full((K, 3), np.nan)
    for k in np.flatnonzero(p.station >= 0):
        j = int(p.station[k])
        frame = p.station_frames[j]
        cmd = aiming3d.pan_tilt_commands(run.heads_est, [j], nominal[frame][0][k][None])
        origin, u = aiming3d.pan_tilt_beam(run.heads_true, [j], cmd, run.head_error)
        r = aiming3d.read_beam(origin, u, actual[frame][k][None], nominal[frame][1][k], run.dead_paths_mm[j],
                               run.options, run.budget, np.random.default_rng([run.laser_seed, k + 1]),
                               pose_noise_on="origin")
        valid[k] = int(r.valid[0])
        disp[k] = r.reading_mm[0] if r.valid[0] else np.nan
    for k in np.flatnonzero(p.nest >= 0):
        rtest[k] = rtest_reading(run, k, actual["workpiece"][k])
    return disp, valid, rtest


def rtest_reading(run: FiveAxisRun, k: int, actual_mm) -> np.ndarray:
    """Row k's R-test displacement (3,) mm: the actual ball centre less the nest and its set-up zero, plus
    noise ~N(0, σ) per axis from ``default_rng([rtest_seed, k + 1])``."""
    n = int(run.plan.nest[k])
    noise = np.random.default_rng([run.rtest_seed, k + 1]).standard_normal(3) * run.rtest_sigma_mm
    return np.asarray(actual_mm) - run.plan.nests_mm[n] - run.nest_zeros_mm[n] + noise


def run_columns(run: FiveAxisRun, disp, valid, rtest):
    """(columns, truth) of the readings: formats.md's five-axis campaign; the R-test columns only when there are
    nests, the distance columns only when there are stations (a mixed campaign leaves the other kind's cells empty:
    NaN, '')."""
    p, m = run.plan, run.machine
    cols = {}
    for k, a in enumerate(m.axes):
        cols[f"{a.lower()}_cmd_{'mm' if a in 'XYZ' else 'deg'}"] = p.commands[:, k]
    for k, a in enumerate(m.axes):
        cols[f"dir_{a.lower()}"] = p.directions[:, k].astype(int)
    cols["tool"] = p.tool.astype(int)
    if p.station_frames:
        cols["station"] = np.where(p.station >= 0, p.station, np.nan)  # (an empty cell on another kind's row)
        cols["station_frame"] = np.array([p.station_frames[j] if j >= 0 else "" for j in p.station], dtype=object)
        cols["displacement_mm"] = np.asarray(disp, float)
    if len(p.nests_mm):
        cols["nest"] = np.where(p.nest >= 0, p.nest, np.nan)
        for i, c in enumerate("xyz"):
            cols[f"d{c}_mm"] = np.asarray(rtest, float)[:, i]
    cols["valid"] = np.asarray(valid, int)
    return cols, truth_dict(run, int(np.sum(valid)))


def truth_dict(run: FiveAxisRun, n_valid: int) -> dict:
    """The simulated truth: the errors by ISO name in the ``olti-machine5/1`` result's keys (``location_errors``
    mm/µrad; ``error_motions`` per ISO name on a 5° grid, ``forward``/``reverse``), stations (with frames, true
    and estimated), dead paths, nests and their zeros, seeds."""
    from olti_drake.model.five_axis_errors import COMPONENTS, unit

    m, t, d = run.machine, run.truth, run.scenario
    motions = {}  # the layout of the identified result's error_motions (FiveAxisPositionModel.layout)
    for L in m.rotary:
        c = m.axes.index(L)
        lo, hi = (max(m.lower[c], -180.0), min(m.upper[c], 180.0))
        grid = np.linspace(lo, hi, int(round((hi - lo) / 5.0)) + 1)
        f, r = t.motion_values(L, grid, 1.0), t.motion_values(L, grid, -1.0)
        for i, x in enumerate(COMPONENTS):
            motions[f"E_{x}{L}"] = {"axis": L, "unit": unit(x), "grid_deg": grid.tolist(), "forward": f[:, i].tolist(),
                                    "reverse": r[:, i].tolist()}
    return {"format": FORMAT, "machine": {"file": m.path, "workpiece_frame": m.workpiece_frame,
                                          "tool_frame": m.tool_frame, "axes": list(m.axes)},
            "location_errors": dict(t.location), "error_motions": motions,
            "linear_errors": t.linear is not None, "tool_offsets_mm": np.asarray(t.tool_offsets_mm).tolist(),
            "stations_mm": run.heads_true.centres_mm.tolist(), "station_frames": list(run.plan.station_frames),
            "stations_estimate_mm": run.heads_est.centres_mm.tolist(), "dead_paths_mm": run.dead_paths_mm.tolist(),
            "nests_mm": np.asarray(run.plan.nests_mm).tolist(), "nest_zeros_mm": run.nest_zeros_mm.tolist(),
            "n_readings": int(n_valid), "n_rows": len(run.plan), "seed": d.seed, "truth_seed": d.truth.seed,
            "plan_seed": d.tracking.seed}


# ------------------------------------------------------------------ Drake systems
def _systems():
    """The LeafSystems (pydrake imported when a diagram is built, not at import)."""
    return getattr(_systems, "cache", None) or _make_systems()


def _make_systems():
    from olti_drake.sim import five_axis_systems as m

    _systems.cache = {name: getattr(m, name) for name in ("FiveAxisNominal", "FiveAxisSteering", "FiveAxisTruthTool",
                                                          "FiveAxisInterferometer", "RTestDevice",
                                                          "FiveAxisRecorder")}
    return _systems.cache


def __getattr__(name):
    if name in ("FiveAxisNominal", "FiveAxisSteering", "FiveAxisTruthTool", "FiveAxisInterferometer",
                "RTestDevice", "FiveAxisRecorder"):
        return _systems()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def AddFiveAxisStation(builder, run, name: str = "station"):
    """Add the simulated five-axis station of a planned run (a :class:`FiveAxisRun`, or a
    :class:`FiveAxisScenarioFile` prepared here) to ``builder``; return it (a Diagram). Inside: the
    error truth (:class:`FiveAxisTruthTool`), the nominal plant for the cat's eye's axis, the interferometer heads
    and the R-test device. Inputs ``command`` (n_axes; m, rad), ``direction`` (n_rotary), ``tool``, ``station``,
    ``nest``, ``head_command`` (2, rad); outputs ``displacement`` (1, m), ``valid``, ``miss``, ``status``,
    ``rtest_displacement`` (3, m), ``true_position_base`` / ``true_position_workpiece`` (3, m; simulation only)."""
    from pydrake.systems.framework import DiagramBuilder

    run = run if isinstance(run, FiveAxisRun) else prepare_five_axis(run)
    S = _systems()
    inner = DiagramBuilder()
    truth = inner.AddNamedSystem("error_truth", S["FiveAxisTruthTool"](run.machine, run.truth))
    nominal = inner.AddNamedSystem("catseye_pose", S["FiveAxisNominal"](run.machine, run.tool_offsets_mm,
                                                                         run.catseye_axis_tool))
    laser = inner.AddNamedSystem("laser_interferometer", S["FiveAxisInterferometer"](
        run.heads_true, run.head_error, run.dead_paths_mm, run.plan.station_frames, run.options, run.budget,
        run.laser_seed, run.scenario.period_s))
    probe = inner.AddNamedSystem("rtest_device", S["RTestDevice"](run.plan.nests_mm, run.nest_zeros_mm,
                                                                   run.rtest_sigma_mm, run.rtest_seed,
                                                                   run.scenario.period_s))
    for frame in ("base", "workpiece"):
        inner.Connect(truth.GetOutputPort(f"tool_point_{frame}"), laser.GetInputPort(f"tool_point_{frame}"))
        inner.Connect(nominal.GetOutputPort(f"catseye_axis_{frame}"), laser.GetInputPort(f"catseye_axis_{frame}"))
        inner.ExportOutput(truth.GetOutputPort(f"tool_point_{frame}"), f"true_position_{frame}")
    inner.Connect(truth.GetOutputPort("tool_point_workpiece"), probe.GetInputPort("tool_point"))
    inner.ConnectInput(inner.ExportInput(truth.GetInputPort("command"), "command"), nominal.GetInputPort("command"))
    inner.ConnectInput(inner.ExportInput(truth.GetInputPort("tool"), "tool"), nominal.GetInputPort("tool"))
    inner.ExportInput(truth.GetInputPort("direction"), "direction")
    inner.ExportInput(laser.GetInputPort("station"), "station")
    inner.ExportInput(laser.GetInputPort("head_command"), "head_command")
    inner.ExportInput(probe.GetInputPort("nest"), "nest")
    for port in ("displacement", "valid", "miss", "status"):
        inner.ExportOutput(laser.GetOutputPort(port), port)
    inner.ExportOutput(probe.GetOutputPort("displacement"), "rtest_displacement")
    return builder.AddNamedSystem(name, inner.Build())


def build_five_axis_diagram(run: FiveAxisRun, station_factory=None, recorder=None, extend=None):
    """The whole campaign as a Diagram; returns (diagram, recorder, sequencer). ``station_factory(builder, run)``
    adds the station (default :func:`AddFiveAxisStation`; a device station of ``olti run`` has no ``direction``,
    ``tool``, ``nest`` inputs and no ``rtest_displacement``: those ports are left out / read NaN); ``recorder``
    replaces the :class:`FiveAxisRecorder` (its ``status`` input, if any, gets the station's);
    ``extend(builder, station, sequencer, steering, recorder)`` adds systems before the diagram is built."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import ConstantVectorSource

    from olti_drake.sim.systems import RowSequencer

    S, p, m = _systems(), run.plan, run.machine
    revolute = np.array([a not in "XYZ" for a in m.axes])
    builder = DiagramBuilder()
    station = (station_factory or AddFiveAxisStation)(builder, run)
    seq = builder.AddNamedSystem("machine_sequencer", RowSequencer({
        "command": np.where(revolute, np.radians(p.commands), p.commands / M_TO_MM),
        "direction": p.rotary_directions(m).astype(float), "tool": p.tool.astype(float),
        "station": np.maximum(p.station, 0).astype(float), "nest": np.maximum(p.nest, 0).astype(float),
        "kind": (p.nest >= 0).astype(float), "row": np.arange(len(p), dtype=float)}, run.scenario.period_s))
    nominal = builder.AddNamedSystem("five_axis_plant", S["FiveAxisNominal"](m, run.tool_offsets_mm,
                                                                           run.catseye_axis_tool))
    steer = builder.AddNamedSystem("pan_tilt_steering", S["FiveAxisSteering"](run.heads_est, p.station_frames))
    rec = builder.AddNamedSystem("machine_recorder", recorder or S["FiveAxisRecorder"](run.scenario.period_s))
    for port in ("command", "tool"):
        builder.Connect(seq.GetOutputPort(port), nominal.GetInputPort(port))
    for port in ("command", "direction", "tool", "station", "nest"):
        if station.HasInputPort(port):      # a device station: the controller keeps the directions, the aim the tool
            builder.Connect(seq.GetOutputPort(port), station.GetInputPort(port))
    for frame in ("base", "workpiece"):
        builder.Connect(nominal.GetOutputPort(f"nominal_{frame}"), steer.GetInputPort(f"nominal_{frame}"))
    builder.Connect(seq.GetOutputPort("station"), steer.GetInputPort("station"))
    builder.Connect(steer.GetOutputPort("head_command"), station.GetInputPort("head_command"))
    for port in ("row", "kind"):
        builder.Connect(seq.GetOutputPort(port), rec.GetInputPort(port))
    for port in ("displacement", "valid", "rtest_displacement", "status"):
        if station.HasOutputPort(port) and rec.HasInputPort(port):
            builder.Connect(station.GetOutputPort(port), rec.GetInputPort(port))
    if not station.HasOutputPort("rtest_displacement"):    # no R-test device on the line protocol
        nan = builder.AddNamedSystem("rtest_unavailable", ConstantVectorSource(np.full(3, np.nan)))
        builder.Connect(nan.get_output_port(), rec.GetInputPort("rtest_displacement"))
    if extend is not None:
        extend(builder, station, seq, steer, rec)
    diagram = builder.Build()
    diagram.station, diagram.machine = station, m  # keep the plant the systems read alive
    return diagram, rec, seq


def diagram_readings(run: FiveAxisRun):
    """Simulate the diagram over every row: (displacement_mm, valid, rtest_mm), as :func:`twin_readings`."""
    from pydrake.systems.analysis import Simulator

    diagram, rec, seq = build_five_axis_diagram(run)
    simulator = Simulator(diagram)
    simulator.AdvanceTo(seq.duration_s)
    rows = np.array(rec.GetReadings(simulator.get_context()), float).reshape(-1, 6)
    order = np.argsort(rows[:, 0], kind="stable")
    rows = rows[order]
    if len(rows) != len(run.plan) or np.any(rows[:, 0] != np.arange(len(run.plan))):
        raise RuntimeError(f"five-axis diagram: recorded {len(rows)} rows of {len(run.plan)}")
    return rows[:, 1], rows[:, 2].astype(int), rows[:, 3:6]


def run_five_axis_campaign(scenario, truth=None):
    """The campaign by the Drake diagram: (columns, truth), the layout of :func:`simulate_five_axis_campaign`."""
    run = scenario if isinstance(scenario, FiveAxisRun) else prepare_five_axis(scenario, truth=truth)
    return run_columns(run, *diagram_readings(run))


def write_campaign(path, columns) -> None:
    """The campaign CSV: :func:`olti_drake.io.five_axis_io.write_five_axis_campaign` when it exists, else
    formats.md's columns through :func:`olti_drake.io.csvio.write_table`."""
    try:
        from olti_drake.io.five_axis_io import write_five_axis_campaign
    except ImportError:
        from olti_drake.io.csvio import write_table

        fmt = {k: ("%d" if k.startswith("dir_") or k in ("tool", "station", "nest", "valid") else
                   "%s" if k == "station_frame" else "%.9f" if k.endswith("_mm") and not k.endswith("cmd_mm")
                   else "%.6f") for k in columns}
        write_table(path, columns, fmt, measurement=True)
        return
    write_five_axis_campaign(path, columns)


def simulate_five_axis_command(path, name, text, out_dir, seed=None, meshcat=False) -> str:
    """``olti simulate machine_5axis.yaml --out DIR``: load, check the outputs before any work, run the diagram,
    write DIR/campaign.csv and DIR/truth.json; returns the summary."""
    from olti_drake.io.outputs import make_dir, preflight, write_json

    if meshcat:
        raise ValueError(f"--meshcat: the live view is not available for five-axis scenarios yet ({path})")
    t0 = time.perf_counter()
    doc = load_five_axis_scenario(path, name, text)
    if seed is not None:
        doc.seed = seed
    where = f"scenario {path}"
    csv_path, truth_path = (os.path.join(out_dir, n) for n in ("campaign.csv", "truth.json"))
    preflight([], [path] + ([doc.resolve(doc.budget)] if doc.budget else []), measurements=[csv_path, truth_path],
              dirs=[out_dir], create_dirs=True)
    run = prepare_five_axis(doc, where)
    cols, truth = run_five_axis_campaign(run)
    make_dir(out_dir)
    write_campaign(csv_path, cols)
    write_json(truth_path, truth, measurement=True)
    dist = run.plan.station >= 0
    lost = int(np.sum(dist & (cols["valid"] == 0)))
    return "\n".join([f"five-axis campaign: {len(run.plan)} rows ({int(dist.sum())} distance readings from "
                      f"{len(run.plan.station_frames)} pan/tilt heads, {lost} beam lost; {int((~dist).sum())} R-test "
                      f"readings at {len(run.plan.nests_mm)} nests) on {Path(run.machine.path).name}, simulated in "
                      f"{time.perf_counter() - t0:.2f} s", f"wrote {csv_path} and {truth_path}"])
