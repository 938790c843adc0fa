"""Protocol version 2 (docs/protocol.md, "N-axis devices and pan/tilt heads"): N-joint vectors, INFO/AXS,
the head verbs; typed decoders with one-line errors naming frame and field; the SCARA frames unchanged."""

import numpy as np
import pytest

from olti_drake.hardware import protocol as P
from olti_drake.hardware.protocol import Axis, AxisLayout, FieldError, Frame, RangeError, decode_line, encode

UR5 = AxisLayout([Axis("shoulder_pan_joint", "deg", -360, 360), Axis("shoulder_lift_joint", "deg", -360, 360),
                  Axis("elbow_joint", "deg", -180, 180), Axis("wrist_1_joint", "deg", -360, 360),
                  Axis("wrist_2_joint", "deg", -360, 360), Axis("wrist_3_joint", "deg", -360, 360)])


def _wire(seq, verb, *fields) -> Frame:
    """The frame as a receiver decodes it from the bytes a sender encodes."""
    frame = decode_line(encode(seq, verb, *fields).rstrip(b"\n"))
    assert isinstance(frame, Frame)
    return frame


def test_scara_frames_are_the_four_axis_case_byte_for_byte():
    rng = np.random.default_rng(3)
    for q in rng.uniform(-170, 170, (50, 4)):
        q = tuple(np.round(q, 7))
        e = tuple(np.round(np.asarray(q) + rng.normal(0, 1e-3, 4), 7))
        assert P.SCARA_LAYOUT.fields(q) == P.movj_fields(*q)
        assert P.position_fields(q, e, P.SCARA_LAYOUT) == P.pos_fields(P.Joints(*q), P.Joints(*e))
        movj = _wire(7, "MOVJ", *P.movj_fields(*q))
        assert decode_vector_equal(movj, q)
        pos = P.decode_position_n(_wire(8, "POS", *P.pos_fields(P.Joints(*q), P.Joints(*e))), P.SCARA_LAYOUT)
        old = P.decode_position(_wire(8, "POS", *P.pos_fields(P.Joints(*q), P.Joints(*e))))
        assert pos.commanded == tuple(old.commanded) and pos.encoder == tuple(old.encoder)


def decode_vector_equal(frame, q) -> bool:
    return P.decode_vector(frame, P.SCARA_LAYOUT) == tuple(P.decode_movj(frame)) == tuple(float(f"{v:.6f}") for v in q)


def test_six_joint_round_trip_and_the_widest_frame_fits_a_line():
    q = (10.0, -80.0, 95.0, -30.0, -90.0, 45.0)
    assert P.decode_vector(_wire(1, "MOVJ", *UR5.fields(q)), UR5) == q
    enc = (10.000172, -79.999828, 94.999828, -30.0, -90.000172, 45.0)
    pos = P.decode_position_n(_wire(2, "POS", *P.position_fields(q, enc, UR5)), UR5)
    assert pos.commanded == q and pos.encoder == enc
    wide = AxisLayout([Axis(f"j{k}", "deg", -720, 720) for k in range(P.MAX_AXES)])
    line = encode(65535, "POS", *P.position_fields([-720] * 9, [-719.999999] * 9, wide))
    assert len(line) - 1 <= P.MAX_LINE
    with pytest.raises(ValueError, match="axes"):
        AxisLayout([Axis("j", "deg")] * (P.MAX_AXES + 1))


@pytest.mark.parametrize("fields, match", [
    (("10.0", "-80.0", "95.0", "-30.0", "-90.0"), r"MOVJ frame \$5,MOVJ.*: expects 6 fields \(shoulder_pan_joint_deg "
                                                   r".* wrist_3_joint_deg\); got 5"),
    (("10.0", "-80.0", "9e1", "-30.0", "-90.0", "45.0"), r"field 2 \(elbow_joint_deg\) '9e1' is not a plain decimal"),
    (("10.0", "-80.0", "", "-30.0", "-90.0", "45.0"), r"field 2 \(elbow_joint_deg\) '' is not a plain decimal"),
])
def test_joint_vector_errors_name_frame_and_field(fields, match):
    with pytest.raises(FieldError, match=match) as e:
        P.decode_vector(_wire(5, "MOVJ", *fields), UR5)
    assert "\n" not in str(e.value) and not isinstance(e.value, RangeError)


def test_range_checks_per_joint_on_both_sides():
    bad = (10.0, -80.0, 200.0, -30.0, -90.0, 45.0)
    with pytest.raises(ValueError, match=r"^MOVJ: elbow_joint_deg 200.000000 outside -180..180$"):
        UR5.fields(bad)                                   # the host never sends it
    frame = _wire(6, "MOVJ", *UR5.fields(bad, check_range=False))
    with pytest.raises(RangeError, match=r"field 2 \(elbow_joint_deg 200.000000 outside -180..180\)"):
        P.decode_vector(frame, UR5)                       # the device refuses it (NAK,RANGE)
    for i, v in enumerate(bad):                            # every joint checked against its own limits
        q = [0.0] * 6
        q[i] = 361.0 if i != 2 else 181.0
        with pytest.raises(ValueError, match=UR5.axes[i].label):
            UR5.fields(q)
    # Encoders may overshoot the limit by quantization (ENCODER_SLACK), commands may not.
    q = (360.0, 0, 0, 0, 0, 0)
    ok = P.decode_position_n(_wire(7, "POS", *P.position_fields(q, (360.005, 0, 0, 0, 0, 0), UR5)), UR5)
    assert ok.encoder[0] == 360.005
    with pytest.raises(RangeError, match=r"field 6 \(enc_shoulder_pan_joint_deg 360.500000 outside"):
        P.decode_position_n(_wire(7, "POS", *P.position_fields(q, (360.5, 0, 0, 0, 0, 0), UR5)), UR5)
    with pytest.raises(RangeError, match=r"field 0 \(cmd_shoulder_pan_joint_deg 360.005000 outside"):
        P.decode_position_n(_wire(7, "POS", *P.position_fields((360.005, 0, 0, 0, 0, 0), q, UR5)), UR5)
    with pytest.raises(ValueError, match="finite"):
        UR5.fields((np.nan, 0, 0, 0, 0, 0))


def test_info_and_axis_announcements():
    assert P.decode_info(_wire(1, "INF", *P.info_fields(6))) == 6
    for k, axis in enumerate(UR5.axes):
        assert P.decode_axis(_wire(2, "AXS", *P.axis_fields(k, axis)), k) == axis
    assert P.decode_info_request(_wire(3, "INFO")) is None
    assert P.decode_info_request(_wire(3, "INFO", "4")) == 4
    cases = [(("INF", "0"), r"field 0 \(n_axes\) '0' is not an integer 1..9"),
             (("INF", "10"), r"field 0 \(n_axes\) '10'"),
             (("AXS", "1", "elbow_joint", "deg", "-180.0", "180.0"), r"field 0 \(index\) '1' is not the axis asked for \(2\)"),
             (("AXS", "2", "2elbow", "deg", "-180.0", "180.0"), r"field 1 \(name\) '2elbow'"),
             (("AXS", "2", "elbow_joint", "rad", "-180.0", "180.0"), r"field 2 \(unit\) 'rad' must be deg or mm"),
             (("AXS", "2", "elbow_joint", "deg", "180.0", "-180.0"), r"lower must be < upper"),
             (("AXS", "2", "elbow_joint", "deg", "-180.0"), r"expects 5 fields"),
             (("INFO", "x"), r"no field, or one axis index")]
    for (verb, *fields), match in cases:
        decoder = {"INF": P.decode_info, "AXS": lambda f: P.decode_axis(f, 2), "INFO": P.decode_info_request}[verb]
        with pytest.raises(FieldError, match=match) as e:
            decoder(_wire(9, verb, *fields))
        assert str(e.value).startswith(f"{verb} frame $9,{verb}") and "\n" not in str(e.value)
    with pytest.raises(ValueError):
        P.axis_fields(0, Axis("pan", "deg"))              # a device announces finite limits


def test_head_verbs_and_roles():
    pong = P.decode_pong(_wire(1, "PONG", *P.pong_fields("HEAD", "TRACER-EMU", P.NJ_PROTOCOL_VERSION)))
    assert (pong.version, pong.role, pong.model) == (2, "HEAD", "TRACER-EMU")
    assert P.pong_fields("ROBOT", "SCARA-EMU") == ("1", "ROBOT", "SCARA-EMU")   # version 1 unchanged
    with pytest.raises(FieldError, match="ROBOT or COUNTER or HEAD"):
        P.decode_pong(_wire(1, "PONG", "2", "TRACKER", "x"))
    head = P.PAN_TILT_LAYOUT
    assert P.decode_vector(_wire(2, "AIM", *head.fields((-35.25, 12.5), "AIM")), head, "AIM") == (-35.25, 12.5)
    with pytest.raises(ValueError, match="AIM: tilt_deg 120.000000 outside -100..100"):
        head.fields((0.0, 120.0), "AIM")
    pos = P.decode_position_n(_wire(3, "HPOS", *P.position_fields((1, 2), (1.0001, 2.0001), head, "HPOS")), head,
                              "HPOS")
    assert pos == P.JointPosition((1.0, 2.0), (1.0001, 2.0001))
    with pytest.raises(FieldError, match=r"expected a HPOS frame"):
        P.decode_position_n(_wire(3, "POS", *P.position_fields((1, 2), (1, 2), head)), head, "HPOS")
    with pytest.raises(P.NakError, match="RANGE"):
        P.decode_position_n(_wire(3, "NAK", "RANGE", "x"), head, "HPOS")
