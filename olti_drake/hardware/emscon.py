"""Leica emScon (CESAPI) framing: the subset a laser-tracker station needs, and a client for it.

The binary TCP protocol of Leica laser trackers (emScon server, port 700), as its published C header
``ES_C_API_Def.h`` (TPI/SDK 3.6) lays it out: little-endian, structures packed to 4 bytes, ``long`` and
every enum 4 bytes. Every packet starts with ``PacketHeaderT {long lPacketSize; ES_DataType type}``
(8 bytes; the size counts the whole packet); a command adds ``ES_Command command`` (``BasicCommandCT``:
the 12-byte header of every request) and its parameters; its answer (``BasicCommandRT``) adds
``ES_ResultStatus status`` (16 bytes) and the answer's data. ``StartMeasurement`` is answered by its
``BasicCommandRT`` and, when that status is ``ES_RS_AllOK``, by one ``SingleMeasResultT`` packet
(``ES_DT_SingleMeasResult``: status, mode, the point, its standard deviations, pointing errors and the
environment). docs/tracker.md lists the subset, every number and what the emulator does.

Strict: :func:`read_packet` and the decoders refuse a size field that disagrees with the bytes or with
the structure of its type and command, an unknown type or command, a truncated packet and non-finite
numbers, each with an :class:`EmsconError` -- never a measurement. A status that says the tracker has
no reflector in its beam is a :class:`BeamLost`. No checksum exists in emScon (TCP's covers the line):
a changed digit of a coordinate cannot be seen here.

Units on the wire are the session's (``SetUnits``); :class:`EmsconTracker` sets millimetres, degrees,
Celsius, hPa and %RH at ``initialize`` and converts nothing: it speaks mm.
"""

from __future__ import annotations

import math
import socket
import struct
import time
from dataclasses import dataclass
from typing import Optional

from olti_drake.hardware.drivers import DriverError
from olti_drake.hardware.protocol import ProtocolError

#: The emScon server's TCP port on a real tracker.
DEFAULT_PORT = 700
#: Largest packet this implementation accepts (bytes): every supported packet is < 200 bytes.
MAX_PACKET = 1024

# ES_DataType
DT_COMMAND, DT_ERROR, DT_SINGLE_RESULT, DT_STATUS_CHANGE = 0, 1, 2, 8
# ES_Command (the subset; the numbers of ES_C_API_Def.h)
C_GET_SYSTEM_STATUS, C_SET_UNITS, C_GET_UNITS, C_INITIALIZE = 1, 5, 6, 7
C_SET_ENVIRONMENT, C_GET_ENVIRONMENT, C_START_MEASUREMENT = 20, 21, 49
C_SET_MEAS_MODE, C_GET_MEAS_MODE, C_SET_COORD_TYPE, C_GET_COORD_TYPE = 24, 25, 26, 27
C_GO_POSITION, C_POINT_LASER, C_UNKNOWN = 55, 58, 64
# ES_ResultStatus (the subset)
RS_ALL_OK, RS_NOT_IMPLEMENTED, RS_WRONG_PARAMETER, RS_WRONG_PARAMETER1 = 0, 2, 3, 4
RS_TRACKER_NOT_INITIALIZED, RS_INVALID_INPUT_DATA = 39, 98
RS_MEAS_STATUS_NOT_READY = 10004          # ES_API_ERROR_OFFSET (10000) + 4: no reflector in the beam
#: Statuses that mean the beam does not reach a reflector (pointed away, interrupted, reflector lost).
BEAM_STATUSES = (RS_MEAS_STATUS_NOT_READY,)
# ES_LengthUnit, ES_AngleUnit, ES_TemperatureUnit, ES_PressureUnit, ES_HumidityUnit (the subset)
LU_METER, LU_MILLIMETER = 0, 1
AU_RADIAN, AU_DEGREE = 0, 1
TU_CELSIUS, TU_FAHRENHEIT = 0, 1
PU_MBAR, PU_HPASCAL = 0, 1
HU_RH = 0
#: The session's units after :meth:`EmsconTracker.initialize`: mm, degrees, Celsius, hPa, %RH.
UNITS_MM = (LU_MILLIMETER, AU_DEGREE, TU_CELSIUS, PU_HPASCAL, HU_RH)

NAMES = {C_GET_SYSTEM_STATUS: "GetSystemStatus", C_SET_UNITS: "SetUnits", C_GET_UNITS: "GetUnits",
         C_INITIALIZE: "Initialize", C_SET_ENVIRONMENT: "SetEnvironmentParams",
         C_GET_ENVIRONMENT: "GetEnvironmentParams", C_START_MEASUREMENT: "StartMeasurement",
         C_GO_POSITION: "GoPosition", C_POINT_LASER: "PointLaser", C_UNKNOWN: "Unknown",
         C_SET_MEAS_MODE: "SetMeasurementMode", C_GET_MEAS_MODE: "GetMeasurementMode",
         C_SET_COORD_TYPE: "SetCoordinateSystemType", C_GET_COORD_TYPE: "GetCoordinateSystemType"}
#: ES_MeasMode stationary and ES_CoordinateSystemType right-handed Cartesian: the only ones implemented.
MM_STATIONARY, CS_RHR = 0, 0

HEADER = struct.Struct("<ii")                 # PacketHeaderT: lPacketSize, type
#: Per supported command: (its parameters after BasicCommandCT, its answer's data after BasicCommandRT),
#: struct format codes (i: a long/enum/ES_BOOL, d: a double).
COMMANDS = {C_INITIALIZE: ("", ""), C_SET_UNITS: ("5i", ""), C_GET_UNITS: ("", "5i"),
            C_SET_ENVIRONMENT: ("3d", ""), C_GET_ENVIRONMENT: ("", "3d"), C_START_MEASUREMENT: ("", ""),
            C_GO_POSITION: ("3di", ""), C_POINT_LASER: ("3d", ""), C_SET_MEAS_MODE: ("i", ""),
            C_GET_MEAS_MODE: ("", "i"), C_SET_COORD_TYPE: ("i", ""), C_GET_COORD_TYPE: ("", "i")}
#: SingleMeasResultT after its ReturnDataT (header + status): measMode, bIsTryMode, then 17 doubles
#: (dVal1..3, dStd1..3, dStdTotal, dPointingError1..3, dAprioriStd1..3, dAprioriStdTotal, T, P, H).
RESULT_DATA = "ii17d"


def _struct(kind: str, data: str) -> struct.Struct:
    head = {"command": "<iii", "answer": "<iiii", "result": "<iii"}[kind]
    return struct.Struct(head + data)


REQUESTS = {c: _struct("command", p) for c, (p, _) in COMMANDS.items()}
ANSWERS = {c: _struct("answer", a) for c, (_, a) in COMMANDS.items()}
RESULT = _struct("result", RESULT_DATA)
BASIC_ANSWER = _struct("answer", "")         # BasicCommandRT: the answer of a refused command (no data)
ERROR = struct.Struct("<iiii")               # ErrorResponseT: header, command, status
STATUS_CHANGE = struct.Struct("<iii")        # SystemStatusChangeT: header, systemStatusChange


class EmsconError(ProtocolError):
    """A malformed, truncated or unexpected packet, or a command the tracker refused (names it)."""

    def __init__(self, message: str, status: Optional[int] = None):
        super().__init__(message)
        self.status = status


class BeamLost(EmsconError):
    """The tracker has no reflector in its beam (pointed away, beam interrupted, reflector lost)."""


class NotImplementedCommand(EmsconError):
    """The command number is not one this implementation (or the tracker) knows."""


# ------------------------------------------------------------------ encoding

def _finite(values, where: str) -> None:
    for k, v in enumerate(values):
        if isinstance(v, float) and not math.isfinite(v):
            raise EmsconError(f"{where}: parameter {k + 1} is {v!r}, not a finite number",
                              RS_WRONG_PARAMETER1 + min(k, 6))


def encode_command(command: int, *values) -> bytes:
    """A request packet (``<Name>CT``) with its parameters (in the session's units)."""
    s = REQUESTS[command]
    _finite(values, NAMES[command])
    return s.pack(s.size, DT_COMMAND, command, *values)


def encode_answer(command: int, status: int, *values) -> bytes:
    """An answer (``<Name>RT``); a refused command carries no data (``BasicCommandRT``, 16 bytes)."""
    ok = status == RS_ALL_OK
    s = ANSWERS[command] if ok else BASIC_ANSWER
    return s.pack(s.size, DT_COMMAND, command, status, *(values if ok else ()))


def encode_error(command: int, status: int) -> bytes:
    """An ``ErrorResponseT`` (``ES_DT_Error``): what the server sends when it cannot parse a request."""
    return ERROR.pack(ERROR.size, DT_ERROR, command, status)


def encode_result(values17, status: int = RS_ALL_OK, mode: int = 0, try_mode: int = 0) -> bytes:
    """A ``SingleMeasResultT`` packet (156 bytes)."""
    return RESULT.pack(RESULT.size, DT_SINGLE_RESULT, status, mode, try_mode, *values17)


# ------------------------------------------------------------------ decoding

def check_header(head: bytes) -> tuple:
    """(size, type) of an 8-byte header; EmsconError for a size outside 12..MAX_PACKET."""
    if len(head) != HEADER.size:
        raise EmsconError(f"truncated packet header: {len(head)} of {HEADER.size} bytes")
    size, kind = HEADER.unpack(head)
    if not 12 <= size <= MAX_PACKET:
        raise EmsconError(f"packet size field {size} outside 12..{MAX_PACKET} bytes: framing lost")
    return size, kind


def read_exactly(sock, n: int, deadline: float) -> bytes:
    """``n`` bytes from ``sock`` before ``deadline`` (time.monotonic); EmsconError if cut short."""
    buf = bytearray()
    while len(buf) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            raise EmsconError(f"timed out after {len(buf)} of {n} bytes of a packet")
        sock.settimeout(left)
        try:
            chunk = sock.recv(n - len(buf))
        except socket.timeout:
            continue
        if not chunk:
            raise EmsconError(f"connection closed after {len(buf)} of {n} bytes of a packet")
        buf += chunk
    return bytes(buf)


def read_packet(sock, timeout_s: float) -> bytes:
    """One whole packet (its header's size) from ``sock`` within ``timeout_s``; EmsconError if not."""
    deadline = time.monotonic() + timeout_s
    head = read_exactly(sock, HEADER.size, deadline)
    size, _ = check_header(head)
    return head + read_exactly(sock, size - HEADER.size, deadline)


def _unpack(s: struct.Struct, packet: bytes, what: str) -> tuple:
    size = HEADER.unpack_from(packet)[0] if len(packet) >= HEADER.size else -1
    if len(packet) != s.size or size != s.size:
        raise EmsconError(f"{what}: {len(packet)} bytes with size field {size}, the structure has {s.size}",
                          RS_WRONG_PARAMETER)
    values = s.unpack(packet)
    _finite(values, what)
    return values


def decode_request(packet: bytes) -> tuple:
    """Server side: (command, parameters) of a request packet. EmsconError (``status``: what to answer)
    for another data type, an unknown command (:class:`NotImplementedCommand`) or a wrong size."""
    size, kind = check_header(packet[:HEADER.size])
    if kind != DT_COMMAND or len(packet) < 12:
        raise EmsconError(f"data type {kind}: a request must be ES_DT_Command (0)", RS_INVALID_INPUT_DATA)
    command = struct.unpack_from("<i", packet, 8)[0]
    if command not in REQUESTS:
        raise NotImplementedCommand(f"command {command} not implemented", RS_NOT_IMPLEMENTED)
    return command, _unpack(REQUESTS[command], packet, NAMES[command])[3:]


@dataclass(frozen=True)
class Answer:
    """A decoded packet from the tracker: ``kind`` (data type), ``command`` (None for a result or a status
    change), ``status`` and ``values`` (the data after the status)."""
    kind: int
    command: Optional[int]
    status: int
    values: tuple


def decode_answer(packet: bytes) -> Answer:
    """Client side: any packet the tracker sends (an answer, an error, a result, a status change)."""
    size, kind = check_header(packet[:HEADER.size])
    if kind == DT_COMMAND:
        command = struct.unpack_from("<i", packet, 8)[0] if len(packet) >= 12 else None
        if command not in ANSWERS:
            raise EmsconError(f"answer to command {command}, not one this client sent")
        status = struct.unpack_from("<i", packet, 12)[0] if len(packet) >= 16 else None
        full = ANSWERS[command] if status == RS_ALL_OK else BASIC_ANSWER
        v = _unpack(full, packet, f"{NAMES[command]} answer")
        return Answer(kind, command, v[3], v[4:])
    if kind == DT_ERROR:
        v = _unpack(ERROR, packet, "error response")
        return Answer(kind, v[2], v[3], ())
    if kind == DT_SINGLE_RESULT:
        v = _unpack(RESULT, packet, "single measurement result")
        return Answer(kind, None, v[2], v[3:])
    if kind == DT_STATUS_CHANGE:
        v = _unpack(STATUS_CHANGE, packet, "system status change")
        return Answer(kind, None, RS_ALL_OK, v[2:])
    raise EmsconError(f"packet of data type {kind}: not one this client takes")


def status_error(command: int, status: int) -> EmsconError:
    """The exception of a refused command: :class:`BeamLost` for the beam statuses."""
    cls = BeamLost if status in BEAM_STATUSES else EmsconError
    return cls(f"{NAMES.get(command, command)}: tracker status {status}"
               + (" (no reflector in the beam)" if status in BEAM_STATUSES else ""), status)


# ------------------------------------------------------------------ the client

@dataclass(frozen=True)
class Measurement:
    """One stationary measurement: the point (mm, tracker frame: x, y, z), its standard deviations (mm),
    the environment the tracker used (°C, hPa, %RH), and its spherical coordinates."""
    x_mm: float
    y_mm: float
    z_mm: float
    std_mm: tuple
    temperature_c: float
    pressure_hpa: float
    humidity_pct: float

    @property
    def point_mm(self) -> tuple:
        return (self.x_mm, self.y_mm, self.z_mm)

    @property
    def environment(self) -> tuple:
        return (self.temperature_c, self.pressure_hpa, self.humidity_pct)

    def spherical(self) -> tuple:
        """(horizontal angle deg from +x toward +y, elevation deg above the xy plane, distance mm)."""
        d = math.sqrt(self.x_mm ** 2 + self.y_mm ** 2 + self.z_mm ** 2)
        return (math.degrees(math.atan2(self.y_mm, self.x_mm)),
                math.degrees(math.asin(self.z_mm / d)) if d > 0 else 0.0, d)


def measurement_of(values: tuple) -> Measurement:
    """A :class:`Measurement` of a SingleMeasResultT's data (mode, try mode, 17 doubles; session in mm)."""
    v = values[2:]
    return Measurement(v[0], v[1], v[2], tuple(v[3:6]), v[14], v[15], v[16])


class EmsconTracker:
    """A laser tracker over emScon TCP (a real one on port 700, or the emulator).

    ``open(host, port, timeout_s)`` connects; :meth:`initialize` runs ``Initialize`` and sets the units
    to mm/deg/°C/hPa/%RH; :meth:`point_laser` and :meth:`go_position` steer the beam at a point (mm,
    tracker frame); :meth:`measure` runs ``StartMeasurement`` and returns a :class:`Measurement`, or raises
    :class:`BeamLost` (no reflector in the beam) or :class:`EmsconError`. ``timeout_s`` bounds each answer;
    ``Initialize`` may take longer on a real tracker (``INITIALIZE_TIMEOUT_S``).
    """

    INITIALIZE_TIMEOUT_S = 90.0

    def __init__(self, sock, timeout_s: float = 5.0, where: str = ""):
        self.sock, self.timeout_s, self.where = sock, float(timeout_s), where

    @classmethod
    def open(cls, host: str, port: int = DEFAULT_PORT, timeout_s: float = 5.0) -> "EmsconTracker":
        try:
            sock = socket.create_connection((host, int(port)), timeout=timeout_s)
        except OSError as e:
            raise DriverError(f"tracker {host}:{port}: cannot connect ({' '.join(str(e).split())})") from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return cls(sock, timeout_s, f"{host}:{port}")

    def close(self) -> None:
        self.sock.close()

    def _receive(self, timeout_s: Optional[float] = None) -> Answer:
        """The next packet that is not a status change."""
        while True:
            a = decode_answer(read_packet(self.sock, timeout_s or self.timeout_s))
            if a.kind != DT_STATUS_CHANGE:
                return a

    def request(self, command: int, *values, timeout_s: Optional[float] = None) -> tuple:
        """Send a command and return its answer's data; the error of a non-OK status or a stray packet."""
        self.sock.sendall(encode_command(command, *values))
        a = self._receive(timeout_s)
        if a.kind == DT_ERROR and a.status != RS_ALL_OK:
            raise status_error(command, a.status)     # the server could not take the request
        if a.kind != DT_COMMAND or a.command != command:
            raise EmsconError(f"{NAMES[command]}: got a packet of type {a.kind} for command {a.command}")
        if a.status != RS_ALL_OK:
            raise status_error(command, a.status)
        return a.values

    def initialize(self) -> None:
        self.request(C_INITIALIZE, timeout_s=self.INITIALIZE_TIMEOUT_S)
        self.set_units(UNITS_MM)

    def set_units(self, units=UNITS_MM) -> None:
        self.request(C_SET_UNITS, *units)

    def get_units(self) -> tuple:
        return self.request(C_GET_UNITS)

    def environment(self) -> tuple:
        """(temperature, pressure, humidity) in the session's units (°C, hPa, %RH)."""
        return self.request(C_GET_ENVIRONMENT)

    def set_environment(self, temperature_c: float, pressure_hpa: float, humidity_pct: float) -> None:
        self.request(C_SET_ENVIRONMENT, float(temperature_c), float(pressure_hpa), float(humidity_pct))

    def point_laser(self, point_mm) -> None:
        self.request(C_POINT_LASER, *(float(v) for v in point_mm))

    def go_position(self, point_mm, use_adm: bool = True) -> None:
        self.request(C_GO_POSITION, *(float(v) for v in point_mm), int(bool(use_adm)))

    def measure(self) -> Measurement:
        """StartMeasurement: its answer, then exactly one single-measurement result with status OK."""
        self.request(C_START_MEASUREMENT)
        a = self._receive()
        if a.kind != DT_SINGLE_RESULT:
            raise EmsconError(f"StartMeasurement: expected a single measurement result, got type {a.kind}")
        if a.status != RS_ALL_OK:
            raise status_error(C_START_MEASUREMENT, a.status)
        return measurement_of(a.values)
