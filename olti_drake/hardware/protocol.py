"""Line-based serial protocol of the robot controller and the interferometer counter.

The specification is ``docs/protocol.md``; this module is its reference implementation, pure
Python (no pydrake, no numpy, no serial port needed):

- ``encode(seq, verb, *fields) -> bytes`` and ``FrameParser`` (incremental, never raises on
  garbage, never returns a frame whose checksum or syntax is wrong);
- field formatters (``movj_fields``, ``dis_fields``, ...) and typed decoders (``decode_reading``,
  ``decode_position``, ...) that raise a one-line ``ProtocolError`` naming the frame and field;
- ``Transport``: host side, ``request(verb, *fields) -> Frame`` over any byte stream with
  ``write(bytes)`` and ``read(n)`` (a ``serial.Serial`` opened with a short ``timeout``);
- ``Responder``: device side, for emulators: bytes in, reply bytes out, one ``on_<VERB>`` method
  per verb on a handler object;
- version 2 (N-axis devices and pan/tilt heads): ``AxisLayout`` (the axes a device announces with
  ``INFO``/``AXS``; ``SCARA_LAYOUT`` is version 1's), joint vectors of one field per axis
  (``AxisLayout.fields``, ``decode_vector``, ``decode_position_n``) with per-axis range checks
  (``RangeError``), and the head verbs ``AIM`` and ``POSH``/``HPOS``.

Frame: ``$<SEQ>,<VERB>[,<field>...]*<CRC>\\n`` with CRC = CRC-16/CCITT-FALSE of the bytes between
``$`` and ``*``, as 4 uppercase hex digits.
"""

from __future__ import annotations

import binascii
import collections
import logging
import math
import random
import re
import time
from dataclasses import dataclass

PROTOCOL_VERSION = 1
MAX_LINE = 256  # bytes from '$' to the last CRC digit; the '\n' or '\r\n' terminator not counted
SEQ_MODULO = 65536
MAX_WAIT_MS = 600_000

REQUEST_VERBS = ("PING", "MOVJ", "WAIT", "POSJ", "ALRM", "READ", "ZERO", "INFO", "AIM", "POSH")
REPLY_VERBS = ("ACK", "NAK", "PONG", "POS", "ALM", "DIS", "INF", "AXS", "HPOS")
#: PING roles: a robot controller, an interferometer counter, a pan/tilt head with its counter (a tracer).
ROLES = ("ROBOT", "COUNTER", "HEAD")
NAK_CODES = {
    "CRC": "the request's checksum did not match; the host resends it with the same SEQ",
    "SYN": "the request's fields are wrong: count, number format, or a value outside the grammar",
    "VERB": "the device does not know this verb",
    "RANGE": "a value is outside the device's limits (joint range, WAIT time)",
    "BUSY": "a motion is in progress (MOVJ before the previous one is in position)",
    "ALARM": "an alarm is active; read it with ALRM, clear it with ALRM,CLR",
    "TMO": "WAIT: not in position within max_ms",
    "BEAM": "ZERO: no beam at the counter",
    "HW": "device fault; the text says which",
}

_log = logging.getLogger(__name__)

_VERB = re.compile(r"[A-Z]{1,8}")
_FIELD_BAD = re.compile(r"[^\x20-\x7e]|[,*$]")
_BODY = re.compile(rb"(0|[1-9][0-9]{0,4}),([A-Z]{1,8})((?:,[^,*$]*)*)")
_LEADING_SEQ = re.compile(rb"(0|[1-9][0-9]{0,4}),")
_HEX4 = re.compile(rb"[0-9A-F]{4}")
_DELIM = re.compile(rb"[$\n]")
_NONPRINT = re.compile(rb"[^\x20-\x7e]")
_DECIMAL = re.compile(r"-?[0-9]{1,9}(?:\.[0-9]{1,12})?")
_UINT = re.compile(r"0|[1-9][0-9]{0,8}")
_TOKEN = re.compile(r"[A-Z0-9_]{1,16}")


# ----------------------------------------------------------------------------- errors

class ProtocolError(Exception):
    """Anything wrong on the line: a bad frame, a bad field, a NAK, no reply."""


class FrameError(ProtocolError):
    """A parser event: a line that is not a valid frame. Returned by ``FrameParser.feed``, not raised.

    ``raw`` is (the start of) the offending bytes; ``seq`` the SEQ that could be read, else None.
    """

    def __init__(self, detail: str, raw: bytes = b"", seq: int | None = None):
        self.detail, self.raw, self.seq = detail, bytes(raw[:64]), seq
        super().__init__(f"{type(self).__name__}: {detail}: {self.raw!r}")


class ChecksumError(FrameError):
    """The CRC does not match the body."""


class FrameSyntaxError(FrameError):
    """The line does not follow the frame grammar (checksum trailer, SEQ, VERB, characters)."""


class OverlongLine(FrameError):
    """More than MAX_LINE bytes without a terminator; discarded up to the next '\\n' or '$'."""


class NonAsciiError(FrameError):
    """A byte >= 0x80 inside a frame."""


class PartialFrame(FrameError):
    """A frame cut off: by a new '$', or still incomplete at a timeout (``FrameParser.flush``)."""


class NoiseError(FrameError):
    """Bytes outside any frame (before a '$' on a line); blank lines are not noise."""


class FieldError(ProtocolError):
    """A frame that is valid on the line but whose fields are not what its verb requires."""

    def __init__(self, frame: "Frame", what: str):
        self.frame, self.what = frame, what
        super().__init__(f"{frame.verb} frame {frame}: {what}")


class NakError(ProtocolError):
    """The device refused the request: ``NAK,<code>,<text>``. Devices raise it to refuse."""

    def __init__(self, code: str, text: str = "", request: "Frame | None" = None):
        self.code, self.text, self.request = code, text, request
        where = f" to {request}" if request is not None else ""
        super().__init__(f"NAK {code}{where}: {text}")


class TransportTimeout(ProtocolError):
    """No valid reply after all attempts."""


class LinkLost(ProtocolError):
    """The serial line failed (device unplugged, pty closed): no retry can help."""


# ----------------------------------------------------------------------------- frames

def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, not reflected, xorout 0 (check "123456789" -> 0x29B1)."""
    return binascii.crc_hqx(data, 0xFFFF)


@dataclass(frozen=True)
class Frame:
    seq: int
    verb: str
    fields: tuple[str, ...] = ()

    def to_bytes(self) -> bytes:
        return encode(self.seq, self.verb, *self.fields)

    def __str__(self) -> str:
        try:
            return self.to_bytes().decode("ascii").rstrip("\n")
        except (ValueError, TypeError):  # a hand-built frame the grammar forbids: show it, never raise
            return "$" + ",".join(map(repr, (self.seq, self.verb) + tuple(self.fields))) + "*????"


def encode(seq: int, verb: str, *fields: str) -> bytes:
    """The frame ``$<seq>,<verb>[,<field>...]*<CRC>\\n``; ValueError/TypeError on anything the grammar forbids."""
    if type(seq) is not int or not 0 <= seq < SEQ_MODULO:
        raise ValueError(f"SEQ must be an int 0..{SEQ_MODULO - 1}, got {seq!r}")
    if not isinstance(verb, str) or not _VERB.fullmatch(verb):
        raise ValueError(f"VERB must be 1-8 uppercase letters A-Z, got {verb!r}")
    for i, f in enumerate(fields):
        if not isinstance(f, str):
            raise TypeError(f"{verb} field {i}: fields are str (format numbers first), got {type(f).__name__}")
        if _FIELD_BAD.search(f):
            raise ValueError(f"{verb} field {i} {f!r}: printable ASCII only, without ',' '*' '$'")
    body = ",".join((str(seq), verb) + fields).encode("ascii")
    line = b"$" + body + b"*%04X" % crc16(body)
    if len(line) > MAX_LINE:
        raise ValueError(f"{verb} frame is {len(line)} bytes, more than MAX_LINE = {MAX_LINE}")
    return line + b"\n"


def decode_line(line: bytes) -> "Frame | FrameError":
    """One line from '$' to the last CRC digit (no terminator) -> Frame, or the FrameError it is."""
    seq = _leading_seq(line[1:])
    if len(line) > MAX_LINE:
        return OverlongLine(f"{len(line)} bytes > {MAX_LINE}", line, seq)
    bad = _NONPRINT.search(line)
    if bad:
        kind = NonAsciiError if bad.group()[0] >= 0x80 else FrameSyntaxError
        return kind(f"byte 0x{bad.group()[0]:02X} at offset {bad.start()}", line, seq)
    if not line.startswith(b"$") or len(line) < 6 or line[-5:-4] != b"*" or not _HEX4.fullmatch(line[-4:]):
        return FrameSyntaxError("no '*HHHH' checksum (4 uppercase hex digits) at the end", line, seq)
    body = line[1:-5]
    got, want = int(line[-4:], 16), crc16(body)
    if got != want:
        return ChecksumError(f"CRC {got:04X} != computed {want:04X}", line, seq)
    m = _BODY.fullmatch(body)
    if m is None or int(m.group(1)) >= SEQ_MODULO:
        return FrameSyntaxError("body is not <SEQ 0..65535>,<VERB A-Z{1,8}>[,<field>...]", line, seq)
    rest = m.group(3).decode("ascii")
    return Frame(int(m.group(1)), m.group(2).decode("ascii"), tuple(rest.split(",")[1:]) if rest else ())


def _leading_seq(body: bytes) -> int | None:
    m = _LEADING_SEQ.match(body)
    return int(m.group(1)) if m and int(m.group(1)) < SEQ_MODULO else None


class FrameParser:
    """Incremental parser: ``feed(bytes) -> [Frame | FrameError, ...]`` in line order.

    A '$' always starts a new frame (an unfinished one before it is a PartialFrame); a '\\n' always
    ends one. Bytes outside frames are reported once per line as NoiseError. A frame longer than
    MAX_LINE is reported once and discarded up to the next '\\n' or '$'. Memory is bounded by MAX_LINE.
    ``feed`` never raises on any input; errors are returned, never raised.
    """

    _IDLE, _FRAME, _DISCARD = range(3)

    def __init__(self) -> None:
        self._state = self._IDLE
        self._buf = bytearray()
        self._noise = 0
        self._noise_head = b""

    def feed(self, data: bytes) -> list:
        out: list = []
        data = bytes(data)
        pos, n = 0, len(data)
        while pos < n:
            m = _DELIM.search(data, pos)
            end = m.start() if m else n
            if end > pos:
                self._take(data[pos:end], out)
            if m is None:
                break
            if data[end] == 0x24:  # '$'
                self._end_noise(out)
                if self._state == self._FRAME:
                    out.append(PartialFrame("interrupted by a new '$'", self._buf, _leading_seq(self._buf[1:])))
                self._state, self._buf = self._FRAME, bytearray(b"$")
            else:  # '\n'
                if self._state == self._FRAME:
                    line = bytes(self._buf[:-1] if self._buf.endswith(b"\r") else self._buf)
                    out.append(decode_line(line))
                self._end_noise(out, eol=True)
                self._state, self._buf = self._IDLE, bytearray()
            pos = end + 1
        return out

    def flush(self) -> list:
        """At a timeout: report and drop an incomplete line (PartialFrame / NoiseError)."""
        out: list = []
        if self._state == self._FRAME:
            out.append(PartialFrame("incomplete at timeout", self._buf, _leading_seq(self._buf[1:])))
        self._end_noise(out)
        self._state, self._buf = self._IDLE, bytearray()
        return out

    def _take(self, chunk: bytes, out: list) -> None:
        if self._state == self._FRAME:
            self._buf += chunk[:MAX_LINE + 2 - len(self._buf)]  # bounded, whatever the chunk size
            if len(self._buf) > MAX_LINE + 1:  # +1: a '\r' of a '\r\n' terminator is not counted
                out.append(OverlongLine(f"no terminator within {MAX_LINE} bytes", self._buf,
                                        _leading_seq(self._buf[1:])))
                self._state, self._buf = self._DISCARD, bytearray()
        elif self._state == self._IDLE:
            self._noise += len(chunk)
            if len(self._noise_head) < 64:
                self._noise_head += chunk[:64 - len(self._noise_head)]

    def _end_noise(self, out: list, eol: bool = False) -> None:
        if self._noise and not (eol and self._noise_head == b"\r"):  # "\r\n" alone is a blank line
            out.append(NoiseError(f"{self._noise} bytes outside a frame", self._noise_head))
        self._noise, self._noise_head = 0, b""


# ----------------------------------------------------------------------------- fields

@dataclass(frozen=True)
class Joints:
    """A SCARA joint vector: J1, J2 (deg), J3 = z (mm), J4 (deg)."""
    theta1_deg: float
    theta2_deg: float
    z_mm: float
    theta4_deg: float

    def __iter__(self):
        """The four values in wire order (so a SCARA position is a joint vector like an N-axis one)."""
        return iter((self.theta1_deg, self.theta2_deg, self.z_mm, self.theta4_deg))


@dataclass(frozen=True)
class Position:
    """POSJ reply: the commanded joints and the encoder joints."""
    commanded: Joints
    encoder: Joints


@dataclass(frozen=True)
class Reading:
    """READ reply: displacement (mm), the counter's explicit valid flag, its raw status text."""
    displacement_mm: float
    valid: bool
    status: str


@dataclass(frozen=True)
class Pong:
    version: int
    role: str  # "ROBOT" or "COUNTER"
    model: str


def fmt_number(x: float, decimals: int, name: str = "value") -> str:
    """``x`` with ``decimals`` decimals; ValueError for NaN, inf, non-numbers or more than 9 integer digits."""
    if isinstance(x, (bool, str, bytes)) or not hasattr(x, "__float__"):
        raise TypeError(f"{name}: a number, got {x!r}")
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"{name}: finite number required, got {x!r}")
    s = f"{x:.{decimals}f}"
    if not _DECIMAL.fullmatch(s):
        raise ValueError(f"{name}: {x!r} does not fit the decimal format (at most 9 integer digits)")
    return s


def fmt_deg(x: float, name: str = "angle_deg") -> str:
    return fmt_number(x, 6, name)


def fmt_mm(x: float, name: str = "length_mm") -> str:
    return fmt_number(x, 6, name)


def fmt_displacement(x: float) -> str:
    return fmt_number(x, 9, "displacement_mm")


def safe_text(text: str, limit: int = 120) -> str:
    """Free text made field-safe: ',' '*' '$' and non-printables become ' ', cut to ``limit`` chars."""
    return _FIELD_BAD.sub(" ", str(text))[:limit]


def joint_fields(j: Joints) -> tuple[str, ...]:
    return (fmt_deg(j.theta1_deg, "theta1_deg"), fmt_deg(j.theta2_deg, "theta2_deg"),
            fmt_mm(j.z_mm, "z_mm"), fmt_deg(j.theta4_deg, "theta4_deg"))


def movj_fields(theta1_deg: float, theta2_deg: float, z_mm: float, theta4_deg: float) -> tuple[str, ...]:
    return joint_fields(Joints(theta1_deg, theta2_deg, z_mm, theta4_deg))


def wait_fields(max_ms: int) -> tuple[str, ...]:
    if type(max_ms) is not int or not 1 <= max_ms <= MAX_WAIT_MS:
        raise ValueError(f"WAIT max_ms: an int 1..{MAX_WAIT_MS}, got {max_ms!r}")
    return (str(max_ms),)


def pos_fields(commanded: Joints, encoder: Joints) -> tuple[str, ...]:
    return joint_fields(commanded) + joint_fields(encoder)


def dis_fields(displacement_mm: float, valid: bool, status: str) -> tuple[str, ...]:
    if not isinstance(valid, bool):
        raise TypeError(f"valid: a bool, got {valid!r}")
    _check_status(status, "dis_fields")
    return (fmt_displacement(displacement_mm), "1" if valid else "0", status)


def alm_fields(codes) -> tuple[str, ...]:
    codes = tuple(codes)
    for c in codes:
        if not isinstance(c, str) or not _TOKEN.fullmatch(c):
            raise ValueError(f"alarm code {c!r}: 1-16 of A-Z 0-9 _")
    return (str(len(codes)),) + codes


def nak_fields(code: str, text: str = "") -> tuple[str, ...]:
    """``(code, text)``: code 1-8 uppercase letters (NAK_CODES lists the standard ones), text made safe."""
    if not isinstance(code, str) or not _VERB.fullmatch(code):
        raise ValueError(f"NAK code {code!r}: 1-8 uppercase letters, e.g. {', '.join(NAK_CODES)}")
    return (code, safe_text(text))


def pong_fields(role: str, model: str, version: int = PROTOCOL_VERSION) -> tuple[str, ...]:
    """PONG fields; ``version`` 2 announces an N-axis device (``INFO``; docs/protocol.md)."""
    if role not in ROLES:
        raise ValueError(f"PONG role: {' or '.join(ROLES)}, got {role!r}")
    return (str(int(version)), role, safe_text(model, 32))


# ----------------------------------------------------------------------------- decoders

def _fail(frame: Frame, what: str) -> FieldError:
    return FieldError(frame, what)


def _expect(frame: Frame, verb: str, names: tuple[str, ...] | None = ()) -> None:
    """``frame`` is a ``verb`` frame with exactly the fields ``names`` (None: any count); a NAK raises NakError."""
    if not isinstance(frame, Frame):
        raise TypeError(f"expected a Frame, got {type(frame).__name__}")
    if frame.verb == "NAK" and verb != "NAK":
        code, text = (frame.fields + ("", ""))[:2]
        raise NakError(code, text)
    if frame.verb != verb:
        raise _fail(frame, f"expected a {verb} frame")
    if names is not None and len(frame.fields) != len(names):
        listed = f" ({' '.join(names)})" if names else ""
        raise _fail(frame, f"expects {len(names)} fields{listed}; got {len(frame.fields)}")


def _number(frame: Frame, i: int, name: str) -> float:
    s = frame.fields[i]
    if not _DECIMAL.fullmatch(s):
        raise _fail(frame, f"field {i} ({name}) {s!r} is not a plain decimal number (-?digits[.digits])")
    return float(s)


def _joints(frame: Frame, start: int, prefix: str = "") -> Joints:
    names = ("theta1_deg", "theta2_deg", "z_mm", "theta4_deg")
    return Joints(*(_number(frame, start + k, prefix + name) for k, name in enumerate(names)))


def _check_status(status: str, where: str) -> None:
    if not isinstance(status, str) or not 1 <= len(status) <= 32 or _FIELD_BAD.search(status):
        raise ValueError(f"{where}: status must be 1-32 printable chars without ',' '*' '$', got {status!r}")


def expect_ack(frame: Frame) -> None:
    """An ACK with no fields; a NAK raises NakError."""
    _expect(frame, "ACK")


def decode_movj(frame: Frame) -> Joints:
    _expect(frame, "MOVJ", names=("theta1_deg", "theta2_deg", "z_mm", "theta4_deg"))
    return _joints(frame, 0)


def decode_wait(frame: Frame) -> int:
    """The WAIT request's max_ms."""
    _expect(frame, "WAIT", names=("max_ms",))
    s = frame.fields[0]
    if not _UINT.fullmatch(s) or not 1 <= int(s) <= MAX_WAIT_MS:
        raise _fail(frame, f"field 0 (max_ms) {s!r} is not an integer 1..{MAX_WAIT_MS}")
    return int(s)


def decode_alrm(frame: Frame) -> bool:
    """The ALRM request: True if it asks to clear (``ALRM,CLR``), False to only report (``ALRM``)."""
    _expect(frame, "ALRM", None)
    if frame.fields not in ((), ("CLR",)):
        raise _fail(frame, f"fields {list(frame.fields)}: only CLR, or no field")
    return bool(frame.fields)


def decode_position(frame: Frame) -> Position:
    names = tuple(p + n for p in ("cmd_", "enc_") for n in ("theta1_deg", "theta2_deg", "z_mm", "theta4_deg"))
    _expect(frame, "POS", names=names)
    return Position(_joints(frame, 0, "cmd_"), _joints(frame, 4, "enc_"))


def decode_reading(frame: Frame) -> Reading:
    """A DIS reply -> Reading. The valid flag must be exactly '1' or '0'; nothing is defaulted."""
    _expect(frame, "DIS", names=("displacement_mm", "valid", "status"))
    d = _number(frame, 0, "displacement_mm")
    flag = frame.fields[1]
    if flag not in ("0", "1"):
        raise _fail(frame, f"field 1 (valid) {flag!r} must be exactly 1 or 0")
    status = frame.fields[2]
    if not 1 <= len(status) <= 32:
        raise _fail(frame, f"field 2 (status) {status!r} must be 1-32 characters")
    return Reading(d, flag == "1", status)


def decode_alarms(frame: Frame) -> tuple[str, ...]:
    """An ALM reply -> the active alarm codes (empty: none)."""
    _expect(frame, "ALM", None)
    if not frame.fields:
        raise _fail(frame, "field 0 (count) missing")
    count = frame.fields[0]
    if not _UINT.fullmatch(count) or int(count) != len(frame.fields) - 1:
        raise _fail(frame, f"field 0 (count) {count!r} must equal the number of codes that follow "
                           f"({len(frame.fields) - 1})")
    for i, c in enumerate(frame.fields[1:], 1):
        if not _TOKEN.fullmatch(c):
            raise _fail(frame, f"field {i} (alarm code) {c!r} is not 1-16 of A-Z 0-9 _")
    return frame.fields[1:]


def decode_nak(frame: Frame) -> tuple[str, str]:
    """A NAK reply -> (code, text). Unknown codes are accepted (newer devices), empty ones are not."""
    _expect(frame, "NAK", names=("code", "text"))
    if not _VERB.fullmatch(frame.fields[0]):
        raise _fail(frame, f"field 0 (code) {frame.fields[0]!r} is not 1-8 uppercase letters")
    return frame.fields[0], frame.fields[1]


def decode_pong(frame: Frame) -> Pong:
    _expect(frame, "PONG", names=("version", "role", "model"))
    v, role, model = frame.fields
    if not _UINT.fullmatch(v):
        raise _fail(frame, f"field 0 (version) {v!r} is not an integer")
    if role not in ROLES:
        raise _fail(frame, f"field 1 (role) {role!r} must be {' or '.join(ROLES)}")
    return Pong(int(v), role, model)


# ----------------------------------------------------------------------------- N-axis devices (version 2)
#
# A device whose PONG says version 2 announces its axes with INFO (docs/protocol.md, "N-axis devices"):
# ``INFO`` -> ``INF,<n>``; ``INFO,<k>`` -> ``AXS,<k>,<name>,<unit>,<lower>,<upper>``. Its joint vectors
# (MOVJ, POS; a head's AIM, HPOS) carry one 6-decimal field per axis in that order, so the SCARA frames of
# version 1 are the 4-axis case byte for byte. A version-1 robot implies SCARA_LAYOUT (no limits announced).

NJ_PROTOCOL_VERSION = 2
#: Most axes a device may announce: a POS reply of 2 x 9 fields of the widest value still fits MAX_LINE.
MAX_AXES = 9
UNITS = ("deg", "mm")
#: How far (deg or mm) a reported encoder value may lie outside its axis' limits (quantization, settling).
ENCODER_SLACK = 0.01
_AXIS_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,23}")


class RangeError(FieldError):
    """A joint-vector field outside its axis' limits (a device answers it ``NAK,RANGE``, not ``SYN``)."""


@dataclass(frozen=True)
class Axis:
    """One axis of a device: ``name`` (1-24 of A-Z a-z 0-9 _), ``unit`` ``deg`` or ``mm``, limits in that unit."""
    name: str
    unit: str
    lower: float = -math.inf
    upper: float = math.inf

    @property
    def label(self) -> str:
        """The field name in errors: ``<name>_<unit>`` (``theta1_deg``, ``elbow_joint_deg``)."""
        return f"{self.name}_{self.unit}"

    def outside(self, value: float, slack: float = 0.0) -> str | None:
        """None if ``value`` is within the limits (± ``slack``), else the one-line reason."""
        if self.lower - slack <= value <= self.upper + slack:
            return None
        return f"{self.label} {fmt_number(value, 6, self.label)} outside {self.lower:g}..{self.upper:g}"


@dataclass(frozen=True)
class AxisLayout:
    """The axes of a device in wire order (a robot's joints, a head's pan and tilt)."""
    axes: tuple[Axis, ...]

    def __post_init__(self):
        object.__setattr__(self, "axes", tuple(self.axes))
        if not 1 <= len(self.axes) <= MAX_AXES:
            raise ValueError(f"axis layout: 1..{MAX_AXES} axes, got {len(self.axes)}")

    @property
    def n(self) -> int:
        return len(self.axes)

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(a.label for a in self.axes)

    @property
    def revolute(self) -> tuple[bool, ...]:
        """Per axis: True for an angle (deg), False for a length (mm)."""
        return tuple(a.unit == "deg" for a in self.axes)

    def outside(self, values, slack: float = 0.0) -> str | None:
        """The first axis whose value is outside its limits, as one line; None if all are inside."""
        for axis, v in zip(self.axes, values):
            why = axis.outside(float(v), slack)
            if why:
                return why
        return None

    def fields(self, values, verb: str = "MOVJ", check_range: bool = True) -> tuple[str, ...]:
        """One 6-decimal field per axis; ValueError (naming the verb and axis) for a wrong count, a
        non-finite value or (``check_range``) one outside the limits."""
        values = tuple(values)
        if len(values) != self.n:
            raise ValueError(f"{verb}: {self.n} values ({' '.join(self.labels)}), got {len(values)}")
        out = tuple(fmt_number(v, 6, f"{verb} {a.label}") for a, v in zip(self.axes, values))
        why = self.outside(values) if check_range else None
        if why:
            raise ValueError(f"{verb}: {why}")
        return out


#: The SCARA of version 1 (MOVJ/POS without INFO): J1, J2 deg, J3 = z mm, J4 deg; limits not announced.
SCARA_LAYOUT = AxisLayout((Axis("theta1", "deg"), Axis("theta2", "deg"), Axis("z", "mm"), Axis("theta4", "deg")))
#: The default axes of a pan/tilt head (what the emulator announces): pan about the world z axis, tilt up.
PAN_TILT_LAYOUT = AxisLayout((Axis("pan", "deg", -360.0, 360.0), Axis("tilt", "deg", -100.0, 100.0)))


@dataclass(frozen=True)
class JointPosition:
    """POS (N axes) or HPOS reply: commanded and encoder values, one per axis (deg or mm)."""
    commanded: tuple[float, ...]
    encoder: tuple[float, ...]


def info_fields(n: int) -> tuple[str, ...]:
    """``INF`` reply: the number of axes."""
    if type(n) is not int or not 1 <= n <= MAX_AXES:
        raise ValueError(f"INF: axis count 1..{MAX_AXES}, got {n!r}")
    return (str(n),)


def axis_fields(k: int, axis: Axis) -> tuple[str, ...]:
    """``AXS`` reply: index, name, unit, lower and upper limit (6 decimals, finite)."""
    if not _AXIS_NAME.fullmatch(axis.name) or axis.unit not in UNITS or not axis.lower < axis.upper:
        raise ValueError(f"AXS: axis {axis!r}: name 1-24 of A-Z a-z 0-9 _, unit deg or mm, lower < upper")
    return (str(k), axis.name, axis.unit, fmt_number(axis.lower, 6, "lower"), fmt_number(axis.upper, 6, "upper"))


def position_fields(commanded, encoder, layout: AxisLayout, verb: str = "POS") -> tuple[str, ...]:
    """``POS``/``HPOS`` reply fields: the commanded, then the encoder values (not range-checked)."""
    return layout.fields(commanded, verb, False) + layout.fields(encoder, verb, False)


def decode_info_request(frame: Frame) -> int | None:
    """The INFO request: None (how many axes?) or the axis index asked for."""
    _expect(frame, "INFO", None)
    if not frame.fields:
        return None
    if len(frame.fields) != 1 or not _UINT.fullmatch(frame.fields[0]):
        raise _fail(frame, f"fields {list(frame.fields)}: no field, or one axis index")
    return int(frame.fields[0])


def decode_info(frame: Frame) -> int:
    """An INF reply -> the number of axes (1..MAX_AXES)."""
    _expect(frame, "INF", names=("n_axes",))
    s = frame.fields[0]
    if not _UINT.fullmatch(s) or not 1 <= int(s) <= MAX_AXES:
        raise _fail(frame, f"field 0 (n_axes) {s!r} is not an integer 1..{MAX_AXES}")
    return int(s)


def decode_axis(frame: Frame, k: int | None = None) -> Axis:
    """An AXS reply -> Axis; ``k``: the index asked for (checked)."""
    _expect(frame, "AXS", names=("index", "name", "unit", "lower", "upper"))
    index, name, unit = frame.fields[:3]
    if not _UINT.fullmatch(index) or (k is not None and int(index) != k):
        raise _fail(frame, f"field 0 (index) {index!r} is not the axis asked for ({k})")
    if not _AXIS_NAME.fullmatch(name):
        raise _fail(frame, f"field 1 (name) {name!r} is not 1-24 of A-Z a-z 0-9 _ starting with a letter")
    if unit not in UNITS:
        raise _fail(frame, f"field 2 (unit) {unit!r} must be deg or mm")
    lo, hi = _number(frame, 3, "lower"), _number(frame, 4, "upper")
    if not lo < hi:
        raise _fail(frame, f"fields 3, 4 (lower, upper) {lo:g}, {hi:g}: lower must be < upper")
    return Axis(name, unit, lo, hi)


def decode_vector(frame: Frame, layout: AxisLayout, verb: str = "MOVJ", *, start: int = 0, prefix: str = "",
                  count: int | None = None, slack: float = 0.0) -> tuple[float, ...]:
    """A joint vector of ``layout`` in ``frame`` (a ``verb`` frame of ``count`` fields, default one per axis)
    from field ``start``: FieldError naming the frame and field for a wrong count or number, RangeError for
    a value outside its axis' limits (± ``slack``)."""
    names = tuple(prefix + label for label in layout.labels)
    _expect(frame, verb, names=None)
    want = layout.n if count is None else count
    if len(frame.fields) != want:
        listed = " ".join(names) if count is None else f"{count // layout.n} x ({' '.join(layout.labels)})"
        raise _fail(frame, f"expects {want} fields ({listed}); got {len(frame.fields)}")
    values = tuple(_number(frame, start + k, name) for k, name in enumerate(names))
    for k, (axis, v) in enumerate(zip(layout.axes, values)):
        why = axis.outside(v, slack)
        if why:
            raise RangeError(frame, f"field {start + k} ({prefix}{why})")
    return values


def decode_position_n(frame: Frame, layout: AxisLayout, verb: str = "POS") -> JointPosition:
    """A POS (N axes) or HPOS reply -> JointPosition; commanded values within the limits, encoder values
    within them ± ENCODER_SLACK."""
    kw = dict(count=2 * layout.n)
    return JointPosition(decode_vector(frame, layout, verb, prefix="cmd_", **kw),
                         decode_vector(frame, layout, verb, start=layout.n, prefix="enc_", slack=ENCODER_SLACK, **kw))


# ----------------------------------------------------------------------------- host side

class Transport:
    """Host side: ``request(verb, *fields) -> Frame`` over a stream with ``write(bytes)``, ``read(n)``.

    ``read`` must return within a short time (b"" if nothing came): open pyserial with ``timeout=0.05``.
    SEQ increases by one per request (mod 65536) starting at ``seq`` (random if None). A reply with
    another SEQ is stale and discarded, as is an echo of the request. On timeout or ``NAK,CRC`` the
    same frame (same SEQ) is resent, at most ``retries`` times; then TransportTimeout. Any other NAK
    raises NakError at once. ``counts`` tallies what was discarded, by kind.
    """

    def __init__(self, stream, *, timeout_s: float = 1.0, retries: int = 2, seq: int | None = None,
                 clock=time.monotonic):
        self.stream, self.timeout_s, self.retries, self.clock = stream, timeout_s, retries, clock
        self.parser = FrameParser()
        self.seq = random.randrange(SEQ_MODULO) if seq is None else seq % SEQ_MODULO
        self.counts: collections.Counter = collections.Counter()

    def request(self, verb: str, *fields: str, timeout_s: float | None = None,
                retries: int | None = None) -> Frame:
        timeout_s = self.timeout_s if timeout_s is None else timeout_s
        retries = self.retries if retries is None else retries
        request = Frame(self.seq, verb, tuple(fields))
        data = encode(request.seq, verb, *fields)
        self.seq = (self.seq + 1) % SEQ_MODULO
        why, before = [], collections.Counter(self.counts)
        for attempt in range(1 + retries):
            if attempt:
                self.counts["retry"] += 1
                _log.info("retry %d of %s (%s)", attempt, request, why[-1])
            try:
                self.stream.write(data)
                reply = self._await(request, timeout_s)
            except OSError as e:  # pyserial's SerialException is an OSError too
                raise LinkLost(f"serial link lost during {request}: {e}") from None
            if reply is None:
                why.append("timeout")
                continue
            if reply.verb == "NAK":
                code, text = (reply.fields + ("", ""))[:2]
                if code == "CRC":
                    why.append("NAK CRC")
                    continue
                raise NakError(code, text, request)
            return reply
        raise TransportTimeout(f"no valid reply to {request} after {1 + retries} attempts of {timeout_s:g} s "
                               f"({', '.join(why)}; discarded: {dict(self.counts - before) or 'nothing'})")

    def _await(self, request: Frame, timeout_s: float) -> Frame | None:
        deadline = self.clock() + timeout_s
        while True:
            n = getattr(self.stream, "in_waiting", 0) or 1
            for ev in self.parser.feed(self.stream.read(n) or b""):
                if isinstance(ev, Frame):
                    if ev == request:
                        self.counts["echo"] += 1
                    elif ev.seq != request.seq:
                        self.counts["stale"] += 1
                        _log.debug("stale reply %s while waiting for SEQ %d", ev, request.seq)
                    else:
                        return ev
                else:
                    self.counts[type(ev).__name__] += 1
                    _log.debug("%s", ev)
            if self.clock() >= deadline:
                for ev in self.parser.flush():
                    self.counts[type(ev).__name__] += 1
                    _log.debug("%s", ev)
                return None


# ----------------------------------------------------------------------------- device side

class Responder:
    """Device side: ``feed(request bytes) -> reply bytes``; ``handler.on_<VERB>(frame)`` answers.

    A handler method returns the reply as ``(verb, *fields)``, e.g. ``("ACK",)`` or
    ``("DIS", *dis_fields(d, True, "OK"))``, and refuses by raising ``NakError(code, text)``; a
    FieldError from a decoder becomes ``NAK,SYN``, a missing method ``NAK,VERB``. A request frame
    identical to the previous one (a host retry) gets the previous reply again without calling the
    handler. A request with a bad checksum whose SEQ is readable gets ``NAK,CRC``.
    """

    def __init__(self, handler):
        self.handler = handler
        self.parser = FrameParser()
        self._last: tuple[Frame, bytes] | None = None

    def feed(self, data: bytes) -> bytes:
        out = bytearray()
        for ev in self.parser.feed(data):
            if isinstance(ev, Frame):
                out += self.respond(ev)
            elif isinstance(ev, ChecksumError) and ev.seq is not None:
                out += encode(ev.seq, "NAK", *nak_fields("CRC", "checksum mismatch"))
        return bytes(out)

    def respond(self, frame: Frame) -> bytes:
        if self._last is not None and self._last[0] == frame:
            return self._last[1]
        method = getattr(self.handler, "on_" + frame.verb, None)
        try:
            if method is None:
                raise NakError("VERB", f"unknown verb {frame.verb}")
            verb, *fields = method(frame)
        except NakError as e:
            verb, fields = "NAK", list(nak_fields(e.code, e.text))
        except FieldError as e:
            verb, fields = "NAK", list(nak_fields("SYN", e.what))
        reply = encode(frame.seq, verb, *fields)
        self._last = (frame, reply)
        return reply
