"""Device drivers: what the hardware station needs of a robot controller and of a counter.

:class:`~olti_drake.hardware.station.HardwareStation` talks to devices only through
these two interfaces, so another controller or counter is **one class**
(docs/protocol.md, "How to add a new controller or counter"): implement the
methods of :class:`RobotDriver` or :class:`CounterDriver` over the device's
own protocol and name the class in the scenario
(``station: !Hardware {robot_driver: mypkg.fanuc:FanucRobot}``).

:class:`OltiRobot` and :class:`OltiCounter` implement them over the olti
serial protocol (:mod:`olti_drake.hardware.protocol`), which the emulator speaks too.

Units: joint commands and positions in deg (J1, J2, J4) and mm (J3); the
displacement in mm (formats.md).
"""

from __future__ import annotations

import importlib
from typing import Protocol, Sequence

from olti_drake.io.csvio import InputError
from olti_drake.hardware.protocol import (NakError, Position, ProtocolError, Reading, Transport, decode_alarms, decode_pong,
                       decode_position, decode_reading, expect_ack, movj_fields, wait_fields)


class DriverError(RuntimeError):
    """A device request failed (base class for drivers of other protocols; the message names it)."""


class AlarmActive(DriverError):
    """The controller refused or stopped a motion because an alarm is active."""


class RobotDriver(Protocol):
    """A robot controller. Errors: :class:`AlarmActive`, :class:`DriverError` or ``ProtocolError``.

    Opened by the station factory as ``cls.open(port, baud, timeout_s, retries)`` and released by
    ``close()`` (both also for :class:`CounterDriver`).
    """

    def move(self, command: Sequence[float]) -> None:
        """Start a joint move to ``command`` = (θ1*, θ2* deg, z mm, θ4* deg)."""

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


class _OltiDevice:
    """A device on an olti-protocol line: ``open`` checks its role with ``PING``."""

    role = ""

    def __init__(self, transport: Transport):
        self.transport = transport

    @classmethod
    def open(cls, port: str, baud: int, timeout_s: float, retries: int):
        """Open the serial ``port`` (pyserial), check the device's role; a one-line error if not."""
        stream = open_serial(port, baud, cls.role.lower())
        try:
            transport = Transport(stream, timeout_s=timeout_s, retries=retries)
            check_role(transport, cls.role, port)
        except BaseException:
            stream.close()
            raise
        return cls(transport)

    def close(self) -> None:
        self.transport.stream.close()


class OltiRobot(_OltiDevice):
    """:class:`RobotDriver` over the olti protocol (``MOVJ``, ``WAIT``, ``POSJ``, ``ALRM``)."""

    role = "ROBOT"

    def move(self, command) -> None:
        self._ack("MOVJ", *movj_fields(*command))

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

    def position(self) -> Position:
        return decode_position(self.transport.request("POSJ"))

    def alarms(self, clear: bool = False) -> tuple:
        return decode_alarms(self.transport.request("ALRM", *(("CLR",) if clear else ())))

    def _ack(self, verb, *fields, **kw) -> None:
        try:
            expect_ack(self.transport.request(verb, *fields, **kw))
        except NakError as e:
            if e.code == "ALARM":
                raise AlarmActive(f"{verb}: {e}") from None
            raise


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


def check_role(transport: Transport, role: str, port: str = "") -> str:
    """PING an olti-protocol device and check its role (``ROBOT``/``COUNTER``); returns its model."""
    where = f" on {port}" if port else ""
    try:
        pong = decode_pong(transport.request("PING"))
    except ProtocolError as e:
        raise DriverError(f"{role.lower()} PING{where} failed: {type(e).__name__}: {e}") from None
    if pong.role != role:
        raise DriverError(f"the device{where} is a {pong.role} ({pong.model}), expected the {role}")
    return pong.model


#: Drivers named in scenarios by a short name; others by ``module:Class``.
DRIVERS = {"olti": (OltiRobot, OltiCounter)}


def driver_class(name: str, kind: int):
    """The driver class a scenario names: ``olti`` or ``package.module:Class`` (kind 0 robot, 1 counter)."""
    if name in DRIVERS:
        return DRIVERS[name][kind]
    module, _, cls = name.partition(":")
    if not module or not cls:
        raise ValueError(f"driver {name!r}: expected 'olti' or 'package.module:Class'")
    try:
        return getattr(importlib.import_module(module), cls)
    except (ImportError, AttributeError) as e:
        raise ValueError(f"driver {name!r}: cannot import ({type(e).__name__}: {e})") from None


def open_serial(port: str, baud: int, what: str):
    """``serial.Serial(port, baud, timeout=0.05)``, or a one-line InputError naming the port."""
    import serial

    try:
        return serial.Serial(port, baud, timeout=0.05)
    except (OSError, ValueError) as e:  # SerialException is an OSError
        detail = " ".join(str(e).split())
        raise InputError(f"station: cannot open the {what} port {port}: {detail}") from None
