"""The station as real devices: the robot controller and the counter over the serial protocol.

:class:`HardwareStation` is a ``LeafSystem`` with the ports of the simulated
station (``campaign.make_station``) -- inputs ``joint_command`` (4: θ1*, θ2*
rad, J3 m, θ4* rad) and ``reflector`` (1); outputs ``displacement`` (1, m),
``valid`` (1), ``miss`` (1, m: unknown on real devices, always NaN),
``direction`` (4, ±1) and ``position`` (4: the encoder angles from ``POSJ``,
rad/m) -- but it moves a real robot (or the emulator, docs/emulator.md) and
reads a real counter through two :class:`~olti_drake.protocol.Transport` s.

Timing: one unrestricted update per period at ``period_s / 4``, i.e. after
the sequencer's step at k·T and before the recorder's reading at k·T + T/2.
The update moves (``MOVJ``, ``WAIT``) if the command changed, sets up the
reflector (``REFL,<j>`` on the emulator, an operator prompt on hardware) and
zeroes the counter (``ZERO``; retried at the next rows while the counter
answers ``NAK,BEAM``) if the reflector changed, then ``READ`` and
``POSJ``; the outputs are the stored results. A lost beam is ``valid`` 0 and
``displacement`` NaN, never a made-up value. A protocol failure raises
:class:`StationError` naming the command.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem

from .csvio import InputError
from .errormap import approach_directions
from .protocol import (NakError, ProtocolError, decode_pong, decode_position, decode_reading, expect_ack, movj_fields,
                       wait_fields)

M_TO_MM = 1e3
REVOLUTE = np.array([True, True, False, True])
#: Longest in-position wait of one move (ms) sent with WAIT.
WAIT_MS = 60000


class StationError(RuntimeError):
    """A request to the robot controller or the counter failed (names the command)."""


def operator_prompt_required(j: int) -> None:
    """The default reflector hook of a hardware station: no operator to ask."""
    raise StationError(f"hardware station: reflector position {j} must be set up by the operator, but no "
                       f"operator prompt was given (pass set_reflector=callable(j) to make_hardware_station)")


def console_prompt(j: int) -> None:
    """Ask the operator on the console to place the reflector at position ``j``."""
    input(f"Place the reflector at position {j}, aim the beam, then press Enter: ")


class HardwareStation(LeafSystem):
    """The robot and its counter behind the serial protocol, with the simulated station's ports.

    ``robot``, ``counter``: :class:`~olti_drake.protocol.Transport` s.
    ``set_reflector(j)``: sets up reflector position ``j`` (the emulator's
    ``REFL``, or an operator prompt); it returns once done. ``period_s``:
    the campaign clock (the update runs at ``period_s / 4`` in each period).
    """

    def __init__(self, robot, counter, period_s: float,
                 set_reflector: Optional[Callable[[int], None]] = None, wait_ms: int = WAIT_MS):
        super().__init__()
        self.robot, self.counter = robot, counter
        self.set_reflector = set_reflector or operator_prompt_required
        self.wait_ms = int(wait_ms)
        self.closers: list = []
        self.DeclareVectorInputPort("joint_command", 4)
        self.DeclareVectorInputPort("reflector", 1)
        # State: last command sent (4, deg/mm; NaN = none), directions (4), reflector set up (-1 = none),
        # displacement (m), valid, encoder position (4, rad/m), counter zeroed since the reflector was set up.
        x0 = np.concatenate([np.full(4, np.nan), np.ones(4), [-1.0, np.nan, 0.0], np.full(4, np.nan), [0.0]])
        self.DeclareDiscreteState(x0)
        self.DeclarePeriodicUnrestrictedUpdateEvent(period_s, 0.25 * period_s, self._update)
        self.DeclareVectorOutputPort("displacement", 1, lambda c, o: self._out(c, o, slice(9, 10)))
        self.DeclareVectorOutputPort("valid", 1, lambda c, o: self._out(c, o, slice(10, 11)))
        self.DeclareVectorOutputPort("miss", 1, lambda c, o: o.SetAtIndex(0, np.nan))
        self.DeclareVectorOutputPort("direction", 4, lambda c, o: self._out(c, o, slice(4, 8)))
        self.DeclareVectorOutputPort("position", 4, lambda c, o: self._out(c, o, slice(11, 15)))

    def _out(self, context, output: BasicVector, part: slice):
        output.SetFromVector(context.get_discrete_state_vector().value()[part])

    def _request(self, transport, what: str, verb: str, *fields: str, **kw):
        try:
            return transport.request(verb, *fields, **kw)
        except ProtocolError as e:
            raise StationError(f"station: {what} {verb}{',' if fields else ''}{','.join(fields)} failed: "
                               f"{type(e).__name__}: {e}") from None

    def _call(self, what: str, verb: str, decode, transport, *fields: str, **kw):
        frame = self._request(transport, what, verb, *fields, **kw)
        try:
            return decode(frame)
        except ProtocolError as e:
            raise StationError(f"station: {what} {verb}: bad reply: {type(e).__name__}: {e}") from None

    def _update(self, context, state):
        x = context.get_discrete_state_vector().value().copy()
        u = self.get_input_port(0).Eval(context)
        cmd = np.where(REVOLUTE, np.degrees(u), np.asarray(u) * M_TO_MM)
        j = int(self.get_input_port(1).Eval(context)[0])
        last = x[0:4]
        # The approach directions of the commands sent, by the spec's rule (as ErrorMapJoint).
        x[4:8] = approach_directions(cmd[None], last, x[4:8])[0]
        if np.any(np.isnan(last)) or movj_fields(*cmd) != movj_fields(*last):
            self._call("robot", "MOVJ", expect_ack, self.robot, *movj_fields(*cmd))
            self._call("robot", "WAIT", expect_ack, self.robot, *wait_fields(self.wait_ms),
                       timeout_s=self.wait_ms / 1000.0 + self.robot.timeout_s)
        x[0:4] = cmd
        if j != int(x[8]):
            try:
                self.set_reflector(j)
            except ProtocolError as e:
                raise StationError(f"station: setting up reflector {j} failed: {type(e).__name__}: {e}") from None
            x[8], x[15] = j, 0.0
        if x[15] < 0.5:
            # Zero at the first pose of the run where the beam reaches the counter: until then
            # (NAK BEAM) the readings are invalid, as the counter says.
            try:
                expect_ack(self.counter.request("ZERO"))
                x[15] = 1.0
            except NakError as e:
                if e.code != "BEAM":
                    raise StationError(f"station: counter ZERO failed: NakError: {e}") from None
            except ProtocolError as e:
                raise StationError(f"station: counter ZERO failed: {type(e).__name__}: {e}") from None
        reading = self._call("counter", "READ", decode_reading, self.counter)
        x[9] = reading.displacement_mm / M_TO_MM if reading.valid else np.nan
        x[10] = 1.0 if reading.valid else 0.0
        enc = self._call("robot", "POSJ", decode_position, self.robot).encoder
        q = np.array([enc.theta1_deg, enc.theta2_deg, enc.z_mm, enc.theta4_deg])
        x[11:15] = np.where(REVOLUTE, np.radians(q), q / M_TO_MM)
        state.get_mutable_discrete_state().set_value(x)

    def close(self) -> None:
        """Close what the station opened (serial ports, an emulator), last opened first."""
        while self.closers:
            try:
                self.closers.pop()()
            except Exception:  # closing is best effort
                pass


def check_role(transport, role: str, port: str = "") -> str:
    """PING the device and check its role (``ROBOT``/``COUNTER``); returns its model."""
    where = f" on {port}" if port else ""
    try:
        pong = decode_pong(transport.request("PING"))
    except ProtocolError as e:
        raise StationError(f"station: {role.lower()} PING{where} failed: {type(e).__name__}: {e}") from None
    if pong.role != role:
        raise StationError(f"station: the device{where} is a {pong.role} ({pong.model}), expected the {role}")
    return pong.model


def make_hardware_station(builder, setup, transports, set_reflector=None, name: str = "station"):
    """Add a :class:`HardwareStation` on ``transports`` = (robot, counter) to ``builder``; returns it."""
    robot, counter = transports
    station = builder.AddNamedSystem(name, HardwareStation(robot, counter, setup.scenario.period_s,
                                                           set_reflector))
    return station


def open_serial(port: str, baud: int, what: str):
    """``serial.Serial(port, baud, timeout=0.05)``, or a one-line InputError naming the port."""
    import serial

    try:
        return serial.Serial(port, baud, timeout=0.05)
    except (OSError, ValueError) as e:  # SerialException is an OSError
        detail = " ".join(str(e).split())
        raise InputError(f"station: cannot open the {what} port {port}: {detail}") from None


def _transports(station_cfg, robot_port, counter_port, baud, closers):
    from .protocol import Transport

    out = []
    for port, what in ((robot_port, "robot"), (counter_port, "counter")):
        s = open_serial(port, baud, what)
        closers.append(s.close)
        out.append(Transport(s, timeout_s=station_cfg.timeout_s, retries=station_cfg.retries))
    return out


def make_emulated_station(builder, setup, name: str = "station"):
    """Start an in-process Emulator on the setup and add a station driving it through its ptys."""
    from .emulator import Emulator

    cfg = setup.scenario.station
    emu = Emulator(setup, speed=cfg.speed, drop=cfg.drop, garble=cfg.garble, nak_crc=cfg.nak_crc,
                   beam_loss=cfg.beam_loss, latch_beam_loss=cfg.latch_beam_loss).start()
    closers = [emu.stop]

    def refl(counter, j):
        expect_ack(counter.request("REFL", str(int(j))))

    station = _open_station(builder, setup, cfg, emu.robot_port, emu.counter_port, 115200, closers, refl, name)
    station.emulator = emu
    return station


def make_real_station(builder, setup, set_reflector=None, name: str = "station"):
    """Open the scenario's serial ports and add a station driving the real devices."""
    cfg = setup.scenario.station
    hook = None if set_reflector is None else (lambda counter, j: set_reflector(j))
    return _open_station(builder, setup, cfg, cfg.robot_port, cfg.counter_port, cfg.baud, [], hook, name)


def _open_station(builder, setup, cfg, robot_port, counter_port, baud, closers, set_reflector, name):
    """Open both lines, check the devices' roles, add the station; close everything on failure.

    ``set_reflector(counter_transport, j)`` readies reflector j (None: the station refuses a change).
    """
    try:
        robot, counter = _transports(cfg, robot_port, counter_port, baud, closers)
        check_role(robot, "ROBOT", robot_port)
        check_role(counter, "COUNTER", counter_port)
        hook = None if set_reflector is None else (lambda j: set_reflector(counter, j))
        station = make_hardware_station(builder, setup, (robot, counter), hook, name)
    except BaseException:
        for c in reversed(closers):
            c()
        raise
    station.closers = closers
    return station
