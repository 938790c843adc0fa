"""Device emulator: the robot controller and the interferometer counter on pseudo-terminals.

It answers the serial protocol of ``docs/protocol.md`` as the real devices would, backed by the
simulated truth of a scenario; ``docs/emulator.md`` is its manual. Two pseudo-terminals, one per
device, because the protocol gives each serial line one device (``PING`` reports one role):

- **robot** (``PONG,1,ROBOT,SCARA-EMU``): ``MOVJ WAIT POSJ ALRM``. Every axis moves directly to its
  target; its approach direction is kept by the spec's rule (last command and direction per axis,
  as ``ErrorMapJoint``: an axis that did not move keeps its direction), and the actual pose is
  ``TrueRobot.laser_beam`` of the commands and directions.
- **counter** (``PONG,1,COUNTER,LC-EMU``): ``READ ZERO`` and the emulator-only ``REFL`` (which
  reflector position the operator has set up). ``READ`` is ``simulate_readings`` of the current
  pose and reflector (cosine error, beam loss, budget noise, λ/64 as the scenario says), with the
  counter zero taken by ``ZERO`` at the pose of that moment.

Use it as a thread (``with Emulator(scenario) as emu: serial.Serial(emu.robot_port) ...``) or as a
program: ``python -m olti_drake.cli.emulator [SCENARIO.yaml] [--speed fast|realistic] [--seed N]
[--link PREFIX] [fault flags]``. Faults (latency, lost, garbled, bad-checksum and cut frames,
beam loss, an alarm, a disconnect) are injected from a seeded generator, so a run is reproducible.

Units: mm and degrees, as on the wire.
"""

from __future__ import annotations

import array
import dataclasses
import errno
import fcntl
import logging
import os
import select
import termios
import threading
import time
import tty
from typing import Optional

import numpy as np

from olti_drake.model.errormap import approach_directions
from olti_drake.sim.scenario import SEED_STREAMS, Faults, Scenario, load_scenario, stream_rng  # Faults: re-exported
from olti_drake.model.instrument import beam_geometry, simulate_readings
from olti_drake.hardware.protocol import (PROTOCOL_VERSION, SCARA_LAYOUT, Axis, AxisLayout, ChecksumError, Frame,
                       FrameParser, NakError, Responder, alm_fields, decode_alrm, decode_movj, decode_wait,
                       dis_fields, encode, nak_fields, pong_fields, position_fields)

_log = logging.getLogger(__name__)

#: Verbs each device answers; any other verb gets ``NAK,VERB`` on that line.
ROBOT_VERBS = ("PING", "MOVJ", "WAIT", "POSJ", "ALRM")
COUNTER_VERBS = ("PING", "READ", "ZERO", "REFL")
ROLES = ("robot", "counter")

AXES = ("theta1_deg", "theta2_deg", "z_mm", "theta4_deg")
AXIS_NAMES = ("J1", "J2", "J3", "J4")
#: Joint limits (min, max) per axis, deg / mm: the RH-3FRH5515 data sheet (J1 ±170°, J2 ±150°,
#: J3 stroke 0..150 mm, J4 ±360°). The paper plan runs θ1 -142..62°, θ2 -2..142°.
DEFAULT_LIMITS = ((-170.0, 170.0), (-150.0, 150.0), (0.0, 150.0), (-360.0, 360.0))
#: ``realistic`` speed: joint speeds (deg/s, mm/s for J3) and the settling time (s) after a move.
DEFAULT_SPEEDS = (60.0, 60.0, 50.0, 120.0)
DEFAULT_SETTLE_S = 0.2
#: Encoder resolution of POSJ (deg, mm for J3): a 2^20 count/rev encoder; 0 = encoder = command.
DEFAULT_ENCODER_RESOLUTION = (360.0 / 2 ** 20, 360.0 / 2 ** 20, 1e-4, 360.0 / 2 ** 20)

#: Counter status bits (the READ status field, 4 uppercase hex digits).
STATUS_BEAM = 0x0001        # no beam at the receiver (miss > acceptance, or injected)
STATUS_NOT_ZEROED = 0x0002  # no ZERO since power-up or since the reflector was moved (REFL)
STATUS_COUNT_LOST = 0x0004  # latch_beam_loss: the beam was lost at a READ since the last ZERO
STATUS_INJECTED = 0x0010    # the beam loss was injected by the fault switch
STATUS_INVALID = 0x8000     # the displacement is not trustworthy (valid = 0)

#: Random streams (sim.scenario.SEED_STREAMS): stream_rng(seed, name, ...) = default_rng([seed, key, ...]).
STREAM_NOISE = SEED_STREAMS["emulator_noise"]    # the counter's noise
STREAM_FAULTS = SEED_STREAMS["emulator_faults"]  # fault draws of line k (0 robot, 1 counter)

# Uniform draws per received frame (always all of them, so one switch does not shift the others).
_U_DROP_REQ, _U_NAK_CRC, _U_DROP_REPLY, _U_BAD_CRC, _U_GARBLE, _U_GARBLE_POS, _U_GARBLE_VAL, \
    _U_PARTIAL, _U_BEAM = range(9)
_N_DRAWS = 9

ALARM_CODE = "EMU_INJECTED"


def _truth_parts(scenario):
    """(TrueRobot, reflectors (n, 2) mm, interferometer options, budget, seed) of a scenario-like input."""
    if scenario is None:
        scenario = Scenario()
    elif isinstance(scenario, (str, os.PathLike)):
        scenario = load_scenario(scenario)
    setup = None
    if not isinstance(scenario, Scenario) and hasattr(scenario, "scenario"):  # a campaign.Setup
        setup, scenario = scenario, scenario.scenario
    robot = setup.robot if setup is not None else scenario.robot.true_robot()
    P = np.asarray(setup.reflectors_mm if setup is not None else scenario.reflectors_mm, dtype=float)
    budget = setup.budget if setup is not None else scenario.load_budget()
    return robot, P.reshape(-1, 2), scenario.interferometer, budget, scenario.seed


class _Device:
    """One serial line's view of the emulator: its role's verbs, its PING, its own Responder.

    What a line answers comes from the emulator (``_line_spec(role)``: verbs, PING role, model,
    protocol version; ``_verb(role, verb)``: the handler), so one class serves the SCARA's two
    lines and the N-joint emulator's robot and head lines."""

    def __init__(self, emulator: "Emulator", role: str):
        self._emu, self.role = emulator, role
        self.verbs, self.pong_role, self.model, self.version = emulator._line_spec(role)

    def on_PING(self, frame: Frame):
        return ("PONG", *pong_fields(self.pong_role, self.model, self.version))

    def __getattr__(self, name: str):
        if name.startswith("on_") and name[3:] in self.__dict__.get("verbs", ()):
            return self._emu._verb(self.role, name[3:])
        raise AttributeError(name)


class _Line:
    """A pseudo-terminal pair serving one device: master fd, slave path, parser and fault generator."""

    def __init__(self, emulator: "Emulator", role: str, seed: int):
        self.role = role
        self.device = _Device(emulator, role)
        self.responder = Responder(self.device)
        self.parser = FrameParser()
        self.rng = stream_rng(seed, "emulator_faults", emulator.roles.index(role))
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo, no line editing, no CR/LF translation, whoever opens it
        self.path = os.ttyname(self.slave)
        self.link: Optional[str] = None
        self.thread: Optional[threading.Thread] = None

    def close(self) -> None:
        for fd in (self.master, self.slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self.master = self.slave = None


class Emulator:
    """The robot controller and interferometer counter of a scenario, on two pseudo-terminals.

    Args:
        scenario: a :class:`~olti_drake.sim.scenario.Scenario`, a scenario YAML path, a
            :class:`~olti_drake.sim.campaign.Setup`, or None (the paper-000 default scenario).
        speed: ``"fast"`` (moves are done when accepted; replies as fast as the line allows) or
            ``"realistic"`` (a move takes max over axes of distance / speed, plus ``settle_s``).
        seed: seed of the noise and fault generators; None takes the scenario's seed.
        reflector: the reflector position (index into the scenario's reflectors) set up at start.
        faults: a :class:`Faults`; keyword arguments named like its fields override it
            (``Emulator(s, drop=0.1, alarm_at=5)``).
        limits, speeds, settle_s, encoder_resolution, home: robot properties per axis
            (θ1, θ2, z, θ4; deg and mm); ``home`` is where the robot is at power-up.
        link: a path prefix: ``start`` makes the symlinks ``<link>-robot`` and ``<link>-counter``
            to the two pseudo-terminals (removed by ``stop``).
        latch_beam_loss: False (default, as ``simulate_readings`` and the campaign simulation): each
            READ is valid or not on its own. True (as a real counter): once a READ found no beam,
            every READ is invalid until the next ZERO (the count was lost).

    ``start()`` opens the pseudo-terminals and serves them on two daemon threads; ``robot_port`` and
    ``counter_port`` are then the device paths to open with pyserial. ``stop()`` closes them. Use it
    as a context manager. The state (``commanded``, ``directions``, ``history``, ``reflector``,
    ``dead_path_mm``, ``alarms``, ``requests``) can be read at any time.
    """

    #: The serial lines, in the order of their fault streams (``emulator_faults``, line index).
    roles = ROLES

    def __init__(self, scenario=None, *, speed: str = "fast", seed: Optional[int] = None,
                 reflector: int = 0, faults: Optional[Faults] = None, limits=DEFAULT_LIMITS,
                 speeds=DEFAULT_SPEEDS, settle_s: float = DEFAULT_SETTLE_S,
                 encoder_resolution=DEFAULT_ENCODER_RESOLUTION, home=(0.0, 0.0, 0.0, 0.0),
                 link: Optional[str] = None, latch_beam_loss: bool = False,
                 models=("SCARA-EMU", "LC-EMU"), clock=time.monotonic, **fault_switches):
        self._init_lines(speed, faults, fault_switches, link, latch_beam_loss, models, clock)
        self.robot, self.reflectors_mm, self.options, self.budget, scenario_seed = _truth_parts(scenario)
        self.seed = int(scenario_seed if seed is None else seed)
        self._noise = stream_rng(self.seed, "emulator_noise")
        self._init_robot(SCARA_LAYOUT, limits, speeds, settle_s, encoder_resolution, home)

        # Counter state.
        self._check_reflector(reflector)
        self._reflector = int(reflector)
        self._zeroed = False
        self._count_lost = False
        self._dead_path = np.nan
        self._last_value = 0.0

    def _init_lines(self, speed, faults, fault_switches, link, latch_beam_loss, models, clock) -> None:
        """What every emulator has: speed, fault switches, the lines (not yet open), the lock."""
        if speed not in ("fast", "realistic"):
            raise ValueError(f"speed must be 'fast' or 'realistic', got {speed!r}")
        unknown = set(fault_switches) - {f.name for f in dataclasses.fields(Faults)}
        if unknown:
            raise TypeError(f"{type(self).__name__}: unknown argument(s) {', '.join(sorted(unknown))}")
        self.faults = dataclasses.replace(faults or Faults(), **fault_switches).validate()
        self.speed = speed
        self.models = tuple(models)
        self.link = link
        self.latch_beam_loss = bool(latch_beam_loss)
        self.clock = clock
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self.disconnected = threading.Event()
        self._lines: dict[str, _Line] = {}
        self._tls = threading.local()  # per line thread: the fault draw for the READ being answered
        self._requests = 0

    def _init_robot(self, layout: AxisLayout, limits, speeds, settle_s, encoder_resolution, home) -> None:
        """The controller of the robot's n = ``layout.n`` axes: ``limits`` (n, 2), ``speeds`` (n,),
        ``encoder_resolution`` (n,), ``home`` (n,) in deg or mm per axis."""
        n = layout.n
        self.limits = np.asarray(limits, dtype=float).reshape(n, 2)
        self.layout = AxisLayout(tuple(Axis(a.name, a.unit, lo, hi) for a, (lo, hi) in zip(layout.axes, self.limits)))
        self.speeds = np.asarray(speeds, dtype=float).reshape(n)
        if np.any(self.speeds <= 0):
            raise ValueError("speeds must be > 0")
        self.settle_s = float(settle_s)
        self.encoder_resolution = np.asarray(encoder_resolution, dtype=float).reshape(n)
        # Like ErrorMapJoint, the controller starts without a last command: the first
        # MOVJ keeps the initial direction +1 of every axis (approach_directions with no start).
        self._start = np.asarray(home, dtype=float).reshape(n)   # segment start (deg/mm)
        self._target = self._start.copy()                         # commanded (deg/mm)
        self._t0 = self._t_end = self._t_settled = -np.inf        # segment timing (clock)
        self._last_command = np.full(n, np.nan)                   # the rule's "previous command"
        self._direction = np.ones(n)
        self.history: list[tuple] = []            # every executed MOVJ
        self.direction_history: list[tuple] = []
        self._moves = 0
        self._alarms: list[str] = []

    def _line_spec(self, role: str):
        """(verbs, PING role, model, protocol version) of the line ``role``."""
        k = ROLES.index(role)
        return (ROBOT_VERBS, COUNTER_VERBS)[k], role.upper(), self.models[k], PROTOCOL_VERSION

    def _verb(self, role: str, verb: str):
        """The handler of ``verb`` on the line ``role``: ``handler(frame) -> reply``."""
        return getattr(self, "on_" + verb)

    def _command(self, frame: Frame) -> np.ndarray:
        """The MOVJ request's joint vector (deg/mm); a malformed one is NAK,SYN (FieldError)."""
        return np.array(tuple(decode_movj(frame)))

    # ------------------------------------------------------------------ lifecycle

    def start(self) -> "Emulator":
        if self._lines:
            raise RuntimeError("emulator already started")
        try:
            for role in self.roles:
                self._lines[role] = _Line(self, role, self.seed)
            if self.link:
                for role, line in self._lines.items():
                    line.link = _make_link(f"{self.link}-{role}", line.path)
        except BaseException:
            self.stop()
            raise
        for line in self._lines.values():
            line.thread = threading.Thread(target=self._serve, args=(line,), daemon=True,
                                           name=f"olti-emulator-{line.role}")
            line.thread.start()
        _log.info("%s", ", ".join(f"{role} on {line.path}" for role, line in self._lines.items()))
        return self

    def stop(self) -> None:
        self._stop.set()
        for line in self._lines.values():
            if line.thread is not None and line.thread is not threading.current_thread():
                line.thread.join(timeout=5.0)
            line.close()
            if line.link and os.path.islink(line.link):
                os.unlink(line.link)
                line.link = None

    def __enter__(self) -> "Emulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def robot_port(self) -> str:
        """The robot controller's device path (the pty slave), e.g. ``/dev/pts/7``."""
        return self._lines["robot"].path

    @property
    def counter_port(self) -> str:
        """The interferometer counter's device path (the pty slave)."""
        return self._lines["counter"].path

    @property
    def ports(self) -> dict:
        return {role: line.path for role, line in self._lines.items()}

    # ------------------------------------------------------------------ state (thread-safe reads)

    @property
    def commanded(self) -> tuple:
        with self._lock:
            return tuple(map(float, self._target))

    @property
    def directions(self) -> tuple:
        """Approach direction (±1) of each axis (θ1, θ2, z, θ4) after the last executed MOVJ."""
        with self._lock:
            return tuple(map(float, self._direction))

    @property
    def reflector(self) -> int:
        with self._lock:
            return self._reflector

    @reflector.setter
    def reflector(self, j: int) -> None:
        """The Python side channel: the operator moved the reflector to position ``j`` (as REFL,j)."""
        self.set_reflector(j)

    @property
    def dead_path_mm(self) -> float:
        """The counter zero: the optical length at the last ZERO (NaN before any)."""
        with self._lock:
            return self._dead_path

    @property
    def alarms(self) -> tuple:
        with self._lock:
            return tuple(self._alarms)

    @property
    def requests(self) -> int:
        """Request frames received on both lines (retries included)."""
        with self._lock:
            return self._requests

    def set_reflector(self, j: int) -> None:
        self._check_reflector(j)
        with self._lock:
            self._reflector = int(j)
            self._zeroed = False  # the beam was broken while the reflector was moved
            self._last_value = 0.0

    def actual_beam(self):
        """Actual beam origin (2,) mm and world beam angle (deg) now (moving or not)."""
        with self._lock:
            q = self._position(self.clock())
            origin, angle = self.robot.laser_beam(q[0:1], q[1:2], q[3:4], *self._direction[[0, 1, 3]])
            return origin[0], float(angle[0])

    def optical_length_mm(self) -> float:
        """Noise-free optical length to the current reflector (what ZERO stores as the counter zero)."""
        origin, angle = self.actual_beam()
        along, miss = beam_geometry(origin, angle, self.reflectors_mm[self._reflector])
        return float(along if self.options.cosine_error else np.hypot(along, miss))

    # ------------------------------------------------------------------ robot verbs

    def on_MOVJ(self, frame: Frame):
        cmd = self._command(frame)
        with self._lock:
            now = self.clock()
            self._moves += 1
            if self.faults.alarm_at is not None and self._moves == self.faults.alarm_at:
                self._raise_alarm(ALARM_CODE, now)
            if self._alarms:
                raise NakError("ALARM", f"alarm active: {' '.join(self._alarms)}; ALRM,CLR clears")
            why = self.layout.outside(cmd)
            if why:
                raise NakError("RANGE", why)
            if now < self._t_settled:
                raise NakError("BUSY", "previous move not in position; WAIT first")
            self._direction = approach_directions(cmd[None], self._last_command, self._direction)[0]
            self._last_command = cmd.copy()
            self._start, self._target = self._target.copy(), cmd
            self.history.append(tuple(map(float, cmd)))
            self.direction_history.append(tuple(map(float, self._direction)))
            if self.speed == "realistic":
                move_s = float(np.max(np.abs(cmd - self._start) / self.speeds))
                self._t0, self._t_end, self._t_settled = now, now + move_s, now + move_s + self.settle_s
            else:
                self._t0 = self._t_end = self._t_settled = now
        return ("ACK",)

    def on_WAIT(self, frame: Frame):
        max_s = decode_wait(frame) / 1000.0
        deadline = self.clock() + max_s
        while True:
            with self._lock:
                if self._alarms:
                    raise NakError("ALARM", f"motion stopped by alarm {' '.join(self._alarms)}")
                now = self.clock()
                if now >= self._t_settled:
                    return ("ACK",)
                slowest = int(np.argmax(np.abs(self._target - self._start) / self.speeds))
                remaining = self._t_settled - now
            if now >= deadline:
                raise NakError("TMO", f"J{slowest + 1} not in position after {round(max_s * 1000)} ms")
            if self._stop.wait(min(remaining, deadline - now, 0.05)):
                raise NakError("HW", "emulator stopping")

    def on_POSJ(self, frame: Frame):
        if frame.fields:
            raise NakError("SYN", f"expects 0 fields; got {len(frame.fields)}")
        with self._lock:
            q = self._position(self.clock())
            res = self.encoder_resolution
            enc = np.where(res > 0, np.round(q / np.where(res > 0, res, 1.0)) * res, q)
            return ("POS", *position_fields(self._target, enc, self.layout))

    def on_ALRM(self, frame: Frame):
        clear = decode_alrm(frame)
        with self._lock:
            if clear:
                self._alarms.clear()
            return ("ALM", *alm_fields(self._alarms))

    def raise_alarm(self, code: str = ALARM_CODE) -> None:
        """Raise a controller alarm now (as the ``alarm_at`` fault does): MOVJ/WAIT get NAK,ALARM."""
        with self._lock:
            self._raise_alarm(code, self.clock())

    def _raise_alarm(self, code: str, now: float) -> None:
        if now < self._t_end:  # the alarm stops the motion where it is
            q = self._position(now)
            self._start, self._target = q.copy(), q.copy()
            self._last_command = q.copy()
        self._t0 = self._t_end = self._t_settled = min(self._t_settled, now)
        if code not in self._alarms:
            self._alarms.append(code)
        _log.warning("alarm %s raised", code)

    def _position(self, now: float) -> np.ndarray:
        """Joint positions (deg/mm) along the current move: linear from start to target."""
        if now >= self._t_end or self._t_end <= self._t0:
            return self._target.copy()
        f = (now - self._t0) / (self._t_end - self._t0)
        return self._start + max(0.0, f) * (self._target - self._start)

    # ------------------------------------------------------------------ counter verbs

    def on_READ(self, frame: Frame):
        if frame.fields:
            raise NakError("SYN", f"expects 0 fields; got {len(frame.fields)}")
        forced = getattr(self._tls, "forced_beam_loss", False)
        with self._lock:
            origin, angle = self.actual_beam()
            j = self._reflector
            d0 = self._dead_path if self._zeroed else self.optical_length_mm()
            reading, valid, miss = simulate_readings(origin[None], [angle], self.reflectors_mm[j][None], [d0],
                                                     self.options, self.budget, self._noise)
            return counter_reply(self, float(reading[0]), bool(valid[0]), forced, self.latch_beam_loss)

    def on_ZERO(self, frame: Frame):
        if frame.fields:
            raise NakError("SYN", f"expects 0 fields; got {len(frame.fields)}")
        with self._lock:
            origin, angle = self.actual_beam()
            along, miss = beam_geometry(origin, angle, self.reflectors_mm[self._reflector])
            if self.options.beam_loss and miss > self.options.acceptance_mm:
                raise NakError("BEAM", "no beam at the receiver")
            self._dead_path = self.optical_length_mm()
            self._zeroed, self._count_lost = True, False
            self._last_value = 0.0
        return ("ACK",)

    def on_REFL(self, frame: Frame):
        """Emulator-only: ``REFL,<j>`` = the operator set up reflector position j (ACK);
        ``REFL`` = which one is set up (``RFL,<j>,<count>``)."""
        if not frame.fields:
            with self._lock:
                return ("RFL", str(self._reflector), str(len(self.reflectors_mm)))
        if len(frame.fields) != 1 or not frame.fields[0].isdigit() or (
                len(frame.fields[0]) > 1 and frame.fields[0][0] == "0"):
            raise NakError("SYN", "expects REFL or REFL,<index 0..n-1>")
        j = int(frame.fields[0])
        if j >= len(self.reflectors_mm):
            raise NakError("RANGE", f"reflector {j} outside 0..{len(self.reflectors_mm) - 1}")
        self.set_reflector(j)
        return ("ACK",)

    def _check_reflector(self, j) -> None:
        if not (isinstance(j, (int, np.integer)) and 0 <= j < len(self.reflectors_mm)):
            raise ValueError(f"reflector index {j!r} outside 0..{len(self.reflectors_mm) - 1}")

    # ------------------------------------------------------------------ the line

    def _serve(self, line: _Line) -> None:
        try:
            while not self._stop.is_set() and not self.disconnected.is_set():
                try:
                    ready, _, _ = select.select([line.master], [], [], 0.05)
                    if not ready:
                        continue
                    data = os.read(line.master, 4096)
                except OSError as e:
                    if e.errno == errno.EIO:  # nobody has the slave open: wait for a host
                        self._stop.wait(0.05)
                        continue
                    raise
                if self.disconnected.is_set():  # the other line disconnected meanwhile: gone
                    break
                for ev in line.parser.feed(data):
                    if isinstance(ev, Frame):
                        self._handle(line, ev)
                    elif isinstance(ev, ChecksumError) and ev.seq is not None:
                        self._write(line, encode(ev.seq, "NAK", *nak_fields("CRC", "checksum mismatch")))
                    else:
                        _log.debug("%s: %s", line.role, ev)
                    if self.disconnected.is_set():
                        break
        except Exception:  # a closed fd at stop, or a bug: log it, never hang the host silently
            if not (self._stop.is_set() or self.disconnected.is_set()):
                _log.exception("%s line failed", line.role)
        finally:
            if self.disconnected.is_set():
                self._drain(line)
                line.close()  # each thread closes its own fds: no fd is reused under another thread

    def _drain(self, line: _Line, arrive_s: float = 0.2, read_s: float = 1.0) -> None:
        """Let the host read what was written before the master is closed: closing it discards the
        bytes still queued at the slave, so the last reply would be lost. The pty moves written bytes
        to the slave's queue asynchronously: wait (at most ``arrive_s``) for them to show up there,
        then (at most ``read_s``) for the host to read them."""
        def queued() -> int:
            buf = array.array("i", [0])
            fcntl.ioctl(line.slave, termios.FIONREAD, buf, True)
            return buf[0]

        try:
            for wait_s, done in ((arrive_s, lambda n: n > 0), (read_s, lambda n: n == 0)):
                deadline = time.monotonic() + wait_s
                while not done(queued()) and time.monotonic() < deadline:
                    time.sleep(0.002)
        except OSError:
            pass

    def _handle(self, line: _Line, request: Frame) -> None:
        f = self.faults
        u = line.rng.random(_N_DRAWS)
        with self._lock:
            self._requests += 1
            count = self._requests
        _log.debug("%s <- %s", line.role, request)
        if u[_U_DROP_REQ] < f.drop:
            _log.info("%s: fault: request %s lost", line.role, request)
        elif u[_U_NAK_CRC] < f.nak_crc:
            _log.info("%s: fault: request %s taken as corrupted", line.role, request)
            self._send(line, encode(request.seq, "NAK", *nak_fields("CRC", "checksum mismatch")), u)
        else:
            self._tls.forced_beam_loss = bool(u[_U_BEAM] < f.beam_loss)
            try:
                reply = line.responder.respond(request)
            finally:
                self._tls.forced_beam_loss = False
            self._send(line, reply, u)
        if f.disconnect_after is not None and count >= f.disconnect_after:
            _log.warning("fault: disconnect after %d requests", count)
            self.disconnected.set()

    def _send(self, line: _Line, reply: bytes, u) -> None:
        f = self.faults
        if f.latency_s and self._stop.wait(f.latency_s):
            return
        if u[_U_DROP_REPLY] < f.drop:
            _log.info("%s: fault: reply %r lost", line.role, reply)
            return
        data = bytearray(reply)
        if u[_U_BAD_CRC] < f.bad_crc:  # the body intact, the checksum wrong
            star = data.rindex(b"*")
            crc = int(data[star + 1:star + 5], 16) ^ (1 + int(u[_U_GARBLE_VAL] * 0xFFFE))
            data[star + 1:star + 5] = b"%04X" % crc
        if u[_U_GARBLE] < f.garble:  # one byte changed anywhere before the terminator
            pos = min(int(u[_U_GARBLE_POS] * (len(data) - 1)), len(data) - 2)
            data[pos] ^= 1 + int(u[_U_GARBLE_VAL] * 255) % 255
        if bytes(data) != reply:
            _log.info("%s: fault: reply %r sent as %r", line.role, reply, bytes(data))
        if u[_U_PARTIAL] < f.partial:
            half = len(data) // 2
            _log.info("%s: fault: reply %r cut after %d bytes", line.role, reply, half)
            self._write(line, bytes(data[:half]))
            if f.partial_delay_s is None or self._stop.wait(f.partial_delay_s):
                return
            data = data[half:]
        self._write(line, bytes(data))
        _log.debug("%s -> %r", line.role, reply)

    def _write(self, line: _Line, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(line.master, view)
            view = view[n:]

    # ------------------------------------------------------------------ program

    def serve_forever(self) -> None:
        """Serve until KeyboardInterrupt or the injected disconnect."""
        try:
            while not self.disconnected.wait(0.2):
                pass
        except KeyboardInterrupt:
            pass


def counter_reply(counter, reading_mm: float, beam_ok: bool, forced: bool, latch: bool) -> tuple:
    """The ``DIS`` reply of a counter (the SCARA's, or a tracer head's) and its state update.

    ``counter`` holds ``_zeroed``, ``_count_lost`` and ``_last_value`` (mm); ``reading_mm`` is the
    displacement the optics give now, ``beam_ok`` whether the beam returned, ``forced`` an injected
    beam loss, ``latch`` the real counter's behaviour (lost count until the next ZERO). An invalid
    reading repeats the last valid value with the status bits saying why (docs/emulator.md)."""
    status = 0
    if not beam_ok:
        status |= STATUS_BEAM
    if forced:
        status |= STATUS_BEAM | STATUS_INJECTED
    if not counter._zeroed:
        status |= STATUS_NOT_ZEROED
    elif latch and (status & STATUS_BEAM or counter._count_lost):
        counter._count_lost = True
        status |= STATUS_COUNT_LOST
    ok = status == 0
    if ok:
        counter._last_value = float(reading_mm)
    else:
        status |= STATUS_INVALID
    return ("DIS", *dis_fields(counter._last_value, ok, f"{status:04X}"))


def _make_link(path: str, target: str) -> str:
    if os.path.islink(path):
        os.unlink(path)  # a stale link of an earlier run
    elif os.path.exists(path):
        raise FileExistsError(f"--link: {path} exists and is not a symlink; not replacing it")
    os.symlink(target, path)
    return path
