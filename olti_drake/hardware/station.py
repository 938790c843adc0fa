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

N joints: the station takes its joint count and joint kinds from the robot driver's ``layout``
(:class:`~olti_drake.hardware.protocol.AxisLayout`, announced by a version-2 controller; a driver
without one is the SCARA's): ``joint_command``, ``direction`` and ``measured_position`` then have N
entries. Floor tracers: when the counter driver can aim (``aim``: the pan/tilt heads of
:class:`~olti_drake.hardware.drivers.TracerHeads`), the ``reflector`` input selects the head, the
input ``head_command`` (2: pan, tilt rad) aims it before it is zeroed or read, and the output
``head_position`` (2, rad) gives its encoders; a re-zeroing also re-aims the head where it was zeroed.
"""

from __future__ import annotations

import time
from typing import Callable, Optional

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import AbstractStateIndex, BasicVector, LeafSystem

from olti_drake.errors import InputError
from olti_drake.model.errormap import approach_directions
from olti_drake.hardware.drivers import AlarmActive, DriverError
from olti_drake.hardware.protocol import SCARA_LAYOUT, ProtocolError, expect_ack
from olti_drake.sim.scenario import SEED_STREAMS, stream_seed
from olti_drake.sim.serial_scenario import scenario_kind
from olti_drake.sim.systems import ReadStatus, set_default_name

M_TO_MM = 1e3
REVOLUTE = np.array(SCARA_LAYOUT.revolute)   # the SCARA's joints (θ1, θ2, z, θ4)
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
    ``command_port``, ``selector_port``: the names of the first two inputs (the 3D machine tool's
    station calls them ``target_command`` and ``station``, as its simulated station does).
    """

    def __init__(self, robot, counter, period_s: float,
                 set_reflector: Optional[Callable[[int], None]] = None, wait_ms: int = WAIT_MS,
                 policy=None, on_event: Optional[Callable[..., None]] = None,
                 command_port: str = "joint_command", selector_port: str = "reflector"):
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
        self.layout = getattr(robot, "layout", None) or SCARA_LAYOUT
        n = self.layout.n
        self.revolute = np.array(self.layout.revolute)
        self._lower, self._upper = (np.array([getattr(a, k) for a in self.layout.axes], float)
                                    for k in ("lower", "upper"))
        self.heads = callable(getattr(counter, "aim", None))
        self.s = _StateLayout(n)
        self.DeclareVectorInputPort(command_port, n)
        self.DeclareVectorInputPort(selector_port, 1)
        if self.heads:
            self.DeclareVectorInputPort("head_command", 2)
        self.DeclareDiscreteState(self.s.initial())
        self.DeclareAbstractState(AbstractValue.Make(ReadStatus()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.25 * period_s, self._update)
        self.DeclareVectorOutputPort("displacement", 1, lambda c, o: self._out(c, o, self.s.disp))
        self.DeclareVectorOutputPort("valid", 1, lambda c, o: self._out(c, o, self.s.valid))
        self.DeclareVectorOutputPort("miss", 1, lambda c, o: o.SetAtIndex(0, np.nan))
        self.DeclareStateOutputPort("status", AbstractStateIndex(0))
        self.DeclareVectorOutputPort("direction", n, lambda c, o: self._out(c, o, self.s.dirs))
        self.DeclareVectorOutputPort("measured_position", n, lambda c, o: self._out(c, o, self.s.encoder))
        if self.heads:
            self.DeclareVectorOutputPort("head_position", 2, lambda c, o: self._out(c, o, self.s.head_encoder))

    def _out(self, context, output: BasicVector, part: slice):
        output.SetFromVector(context.get_discrete_state_vector().value()[part])

    def resume_at(self, context, last_command, last_directions) -> None:
        """Continue an interrupted campaign: the robot is somewhere unknown.

        ``last_command`` (N, deg/mm) and ``last_directions`` (N, ±1) are the
        plan's previous row, so the next command gets the plan's approach
        directions; the first move is a re-approach that makes the robot
        arrive from those sides (``policy.approach_overrun_deg``).
        """
        x = self.s.initial()
        x[self.s.last], x[self.s.dirs], x[self.s.reapproach] = last_command, last_directions, 1.0
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
                    before = cmd - np.where(self.revolute, directions * self.policy.approach_overrun_deg, 0.0)
                    # Within the travel (a rotary axis near its limit is still approached from the planned side:
                    # a pose at the limit was reached from inside).
                    self._movj_wait(np.clip(before, self._lower, self._upper))
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
        x[self.s.zeroed] = 1.0
        return True

    def _aim(self, aim_deg) -> None:
        """Aim the selected tracer head (pan, tilt deg) and wait until it is there."""
        what = f"head aim at ({aim_deg[0]:.6f}, {aim_deg[1]:.6f}) deg"
        self._do(what, self.counter.aim, aim_deg)
        self._do(what + " (wait in position)", self.counter.wait, self.wait_ms)

    def _zero_event(self, x, j: int, again: bool) -> None:
        aim = {"aim": list(x[self.s.zero_aim])} if self.heads else {}
        self.on_event("zero", reflector=j, command=list(x[self.s.zero_cmd]), directions=list(x[self.s.zero_dirs]),
                      again=again, **aim)

    def _rezero(self, x, j: int) -> None:
        """Zero again at the run's reference pose, approached as when it was first zeroed (a tracer
        head aimed as then), then return."""
        s = self.s
        self._move(x[s.zero_cmd], x[s.zero_dirs], approach=True)
        if self.heads:
            self._aim(x[s.zero_aim])
        if not self._zero(x):
            raise StationError(f"station: the counter has no beam at the reference pose of reflector {j} "
                               f"(where the run was zeroed): check the reflector, then resume")
        self._zero_event(x, j, again=True)
        self._move(x[s.last], x[s.dirs], approach=True)
        if self.heads:
            self._aim(x[s.aim])

    def _read(self, x, j: int):
        """READ with the policy's re-reads and re-zeroings; returns (reading, ReadStatus)."""
        reads = rezeros = 0
        if x[self.s.zeroed] < 0.5:   # no zero yet (no beam at this run's poses so far): nothing to retry
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
            if rezeros >= self.policy.rezeros or np.isnan(x[self.s.zero_cmd][0]):
                return reading, ReadStatus(reading.status, reads, rezeros)
            self._rezero(x, j)
            rezeros += 1

    # ---------------------------------------------------------------- the period

    def _update(self, context, state):
        s = self.s
        x = context.get_discrete_state_vector().value().copy()
        u = self.get_input_port(0).Eval(context)
        cmd = np.where(self.revolute, np.degrees(u), np.asarray(u) * M_TO_MM)
        j = int(self.get_input_port(1).Eval(context)[0])
        last = x[s.last].copy()
        # The approach directions of the commands sent, by the spec's rule (as ErrorMapJoint).
        x[s.dirs] = approach_directions(cmd[None], last, x[s.dirs])[0]
        x[s.last] = cmd
        if x[s.reapproach] > 0.5:
            self.on_event("reapproach", command=list(cmd), directions=list(x[s.dirs]))
            self._move(cmd, x[s.dirs], approach=True)
            x[s.reapproach] = 0.0
        elif np.any(np.isnan(last)) or self._wire(cmd) != self._wire(last):
            self._move(cmd, x[s.dirs], approach=False)
        if j != int(x[s.reflector]):
            try:
                self.set_reflector(j)
            except (ProtocolError, DriverError) as e:
                raise StationError(f"station: setting up reflector {j} failed: {type(e).__name__}: {e}") from None
            x[s.reflector], x[s.zeroed] = j, 0.0
            known = self.zero_poses.get(j)
            x[s.zero_cmd], x[s.zero_dirs] = known[:2] if known is not None else (np.nan, np.nan)
            x[s.zero_aim] = known[2] if known is not None and len(known) > 2 else np.nan
        if self.heads:
            x[s.aim] = np.degrees(self.get_input_port(2).Eval(context))
            self._aim(x[s.aim])
        if x[s.zeroed] < 0.5:
            if not np.isnan(x[s.zero_cmd][0]):
                self._rezero(x, j)     # resuming: zero where the interrupted run did
            elif self._zero(x):
                # Zero at the first pose of the run where the beam reaches the counter: until then
                # (NAK BEAM) the readings are invalid, as the counter says. This pose is the run's
                # reference: a re-zeroing returns here.
                x[s.zero_cmd], x[s.zero_dirs], x[s.zero_aim] = cmd, x[s.dirs], x[s.aim]
                self._zero_event(x, j, again=False)
        reading, status = self._read(x, j)
        x[s.disp] = reading.displacement_mm / M_TO_MM if reading.valid else np.nan
        x[s.valid] = 1.0 if reading.valid else 0.0
        q = np.array(tuple(self._do("robot position", self.robot.position).encoder), dtype=float)
        x[s.encoder] = np.where(self.revolute, np.radians(q), q / M_TO_MM)
        if self.heads:
            x[s.head_encoder] = np.radians(tuple(self._do("head position", self.counter.position).encoder))
        state.get_mutable_discrete_state().set_value(x)
        state.get_mutable_abstract_state(0).set_value(status)

    def _wire(self, cmd) -> tuple:
        """The command as sent (6 decimals per joint): a move is needed only if this changes."""
        return self.layout.fields(cmd, check_range=False)

    def close(self) -> None:
        """Close what the station opened (serial ports, an emulator), last opened first."""
        while self.closers:
            try:
                self.closers.pop()()
            except Exception:  # closing is best effort
                pass


def _joints_text(cmd) -> str:
    return "(" + ", ".join(f"{v:.6f}" for v in cmd) + ") deg/mm"


class _StateLayout:
    """The station's discrete state for n joints: last command sent (n, deg/mm; NaN = none),
    directions (n), reflector set up (-1 = none), displacement (m), valid, encoder position (n,
    rad/m), counter zeroed since the reflector was set up, the run's reference (zero) pose: command
    (n) and directions (n), "re-approach the next command" (after a resume); tracer heads: the aim
    sent (2, deg), the aim at the zero (2, deg), the head encoders (2, rad)."""

    def __init__(self, n: int):
        sizes = (("last", n), ("dirs", n), ("reflector", None), ("disp", 1), ("valid", 1), ("encoder", n),
                 ("zeroed", None), ("zero_cmd", n), ("zero_dirs", n), ("reapproach", None), ("aim", 2),
                 ("zero_aim", 2), ("head_encoder", 2))
        k = 0
        for name, size in sizes:
            setattr(self, name, k if size is None else slice(k, k + size))
            k += 1 if size is None else size
        self.n, self.size = n, k

    def initial(self) -> np.ndarray:
        x = np.full(self.size, np.nan)
        x[self.dirs] = 1.0
        x[self.reflector], x[self.valid], x[self.zeroed], x[self.reapproach] = -1.0, 0.0, 0.0, 0.0
        return x


def AddStation(builder, setup, name: str = "station", session: int = 0):
    """Add the station the scenario names (``setup.scenario.station``) to ``builder``; returns it.

    The one place that decides simulated or real, as Drake's ``MakeHardwareStation`` (a six-axis setup
    of :mod:`olti_drake.sim.serial_station` too: its simulated or emulated N-joint station): ``Simulated``
    -> :func:`olti_drake.sim.campaign.AddSimulatedStation` (a Diagram), ``Emulated`` ->
    :func:`AddEmulatedStation`, ``Hardware`` -> :func:`AddRealStation` (operator prompt on the
    console); a setup with its own ``add_station`` (``station: !Tracker``:
    :func:`~olti_drake.hardware.tracker_station.prepare_tracker` sets ``AddTrackerStation``, an emScon tracker or
    its emulator) -> that. All have the same ports (the simulated one adds ``true_position`` and
    ``query_object``); an emulated or hardware station's ``close()`` releases its ports.
    ``session``: 0 for a campaign's first run, n for its n-th resumption (``olti run --resume``):
    an emulator then draws fresh noise.

    The 3D machine tool (a :class:`~olti_drake.sim.machine3d_campaign.Machine3DCampaignSetup`, or the
    simulated diagram's ``Machine3DSetup``): ``Simulated`` ->
    :func:`~olti_drake.sim.machine3d_station.AddMachine3DStation`, ``Emulated`` -> the 3D machine
    emulator (:class:`~olti_drake.hardware.machine3d_emulator.Machine3DEmulator`), ``Hardware`` ->
    :func:`AddRealMachine3DStation`; the device stations have the simulated one's port names
    (``target_command``, ``station``, ``head_command``; no ``tool`` input, no ``true_position``).

    The five-axis machine tool (a :class:`~olti_drake.sim.five_axis_campaign.FiveAxisCampaignSetup`, or a
    ``FiveAxisRun``): ``Simulated`` -> :func:`~olti_drake.sim.five_axis_station.AddFiveAxisStation`, ``Emulated``
    -> the five-axis emulator (:class:`~olti_drake.hardware.machine5_emulator.Machine5Emulator`), ``Hardware`` ->
    :func:`AddRealMachine5Station`; the device stations take ``command`` (n_axes; m, rad), ``station`` and
    ``head_command`` (no ``direction``, ``tool``, ``nest``: the controller and the aim see to them).
    """
    from olti_drake.sim.campaign import AddSimulatedStation
    from olti_drake.sim.scenario import Emulated, Hardware

    kind = scenario_kind(setup)
    if kind == "machine5":                   # the five-axis machine tool (sim.five_axis_campaign)
        cfg = getattr(setup.scenario, "station", None)
        if isinstance(cfg, Emulated):
            return AddEmulatedStation(builder, setup, name, session)
        if isinstance(cfg, Hardware):
            return AddRealMachine5Station(builder, setup, name)
        from olti_drake.sim.five_axis_station import AddFiveAxisStation
        return AddFiveAxisStation(builder, getattr(setup, "run", setup), name)
    if kind == "machine3d":                  # the 3D machine tool
        machine = _machine3d(setup)
        cfg = getattr(setup.scenario, "station", None) if machine is not setup else None
        if isinstance(cfg, Emulated):
            return AddEmulatedStation(builder, setup, name, session)
        if isinstance(cfg, Hardware):
            return AddRealMachine3DStation(builder, setup, name)
        from olti_drake.sim.machine3d_station import AddMachine3DStation
        return AddMachine3DStation(builder, machine, name)
    own = getattr(setup, "add_station", None)   # a setup that brings its station (the tracker's: docs/tracker.md)
    if own is not None:
        return own(builder, setup, name, session)
    if isinstance(setup.scenario.station, Emulated):
        return AddEmulatedStation(builder, setup, name, session)
    if isinstance(setup.scenario.station, Hardware):
        if kind == "serial":
            return AddRealSerialStation(builder, setup, name)
        return AddRealStation(builder, setup, console_prompt, name)
    if kind == "serial":
        from olti_drake.sim.serial_station import AddSimulatedSerialStation
        return AddSimulatedSerialStation(builder, setup, name)
    return AddSimulatedStation(builder, setup, name)


def AddHardwareStation(builder, setup, devices, set_reflector=None, name: str = "station", policy=None,
                       **ports):
    """Add a :class:`HardwareStation` on ``devices`` = (robot, counter) drivers to ``builder``; returns it.

    Without ``set_reflector``, a counter driver that sets up the reflector itself (a test bench's
    ``set_up_reflector``, the tracer heads' selection) does it. ``ports``: ``command_port``,
    ``selector_port`` (:class:`HardwareStation`)."""
    robot, counter = devices
    set_reflector = set_reflector or getattr(counter, "set_up_reflector", None)
    station = builder.AddNamedSystem(name, HardwareStation(robot, counter, setup.scenario.period_s,
                                                           set_reflector, policy=policy, **ports))
    return station


def _machine3d(setup):
    """The simulated 3D machine diagram's setup (``sim.machine3d_station.Machine3DSetup``) of a 3D machine
    setup: a ``Machine3DCampaignSetup``'s ``machine``, or the diagram's setup itself."""
    return getattr(setup, "machine", setup)


#: The 3D machine station's input names (as its simulated station's).
MACHINE3D_PORTS = dict(command_port="target_command", selector_port="station")
#: The five-axis station's input names (as its simulated station's).
MACHINE5_PORTS = dict(command_port="command", selector_port="station")


#: Noise stream of an emulator started for a resumed session (sim.scenario.SEED_STREAMS).
STREAM_EMULATOR = SEED_STREAMS["emulator_session"]


def AddEmulatedStation(builder, setup, name: str = "station", session: int = 0):
    """Start an in-process emulator on the setup and add a station driving it through its ptys.

    The SCARA emulator for a SCARA setup; for a six-axis floor-tracer setup (``sim.serial_station``'s,
    with ``heads_true``) the N-joint one (:func:`serial_emulator_for`), whose robot line announces
    its joints and whose head lines are the counter (:class:`~olti_drake.hardware.drivers.TracerHeads`);
    for a 3D machine setup the 3D machine emulator (:func:`machine3d_emulator_for`: X, Y, Z and the
    pan/tilt heads, the same protocol). ``session`` > 0 (a resumed campaign) seeds the emulator's noise
    and faults afresh.
    """
    from olti_drake.hardware.emulator import Emulator

    cfg = setup.scenario.station
    seed = None if session == 0 else stream_seed(setup.scenario.seed, STREAM_EMULATOR, session)
    closers = []
    kind = scenario_kind(setup)
    if kind in ("machine3d", "machine5"):    # a machine tool: its axes and a pan/tilt head per station
        emu = (machine3d_emulator_for if kind == "machine3d" else machine5_emulator_for)(setup, seed, cfg).start()
        closers.append(emu.stop)
        station = _open_station(builder, setup, cfg, emu.robot_port, emu.head_ports, 115200, closers, None, name,
                                machine_axes=_machine_axes(setup))
    elif kind == "serial":                   # a six-axis setup: N joints, the heads as counters
        emu = serial_emulator_for(setup, seed, cfg).start()
        closers.append(emu.stop)
        station = _open_station(builder, setup, cfg, emu.robot_port, emu.head_ports, 115200, closers, None, name)
    else:
        emu = Emulator(setup, speed=cfg.speed, seed=seed, faults=cfg.faults(),
                       latch_beam_loss=cfg.latch_beam_loss).start()
        closers.append(emu.stop)

        def refl(counter, j):
            expect_ack(counter.transport.request("REFL", str(int(j))))

        station = _open_station(builder, setup, cfg, emu.robot_port, emu.counter_port, 115200, closers, refl, name)
    station.emulator = emu
    return station


def serial_emulator_for(setup, seed, cfg):
    """The N-joint emulator of a six-axis floor-tracer setup: its truth, heads (true centres, zeros and
    angular errors), cat's eye, interferometer and budget; ``seed`` None = the scenario's."""
    from olti_drake.hardware.serial_emulator import SerialEmulator

    if getattr(setup, "heads_true", None) is None:
        raise InputError("station: !Emulated: only floor-tracer six-axis scenarios are emulated "
                         "(the robot-mounted scheme has no emulator yet)")
    s = setup.scenario
    return SerialEmulator(truth=setup.truth, heads_true=setup.heads_true, head_errors=setup.head_errors,
                          catseye_axis_tool=s.scheme.catseye_axis_tool, options=s.interferometer,
                          budget=setup.budget, seed=s.seed if seed is None else seed, speed=cfg.speed,
                          faults=cfg.faults(), latch_beam_loss=cfg.latch_beam_loss)


def machine3d_emulator_for(setup, seed, cfg):
    """The 3D machine emulator of a ``Machine3DCampaignSetup``: its planned run (truth, heads, head errors),
    tools, cat's eye, interferometer and budget; ``seed`` None = the scenario's."""
    from olti_drake.hardware.machine3d_emulator import Machine3DEmulator

    m = setup.machine
    return Machine3DEmulator(m.scenario, run=m.run, budget=m.budget,
                             seed=setup.scenario.seed if seed is None else seed, speed=cfg.speed,
                             faults=cfg.faults(), latch_beam_loss=cfg.latch_beam_loss)


def machine5_emulator_for(setup, seed, cfg):
    """The five-axis emulator of a ``FiveAxisCampaignSetup``: its planned run (truth, heads, head error, tools, cat's
    eye, interferometer, budget); ``seed`` None = the scenario's."""
    from olti_drake.hardware.machine5_emulator import Machine5Emulator

    return Machine5Emulator(setup.run, seed=setup.scenario.seed if seed is None else seed, speed=cfg.speed,
                            faults=cfg.faults(), latch_beam_loss=cfg.latch_beam_loss)


def AddRealMachine5Station(builder, setup, name: str = "station"):
    """Open a five-axis campaign's controller (``robot_port``: the model file's axes, X, Y, Z in mm and the rotary
    letters in deg, in its order) and pan/tilt heads (``head_ports``: one per station, the bed's then the table's)
    and add the station driving them (the head's aim selects the cat's eye: no prompt)."""
    return _open_real_machine_station(builder, setup, name, "a five-axis campaign", "in station order (bed, table)")


def _open_real_machine_station(builder, setup, name, what, order):
    cfg = setup.scenario.station
    n = len(setup.stations_mm)
    if len(cfg.head_ports) != n or not cfg.robot_port:
        raise InputError(f"station: !Hardware: {what} needs robot_port (the machine's controller) and head_ports: "
                         f"one serial port per pan/tilt head, {n} {order} (got {len(cfg.head_ports)})")
    return _open_station(builder, setup, cfg, cfg.robot_port, list(cfg.head_ports), cfg.baud, [], None, name,
                         machine_axes=_machine_axes(setup))


def _machine_axes(setup) -> tuple:
    """The axis letters a machine tool's controller must announce: X, Y, Z (3D), the model file's (five-axis)."""
    run = getattr(setup, "run", None)
    return tuple(run.machine.axes) if scenario_kind(setup) == "machine5" else ("X", "Y", "Z")


def AddRealMachine3DStation(builder, setup, name: str = "station"):
    """Open a 3D machine campaign's controller (``robot_port``: three linear axes X, Y, Z announced in mm)
    and pan/tilt heads (``head_ports``, one per head in the order of ``heads_mm``) and add the station
    driving them (the head's aim selects the cat's eye: no prompt)."""
    return _open_real_machine_station(builder, setup, name, "a 3D machine campaign", "in the order of heads_mm")


def AddRealStation(builder, setup, set_reflector=None, name: str = "station"):
    """Open the scenario's serial ports and add a station driving the real devices."""
    cfg = setup.scenario.station
    hook = None if set_reflector is None else (lambda counter, j: set_reflector(j))
    return _open_station(builder, setup, cfg, cfg.robot_port, cfg.counter_port, cfg.baud, [], hook, name)


def AddRealSerialStation(builder, setup, name: str = "station"):
    """Open a six-axis floor-tracer campaign's robot controller and tracer heads (``head_ports``, one per
    station, in station order) and add the station driving them (the heads aim themselves: no prompt)."""
    cfg = setup.scenario.station
    if getattr(setup, "heads_true", None) is None:
        raise InputError("station: !Hardware: only floor-tracer six-axis campaigns run on hardware so far (the "
                         "robot-mounted scheme aims the robot, not heads)")
    n = len(setup.stations_mm)
    if len(cfg.head_ports) != n or not cfg.robot_port:
        raise InputError(f"station: !Hardware: a six-axis floor-tracer campaign needs robot_port and head_ports: "
                         f"one serial port per tracer head, {n} in station order (got {len(cfg.head_ports)})")
    return _open_station(builder, setup, cfg, cfg.robot_port, list(cfg.head_ports), cfg.baud, [], None, name)


def _open_station(builder, setup, cfg, robot_port, counter_port, baud, closers, set_reflector, name,
                  machine_axes=None):
    """Open both devices with the scenario's drivers, add the station; close everything on failure.

    ``counter_port``: the counter's port, or a list of tracer heads' ports (one per station: the
    counter is then their :class:`~olti_drake.hardware.drivers.TracerHeads`).
    ``set_reflector(counter, j)`` readies reflector j (None: the station refuses a change).
    ``machine_axes``: a machine tool's axis letters the controller must announce, in order (X, Y, Z in mm, rotary
    letters in deg); the station's inputs then get the machine station's names (:data:`MACHINE3D_PORTS`, the
    five-axis :data:`MACHINE5_PORTS`).
    """
    from olti_drake.hardware.drivers import TracerHeads, driver_class

    names = (getattr(cfg, "robot_driver", "olti"), getattr(cfg, "counter_driver", "olti"))
    heads = not isinstance(counter_port, str)
    lines = [(robot_port, "robot", 0)] + ([(p, f"head {k}", 2) for k, p in enumerate(counter_port)] if heads
                                          else [(counter_port, "counter", 1)])
    try:
        devices = []
        for port, what, kind in lines:
            try:
                cls = driver_class(names[min(kind, 1)], kind)
            except ValueError as e:
                raise InputError(f"station: {what.split()[0]}_driver: {e}") from None
            try:
                devices.append(cls.open(port, baud, cfg.timeout_s, cfg.retries))
            except DriverError as e:
                raise StationError(f"station: {e}") from None
            closers.append(devices[-1].close)
        robot, counter = devices[0], (TracerHeads(devices[1:]) if heads else devices[1])
        if machine_axes is not None:
            _check_machine_axes(robot, robot_port, machine_axes)
        # A counter driver that knows the reflector set-up (a test bench) does it; else the hook (operator).
        hook = getattr(counter, "set_up_reflector", None) or (
            None if set_reflector is None else (lambda j: set_reflector(counter, j)))
        station = AddHardwareStation(builder, setup, (robot, counter), hook, name, policy=cfg.policy,
                                     **({} if machine_axes is None else MACHINE3D_PORTS if len(machine_axes) == 3
                                        else MACHINE5_PORTS))
    except BaseException:
        for c in reversed(closers):
            c()
        raise
    station.closers = closers
    return station


def _check_machine_axes(robot, port, letters) -> None:
    """A machine tool's controller announces its axes: ``letters`` in that order, X, Y, Z in mm and a rotary
    letter in deg; else one line naming both (bad input: the scenario's machine is not the device's)."""
    want = tuple(f"{a}_{'mm' if a in 'XYZ' else 'deg'}" for a in letters)
    layout = getattr(robot, "layout", None)
    got = () if layout is None else tuple(layout.labels)
    if got != want:
        kind = "a 3D machine campaign" if tuple(letters) == ("X", "Y", "Z") else "the machine file"
        raise InputError(f"station: the controller on {port} announces {', '.join(got) or 'no axes'}; {kind} "
                           f"needs the axes {', '.join(want)} (mm, deg) in that order")
