"""Device drivers: what the hardware station needs of a robot controller and of a counter.

:class:`~olti_drake.hardware.station.HardwareStation` talks to devices only through
these two interfaces, so another controller or counter is **one class**
(docs/protocol.md, "How to add a new controller or counter"): implement the
methods of :class:`RobotDriver` or :class:`CounterDriver` over the device's
own protocol and name the class in the scenario
(``station: !Hardware {robot_driver: mypkg.fanuc:FanucRobot}``).

:class:`OltiRobot` and :class:`OltiCounter` implement them over the olti
serial protocol (:mod:`olti_drake.hardware.protocol`), which the emulator speaks too.

A robot speaking protocol version 2 announces its N joints (``INFO``); :class:`OltiRobot`
then moves and reads N joints (``layout``), and :class:`TracerHeads` (the pan/tilt heads of the
floor tracer stations, one :class:`OltiHead` per line) is the counter of such a campaign
(docs/protocol.md, "N-axis devices and pan/tilt heads").

Units: joint commands and positions in deg (J1, J2, J4) and mm (J3) -- per axis as announced for
N joints; the displacement in mm (formats.md).
"""

from __future__ import annotations

from typing import Protocol, Sequence

from olti_drake.errors import InputError
from olti_drake.named import resolve
from olti_drake.hardware.protocol import (SCARA_LAYOUT, AxisLayout, NakError, Pong, Position, ProtocolError, Reading,
                       Transport, decode_alarms, decode_axis, decode_info, decode_pong, decode_position,
                       decode_position_n, decode_reading, expect_ack, wait_fields)


class DriverError(RuntimeError):
    """A device request failed (base class for drivers of other protocols; the message names it)."""


class AlarmActive(DriverError):
    """The controller refused or stopped a motion because an alarm is active."""


class RobotDriver(Protocol):
    """A robot controller. Errors: :class:`AlarmActive`, :class:`DriverError` or ``ProtocolError``.

    Opened by the station factory as ``cls.open(port, baud, timeout_s, retries)`` and released by
    ``close()`` (both also for :class:`CounterDriver`).
    """

    #: Optional: the robot's axes (``protocol.AxisLayout``); without it the station takes the SCARA's.
    layout: AxisLayout

    def move(self, command: Sequence[float]) -> None:
        """Start a joint move to ``command`` = (θ1*, θ2* deg, z mm, θ4* deg), or one value per axis of ``layout``."""

    def wait(self, max_ms: int) -> None:
        """Return once in position; raise if not within ``max_ms`` milliseconds."""

    def position(self) -> Position:
        """The commanded and the encoder joint positions (deg, mm)."""

    def alarms(self, clear: bool = False) -> tuple:
        """The active alarm codes (after clearing what can be cleared, if ``clear``)."""


class CounterDriver(Protocol):
    """An interferometer counter. Errors: :class:`DriverError` or ``ProtocolError``."""

    def read(self) -> Reading:
        """The displacement (mm), the counter's own valid flag and its raw status."""

    def zero(self) -> bool:
        """Zero the displacement here; False if there is no beam to zero on."""


def open_serial(port: str, baud: int, what: str):
    """``serial.Serial(port, baud, timeout=0.05)``, or a one-line InputError naming the port."""
    import serial

    try:
        return serial.Serial(port, baud, timeout=0.05)
    except (OSError, ValueError) as e:  # SerialException is an OSError
        detail = " ".join(str(e).split())
        raise InputError(f"station: cannot open the {what} port {port}: {detail}") from None


class _OltiDevice:
    """A device on an olti-protocol line: ``open`` checks its role with ``PING``."""

    role = ""

    def __init__(self, transport: Transport, pong: Pong | None = None, port: str = ""):
        self.transport = transport
        self.pong = pong or Pong(1, self.role, "")
        self.port = port
        self.layout = read_layout(transport, port) if self.pong.version >= 2 else self.v1_layout

    #: The axes of a version-1 device of this role (a SCARA robot; none for a counter).
    v1_layout = None

    @classmethod
    def open(cls, port: str, baud: int, timeout_s: float, retries: int):
        """Open the serial ``port`` (pyserial), check the device's role (and read a version-2
        device's axes); a one-line error if not."""
        stream = open_serial(port, baud, cls.role.lower())
        try:
            transport = Transport(stream, timeout_s=timeout_s, retries=retries)
            return cls(transport, check_pong(transport, cls.role, port), port)
        except BaseException:
            stream.close()
            raise

    def close(self) -> None:
        self.transport.stream.close()

    #: One WAIT request's limit (ms): a longer wait is several requests, so a lost frame costs at
    #: most this much (plus the line timeout) before the retry, not the whole wait.
    WAIT_CHUNK_MS = 2000

    def wait(self, max_ms: int) -> None:
        left = int(max_ms)
        while True:
            chunk = min(left, self.WAIT_CHUNK_MS)
            try:
                self._ack("WAIT", *wait_fields(chunk), timeout_s=chunk / 1000.0 + self.transport.timeout_s)
                return
            except NakError as e:
                left -= chunk
                if e.code != "TMO" or left <= 0:
                    raise

    def _move(self, verb: str, values) -> None:
        """``verb`` with one field per axis of ``layout``; a value the layout refuses is a DriverError."""
        try:
            fields = self.layout.fields(values, verb)
        except (ValueError, TypeError) as e:
            raise DriverError(f"{self.role.lower()}{' on ' + self.port if self.port else ''}: {e}") from None
        self._ack(verb, *fields)

    def _ack(self, verb, *fields, **kw) -> None:
        try:
            expect_ack(self.transport.request(verb, *fields, **kw))
        except NakError as e:
            if e.code == "ALARM":
                raise AlarmActive(f"{verb}: {e}") from None
            raise


class OltiRobot(_OltiDevice):
    """:class:`RobotDriver` over the olti protocol (``MOVJ``, ``WAIT``, ``POSJ``, ``ALRM``).

    ``layout``: the SCARA's for a version-1 controller (the frames of version 1, byte for byte),
    the announced joints of a version-2 one (``MOVJ``/``POS`` with one field per joint)."""

    role = "ROBOT"
    v1_layout = SCARA_LAYOUT

    def move(self, command) -> None:
        self._move("MOVJ", command)

    def position(self):
        """Commanded and encoder joints: a :class:`Position` (version 1) or a ``JointPosition`` (N joints)."""
        reply = self.transport.request("POSJ")
        return decode_position(reply) if self.pong.version < 2 else decode_position_n(reply, self.layout)

    def alarms(self, clear: bool = False) -> tuple:
        return decode_alarms(self.transport.request("ALRM", *(("CLR",) if clear else ())))


class OltiCounter(_OltiDevice):
    """:class:`CounterDriver` over the olti protocol (``READ``, ``ZERO``)."""

    role = "COUNTER"

    def read(self) -> Reading:
        return decode_reading(self.transport.request("READ"))

    def zero(self) -> bool:
        try:
            expect_ack(self.transport.request("ZERO"))
        except NakError as e:
            if e.code == "BEAM":
                return False
            raise
        return True


class BenchCounter(OltiCounter):
    """:class:`CounterDriver` of a test bench: the olti counter whose reflector position is set by a
    command, ``REFL,<j>`` (the emulator's bench verb, docs/emulator.md), instead of an operator prompt.

    Named ``counter_driver: bench`` in a ``!Hardware`` scenario, it runs the whole campaign against a
    separately started emulator (``python -m olti_drake.cli.emulator``) or a bench that speaks ``REFL``
    with nobody at the console. The station calls :meth:`set_up_reflector` between reflector runs.
    """

    def set_up_reflector(self, j: int) -> None:
        """Aim at reflector position ``j`` (0-based); the counter needs a ZERO afterwards (the station's)."""
        expect_ack(self.transport.request("REFL", str(int(j))))


class OltiHead(OltiCounter):
    """A pan/tilt head of a floor tracer station with its counter (protocol version 2, role ``HEAD``):
    ``aim((pan, tilt))`` deg, ``wait``, ``position()`` (``HPOS``), and the counter's ``read``/``zero``."""

    role = "HEAD"

    def __init__(self, transport: Transport, pong: Pong | None = None, port: str = ""):
        super().__init__(transport, pong or Pong(2, self.role, ""), port)
        if self.layout is None or self.layout.n != 2:
            raise DriverError(f"head{' on ' + port if port else ''}: a pan/tilt head announces 2 axes, "
                              f"got {None if self.layout is None else self.layout.n}")

    def aim(self, angles) -> None:
        self._move("AIM", angles)

    def position(self):
        return decode_position_n(self.transport.request("POSH"), self.layout, "HPOS")


class TracerHeads:
    """The counter of a floor-tracer campaign: K heads (:class:`OltiHead` or alike), one per station.

    The station's ``reflector`` input selects the head (``set_up_reflector(j)``: no operator, the
    head is there); ``read``, ``zero``, ``aim``, ``wait`` and ``position`` go to the selected head.
    Each head keeps its own counter zero (its dead path)."""

    def __init__(self, heads):
        self.heads = list(heads)
        self.current = 0

    @property
    def head(self):
        return self.heads[self.current]

    def set_up_reflector(self, j: int) -> None:
        if not 0 <= int(j) < len(self.heads):
            raise DriverError(f"tracer station {j} outside 0..{len(self.heads) - 1}")
        self.current = int(j)

    def read(self) -> Reading:
        return self.head.read()

    def zero(self) -> bool:
        return self.head.zero()

    def aim(self, angles) -> None:
        self.head.aim(angles)

    def wait(self, max_ms: int) -> None:
        self.head.wait(max_ms)

    def position(self):
        return self.head.position()

    def close(self) -> None:
        for h in self.heads:
            h.close()


def read_layout(transport: Transport, port: str = "") -> AxisLayout:
    """The axes a version-2 device announces (``INFO``, ``INFO,<k>``); DriverError naming the port."""
    try:
        n = decode_info(transport.request("INFO"))
        return AxisLayout([decode_axis(transport.request("INFO", str(k)), k) for k in range(n)])
    except ProtocolError as e:
        raise DriverError(f"INFO{' on ' + port if port else ''} failed: {type(e).__name__}: {e}") from None


def check_pong(transport: Transport, role: str, port: str = "") -> Pong:
    """PING an olti-protocol device and check its role (``ROBOT``/``COUNTER``/``HEAD``); returns the PONG."""
    where = f" on {port}" if port else ""
    try:
        pong = decode_pong(transport.request("PING"))
    except ProtocolError as e:
        raise DriverError(f"{role.lower()} PING{where} failed: {type(e).__name__}: {e}") from None
    if pong.role != role:
        raise DriverError(f"the device{where} is a {pong.role} ({pong.model}), expected the {role}")
    return pong


def check_role(transport: Transport, role: str, port: str = "") -> str:
    """PING an olti-protocol device and check its role; returns its model."""
    return check_pong(transport, role, port).model


#: Drivers named in scenarios by a short name (robot, counter, tracer head); others by ``module:Class``.
DRIVERS = {"olti": (OltiRobot, OltiCounter, OltiHead), "bench": (OltiRobot, BenchCounter, OltiHead)}


def driver_class(name: str, kind: int):
    """The driver class a scenario names: ``olti``, ``bench`` (the olti robot and :class:`BenchCounter`) or
    ``package.module:Class`` (kind 0 robot, 1 counter, 2 tracer head: ``counter_driver`` names it too)."""
    if name in DRIVERS:
        return DRIVERS[name][kind]
    module, _, cls = name.partition(":")
    if not module or not cls:
        raise ValueError(f"driver {name!r}: expected {' or '.join(repr(k) for k in DRIVERS)} or 'package.module:Class'")
    try:
        return resolve(name)
    except (ImportError, AttributeError) as e:
        raise ValueError(f"driver {name!r}: cannot import ({type(e).__name__}: {e})") from None
