"""The laser-tracker station: a six-axis campaign measured open loop by an emScon tracker (docs/tracker.md).

The paper's idea on a commercial tracker: for each planned command the station moves the robot (the olti
robot driver, :class:`~olti_drake.hardware.station.HardwareStation`'s moves and re-approaches), points the
beam with ``PointLaser`` at where the COMMAND says the cat's eye is -- the nominal forward kinematics of the
command and the nominal tool offset, in the tracker frame of the tracker's nominal placement -- and runs
``StartMeasurement``. The reading is the tracker's point (x, y, z mm, tracker frame: formats.md "Point
campaign (laser tracker)") with the environment the tracker used (°C, hPa, %RH), logged with every row.
A beam interruption (:class:`~olti_drake.hardware.emscon.BeamLost`) is an event ``beam_interrupted`` in
``events.jsonl``; the station points again and measures again up to ``policy.rereads`` times, and a row
still without beam is logged ``valid`` 0 with NaN coordinates: never a reading.

The plan: the scenario's floor-tracer plan rules with the tracker as the only station (a pose is kept when
the cat's eye sees the tracker past the arm, ``min_stations`` 1), each pose approached from its planned
side (:func:`olti_drake.sim.serial_station.prepare_serial`).

Units: mm and degrees at the devices and in the files; the Drake ports in m and rad.
"""

from __future__ import annotations

import copy
import dataclasses
import time

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import DiagramBuilder

from olti_drake.hardware.emscon import BeamLost, EmsconTracker
from olti_drake.hardware.protocol import ProtocolError, Reading
from olti_drake.hardware.station import M_TO_MM, HardwareStation, StationError
from olti_drake.model.frames import XYZ_CONVENTION, into_frame, xyz_rotation
from olti_drake.sim.scenario import stream_seed
from olti_drake.sim.systems import ReadingRecorder, ReadStatus, RowSequencer

#: The tracker-frame convention (as PointMeasurement's tracker_frame).
CONVENTION = XYZ_CONVENTION


def tracker_frame(position_mm, rotation_deg) -> np.ndarray:
    """The frame (6: t mm, angles deg) of a tracker at ``position_mm`` (robot base frame) turned by
    ``rotation_deg``: m = R (p − position) = R p + t, t = −R·position."""
    rot, _ = xyz_rotation(rotation_deg)
    return np.concatenate([-rot @ np.asarray(position_mm, float), np.asarray(rotation_deg, float)])


def base_to_tracker(points_mm, frame) -> np.ndarray:
    """Robot-base points (M, 3) mm in the tracker frame ``frame`` (the inverse of ``model.serial.tracker_to_base``)."""
    return into_frame(points_mm, frame)


def prepare_tracker(scenario):
    """The six-axis setup of a ``station: !Tracker`` scenario: the plan with the tracker as the one station
    (at its emulated true place, estimated at its nominal one), ``tracker_nominal`` and ``tracker_true``
    (frames, 6) and ``add_station`` (:func:`AddTrackerStation`, for ``AddStation``) set on it, the scenario
    (with its tracker) as given."""
    from olti_drake.sim.serial_station import prepare_serial

    cfg = scenario.station
    position = np.asarray(cfg.position_mm, float)
    true_position = position + np.asarray(cfg.emulator_offset_mm, float)
    inner = copy.deepcopy(scenario)
    inner.scheme = dataclasses.replace(scenario.scheme, stations_mm=[true_position.tolist()],
                                       stations_estimate_mm=[position.tolist()], zeros_deg=[], zeros_estimate_deg=[])
    inner.plan.min_stations = 1
    setup = dataclasses.replace(prepare_serial(inner), scenario=scenario)
    setup.tracker_nominal = tracker_frame(position, cfg.rotation_deg)
    setup.tracker_true = tracker_frame(true_position, np.add(cfg.rotation_deg, cfg.emulator_rotation_deg))
    setup.add_station = AddTrackerStation       # what AddStation adds for this setup
    return setup


def nominal_targets(setup, commands_deg) -> np.ndarray:
    """Where the commands (M, N) deg put the cat's eye by the nominal model, in the nominal tracker frame (mm)."""
    chain = setup.chain
    p = chain.positions(np.atleast_2d(commands_deg), chain.nominal_parameters(setup.tool_offset_mm))
    return base_to_tracker(p, setup.tracker_nominal)


class _AbsoluteDistance:
    """The counter of a tracker station: an absolute instrument has no zero to set (no dead path)."""

    def zero(self) -> bool:
        return True


class TrackerStation(HardwareStation):
    """The robot and an emScon tracker, with the hardware station's ports plus the input ``measure`` (1: the
    sequencer's; an approach row is moved to, not measured) and the outputs ``point`` (3, m: the tracker's point,
    tracker frame; NaN without beam) and ``environment`` (3: °C, hPa, %RH); ``displacement`` is the tracker's
    distance to the point (m). ``tracker``: an :class:`~olti_drake.hardware.emscon.EmsconTracker`."""

    def __init__(self, robot, tracker, setup, period_s: float, policy=None, on_event=None):
        super().__init__(robot, _AbsoluteDistance(), period_s, set_reflector=lambda j: None, policy=policy,
                         on_event=on_event)
        self.tracker, self.setup = tracker, setup
        self._measurement = np.full(6, np.nan)
        self._measure_port = self.DeclareVectorInputPort("measure", 1)   # approach rows: no measurement
        self._reading = self.DeclareAbstractState(AbstractValue.Make(np.full(6, np.nan)))
        self.DeclareVectorOutputPort("point", 3, lambda c, o: o.SetFromVector(self._value(c)[:3] / M_TO_MM))
        self.DeclareVectorOutputPort("environment", 3, lambda c, o: o.SetFromVector(self._value(c)[3:]))

    def _value(self, context) -> np.ndarray:
        return context.get_abstract_state(self._reading).get_value()

    def _tracker(self, what: str, call, *args):
        """One tracker request; BeamLost passes, any other failure is a StationError naming it."""
        try:
            return call(*args)
        except BeamLost:
            raise
        except (ProtocolError, OSError) as e:
            raise StationError(f"station: tracker {what} failed: {type(e).__name__}: {e}") from None

    def _read(self, x, j: int):
        """Point at the commanded tool point, measure; re-point and measure again after a beam interruption."""
        if not self._measuring:          # an approach row: the beam waits for the pose that is measured
            self._measurement = np.full(6, np.nan)
            return Reading(np.nan, False, "-"), ReadStatus("-", 0, 0)
        cmd = x[self.s.last]
        target = nominal_targets(self.setup, cmd)[0]
        status = "0"
        for attempt in range(1 + self.policy.rereads):
            if attempt and self.policy.reread_delay_s > 0:
                time.sleep(self.policy.reread_delay_s)     # e.g. a person walking through the beam
            try:
                self._tracker("PointLaser", self.tracker.point_laser, target)
                m = self._tracker("StartMeasurement", self.tracker.measure)
            except BeamLost as e:
                status = str(e.status)
                self.on_event("beam_interrupted", status=e.status, attempt=attempt + 1, command=list(cmd),
                              target_mm=list(target))
                continue
            self._measurement = np.array(m.point_mm + m.environment)
            return Reading(m.spherical()[2], True, status), ReadStatus(status, attempt + 1, 0)
        env = self._tracker("GetEnvironmentParams", self.tracker.environment)
        self._measurement = np.concatenate([np.full(3, np.nan), env])
        return Reading(np.nan, False, status), ReadStatus(status, 1 + self.policy.rereads, 0)

    def _update(self, context, state):
        self._measuring = self._measure_port.Eval(context)[0] > 0.5
        super()._update(context, state)
        state.get_mutable_abstract_state(self._reading).set_value(self._measurement.copy())

    def _rezero(self, x, j: int) -> None:
        x[self.s.zeroed] = 1.0          # nothing to return to: the tracker measures absolute distances

    def _zero_event(self, x, j: int, again: bool) -> None:
        pass                            # no counter zero, no reference pose


class TrackerRecorder(ReadingRecorder):
    """The measured rows of a tracker campaign: (θ1*..θN* deg, dir1..dirN, x, y, z mm (NaN without beam),
    valid, temperature °C, pressure hPa, humidity %RH, plan row)."""

    def __init__(self, n_joints: int, period_s: float):
        super().__init__(period_s, 0.5 * period_s)
        for name, size in (("joint_command", n_joints), ("direction", n_joints), ("point", 3), ("valid", 1),
                           ("environment", 3), ("measure", 1), ("row", 1)):
            self.DeclareVectorInputPort(name, size)
        self.DeclareAbstractInputPort("status", AbstractValue.Make(ReadStatus()))

    def record(self, context):
        if self.GetInputPort("measure").Eval(context)[0] < 0.5:
            return None
        cmd, direction, point, valid, env, _, row = (self.get_input_port(i).Eval(context) for i in range(7))
        ok = valid[0] > 0.5
        xyz = tuple(point * M_TO_MM) if ok else (np.nan,) * 3
        return (tuple(np.degrees(cmd)) + tuple(int(d) for d in direction) + xyz + (int(ok),) + tuple(env)
                + (int(row[0]),))


def build_tracker_diagram(setup, station_factory, sink=None):
    """The tracker campaign as a Diagram: RowSequencer -> station -> TrackerRecorder; (diagram, recorder,
    sequencer). ``sink(record, status)`` is told of every row as it is taken (``olti run`` writes it)."""
    s = setup.scenario
    builder = DiagramBuilder()
    station = station_factory(builder, setup)
    seq = builder.AddNamedSystem("plan_sequencer", RowSequencer({
        "joint_command": np.radians(setup.commands_deg), "reflector": setup.reflector.astype(float),
        "measure": setup.measure.astype(float), "row": setup.row.astype(float)}, s.period_s))
    rec = builder.AddNamedSystem("campaign_recorder", TrackerRecorder(setup.n_joints, s.period_s))
    for port in ("joint_command", "reflector", "measure"):
        builder.Connect(seq.GetOutputPort(port), station.GetInputPort(port))
    for port in ("joint_command", "measure", "row"):
        builder.Connect(seq.GetOutputPort(port), rec.GetInputPort(port))
    for port in ("direction", "point", "valid", "environment", "status"):
        builder.Connect(station.GetOutputPort(port), rec.GetInputPort(port))
    diagram = builder.Build()
    diagram.station = station
    if sink is not None:
        status = rec.GetInputPort("status")
        rec.on_record = lambda context, record: sink(record, status.Eval(context))
    return diagram, rec, seq


# ------------------------------------------------------------------ devices

def tracker_emulators_for(setup, session: int = 0, port: int = 0):
    """The robot emulator (N joints, the scenario's truth) and the tracker emulator (on 127.0.0.1:``port``, 0:
    an ephemeral one) whose reflector is that robot's true tool point in the true tracker frame; neither
    started. Session k > 0 draws fresh noise."""
    from olti_drake.hardware.station import serial_emulator_for
    from olti_drake.hardware.tracker_emulator import TrackerEmulator
    from olti_drake.sim.scenario import Emulated

    s, cfg = setup.scenario, setup.scenario.station
    robot = serial_emulator_for(setup, None if session == 0 else stream_seed(s.seed, "emulator_session", session),
                                Emulated())
    truth = setup.truth

    def reflector():
        return base_to_tracker(truth.chain.positions(robot.actual_angles()[None], truth.chain_params),
                               setup.tracker_true)[0]

    tracker = TrackerEmulator(reflector=reflector, seed=stream_seed(s.seed, "tracker", session),
                              capture_mm=cfg.capture_mm, u_const_um=cfg.u_const_um, u_per_m_um=cfg.u_per_m_um,
                              coverage_k=cfg.coverage_k, beam_break=cfg.beam_break,
                              reflector_lost=cfg.reflector_lost, environment=cfg.environment, drift=cfg.drift,
                              port=port)
    return robot, tracker


def AddTrackerStation(builder, setup, name: str = "station", session: int = 0):
    """Open the robot controller and the tracker the scenario's ``!Tracker`` names (or start both emulators,
    ``host`` empty), initialize the tracker (units mm, deg, °C, hPa) and add the :class:`TrackerStation`."""
    from olti_drake.hardware.drivers import DriverError, driver_class

    cfg = setup.scenario.station
    closers, emulator = [], None
    try:
        host, port, robot_port = cfg.host, cfg.port, cfg.robot_port
        if not host:
            robot_emu, emulator = tracker_emulators_for(setup, session)
            robot_emu.start()
            closers.append(robot_emu.stop)
            emulator.start()
            closers.append(emulator.stop)
            host, port, robot_port = "127.0.0.1", emulator.port, robot_emu.robot_port
        try:
            robot = driver_class(cfg.robot_driver, 0).open(robot_port, cfg.baud, cfg.timeout_s, cfg.retries)
            closers.append(robot.close)
            tracker = EmsconTracker.open(host, port, cfg.timeout_s)
            closers.append(tracker.close)
            tracker.initialize()
        except (DriverError, ProtocolError, OSError) as e:
            raise StationError(f"station: {type(e).__name__}: {e}") from None
        station = builder.AddNamedSystem(name, TrackerStation(robot, tracker, setup, setup.scenario.period_s,
                                                              policy=cfg.policy))
    except BaseException:
        for c in reversed(closers):
            c()
        raise
    station.closers, station.emulator = closers, emulator
    return station


def tracker_truth(setup, out_dir: str) -> None:
    """``truth.json`` of a complete emulated tracker campaign (serial result format): the robot's truth and
    the TRUE tracker frame (``tracker_frame``, as an identified point campaign's); one already there is kept."""
    import os

    from olti_drake.io.csvio import read_table
    from olti_drake.io.outputs import write_json
    from olti_drake.sim.serial_station import serial_truth_result

    path = os.path.join(out_dir, "truth.json")
    if os.path.exists(path):
        return
    names = [f"theta{i + 1}_deg" for i in range(setup.n_joints)] + ["valid"]
    out = serial_truth_result(setup, read_table(os.path.join(out_dir, "campaign.csv"), tuple(names)))
    for key in ("stations_mm", "dead_paths_mm"):
        out.pop(key, None)
    frame = setup.tracker_true
    out["tracker_frame"] = {"translation_mm": frame[:3].tolist(), "rotation_deg": frame[3:].tolist(),
                            "convention": CONVENTION}
    write_json(path, out, measurement=True)
