"""Serial protocol (docs/protocol.md): frame codec, parser robustness, typed decoders, Transport, Responder."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from olti_drake.hardware import protocol as P
from olti_drake.hardware.protocol import (ChecksumError, FieldError, Frame, FrameError, FrameParser, FrameSyntaxError,
                                 Joints, NakError, NoiseError, NonAsciiError, OverlongLine, PartialFrame,
                                 Responder, Transport, TransportTimeout, encode)

DOC = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"


def crc_ref(data: bytes) -> int:
    """Bitwise CRC-16/CCITT-FALSE, independent of the module's implementation."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def parse(data: bytes) -> list:
    p = FrameParser()
    return p.feed(data) + p.flush()


def frames(events) -> list:
    return [e for e in events if isinstance(e, Frame)]


def assert_genuine(frame: Frame, data: bytes) -> None:
    """A returned frame really was on the line, canonical, with a correct checksum."""
    line = encode(frame.seq, frame.verb, *frame.fields)[:-1]
    assert line in data
    assert int(line[-4:], 16) == crc_ref(line[1:-5])


# Samples of every verb: (verb, fields).
SAMPLES = [
    ("PING", ()),
    ("MOVJ", P.movj_fields(-30, 45, 0, 15)),
    ("WAIT", P.wait_fields(30000)),
    ("POSJ", ()),
    ("ALRM", ()),
    ("ALRM", ("CLR",)),
    ("READ", ()),
    ("ZERO", ()),
    ("ACK", ()),
    ("NAK", P.nak_fields("RANGE", "theta1_deg -170.000000 outside -140..140")),
    ("PONG", P.pong_fields("ROBOT", "SCARA-EMU")),
    ("POS", P.pos_fields(Joints(-30, 45, 0, 15), Joints(-29.998712, 45.00153, 0.0004, 14.999871))),
    ("ALM", P.alm_fields(["E2_LIMIT", "E_ESTOP"])),
    ("DIS", P.dis_fields(412.837460125, True, "0000")),
]


# ----------------------------------------------------------------------------- codec

def test_crc_is_ccitt_false():
    assert P.crc16(b"123456789") == crc_ref(b"123456789") == 0x29B1
    for data in (b"", b"7,READ", bytes(range(256))):
        assert P.crc16(data) == crc_ref(data)


@pytest.mark.parametrize("verb,fields", SAMPLES, ids=[f"{v}{len(f)}" for v, f in SAMPLES])
def test_round_trip_every_verb(verb, fields):
    for seq in (0, 1, 4242, 65535):
        data = encode(seq, verb, *fields)
        assert data.startswith(b"$") and data.endswith(b"\n") and len(data) - 1 <= P.MAX_LINE
        assert parse(data) == [Frame(seq, verb, tuple(fields))]
        assert parse(data[:-1] + b"\r\n") == [Frame(seq, verb, tuple(fields))]  # CRLF accepted
        byte_by_byte = FrameParser()
        assert [e for b in data for e in byte_by_byte.feed(bytes([b]))] == [Frame(seq, verb, tuple(fields))]
        assert Frame(seq, verb, tuple(fields)).to_bytes() == data


def test_typed_round_trips():
    j = Joints(-30.0, 45.0, 12.5, 15.0)
    assert P.decode_movj(Frame(1, "MOVJ", P.joint_fields(j))) == j
    assert P.decode_wait(Frame(1, "WAIT", P.wait_fields(30000))) == 30000
    assert P.decode_alrm(Frame(1, "ALRM", ())) is False and P.decode_alrm(Frame(1, "ALRM", ("CLR",))) is True
    e = Joints(-29.998712, 45.00153, 12.5004, 14.999871)
    assert P.decode_position(Frame(1, "POS", P.pos_fields(j, e))) == P.Position(j, e)
    r = P.decode_reading(Frame(1, "DIS", P.dis_fields(-0.000000123, True, "0000")))
    assert r == P.Reading(-0.000000123, True, "0000")
    assert P.decode_reading(Frame(1, "DIS", P.dis_fields(412.8, False, "8001"))).valid is False
    assert P.decode_alarms(Frame(1, "ALM", P.alm_fields([]))) == ()
    assert P.decode_alarms(Frame(1, "ALM", P.alm_fields(["E1", "E_2"]))) == ("E1", "E_2")
    assert P.decode_nak(Frame(1, "NAK", P.nak_fields("TMO", "not, in $position*"))) == ("TMO", "not  in  position ")
    assert P.decode_pong(Frame(1, "PONG", P.pong_fields("COUNTER", "LC"))) == P.Pong(1, "COUNTER", "LC")
    P.expect_ack(Frame(1, "ACK", ()))
    assert P.fmt_displacement(412.837460125) == "412.837460125"
    assert P.fmt_deg(-30) == "-30.000000"


@pytest.mark.parametrize("args", [(-1, "PING"), (65536, "PING"), (True, "PING"), ("1", "PING"), (1.0, "PING"),
                                  (1, "read"), (1, ""), (1, "TOOLONGVB"), (1, "RE AD"), (1, "READ", "a,b"),
                                  (1, "READ", "a*"), (1, "READ", "$"), (1, "READ", "a\n"), (1, "READ", "\t"),
                                  (1, "READ", "é"), (1, "READ", 1.5), (1, "READ", "x" * 250)])
def test_encode_rejects_what_the_grammar_forbids(args):
    with pytest.raises((ValueError, TypeError)):
        encode(*args)


# ----------------------------------------------------------------------------- the doc cannot rot

def _doc():
    return DOC.read_text(encoding="utf-8")


def _doc_line(label):
    m = re.search(rf"^{label}:\s+(.+?)\s*$", _doc(), re.M)
    assert m, f"docs/protocol.md: no '{label}:' line in the worked example"
    return m.group(1)


def test_doc_worked_example_is_what_encode_produces():
    call = _doc_line("call")
    m = re.fullmatch(r"encode\((.*)\)", call)
    args = ast.literal_eval(f"({m.group(1)},)")
    frame = encode(*args)
    body = frame[1:frame.index(b"*")]
    assert _doc_line("body").encode() == body
    assert bytes.fromhex(_doc_line("bytes")) == body
    assert int(_doc_line("CRC"), 16) == crc_ref(body) == P.crc16(body)
    assert _doc_line("frame") == frame.decode().replace("\n", "\\n")


def test_doc_frames_are_real_and_replies_echo_the_seq():
    arrows = re.findall(r"^([→←✗]) (\S.*?)\s*$", _doc(), re.M)
    assert len(arrows) > 30
    request_seq = None
    for arrow, text in arrows:
        events = parse(text.encode() + b"\n")
        if arrow == "✗":
            assert not frames(events), f"docs: {text} is shown as corrupt but decodes"
            assert isinstance(events[0], ChecksumError)
            request_seq = events[0].seq
            continue
        assert len(events) == 1 and isinstance(events[0], Frame), f"docs: {text} -> {events}"
        f = events[0]
        assert str(f) == text
        if arrow == "→":
            assert f.verb in P.REQUEST_VERBS or f.verb == "FOO"
            request_seq = f.seq
        else:
            assert f.verb in P.REPLY_VERBS
            assert f.seq == request_seq, f"docs: reply {text} does not echo SEQ {request_seq}"


def test_doc_names_every_verb_and_error_code():
    doc = _doc()
    for verb in P.REQUEST_VERBS + P.REPLY_VERBS:
        assert f"`{verb}" in doc, verb
    for code in P.NAK_CODES:
        assert f"| `{code}` |" in doc, code


def _doc_python_blocks():
    return re.findall(r"```python\n(.*?)```", _doc(), re.S)


def test_doc_bitwise_crc_matches():
    (src,) = [b for b in _doc_python_blocks() if "def crc16_ccitt_false" in b]
    ns = {}
    exec(src, ns)
    for data in (b"123456789", b"7,DIS,123.456789012,1,0000", bytes(range(256))):
        assert ns["crc16_ccitt_false"](data) == P.crc16(data)


def test_doc_emulator_example_answers_the_olti_counter_driver():
    from olti_drake.hardware.drivers import OltiCounter

    (emulator,) = [b for b in _doc_python_blocks() if "class CounterEmulator" in b]
    ns = {"request_bytes": encode(3, "READ")}
    exec(emulator, ns)
    assert parse(ns["reply"]) == [Frame(3, "DIS", ("0.000000000", "1", "0000"))]
    emu = ns["CounterEmulator"]()
    counter = OltiCounter(P.Transport(Loopback(Responder(emu))))
    emu.displacement_mm = 5.25
    assert counter.read() == P.Reading(5.25, True, "0000")
    assert counter.zero() is True
    assert counter.read().displacement_mm == 0.0
    emu.beam = False
    assert counter.zero() is False          # NAK BEAM: no beam to zero on
    assert counter.read().valid is False


def test_doc_driver_of_another_protocol_meets_the_driver_rules():
    from olti_drake.hardware.drivers import AlarmActive, DriverError

    (driver,) = [b for b in _doc_python_blocks() if "class FanucRobot" in b]

    class VendorLink:  # the vendor's own link, as the example assumes it
        def __init__(self, port, baud, timeout_s):
            self.alarm_codes_, self.q, self.refuse = [], (0.0, 0.0, 0.0, 0.0), False

        def send_joint_move(self, *q):
            if self.alarm_codes_ or self.refuse:
                return False
            self.q = q
            return True

        def alarm(self):
            return bool(self.alarm_codes_)

        def alarm_text(self):
            return " ".join(self.alarm_codes_)

        def wait_in_position(self, s):
            pass

        def joints(self):
            return self.q, self.q

        def reset_alarms(self):
            self.alarm_codes_ = []

        def alarm_codes(self):
            return self.alarm_codes_

        def close(self):
            pass

    ns = {"MyVendorLink": VendorLink}
    exec(driver, ns)
    robot = ns["FanucRobot"].open("/dev/fake", 115200, 1.0, 2)
    robot.move((10.0, 20.0, 0.0, 30.0))
    robot.wait(1000)
    assert robot.position().encoder == P.Joints(10.0, 20.0, 0.0, 30.0)
    robot.link.alarm_codes_ = ["E2_LIMIT"]
    with pytest.raises(AlarmActive, match="E2_LIMIT"):
        robot.move((0.0, 0.0, 0.0, 0.0))
    assert robot.alarms() == ("E2_LIMIT",) and robot.alarms(clear=True) == ()
    robot.link.refuse = True
    with pytest.raises(DriverError, match="move refused"):
        robot.move((0.0, 0.0, 0.0, 0.0))


# ----------------------------------------------------------------------------- corruption

CORRUPTION_FRAMES = [encode(7, "DIS", "123.456789012", "1", "0000"), encode(65535, "PING"),
                     encode(12, "POS", *SAMPLES[11][1][:8]), encode(300, "NAK", "CRC", "checksum mismatch")]


@pytest.mark.parametrize("frame", CORRUPTION_FRAMES, ids=lambda f: f.split(b",")[1][:4].decode())
def test_no_single_byte_change_decodes(frame):
    for i in range(len(frame)):
        for value in range(256):
            if value == frame[i]:
                continue
            bad = frame[:i] + bytes([value]) + frame[i + 1:]
            events = parse(bad)
            assert not frames(events), (i, value, bad, events)
            assert events, (i, value, bad)  # the damage is always reported


@pytest.mark.parametrize("frame", CORRUPTION_FRAMES, ids=lambda f: f.split(b",")[1][:4].decode())
def test_truncations_never_decode_and_the_next_frame_survives(frame):
    good = encode(1, "ACK")
    for n in range(len(frame) - 1):  # every proper prefix, the '\n' excluded
        cut = frame[:n]
        assert not frames(parse(cut))
        assert not frames(parse(cut + b"\n"))
        assert frames(parse(cut + good)) == [Frame(1, "ACK")]
        assert frames(parse(cut + b"\r\n" + good)) == [Frame(1, "ACK")]
    p = FrameParser()
    assert p.feed(frame[:-1]) == [] and isinstance(p.flush()[0], PartialFrame)  # partial line at timeout


def test_every_wrong_checksum_is_rejected():
    frame = CORRUPTION_FRAMES[0]
    head, crc = frame[:-5], int(frame[-5:-1], 16)
    parser = FrameParser()
    for wrong in range(0x10000):
        if wrong == crc:
            continue
        (event,) = parser.feed(head + b"%04X\n" % wrong)
        assert isinstance(event, ChecksumError) and event.seq == 7
    assert parse(head + b"%04x\n" % crc) != [Frame(7, "DIS", ("123.456789012", "1", "0000"))]  # lowercase hex
    assert parser.feed(frame) == [Frame(7, "DIS", ("123.456789012", "1", "0000"))]


def test_error_events_are_typed():
    ok = encode(1, "ACK")
    assert [type(e) for e in parse(b"hello\n" + ok)] == [NoiseError, Frame]
    assert parse(b"\n\r\n" + ok) == [Frame(1, "ACK")]  # blank lines are not noise
    assert [type(e) for e in parse(b"$" + b"9" * 400 + ok)] == [OverlongLine, Frame]
    assert [type(e) for e in parse(b"$" + b"9" * 400 + b"\n" + ok)] == [OverlongLine, Frame]
    assert [type(e) for e in parse(ok[:3] + b"\xff" + ok[3:])] == [NonAsciiError]
    assert [type(e) for e in parse(ok[:3] + b"\t" + ok[3:])] == [FrameSyntaxError]
    assert [type(e) for e in parse(ok[:-1] + b"\r\r\n")] == [FrameSyntaxError]
    assert [type(e) for e in parse(b"$01,ACK*%04X\n" % P.crc16(b"01,ACK"))] == [FrameSyntaxError]  # leading 0
    assert [type(e) for e in parse(b"$70000,ACK*%04X\n" % P.crc16(b"70000,ACK"))] == [FrameSyntaxError]
    assert [type(e) for e in parse(b"$1,ACK,a*b*%04X\n" % P.crc16(b"1,ACK,a*b"))] == [FrameSyntaxError]
    assert [type(e) for e in parse(ok[:4] + ok)] == [PartialFrame, Frame]
    p = FrameParser()
    assert [type(e) for e in p.feed(b"$" + b"7" * 1_000_000)] == [OverlongLine] and len(p._buf) <= P.MAX_LINE + 2
    # longest frame accepted with LF and with CRLF; one more byte is overlong
    longest = encode(1, "NAK", "HW", "x" * (P.MAX_LINE - len(encode(1, "NAK", "HW", "")) + 1))
    assert len(longest) - 1 == P.MAX_LINE
    assert frames(parse(longest)) and frames(parse(longest[:-1] + b"\r\n"))
    assert isinstance(parse(longest[:-6] + b"x" + longest[-6:])[0], OverlongLine)
    for event in parse(b"junk\n$1,AC\n" + ok[:-2] + b"X\n"):
        assert isinstance(event, FrameError) and "\n" not in str(event)


# ----------------------------------------------------------------------------- fuzz

FRAME_ALPHABET = b"$*,\r\n0123456789ACDEFIKLMNOPRSZ.-"
noise = st.one_of(st.binary(max_size=300), st.lists(st.sampled_from(FRAME_ALPHABET), max_size=300).map(bytes))
valid_frames = st.builds(lambda seq, sample: encode(seq, sample[0], *sample[1]),
                         st.integers(0, 65535), st.sampled_from(SAMPLES))
# derandomize: the same examples every run (seeded), so CI cannot fail on a draw the developers never saw.
FUZZ = settings(max_examples=300, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def _feed_in_chunks(data: bytes, cuts: list[int]) -> list:
    p, events, last = FrameParser(), [], 0
    for cut in sorted(c % (len(data) + 1) for c in cuts) + [len(data)]:
        events += p.feed(data[last:cut])
        last = cut
    return events + p.flush()


@FUZZ
@given(data=noise, cuts=st.lists(st.integers(0, 10_000), max_size=8))
def test_fuzz_garbage_never_crashes_nor_yields_a_bad_frame(data, cuts):
    events = _feed_in_chunks(data, cuts)
    for e in events:
        assert isinstance(e, (Frame, FrameError))
        if isinstance(e, Frame):
            assert_genuine(e, data)
    # chunking does not change what is found
    assert [e if isinstance(e, Frame) else type(e) for e in events] == \
        [e if isinstance(e, Frame) else type(e) for e in parse(data)]


@FUZZ
@given(parts=st.lists(st.tuples(noise, st.sampled_from([b"\n", b"\r\n", b""]), valid_frames), max_size=6),
       tail=noise, cuts=st.lists(st.integers(0, 10_000), max_size=8))
def test_fuzz_valid_frames_after_garbage_are_recovered(parts, tail, cuts):
    data = b"".join(g + sep + f for g, sep, f in parts) + tail
    found = frames(_feed_in_chunks(data, cuts))
    for f in found:
        assert_genuine(f, data)
    expected = [frames(parse(f))[0] for _, _, f in parts]
    it = iter(found)
    assert all(any(x == want for x in it) for want in expected), (expected, found)  # in order


@FUZZ
@given(frame=valid_frames, i=st.integers(0, 1000), value=st.integers(0, 255),
       delete=st.booleans())
def test_fuzz_damaged_frame_never_decodes(frame, i, value, delete):
    i %= len(frame)
    assume(delete or value != frame[i])  # writing a byte over itself damages nothing
    bad = frame[:i] + frame[i + 1:] if delete else frame[:i] + bytes([value]) + frame[i + 1:]
    for f in frames(parse(bad)):  # a deletion can in principle slip past CRC-16; then it must be genuine
        assert_genuine(f, bad)
        assert f != frames(parse(frame))[0]
    if not delete:
        assert not frames(parse(bad))


# ----------------------------------------------------------------------------- decoders reject

def _dis(*fields):
    return Frame(5, "DIS", fields)


@pytest.mark.parametrize("number", ["", "abc", "1.2.3", "1e3", "1E-3", "nan", "NaN", "inf", "-inf", "Infinity",
                                    "+1.0", " 1.0", "1.0 ", "1.", ".5", "0x10", "--1", "1_000", "1234567890.0",
                                    "1.0000000000001"])
def test_decode_reading_rejects_malformed_numbers(number):
    with pytest.raises(FieldError) as e:
        P.decode_reading(_dis(number, "1", "0000"))
    msg = str(e.value)
    assert "\n" not in msg and "displacement_mm" in msg and "$5,DIS," in msg and "field 0" in msg


@pytest.mark.parametrize("flag", ["", "true", "True", "2", "yes", "01", " 1", "1.0", "-1", "0000"])
def test_decode_reading_needs_an_explicit_valid_flag(flag):
    with pytest.raises(FieldError, match=r"field 1 \(valid\)"):
        P.decode_reading(_dis("412.800000000", flag, "0000"))


@pytest.mark.parametrize("fields", [(), ("412.800000000",), ("412.800000000", "1"), ("412.800000000", "0000"),
                                    ("412.800000000", "1", "0000", "extra"), ("412.800000000", "1", "")])
def test_decode_reading_rejects_missing_or_extra_fields(fields):
    with pytest.raises(FieldError, match=r"\$5,DIS"):
        P.decode_reading(_dis(*fields))


def test_decoders_reject_wrong_frames():
    with pytest.raises(FieldError, match="expected a DIS frame"):
        P.decode_reading(Frame(5, "ACK"))
    with pytest.raises(NakError, match="BEAM"):
        P.decode_reading(Frame(5, "NAK", ("BEAM", "no beam")))
    with pytest.raises(FieldError, match="ACK frame"):
        P.expect_ack(Frame(5, "ACK", ("x",)))
    pos = P.pos_fields(Joints(1, 2, 3, 4), Joints(1, 2, 3, 4))
    with pytest.raises(FieldError, match="expects 8 fields"):
        P.decode_position(Frame(5, "POS", pos[:7]))
    with pytest.raises(FieldError, match=r"field 6 \(enc_z_mm\) 'nan'"):
        P.decode_position(Frame(5, "POS", pos[:6] + ("nan",) + pos[7:]))
    with pytest.raises(FieldError, match=r"field 3 \(theta4_deg\)"):
        P.decode_movj(Frame(5, "MOVJ", ("1", "2", "3", "inf")))
    with pytest.raises(FieldError, match="count"):
        P.decode_alarms(Frame(5, "ALM", ("2", "E1")))
    with pytest.raises(FieldError, match="count"):
        P.decode_alarms(Frame(5, "ALM", ()))
    with pytest.raises(FieldError, match="alarm code"):
        P.decode_alarms(Frame(5, "ALM", ("1", "e1")))
    for ms in ("0", "600001", "-5", "1.5", "010", ""):
        with pytest.raises(FieldError, match="max_ms"):
            P.decode_wait(Frame(5, "WAIT", (ms,)))
    with pytest.raises(FieldError, match="CLR"):
        P.decode_alrm(Frame(5, "ALRM", ("CLEAR",)))
    with pytest.raises(FieldError, match="role"):
        P.decode_pong(Frame(5, "PONG", ("1", "PLC", "x")))
    with pytest.raises(FieldError, match="code"):
        P.decode_nak(Frame(5, "NAK", ("", "x")))


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), "1.0", True, None, 1e12])
def test_formatters_reject_non_finite_and_non_numbers(bad):
    with pytest.raises((ValueError, TypeError)):
        P.fmt_displacement(bad)
    with pytest.raises((ValueError, TypeError)):
        P.movj_fields(0, 0, bad, 0)


def test_field_builders_validate():
    for call in (lambda: P.dis_fields(1.0, 1, "0000"), lambda: P.dis_fields(1.0, True, ""),
                 lambda: P.dis_fields(1.0, True, "a,b"), lambda: P.alm_fields(["e1"]),
                 lambda: P.wait_fields(0), lambda: P.wait_fields(1.5), lambda: P.pong_fields("PLC", "x"),
                 lambda: P.nak_fields("crc", "x")):
        with pytest.raises((ValueError, TypeError)):
            call()


# ----------------------------------------------------------------------------- Transport

class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


class ScriptedStream:
    """One script entry per write: a function (request Frame) -> [(delay_s, bytes), ...] or bytes."""

    def __init__(self, clock, script):
        self.clock, self.script, self.written, self.pending = clock, list(script), [], []

    def write(self, data):
        self.written.append(bytes(data))
        (request,) = frames(parse(data))
        out = self.script.pop(0)(request) if self.script else []
        if isinstance(out, bytes):
            out = [(0.0, out)]
        self.pending += [(self.clock.t + delay, chunk) for delay, chunk in out]
        return len(data)

    def read(self, n):
        ready = [p for p in self.pending if p[0] <= self.clock.t]
        if not ready:
            self.clock.t += 0.01  # a serial read that timed out
            return b""
        self.pending.remove(ready[0])
        chunk = ready[0][1]
        if len(chunk) > n:
            self.pending.insert(0, (ready[0][0], chunk[n:]))
        return chunk[:n]


class Loopback:
    """A stream wired to a Responder: what is written is answered at once."""

    def __init__(self, responder):
        self.responder, self.buf = responder, bytearray()

    def write(self, data):
        self.buf += self.responder.feed(data)

    def read(self, n):
        out = bytes(self.buf[:n])
        del self.buf[:n]
        return out


def no_reply(request):
    return []


def reply(verb, *fields, seq_offset=0):
    return lambda request: encode((request.seq + seq_offset) % P.SEQ_MODULO, verb, *fields)


def transport(script, **kw):
    clock = Clock()
    stream = ScriptedStream(clock, script)
    return Transport(stream, clock=clock, seq=kw.pop("seq", 100), **kw), stream


def test_timeout_then_success_retries_with_the_same_seq():
    t, s = transport([no_reply, reply("ACK"), reply("ACK")])
    assert t.request("ZERO") == Frame(100, "ACK")
    assert s.written == [encode(100, "ZERO")] * 2
    assert t.counts["retry"] == 1
    assert t.request("ZERO").seq == 101  # the next request gets the next SEQ


def test_stale_replies_are_discarded():
    dis = P.dis_fields(1.5, True, "0000")
    # a stale reply (previous SEQ) arrives just before the real one
    t, s = transport([lambda r: encode(r.seq - 1, "DIS", *P.dis_fields(9.0, True, "0000")) + encode(r.seq, "DIS", *dis)])
    assert P.decode_reading(t.request("READ")).displacement_mm == 1.5
    assert t.counts["stale"] == 1
    # the reply to a request that timed out arrives late, during the next request
    t, s = transport([lambda r: [(1.1, encode(r.seq, "DIS", *P.dis_fields(9.0, True, "0000")))],
                      lambda r: [(0.3, encode(r.seq, "DIS", *dis))]], timeout_s=1.0)
    with pytest.raises(TransportTimeout):
        t.request("READ", retries=0)
    assert P.decode_reading(t.request("READ")).displacement_mm == 1.5
    assert t.counts["stale"] == 1


def test_nak_crc_is_retried_with_the_same_seq():
    t, s = transport([reply("NAK", "CRC", "checksum mismatch"), reply("ALM", "0")])
    assert P.decode_alarms(t.request("ALRM")) == ()
    assert s.written == [encode(100, "ALRM")] * 2


def test_retries_exhausted_raise_a_clear_error():
    t, s = transport([no_reply] * 2 + [reply("NAK", "CRC", "x")], retries=2, timeout_s=0.5)
    with pytest.raises(TransportTimeout) as e:
        t.request("READ")
    msg = str(e.value)
    assert "$100,READ*" in msg and "3 attempts" in msg and "timeout, timeout, NAK CRC" in msg and "\n" not in msg
    assert s.written == [encode(100, "READ")] * 3


def test_other_nak_raises_at_once():
    t, s = transport([reply("NAK", "RANGE", "theta1_deg outside -140..140")])
    with pytest.raises(NakError) as e:
        t.request("MOVJ", *P.movj_fields(-170, 0, 0, 0))
    assert e.value.code == "RANGE" and "$100,MOVJ," in str(e.value) and len(s.written) == 1


def test_echo_noise_corrupt_and_partial_replies_are_skipped():
    good = encode(100, "ACK")
    t, s = transport([lambda r: b"\x00junk\n" + r.to_bytes() + good[:4],  # echo, noise, then a partial line
                      lambda r: good[:-3] + b"00\n",                       # a corrupted reply
                      lambda r: [(0.3, good[:3]), (0.35, good[3:])]])      # split across reads
    assert t.request("ZERO") == Frame(100, "ACK")
    assert t.counts["echo"] == 1 and t.counts["NoiseError"] == 1 and t.counts["PartialFrame"] == 1
    assert t.counts["ChecksumError"] + t.counts["FrameSyntaxError"] == 1 and t.counts["retry"] == 2


def test_seq_wraps():
    t, s = transport([reply("ACK")] * 3, seq=65534)
    assert [t.request("PING").seq for _ in range(3)] == [65534, 65535, 0]


def test_transport_and_responder_end_to_end_retry_is_not_executed_twice():
    class Counter:
        zeros = 0

        def on_ZERO(self, frame):
            self.zeros += 1
            return ("ACK",)

        def on_READ(self, frame):
            return ("DIS", *P.dis_fields(0.0, True, "0000"))

    dev = Counter()
    responder = Responder(dev)

    class LossyLoopback(Loopback):  # loses the first reply
        lost = False

        def write(self, data):
            out = self.responder.feed(data)
            if not self.lost:
                self.lost = True
                return
            self.buf += out

    clock = Clock()
    stream = LossyLoopback(responder)
    stream.read = lambda n, read=stream.read: read(n) or (setattr(clock, "t", clock.t + 0.01) or b"")
    t = Transport(stream, clock=clock, seq=7)
    P.expect_ack(t.request("ZERO"))
    assert dev.zeros == 1 and t.counts["retry"] == 1  # the retry got the stored reply
    P.expect_ack(t.request("ZERO"))
    assert dev.zeros == 2  # a new SEQ is executed
    with pytest.raises(NakError, match="VERB"):
        t.request("MOVJ", *P.movj_fields(0, 0, 0, 0))


def test_responder_naks():
    class Robot:
        def on_MOVJ(self, frame):
            j = P.decode_movj(frame)
            if not -140 <= j.theta1_deg <= 140:
                raise NakError("RANGE", f"theta1_deg {j.theta1_deg} outside -140..140")
            return ("ACK",)

    r = Responder(Robot())
    assert parse(r.feed(encode(1, "MOVJ", *P.movj_fields(10, 0, 0, 0)))) == [Frame(1, "ACK")]
    (nak,) = parse(r.feed(encode(2, "MOVJ", *P.movj_fields(-170, 0, 0, 0))))
    assert P.decode_nak(nak)[0] == "RANGE" and nak.seq == 2
    (nak,) = parse(r.feed(encode(3, "MOVJ", "1", "2", "3")))
    assert P.decode_nak(nak)[0] == "SYN" and "expects 4 fields" in nak.fields[1]
    bad = encode(4, "MOVJ", *P.movj_fields(10, 0, 0, 0))
    (nak,) = parse(r.feed(bad[:8] + b"9" + bad[9:]))  # corrupted request, readable SEQ
    assert nak == Frame(4, "NAK", ("CRC", "checksum mismatch"))
    assert r.feed(b"$x4,MOVJ*0000\n") == b""  # unreadable SEQ: silence
    (unknown,) = parse(r.feed(encode(5, "READ")))
    assert P.decode_nak(unknown)[0] == "VERB"


def test_import_pulls_neither_pydrake_nor_numpy():
    code = ("import sys, olti_drake.hardware.protocol; "
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in ('pydrake', 'numpy')); "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)
