"""``olti run``: a scenario's campaign on its station, logged reading by reading, resumable.

The diagram is the campaign diagram of :mod:`olti_drake.sim.campaign` whatever
the station (simulated, emulated or hardware); the recorder's sink writes
every reading to :class:`~olti_drake.hardware.runlog.CampaignLog` as it arrives.

A six-axis floor-tracer scenario (:mod:`olti_drake.sim.serial_scenario`) runs the same way on the
N-joint diagram of :mod:`olti_drake.sim.serial_station`, its station simulated, the N-joint emulator
or the real robot and heads behind the same hardware station (``_Serial``: the log's columns, where
a record goes, the resumed state); a 3D machine-tool scenario (``heads_mm``:
:mod:`olti_drake.sim.machine3d_station`) on the diagram of :mod:`olti_drake.sim.machine3d_campaign`,
its station simulated, the 3D machine emulator or the real controller and pan/tilt heads
(``_Machine3D``); a five-axis scenario (``machine_model``: :mod:`olti_drake.sim.five_axis_station`) its distance
campaign on the diagram of :mod:`olti_drake.sim.five_axis_campaign`, its station simulated, the five-axis emulator
or the real controller and pan/tilt heads (``_Machine5``). Every kind takes an ``extend`` hook, called as
``extend(builder, setup=, station=, sequencer=, steering=, recorder=)`` before the diagram is built.

Resuming (``--resume``) after Ctrl-C, ``kill -9`` or a lost line starts the
command sequence at the first planned reading not on disk and records only
readings not on disk, so none is lost and none is duplicated. The robot is
then somewhere unknown, so the station first re-approaches that row from
the sides of the plan's approach directions (backlash differs by direction,
000 Eq. 7), and zeroes the counter again at the pose where the interrupted
run zeroed it, approached the same way: the run keeps one dead path.
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from olti_drake.errors import InputError


class RunInterrupted(Exception):
    """``olti run``: Ctrl-C (SIGINT) or SIGTERM stopped the run after the reading in progress was written."""


@dataclass
class RunResult:
    """What :func:`run` did and what a script needs afterwards.

    Counts: readings ``planned``, ``on_disk`` (all sessions), ``taken`` in this session
    (``invalid`` of them without a trustworthy reading), from plan step ``start_step``, in
    ``elapsed_s`` seconds of wall time; ``session`` is this session's number (0 = the first).
    ``complete``: every planned reading is on disk. ``stopped``: why the session ended early
    (``should_stop``'s reason, e.g. ``"SIGINT"``), None if it did not. ``diagram``,
    ``simulator`` (and its ``context``): the campaign diagram as it was when the session ended
    (None when there was nothing left to do); its station is closed. ``log_path``: the campaign
    log ``OUT/campaign.csv`` (mm and degrees); ``run.json`` and ``events.jsonl`` sit beside it.
    """

    out_dir: str
    planned: int
    on_disk: int
    taken: int
    invalid: int
    start_step: int
    session: int
    elapsed_s: float
    complete: bool
    stopped: Optional[str] = None
    diagram: object = None
    simulator: object = None

    @property
    def log_path(self) -> str:
        return os.path.join(self.out_dir, "campaign.csv")

    @property
    def context(self):
        return self.simulator.get_context() if self.simulator is not None else None


#: The name the runner's result had before it carried the diagram (kept for callers of that name).
RunSummary = RunResult


def _fingerprint(setup, commands, measured) -> str:
    """SHA-256 of what a resumed session must repeat exactly: the command sequence and readings."""
    table = np.column_stack([np.round(commands[k], 9) for k in ("theta1", "theta2", "theta4")] +
                            [commands["reflector"], measured])
    return hashlib.sha256(np.ascontiguousarray(table, dtype=float).tobytes()).hexdigest()


def _station_kind(scenario) -> str:
    return type(scenario.station).__name__.lower()


def _plan(setup):
    """The global command sequence (campaign.campaign_commands) and its measured mask."""
    from olti_drake.sim.campaign import campaign_commands

    r = setup.scenario.robot
    c = campaign_commands(setup.plan, setup.reflectors_estimate_mm, setup.theta40_estimate_deg,
                          r.nominal_L1_mm, r.nominal_L2_mm)
    return c, setup.plan.measure[c["plan_row"]]


class _Scara:
    """What ``run`` needs of a SCARA campaign (sim.campaign): the command sequence and its readings,
    the log's columns, the diagram, where a record goes, the resumed state, the truth."""

    columns = None          # runlog.COLUMNS
    comment = ("olti_drake SCARA campaign (shared/spec/formats.md): mm and degrees; dir = approach direction; "
               "valid 0 = no trustworthy reading (kept); step/session/status/reads/rezeros/time: the run log "
               "(docs/runner.md)")

    def __init__(self, scenario):
        from olti_drake.sim.campaign import prepare

        self.scenario = scenario
        self.setup = prepare(scenario)
        self.commands, self.measured = _plan(self.setup)
        self.n_rows = len(self.setup.plan)

    def fingerprint(self) -> str:
        return _fingerprint(self.setup, self.commands, self.measured)

    def build(self, station_factory, extend, sink):
        from olti_drake.sim.campaign import build_campaign_diagram

        return build_campaign_diagram(self.setup, station_factory, extend=extend, sink=sink)

    def step_of(self, record) -> int:
        return int(record[0]) * self.n_rows + int(record[8])

    @staticmethod
    def invalid(record) -> bool:
        return record[7] == 0

    def reflector_at(self, step: int) -> int:
        return int(self.commands["reflector"][min(step, len(self.commands["reflector"]) - 1)])

    def previous(self, step: int):
        """The plan's row before ``step``: (command (4), directions (4)), or (None, None) at step 0."""
        if step == 0:
            return None, None
        c, k = self.commands, step - 1
        return (np.array([c["theta1"][k], c["theta2"][k], 0.0, c["theta4"][k]]),
                np.array([c["dir1"][k], c["dir2"][k], 1.0, c["dir4"][k]]))

    def resume_simulated(self, station, context, step: int, prev_cmd, prev_dir) -> None:
        # The simulated station: the joints' last command and directions, the laser's sample count
        # (its noise is a function of it, so a resumed simulation equals an uninterrupted one).
        if prev_cmd is not None:
            joints = station.GetSubsystemByName("error_map_joint")
            joints.GetMyMutableContextFromRoot(context).get_mutable_discrete_state_vector().SetFromVector(
                np.concatenate([prev_cmd, prev_dir]))
        laser = station.GetSubsystemByName("laser_interferometer")
        laser.GetMyMutableContextFromRoot(context).get_mutable_discrete_state_vector().SetAtIndex(0, step)

    def write_truth(self, out_dir) -> None:
        _write_truth(self.setup, out_dir)


class _Serial(_Scara):
    """The same for a six-axis floor-tracer campaign (sim.serial_station): N joints, the station index
    as the reflector, a reading's step found from its (station, plan row)."""

    comment = ("olti_drake six-axis distance campaign (olti run): mm and degrees; station = tracer head; "
               "dir = approach direction; valid 0 = no trustworthy reading (kept); step/session/status/reads/"
               "rezeros/time: the run log (docs/runner.md)")

    def __init__(self, scenario):
        from olti_drake.hardware.runlog import serial_columns
        from olti_drake.sim.serial_station import prepare_serial

        self.scenario = scenario
        self.setup = s = prepare_serial(scenario)
        self.measured = np.asarray(s.measure, bool)
        self.columns = serial_columns(s.n_joints)
        steps = np.flatnonzero(self.measured)
        self._step = {(int(s.reflector[k]), int(s.row[k])): int(k) for k in steps}
        if len(self._step) != len(steps):
            raise InputError("six-axis plan: a (station, pose) pair is measured twice; the run log cannot tell "
                             "its readings apart")

    def fingerprint(self) -> str:
        s = self.setup
        table = np.column_stack([np.round(s.commands_deg, 9), s.dirs, s.reflector, s.measure, s.row])
        return hashlib.sha256(np.ascontiguousarray(table, dtype=float).tobytes()).hexdigest()

    def build(self, station_factory, extend, sink):
        from olti_drake.sim.serial_station import build_serial_diagram

        hook = None
        if extend is not None:
            def hook(builder, setup, station, seq):     # the N-joint diagram's positional hook -> the keywords
                def named(name):
                    return builder.GetSubsystemByName(name) if builder.HasSubsystemNamed(name) else None
                extend(builder, setup=setup, station=station, sequencer=seq, steering=named("pan_tilt_steering"),
                       recorder=named("campaign_recorder"))
        diagram, rec, seq = build_serial_diagram(self.setup, station_factory=station_factory, extend=hook)
        status = rec.GetInputPort("status")
        rec.on_record = lambda context, record: sink(record, status.Eval(context))
        return diagram, rec, seq

    def resume_simulated(self, station, context, step: int, prev_cmd, prev_dir) -> None:
        # The simulated N-joint station: the joints' last command and directions (deg), the laser's
        # sample count (its noise is a function of it), as the SCARA's.
        _resume_simulated_systems(station, context, step, prev_cmd, prev_dir)

    def step_of(self, record) -> int:
        n = self.setup.n_joints
        return self._step[(int(record[0]), int(record[2 * n + 3]))]

    def invalid(self, record) -> bool:
        return record[2 * self.setup.n_joints + 2] == 0

    def reflector_at(self, step: int) -> int:
        return int(self.setup.reflector[min(step, len(self.setup.reflector) - 1)])

    def previous(self, step: int):
        if step == 0:
            return None, None
        return self.setup.commands_deg[step - 1].copy(), self.setup.dirs[step - 1].copy()

    def write_truth(self, out_dir) -> None:
        from olti_drake.io.csvio import read_table
        from olti_drake.io.outputs import write_json
        from olti_drake.sim.serial_station import serial_truth_result

        if os.path.exists(os.path.join(out_dir, "truth.json")):
            return
        names = [f"theta{i + 1}_deg" for i in range(self.setup.n_joints)] + ["valid"]
        t = read_table(os.path.join(out_dir, "campaign.csv"), tuple(names))
        write_json(os.path.join(out_dir, "truth.json"), serial_truth_result(self.setup, t), measurement=True)


class _Tracker(_Serial):
    """The same for a six-axis campaign measured by an emScon laser tracker (``station: !Tracker``,
    hardware.tracker_station): every pose once, the point in the tracker frame and the environment per row."""

    comment = ("olti_drake six-axis point campaign (olti run, laser tracker; formats.md \"Point campaign (laser "
               "tracker)\"): mm and degrees; x/y/z_mm in the tracker frame; temperature_c, pressure_hpa, "
               "humidity_pct: the tracker's environment at the reading; valid 0 = no beam (kept, NaN); step/session/"
               "status (emScon status)/reads/rezeros/time: the run log (docs/runner.md, docs/tracker.md)")

    def __init__(self, scenario):
        from olti_drake.hardware.runlog import tracker_columns
        from olti_drake.hardware.tracker_station import prepare_tracker

        self.scenario = scenario
        self.setup = s = prepare_tracker(scenario)
        self.measured = np.asarray(s.measure, bool)
        self.columns = tracker_columns(s.n_joints)
        self._step = {(0, int(s.row[k])): int(k) for k in np.flatnonzero(self.measured)}

    def build(self, station_factory, extend, sink):
        from olti_drake.hardware.tracker_station import build_tracker_diagram

        if extend is not None:
            raise InputError("olti run: a tracker campaign takes no extend hook (no live view yet)")
        return build_tracker_diagram(self.setup, station_factory, sink)

    def step_of(self, record) -> int:
        return self._step[(0, int(record[-1]))]

    def invalid(self, record) -> bool:
        return record[2 * self.setup.n_joints + 3] == 0

    def write_truth(self, out_dir) -> None:
        """The emulated truth (an in-process emulator only): the robot and the true tracker frame."""
        from olti_drake.hardware.tracker_station import tracker_truth

        if not self.scenario.station.host:
            tracker_truth(self.setup, out_dir)


class _Machine3D(_Scara):
    """The same for a 3D machine-tool campaign (sim.machine3d_campaign): every row is a reading (head j,
    target i: step = j x targets + i), the log's columns those of the 3D machine campaign."""

    comment = ("olti_drake 3D machine campaign (olti run; formats.md \"Machine tool in 3D\"): mm; station = "
               "pan/tilt head; target = command and tool; valid 0 = beam lost (kept); plan_row = target; "
               "step/session/status/reads/rezeros/time: the run log (docs/runner.md)")

    def __init__(self, scenario):
        from olti_drake.hardware.runlog import machine3d_columns
        from olti_drake.sim.machine3d_campaign import prepare_machine3d_campaign

        self.scenario = scenario
        where = getattr(scenario, "source_file", None)
        self.setup = s = prepare_machine3d_campaign(scenario, f"scenario {where}" if where else "scenario")
        self.columns = machine3d_columns()
        self.measured = np.ones(s.n_steps, bool)
        self.n_targets = len(s.run.commands_mm)
        self._commands, self._dirs = s.commands_mm(), s.directions()

    def fingerprint(self) -> str:
        return self.setup.fingerprint()

    def build(self, station_factory, extend, sink):
        from olti_drake.hardware.runlog import MACHINE3D_COLUMNS
        from olti_drake.sim.machine3d_campaign import build_machine3d_campaign_diagram

        n = len(MACHINE3D_COLUMNS)   # the campaign's own columns: the recorder's row without the true tool point

        def log(record, status):
            sink(tuple(record[:n]) + (int(record[1]),), status)   # plan_row = the target

        return build_machine3d_campaign_diagram(self.setup, station_factory, extend=extend, sink=log)

    def step_of(self, record) -> int:
        return int(record[0]) * self.n_targets + int(record[1])

    def reflector_at(self, step: int) -> int:
        j = self.setup.run.sequence["station"]
        return int(j[min(step, len(j) - 1)])

    def previous(self, step: int):
        if step == 0:
            return None, None
        return self._commands[step - 1].copy(), self._dirs[step - 1].copy()

    def resume_simulated(self, station, context, step: int, prev_cmd, prev_dir) -> None:
        # The simulated 3D station has no approach state (the machine's truth has no backlash): only the
        # laser's sample count, so a resumed simulation equals an uninterrupted one.
        _resume_simulated_systems(station, context, step, None, None)

    def write_truth(self, out_dir) -> None:
        from olti_drake.io.csvio import read_table
        from olti_drake.io.outputs import write_json
        from olti_drake.sim.machine3d_campaign import machine3d_truth_result

        if os.path.exists(os.path.join(out_dir, "truth.json")):
            return
        t = read_table(os.path.join(out_dir, "campaign.csv"), ("valid",))
        write_json(os.path.join(out_dir, "truth.json"), machine3d_truth_result(self.setup, t["valid"]),
                   measurement=True)


class _Machine5(_Machine3D):
    """The same for a five-axis distance campaign (sim.five_axis_campaign): every plan row is a reading (step =
    row), the log's columns the five-axis campaign's (commands, dir_<axis>, tool, station, station_frame,
    displacement_mm, valid; formats.md) so that ``olti identify --machine`` reads the run's campaign.csv."""

    comment = ("olti_drake five-axis campaign (olti run; formats.md \"Five-axis machine tools\"): mm and degrees; "
               "station = pan/tilt head, station_frame where it stands; dir = approach direction; valid 0 = beam lost "
               "(kept); plan_row = step = the plan's row; step/session/status/reads/rezeros/time: the run log "
               "(docs/runner.md)")

    def __init__(self, scenario):
        from olti_drake.hardware.runlog import machine5_columns
        from olti_drake.sim.five_axis_campaign import prepare_five_axis_campaign

        self.scenario = scenario
        self.setup = s = prepare_five_axis_campaign(scenario)
        self.columns = machine5_columns(s.run.machine.axes)
        self.measured = np.ones(s.n_steps, bool)
        self._commands, self._dirs = s.run.plan.commands, s.run.plan.directions.astype(float)
        self._valid = len(self.columns) - 9          # the log's 'valid' column (before the run-log columns)

    def build(self, station_factory, extend, sink):
        from olti_drake.sim.five_axis_campaign import build_five_axis_campaign_diagram

        return build_five_axis_campaign_diagram(self.setup, station_factory, extend=extend, sink=sink)

    def step_of(self, record) -> int:
        return int(record[-1])

    def invalid(self, record) -> bool:
        return record[self._valid] == 0

    def reflector_at(self, step: int) -> int:
        j = self.setup.run.plan.station
        return int(j[min(step, len(j) - 1)])

    def write_truth(self, out_dir) -> None:
        from olti_drake.io.csvio import read_table
        from olti_drake.io.outputs import write_json
        from olti_drake.sim.five_axis_campaign import five_axis_truth_result

        if os.path.exists(os.path.join(out_dir, "truth.json")):
            return
        t = read_table(os.path.join(out_dir, "campaign.csv"), ("valid",))
        write_json(os.path.join(out_dir, "truth.json"), five_axis_truth_result(self.setup, t["valid"]),
                   measurement=True)


def _resume_simulated_systems(station, context, step: int, prev_cmd, prev_dir) -> None:
    """A simulated station (a Diagram) put where the uninterrupted campaign was at ``step``: its approach-
    direction joints (``error_map_joint``) get the previous row's command and directions (deg/mm), its 3D
    interferometer (the systems that ``DeclareReading``: state 0 is the sample count) the count ``step``."""
    for system in station.GetSystems():
        state = system.GetMyMutableContextFromRoot(context)
        if system.get_name() == "error_map_joint" and prev_cmd is not None:
            state.get_mutable_discrete_state_vector().SetFromVector(np.concatenate([prev_cmd, prev_dir]))
        elif callable(getattr(system, "DeclareReading", None)):
            state.get_mutable_discrete_state_vector().SetAtIndex(0, step)


def _open_log(scenario_path, kind, out_dir, resume, fsync, planned_steps):
    from olti_drake.hardware.runlog import CampaignLog

    fingerprint = kind.fingerprint()
    station = _station_kind(kind.scenario)
    if not resume:
        manifest = {"scenario": os.path.abspath(scenario_path) if scenario_path else None,
                    "station": station, "seed": kind.scenario.seed, "commands_sha256": fingerprint,
                    "n_steps": int(len(planned_steps.mask)), "readings_planned": int(planned_steps.count)}
        return CampaignLog.create(out_dir, manifest, fsync=fsync, columns=kind.columns, comments=[
            f"olti run: scenario {scenario_path or 'embedded default (paper 000)'}; station {station}", kind.comment])
    log = CampaignLog.reopen(out_dir, fsync=fsync)
    m = log.manifest
    where = os.path.join(out_dir, "run.json")
    if m.get("commands_sha256") != fingerprint or m.get("n_steps") != len(planned_steps.mask):
        log.close()
        raise InputError(f"{where}: the scenario's command sequence differs from the interrupted campaign's "
                         f"(plan, reflectors, steering or seed changed); resume with the same scenario")
    if m.get("station") != station:
        log.close()
        raise InputError(f"{where}: the campaign ran on a {m.get('station')} station, the scenario now has "
                         f"a {station} one; resume on the same kind of station")
    extra = log.recorded - set(np.flatnonzero(planned_steps.mask).tolist())
    if extra:
        log.close()
        raise InputError(f"{os.path.join(out_dir, 'campaign.csv')}: step {min(extra)} is not a planned reading")
    return log


@dataclass
class _Steps:
    mask: np.ndarray

    @property
    def count(self) -> int:
        return int(self.mask.sum())


def _resume_state(diagram, seq, context, kind, step: int, log) -> None:
    """Put the diagram where the uninterrupted campaign was at ``step`` (sequencer ``seq``, station)."""
    seq.GetMyMutableContextFromRoot(context).get_mutable_discrete_state_vector().SetAtIndex(0, step)
    station = diagram.station
    j = kind.reflector_at(step)
    prev_cmd, prev_dir = kind.previous(step)
    if hasattr(station, "resume_at"):          # a device station (emulated or hardware)
        pose = log.zero_pose(j)
        if pose is not None:
            station.zero_poses = {j: pose}
        if prev_cmd is not None:
            station.resume_at(station.GetMyMutableContextFromRoot(context), prev_cmd, prev_dir)
        return
    kind.resume_simulated(station, context, step, prev_cmd, prev_dir)


def _load(scenario, base_dir=None):
    """(Scenario, its file or None) of a Scenario, SerialScenario or Machine3DScenarioFile object, a YAML
    path or None (the paper default); a six-axis file (``scheme``: sim.serial_scenario.scenario_kind) or a
    3D machine-tool one (``heads_mm``) loads as one."""
    from olti_drake.sim.five_axis_station import FiveAxisScenarioFile
    from olti_drake.sim.machine3d_station import Machine3DScenarioFile
    from olti_drake.sim.scenario import Scenario, load_scenario
    from olti_drake.sim.serial_scenario import SerialScenario

    if isinstance(scenario, (Scenario, SerialScenario, Machine3DScenarioFile, FiveAxisScenarioFile)):
        return scenario, getattr(scenario, "source_file", None)
    if scenario is None:
        return load_scenario(None), None
    return load_run_scenario(scenario), os.fspath(scenario)


def load_run_scenario(path, name: Optional[str] = None, text: Optional[str] = None):
    """The scenario ``olti run`` takes: a six-axis one (``SerialScenario``) when the file (or its named
    scenario, or a base) has a ``scheme``, a 3D machine-tool one (``Machine3DScenarioFile``) when it has
    ``heads_mm``, a five-axis one (``FiveAxisScenarioFile``) when it has ``machine_model``, else the SCARA's
    (``load_scenario``): :func:`~olti_drake.sim.serial_scenario.load_any_scenario`."""
    from olti_drake.sim.serial_scenario import load_any_scenario

    return load_any_scenario(path, name, text)


def _campaign_kind(scenario):
    """The campaign of a loaded scenario, by its kind (:func:`~olti_drake.sim.serial_scenario.scenario_kind`)."""
    from olti_drake.sim.serial_scenario import Tracker, scenario_kind

    if isinstance(getattr(scenario, "station", None), Tracker):
        return _Tracker(scenario)
    return {"scara": _Scara, "serial": _Serial, "machine3d": _Machine3D,
            "machine5": _Machine5}[scenario_kind(scenario)](scenario)


def run(scenario, out_dir: str, *, resume: bool = False, should_stop: Optional[Callable[[], object]] = None,
        fsync: bool = True, extend=None, progress: Optional[Callable[[int, int], None]] = None,
        realtime_rate: float = 0.0) -> RunResult:
    """Run (or resume) the scenario's campaign on its station, logging every reading to ``out_dir``.

    ``scenario``: a :class:`~olti_drake.sim.scenario.Scenario`, a six-axis
    :class:`~olti_drake.sim.serial_scenario.SerialScenario` (floor tracers), a 3D machine tool's
    :class:`~olti_drake.sim.machine3d_station.Machine3DScenarioFile`, a five-axis
    :class:`~olti_drake.sim.five_axis_station.FiveAxisScenarioFile`, a scenario YAML path, or None
    (the paper-000 default); its ``station`` (simulated, emulated or hardware) takes the readings.
    ``should_stop()`` is polled between simulator steps (from this thread; it may read a flag
    another thread or a signal handler sets): a truthy value ends the
    session after the reading in progress is on disk, and the result says ``stopped`` (a string
    value is the reason recorded in ``run.json``, e.g. ``"SIGINT"``); ``resume=True`` continues.
    ``progress(on_disk, planned)`` is called after every reading; ``extend`` and
    ``realtime_rate`` as in :func:`~olti_drake.sim.campaign.run_campaign` (e.g. the Meshcat view
    of :mod:`olti_drake.sim.meshcat_view`, a logger): for every kind ``extend(builder, setup=,
    station=, sequencer=, steering=, recorder=)`` adds systems before the diagram is built (the
    N-joint diagram's ``steering`` is None robot-mounted). Raises
    :class:`~olti_drake.hardware.station.StationError` when the station fails (line lost, alarm,
    ...); every reading taken is on disk either way. Units: mm and degrees in the files.
    """
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import EventStatus

    from olti_drake.hardware.runlog import CampaignLog
    from olti_drake.hardware.station import AddStation
    from olti_drake.sim.scenario import Hardware

    scenario, scenario_path = _load(scenario)
    kind = _campaign_kind(scenario)
    measured = kind.measured
    steps = _Steps(measured)
    if not resume:
        CampaignLog.check_new(out_dir)   # before the station opens
    log = None
    if resume:
        log = _open_log(scenario_path, kind, out_dir, resume, fsync, steps)
    recorded = log.recorded if log else set()
    todo = np.flatnonzero(measured & ~np.isin(np.arange(len(measured)), sorted(recorded)))
    t0 = time.monotonic()
    if todo.size == 0:
        session = log.session - 1
        if not log.manifest.get("complete"):
            # Every reading is on disk but the last session stopped before saying so (e.g. interrupted
            # after its last reading): this resume completes the campaign on record.
            session = log.session
            log.begin_session(len(measured), station=_station_kind(scenario), resumed=True)
            if not isinstance(scenario.station, Hardware):
                kind.write_truth(out_dir)
            log.end_session("complete", complete=True, taken=0)
        log.close()
        return RunResult(out_dir, steps.count, len(log.recorded), 0, 0, len(measured), session, 0.0, True)
    # A fresh campaign starts at step 0: the plan's first approach is part of the plan.
    start = int(todo[0]) if recorded else 0
    taken = invalid = 0
    stop = {"reason": None}

    def sink(record, status):
        nonlocal taken, invalid
        step = kind.step_of(record)
        if step in log.recorded:
            return                      # on disk from an earlier session: never twice
        log.append(step, record, status)
        taken += 1
        invalid += int(kind.invalid(record))
        if progress:
            progress(len(log.recorded), steps.count)

    def monitor(context):
        if stop["reason"] is None and should_stop is not None:
            flag = should_stop()
            if flag:
                stop["reason"] = flag if isinstance(flag, str) else "should_stop"
        return EventStatus.ReachedTermination(None, "stop") if stop["reason"] else EventStatus.Succeeded()

    # The station (ports, emulator) opens here; a fresh run's directory is made only once it did.
    session = log.session if log else 0
    diagram, rec, seq = kind.build(lambda b, s: AddStation(b, s, session=session), extend, sink)
    if log is None:
        try:
            log = _open_log(scenario_path, kind, out_dir, resume, fsync, steps)
        except BaseException:
            getattr(diagram.station, "close", lambda: None)()
            raise
    station = diagram.station
    if hasattr(station, "on_event"):
        station.on_event = log.event
    outcome, complete, simulator = "error", False, None
    try:
        log.begin_session(start, station=_station_kind(scenario), resumed=bool(resume))
        simulator = Simulator(diagram)
        simulator.set_target_realtime_rate(realtime_rate)
        _resume_state(diagram, seq, simulator.get_mutable_context(), kind, start, log)
        simulator.set_monitor(monitor)
        simulator.Initialize()
        simulator.AdvanceTo((len(measured) - start) * scenario.period_s)
        complete = log.recorded == set(np.flatnonzero(measured).tolist())
        if stop["reason"] and not complete:
            outcome = f"interrupted ({stop['reason']})"
        else:
            outcome = "complete" if complete else "incomplete"
        if complete and not isinstance(scenario.station, Hardware):
            kind.write_truth(out_dir)
    except BaseException as e:
        if outcome == "error":
            outcome = "interrupted (KeyboardInterrupt)" if isinstance(e, KeyboardInterrupt) else \
                f"error: {' '.join(str(e).split()) or type(e).__name__}"
        raise
    finally:
        close = getattr(station, "close", None)
        if close is not None:
            close()
        log.end_session(outcome, complete=complete, taken=taken)
        log.close()
    return RunResult(out_dir, steps.count, len(log.recorded), taken, invalid, start, log.session,
                     time.monotonic() - t0, complete, None if complete else stop["reason"], diagram, simulator)


def _write_truth(setup, out_dir) -> None:
    """The simulated truth (result format) of a complete simulated or emulated campaign; one already
    there (same command sequence, checked on resume) is kept: measured data is never replaced."""
    from olti_drake.sim.campaign import truth_result
    from olti_drake.io.csvio import read_table
    from olti_drake.io.outputs import write_json

    if os.path.exists(os.path.join(out_dir, "truth.json")):
        return
    t = read_table(os.path.join(out_dir, "campaign.csv"), ("theta1_deg", "theta2_deg", "valid"))
    write_json(os.path.join(out_dir, "truth.json"), truth_result(setup, t), measurement=True)
