"""The station as real devices: a robot controller and an interferometer counter behind drivers.

:class:`HardwareStation` is a ``LeafSystem`` with the ports of the simulated
station (:func:`olti_drake.sim.campaign.AddSimulatedStation`) -- inputs ``joint_command`` (4: θ1*, θ2*
rad, J3 m, θ4* rad) and ``reflector`` (1); outputs ``displacement`` (1, m),
``valid`` (1), ``miss`` (1, m: unknown on real devices, always NaN),
``status`` (a :class:`~olti_drake.sim.systems.ReadStatus`), ``direction`` (4, ±1)
and ``measured_position`` (4: the encoder angles, rad/m; the simulated station has no
encoders and gives the commanded positions there) -- but it moves a real robot
(or the emulator, docs/emulator.md) and reads a real counter through two
drivers (:mod:`olti_drake.hardware.drivers`; the olti serial protocol by default).

Timing: one unrestricted update per period at ``period_s / 4``, i.e. after
the sequencer's step at k·T and before the recorder's reading at k·T + T/2.
The update moves and waits in position if the command changed (re-approaching
it from the planned sides after a resume or an alarm), sets up the reflector
(``REFL,<j>`` on the emulator, an operator prompt on hardware) and zeroes the
counter if the reflector changed (retried at the next rows while there is no
beam; the pose where it succeeds is the run's reference pose), then reads the
counter -- with the policy's re-reads and re-zeroings at the reference pose
(:class:`~olti_drake.sim.scenario.RunPolicy`) -- and the encoders. A lost beam is
``valid`` 0 and ``displacement`` NaN, never a made-up value. A device failure
raises :class:`StationError` naming the operation.
"""

from __future__ import annotations

import time
from typing import Callable, Optional

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import AbstractStateIndex, BasicVector, LeafSystem

from olti_drake.io.csvio import InputError
from olti_drake.model.errormap import approach_directions
from olti_drake.hardware.drivers import AlarmActive, DriverError
from olti_drake.hardware.protocol import ProtocolError, expect_ack, movj_fields
from olti_drake.sim.scenario import SEED_STREAMS, stream_seed
from olti_drake.sim.systems import ReadStatus, set_default_name

M_TO_MM = 1e3
REVOLUTE = np.array([True, True, False, True])
#: Longest in-position wait of one move (ms) sent with WAIT.
WAIT_MS = 60000


class StationError(RuntimeError):
    """A request to the robot controller or the counter failed (names the command)."""


def operator_prompt_required(j: int) -> None:
    """The default reflector hook of a hardware station: no operator to ask."""
    raise StationError(f"hardware station: reflector position {j} must be set up by the operator, but no "
                       f"operator prompt was given (pass set_reflector=callable(j) to AddHardwareStation)")


def console_prompt(j: int) -> None:
    """Ask the operator on the console to place the reflector at position ``j``."""
    input(f"Place the reflector at position {j}, aim the beam, then press Enter: ")


class HardwareStation(LeafSystem):
    """The robot and its counter behind the serial protocol, with the simulated station's ports.

    ``robot``, ``counter``: a :class:`~olti_drake.hardware.drivers.RobotDriver` and a
    :class:`~olti_drake.hardware.drivers.CounterDriver`.
    ``set_reflector(j)``: sets up reflector position ``j`` (the emulator's
    ``REFL``, or an operator prompt); it returns once done. ``period_s``:
    the campaign clock (the update runs at ``period_s / 4`` in each period).
    ``policy``: a :class:`~olti_drake.sim.scenario.RunPolicy` (re-reads,
    re-zeroing, alarms). ``on_event(kind, **fields)``: told of every zeroing,
    re-read, re-zeroing, re-approach and alarm (``olti run`` logs them).
    """

    def __init__(self, robot, counter, period_s: float,
                 set_reflector: Optional[Callable[[int], None]] = None, wait_ms: int = WAIT_MS,
                 policy=None, on_event: Optional[Callable[..., None]] = None):
        from olti_drake.sim.scenario import RunPolicy

        super().__init__()
        set_default_name(self)
        self.robot, self.counter = robot, counter
        self.set_reflector = set_reflector or operator_prompt_required
        self.wait_ms = int(wait_ms)
        self.policy = policy or RunPolicy()
        self.on_event = on_event or (lambda kind, **fields: None)
        #: Reference (zero) poses known before the run, {reflector: (command (4,) deg/mm, directions (4,))}:
        #: set by ``olti run --resume`` so that the counter is zeroed where the interrupted run zeroed it.
        self.zero_poses: dict = {}
        self.closers: list = []
        self._alarms_cleared = 0
        self.DeclareVectorInputPort("joint_command", 4)
        self.DeclareVectorInputPort("reflector", 1)
        self.DeclareDiscreteState(_initial_state())
        self.DeclareAbstractState(AbstractValue.Make(ReadStatus()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.25 * period_s, self._update)
        self.DeclareVectorOutputPort("displacement", 1, lambda c, o: self._out(c, o, _DISP))
        self.DeclareVectorOutputPort("valid", 1, lambda c, o: self._out(c, o, _VALID))
        self.DeclareVectorOutputPort("miss", 1, lambda c, o: o.SetAtIndex(0, np.nan))
        self.DeclareStateOutputPort("status", AbstractStateIndex(0))
        self.DeclareVectorOutputPort("direction", 4, lambda c, o: self._out(c, o, _DIRS))
        self.DeclareVectorOutputPort("measured_position", 4, lambda c, o: self._out(c, o, _ENCODER))

    def _out(self, context, output: BasicVector, part: slice):
        output.SetFromVector(context.get_discrete_state_vector().value()[part])

    def resume_at(self, context, last_command, last_directions) -> None:
        """Continue an interrupted campaign: the robot is somewhere unknown.

        ``last_command`` (4, deg/mm) and ``last_directions`` (4, ±1) are the
        plan's previous row, so the next command gets the plan's approach
        directions; the first move is a re-approach that makes the robot
        arrive from those sides (``policy.approach_overrun_deg``).
        """
        x = _initial_state()
        x[_LAST], x[_DIRS], x[_REAPPROACH] = last_command, last_directions, 1.0
        context.get_mutable_discrete_state_vector().SetFromVector(x)

    def _do(self, what: str, call, *args):
        """One driver call; a device failure becomes a StationError naming the operation."""
        try:
            return call(*args)
        except (ProtocolError, DriverError) as e:
            if isinstance(e, AlarmActive):
                raise
            raise StationError(f"station: {what} failed: {type(e).__name__}: {e}") from None

    def _movj_wait(self, cmd) -> None:
        """Move and wait in position; an alarm becomes :class:`AlarmActive` (handled by ``_move``)."""
        what = f"robot move to {_joints_text(cmd)}"
        self._do(what, self.robot.move, cmd)
        self._do(what + " (wait in position)", self.robot.wait, self.wait_ms)

    def _handle_alarm(self, cmd) -> None:
        codes = self._do("robot alarm report", self.robot.alarms)
        self.on_event("alarm", codes=list(codes), command=list(cmd))
        if self._alarms_cleared >= self.policy.clear_alarms:
            raise StationError(f"station: controller alarm {' '.join(codes) or '(no code)'} at the move to "
                               f"{_joints_text(cmd)}; the policy clears at most {self.policy.clear_alarms}: "
                               f"remove the cause, clear it, then resume")
        left = self._do("robot alarm clear", self.robot.alarms, True)
        if left:
            raise StationError(f"station: controller alarm {' '.join(left)} cannot be cleared")
        self._alarms_cleared += 1
        self.on_event("alarm_cleared", codes=list(codes))

    def _move(self, cmd, directions, approach: bool) -> None:
        """Go to ``cmd`` (deg/mm); with ``approach``, arrive in ``directions`` from the overrun point.

        A move stopped by an alarm (cleared per the policy) is redone as a re-approach, since the
        robot stopped somewhere on the way and the approach side must be re-established.
        """
        while True:
            try:
                if approach:
                    before = cmd - np.where(REVOLUTE, directions * self.policy.approach_overrun_deg, 0.0)
                    self._movj_wait(before)
                self._movj_wait(cmd)
                return
            except AlarmActive:
                self._handle_alarm(cmd)
                approach = True

    # ---------------------------------------------------------------- counter

    def _zero(self, x) -> bool:
        """Zero the counter at the current pose; False while it has no beam."""
        if not self._do("counter zero", self.counter.zero):
            return False
        x[_ZEROED] = 1.0
        return True

    def _rezero(self, x, j: int) -> None:
        """Zero again at the run's reference pose, approached as when it was first zeroed, then return."""
        ref_cmd, ref_dirs = x[_ZERO_CMD], x[_ZERO_DIRS]
        self._move(ref_cmd, ref_dirs, approach=True)
        if not self._zero(x):
            raise StationError(f"station: the counter has no beam at the reference pose of reflector {j} "
                               f"(where the run was zeroed): check the reflector, then resume")
        self.on_event("zero", reflector=j, command=list(ref_cmd), directions=list(ref_dirs), again=True)
        self._move(x[_LAST], x[_DIRS], approach=True)

    def _read(self, x, j: int):
        """READ with the policy's re-reads and re-zeroings; returns (reading, ReadStatus)."""
        reads = rezeros = 0
        if x[_ZEROED] < 0.5:   # no zero yet (no beam at this run's poses so far): nothing to retry
            reading = self._do("counter read", self.counter.read)
            return reading, ReadStatus(reading.status, 1, 0)
        while True:
            for _ in range(1 + self.policy.rereads):
                if reads and self.policy.reread_delay_s > 0:
                    time.sleep(self.policy.reread_delay_s)
                reading = self._do("counter read", self.counter.read)
                reads += 1
                if reading.valid:
                    return reading, ReadStatus(reading.status, reads, rezeros)
                self.on_event("invalid_reading", reflector=j, status=reading.status, reads=reads)
            if rezeros >= self.policy.rezeros or np.isnan(x[_ZERO_CMD][0]):
                return reading, ReadStatus(reading.status, reads, rezeros)
            self._rezero(x, j)
            rezeros += 1

    # ---------------------------------------------------------------- the period

    def _update(self, context, state):
        x = context.get_discrete_state_vector().value().copy()
        u = self.get_input_port(0).Eval(context)
        cmd = np.where(REVOLUTE, np.degrees(u), np.asarray(u) * M_TO_MM)
        j = int(self.get_input_port(1).Eval(context)[0])
        last = x[_LAST].copy()
        # The approach directions of the commands sent, by the spec's rule (as ErrorMapJoint).
        x[_DIRS] = approach_directions(cmd[None], last, x[_DIRS])[0]
        x[_LAST] = cmd
        if x[_REAPPROACH] > 0.5:
            self.on_event("reapproach", command=list(cmd), directions=list(x[_DIRS]))
            self._move(cmd, x[_DIRS], approach=True)
            x[_REAPPROACH] = 0.0
        elif np.any(np.isnan(last)) or movj_fields(*cmd) != movj_fields(*last):
            self._move(cmd, x[_DIRS], approach=False)
        if j != int(x[_REFLECTOR]):
            try:
                self.set_reflector(j)
            except (ProtocolError, DriverError) as e:
                raise StationError(f"station: setting up reflector {j} failed: {type(e).__name__}: {e}") from None
            x[_REFLECTOR], x[_ZEROED] = j, 0.0
            known = self.zero_poses.get(j)
            x[_ZERO_CMD], x[_ZERO_DIRS] = known if known is not None else (np.nan, np.nan)
        if x[_ZEROED] < 0.5:
            if not np.isnan(x[_ZERO_CMD][0]):
                self._rezero(x, j)     # resuming: zero where the interrupted run did
            elif self._zero(x):
                # Zero at the first pose of the run where the beam reaches the counter: until then
                # (NAK BEAM) the readings are invalid, as the counter says. This pose is the run's
                # reference: a re-zeroing returns here.
                x[_ZERO_CMD], x[_ZERO_DIRS] = cmd, x[_DIRS]
                self.on_event("zero", reflector=j, command=list(cmd), directions=list(x[_DIRS]), again=False)
        reading, status = self._read(x, j)
        x[_DISP] = reading.displacement_mm / M_TO_MM if reading.valid else np.nan
        x[_VALID] = 1.0 if reading.valid else 0.0
        enc = self._do("robot position", self.robot.position).encoder
        q = np.array([enc.theta1_deg, enc.theta2_deg, enc.z_mm, enc.theta4_deg])
        x[_ENCODER] = np.where(REVOLUTE, np.radians(q), q / M_TO_MM)
        state.get_mutable_discrete_state().set_value(x)
        state.get_mutable_abstract_state(0).set_value(status)

    def close(self) -> None:
        """Close what the station opened (serial ports, an emulator), last opened first."""
        while self.closers:
            try:
                self.closers.pop()()
            except Exception:  # closing is best effort
                pass


def _joints_text(cmd) -> str:
    return "(" + ", ".join(f"{v:.6f}" for v in cmd) + ") deg/mm"


# The station's discrete state: last command sent (4, deg/mm; NaN = none), directions (4), reflector
# set up (-1 = none), displacement (m), valid, encoder position (4, rad/m), counter zeroed since the
# reflector was set up, the run's reference (zero) pose: command (4) and directions (4), and
# "re-approach the next command" (after a resume).
_LAST, _DIRS, _REFLECTOR, _DISP, _VALID = slice(0, 4), slice(4, 8), 8, slice(9, 10), slice(10, 11)
_ENCODER, _ZEROED, _ZERO_CMD, _ZERO_DIRS, _REAPPROACH = slice(11, 15), 15, slice(16, 20), slice(20, 24), 24


def _initial_state() -> np.ndarray:
    return np.concatenate([np.full(4, np.nan), np.ones(4), [-1.0, np.nan, 0.0], np.full(4, np.nan), [0.0],
                           np.full(8, np.nan), [0.0]])


def AddStation(builder, setup, name: str = "station", session: int = 0):
    """Add the station the scenario names (``setup.scenario.station``) to ``builder``; returns it.

    The one place that decides simulated or real, as Drake's ``MakeHardwareStation``: ``Simulated``
    -> :func:`olti_drake.sim.campaign.AddSimulatedStation` (a Diagram), ``Emulated`` ->
    :func:`AddEmulatedStation`, ``Hardware`` -> :func:`AddRealStation` (operator prompt on the
    console). All have the same ports (the simulated one adds ``true_position`` and
    ``query_object``); an emulated or hardware station's ``close()`` releases its ports.
    ``session``: 0 for a campaign's first run, n for its n-th resumption (``olti run --resume``):
    an emulator then draws fresh noise.
    """
    from olti_drake.sim.campaign import AddSimulatedStation
    from olti_drake.sim.scenario import Emulated, Hardware

    if isinstance(setup.scenario.station, Emulated):
        return AddEmulatedStation(builder, setup, name, session)
    if isinstance(setup.scenario.station, Hardware):
        return AddRealStation(builder, setup, console_prompt, name)
    return AddSimulatedStation(builder, setup, name)


def AddHardwareStation(builder, setup, devices, set_reflector=None, name: str = "station", policy=None):
    """Add a :class:`HardwareStation` on ``devices`` = (robot, counter) drivers to ``builder``; returns it."""
    robot, counter = devices
    station = builder.AddNamedSystem(name, HardwareStation(robot, counter, setup.scenario.period_s,
                                                           set_reflector, policy=policy))
    return station


#: Noise stream of an emulator started for a resumed session (sim.scenario.SEED_STREAMS).
STREAM_EMULATOR = SEED_STREAMS["emulator_session"]


def AddEmulatedStation(builder, setup, name: str = "station", session: int = 0):
    """Start an in-process Emulator on the setup and add a station driving it through its ptys.

    ``session`` > 0 (a resumed campaign) seeds the emulator's noise and faults afresh.
    """
    from olti_drake.hardware.emulator import Emulator

    cfg = setup.scenario.station
    seed = None if session == 0 else stream_seed(setup.scenario.seed, STREAM_EMULATOR, session)
    emu = Emulator(setup, speed=cfg.speed, seed=seed, faults=cfg.faults(),
                   latch_beam_loss=cfg.latch_beam_loss).start()
    closers = [emu.stop]

    def refl(counter, j):
        expect_ack(counter.transport.request("REFL", str(int(j))))

    station = _open_station(builder, setup, cfg, emu.robot_port, emu.counter_port, 115200, closers, refl, name)
    station.emulator = emu
    return station


def AddRealStation(builder, setup, set_reflector=None, name: str = "station"):
    """Open the scenario's serial ports and add a station driving the real devices."""
    cfg = setup.scenario.station
    hook = None if set_reflector is None else (lambda counter, j: set_reflector(j))
    return _open_station(builder, setup, cfg, cfg.robot_port, cfg.counter_port, cfg.baud, [], hook, name)


def _open_station(builder, setup, cfg, robot_port, counter_port, baud, closers, set_reflector, name):
    """Open both devices with the scenario's drivers, add the station; close everything on failure.

    ``set_reflector(counter, j)`` readies reflector j (None: the station refuses a change).
    """
    from olti_drake.hardware.drivers import driver_class

    names = (getattr(cfg, "robot_driver", "olti"), getattr(cfg, "counter_driver", "olti"))
    try:
        devices = []
        for kind, (port, what) in enumerate(((robot_port, "robot"), (counter_port, "counter"))):
            try:
                cls = driver_class(names[kind], kind)
            except ValueError as e:
                raise InputError(f"station: {what}_driver: {e}") from None
            try:
                devices.append(cls.open(port, baud, cfg.timeout_s, cfg.retries))
            except DriverError as e:
                raise StationError(f"station: {e}") from None
            closers.append(devices[-1].close)
        robot, counter = devices
        # A counter driver that knows the reflector set-up (a test bench) does it; else the hook (operator).
        hook = getattr(counter, "set_up_reflector", None) or (
            None if set_reflector is None else (lambda j: set_reflector(counter, j)))
        station = AddHardwareStation(builder, setup, (robot, counter), hook, name, policy=cfg.policy)
    except BaseException:
        for c in reversed(closers):
            c()
        raise
    station.closers = closers
    return station
