"""``olti run``: a scenario's campaign on its station, logged reading by reading, resumable.

The diagram is the campaign diagram of :mod:`olti_drake.sim.campaign` whatever
the station (simulated, emulated or hardware); the recorder's sink writes
every reading to :class:`~olti_drake.hardware.runlog.CampaignLog` as it arrives.

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

from olti_drake.io.csvio import InputError


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


def _open_log(scenario_path, setup, out_dir, resume, fsync, fingerprint, planned_steps):
    from olti_drake.hardware.runlog import CampaignLog

    kind = _station_kind(setup.scenario)
    if not resume:
        manifest = {"scenario": os.path.abspath(scenario_path) if scenario_path else None,
                    "station": kind, "seed": setup.scenario.seed, "commands_sha256": fingerprint,
                    "n_steps": int(len(planned_steps.mask)), "readings_planned": int(planned_steps.count)}
        return CampaignLog.create(out_dir, manifest, fsync=fsync, comments=[
            f"olti run: scenario {scenario_path or 'embedded default (paper 000)'}; station {kind}",
            "olti_drake SCARA campaign (shared/spec/formats.md): mm and degrees; dir = approach direction; "
            "valid 0 = no trustworthy reading (kept); step/session/status/reads/rezeros/time: the run log "
            "(docs/runner.md)"])
    log = CampaignLog.reopen(out_dir, fsync=fsync)
    m = log.manifest
    where = os.path.join(out_dir, "run.json")
    if m.get("commands_sha256") != fingerprint or m.get("n_steps") != len(planned_steps.mask):
        log.close()
        raise InputError(f"{where}: the scenario's command sequence differs from the interrupted campaign's "
                         f"(plan, reflectors, steering or seed changed); resume with the same scenario")
    if m.get("station") != kind:
        log.close()
        raise InputError(f"{where}: the campaign ran on a {m.get('station')} station, the scenario now has "
                         f"a {kind} one; resume on the same kind of station")
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


def _resume_state(diagram, context, setup, commands, step: int, log) -> None:
    """Put the diagram where the uninterrupted campaign was at ``step`` (sequencer, station)."""
    seq = diagram.GetSubsystemByName("plan_sequencer")
    seq.GetMyMutableContextFromRoot(context).get_mutable_discrete_state_vector().SetAtIndex(0, step)
    station = diagram.station
    j = int(commands["reflector"][min(step, len(commands["reflector"]) - 1)])
    if step == 0:
        prev_cmd = prev_dir = None
    else:
        k = step - 1
        prev_cmd = np.array([commands["theta1"][k], commands["theta2"][k], 0.0, commands["theta4"][k]])
        prev_dir = np.array([commands["dir1"][k], commands["dir2"][k], 1.0, commands["dir4"][k]])
    if hasattr(station, "resume_at"):          # a device station (emulated or hardware)
        pose = log.zero_pose(j)
        if pose is not None:
            station.zero_poses = {j: pose}
        if prev_cmd is not None:
            station.resume_at(station.GetMyMutableContextFromRoot(context), prev_cmd, prev_dir)
        return
    # The simulated station: the joints' last command and directions, the laser's sample count
    # (its noise is a function of it, so a resumed simulation equals an uninterrupted one).
    if prev_cmd is not None:
        joints = station.GetSubsystemByName("error_map_joint")
        joints.GetMyMutableContextFromRoot(context).get_mutable_discrete_state_vector().SetFromVector(
            np.concatenate([prev_cmd, prev_dir]))
    laser = station.GetSubsystemByName("laser_interferometer")
    laser.GetMyMutableContextFromRoot(context).get_mutable_discrete_state_vector().SetAtIndex(0, step)


def _load(scenario, base_dir=None):
    """(Scenario, its file or None) of a Scenario object, a YAML path or None (the paper default)."""
    from olti_drake.sim.scenario import Scenario, load_scenario

    if isinstance(scenario, Scenario):
        return scenario, getattr(scenario, "source_file", None)
    if scenario is None:
        return load_scenario(None), None
    return load_scenario(scenario), os.fspath(scenario)


def run(scenario, out_dir: str, *, resume: bool = False, should_stop: Optional[Callable[[], object]] = None,
        fsync: bool = True, extend=None, progress: Optional[Callable[[int, int], None]] = None,
        realtime_rate: float = 0.0) -> RunResult:
    """Run (or resume) the scenario's campaign on its station, logging every reading to ``out_dir``.

    ``scenario``: a :class:`~olti_drake.sim.scenario.Scenario`, a scenario YAML path, or None
    (the paper-000 default). ``should_stop()`` is polled between simulator steps (from this
    thread; it may read a flag another thread or a signal handler sets): a truthy value ends the
    session after the reading in progress is on disk, and the result says ``stopped`` (a string
    value is the reason recorded in ``run.json``, e.g. ``"SIGINT"``); ``resume=True`` continues.
    ``progress(on_disk, planned)`` is called after every reading; ``extend`` and
    ``realtime_rate`` as in :func:`~olti_drake.sim.campaign.run_campaign` (e.g. the Meshcat view
    of :mod:`olti_drake.sim.meshcat_view`). Raises
    :class:`~olti_drake.hardware.station.StationError` when the station fails (line lost, alarm,
    ...); every reading taken is on disk either way. Units: mm and degrees in the files.
    """
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import EventStatus

    from olti_drake.sim.campaign import build_campaign_diagram, prepare
    from olti_drake.hardware.runlog import CampaignLog
    from olti_drake.hardware.station import AddStation
    from olti_drake.sim.scenario import Hardware

    scenario, scenario_path = _load(scenario)
    setup = prepare(scenario)
    commands, measured = _plan(setup)
    steps = _Steps(measured)
    if not resume:
        CampaignLog.check_new(out_dir)   # before the station opens
    log = None
    if resume:
        log = _open_log(scenario_path, setup, out_dir, resume, fsync, _fingerprint(setup, commands, measured), steps)
    recorded = log.recorded if log else set()
    todo = np.flatnonzero(measured & ~np.isin(np.arange(len(measured)), sorted(recorded)))
    n_rows = len(setup.plan)
    t0 = time.monotonic()
    if todo.size == 0:
        session = log.session - 1
        if not log.manifest.get("complete"):
            # Every reading is on disk but the last session stopped before saying so (e.g. interrupted
            # after its last reading): this resume completes the campaign on record.
            session = log.session
            log.begin_session(len(measured), station=_station_kind(scenario), resumed=True)
            if not isinstance(scenario.station, Hardware):
                _write_truth(setup, out_dir)
            log.end_session("complete", complete=True, taken=0)
        log.close()
        return RunResult(out_dir, steps.count, len(log.recorded), 0, 0, len(measured), session, 0.0, True)
    # A fresh campaign starts at step 0: the plan's first approach is part of the plan.
    start = int(todo[0]) if recorded else 0
    taken = invalid = 0
    stop = {"reason": None}

    def sink(record, status):
        nonlocal taken, invalid
        step = int(record[0]) * n_rows + int(record[8])
        if step in log.recorded:
            return                      # on disk from an earlier session: never twice
        log.append(step, record, status)
        taken += 1
        invalid += int(record[7] == 0)
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
    diagram, rec, seq = build_campaign_diagram(setup, lambda b, s: AddStation(b, s, session=session),
                                               extend=extend, sink=sink)
    if log is None:
        try:
            log = _open_log(scenario_path, setup, out_dir, resume, fsync, _fingerprint(setup, commands, measured),
                            steps)
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
        _resume_state(diagram, simulator.get_mutable_context(), setup, commands, start, log)
        simulator.set_monitor(monitor)
        simulator.Initialize()
        simulator.AdvanceTo((len(measured) - start) * scenario.period_s)
        complete = log.recorded == set(np.flatnonzero(measured).tolist())
        if stop["reason"] and not complete:
            outcome = f"interrupted ({stop['reason']})"
        else:
            outcome = "complete" if complete else "incomplete"
        if complete and not isinstance(scenario.station, Hardware):
            _write_truth(setup, out_dir)
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
