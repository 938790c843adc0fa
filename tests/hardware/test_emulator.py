"""Device emulator (docs/emulator.md): through real pseudo-terminals with pyserial and the host Transport.

No timing assertions: timeouts only bound how long a test may hang. Readings are checked against the
numpy truth (TrueRobot geometry), directions against ``approach_directions``.
"""

import contextlib
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import serial

from olti_drake.sim.campaign import campaign_commands, prepare, simulate_vectorized
from olti_drake.hardware.emulator import (ALARM_CODE, DEFAULT_ENCODER_RESOLUTION, STREAM_NOISE, Emulator, Faults, _Device)
from olti_drake.model.errormap import approach_directions
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.hardware.protocol import (Frame, LinkLost, FrameParser, NakError, Responder, Transport, decode_alarms, decode_pong,
                                 decode_position, decode_reading, encode, expect_ack, fmt_deg, movj_fields)
from olti_drake.sim.scenario import ExactEstimate, Scenario
from olti_drake.model.instrument import beam_command_deg

QUIET = InterferometerOptions(noise=False, quantization=False, cosine_error=False, beam_loss=False)


def quiet_scenario(**kw) -> Scenario:
    """Noise, quantization, cosine error and beam loss off; steering knows the truth."""
    return Scenario(reflector_estimate=ExactEstimate(), interferometer=QUIET, **kw)


@contextlib.contextmanager
def ports(emu, timeout_s=1.0, retries=2):
    """Host transports (robot, counter) on the emulator's pseudo-terminals."""
    lines = [serial.Serial(p, 115200, timeout=0.05) for p in (emu.robot_port, emu.counter_port)]
    try:
        yield tuple(Transport(s, timeout_s=timeout_s, retries=retries, seq=1000 * k)
                    for k, s in enumerate(lines))
    finally:
        for s in lines:
            with contextlib.suppress(Exception):
                s.close()


class Host:
    """A minimal host: moves, zeroes, reads, and keeps what the numpy truth needs."""

    def __init__(self, robot: Transport, counter: Transport, scenario: Scenario, wait_ms: int = 2000):
        self.robot, self.counter, self.s, self.wait_ms = robot, counter, scenario, wait_ms
        self.true_robot = scenario.robot.true_robot()
        self.P = np.asarray(scenario.reflectors_mm, dtype=float)
        self.sent = []  # every MOVJ the device accepted, as decoded from the wire (6 decimals)
        self.reflector = 0
        self.zero_length = None

    def steer(self, t1, t2, j=None):
        """θ4* aiming at reflector j (the true position: ExactEstimate), rounded as on the wire."""
        r = self.s.robot
        t4 = beam_command_deg(t1, t2, self.P[self.reflector if j is None else j], r.nominal_L1_mm,
                              r.nominal_L2_mm, r.theta40_deg)
        return float(fmt_deg(float(t4)))

    def move(self, t1, t2, t4=None, z=0.0):
        t4 = self.steer(t1, t2) if t4 is None else t4
        expect_ack(self.robot.request("MOVJ", *movj_fields(t1, t2, z, t4)))
        self.sent.append((float(fmt_deg(t1)), float(fmt_deg(t2)), z, float(fmt_deg(t4))))
        # The protocol's rule: the WAIT reply comes within max_ms, so wait max_ms + timeout_s for it.
        expect_ack(self.robot.request("WAIT", str(self.wait_ms),
                                      timeout_s=self.wait_ms / 1000 + self.robot.timeout_s))

    def length(self) -> float:
        """True optical length now (cosine error off: the distance from the beam origin)."""
        cmd = np.array(self.sent)
        d = approach_directions(cmd)[-1]
        origin, _ = self.true_robot.laser_beam(cmd[-1:, 0], cmd[-1:, 1], cmd[-1:, 3], d[0], d[1], d[3])
        return float(np.hypot(*(self.P[self.reflector] - origin[0])))

    def refl(self, j):
        expect_ack(self.counter.request("REFL", str(j)))
        self.reflector = j

    def zero(self):
        expect_ack(self.counter.request("ZERO"))
        self.zero_length = self.length()

    def read(self):
        return decode_reading(self.counter.request("READ"))

    def truth(self) -> float:
        return self.length() - self.zero_length


POSES = [(-30.0, 45.0), (-10.0, 60.0), (5.5, 80.25), (-10.0, 60.0), (-50.0, 30.0), (-10.0, 60.0)]


# ----------------------------------------------------------------------------- round trip


def test_ping_roles_and_verbs_per_line():
    with Emulator(quiet_scenario()) as emu, ports(emu) as (robot, counter):
        assert decode_pong(robot.request("PING")).role == "ROBOT"
        assert decode_pong(counter.request("PING")).role == "COUNTER"
        assert os.path.realpath(emu.robot_port).startswith("/dev/")
        for t, verb in ((robot, "READ"), (counter, "MOVJ"), (robot, "FOO")):
            with pytest.raises(NakError) as e:
                t.request(verb)
            assert e.value.code == "VERB"
        with pytest.raises(NakError) as e:  # a field count error is the decoder's: NAK,SYN
            robot.request("MOVJ", "1.0", "2.0", "0.0")
        assert e.value.code == "SYN"
        with pytest.raises(NakError) as e:
            robot.request("MOVJ", *movj_fields(-175.0, 0.0, 0.0, 0.0))
        assert e.value.code == "RANGE" and "theta1_deg -175.000000 outside -170..170" in e.value.text


def test_noise_free_readings_equal_the_numpy_truth():
    s = quiet_scenario()
    with Emulator(s, encoder_resolution=DEFAULT_ENCODER_RESOLUTION) as emu, ports(emu) as (robot, counter):
        h = Host(robot, counter, s)
        h.refl(1)
        h.move(*POSES[0])
        h.zero()
        assert emu.dead_path_mm == pytest.approx(h.zero_length, abs=1e-9)
        first = h.read()
        assert first.valid and first.displacement_mm == 0.0 and first.status == "0000"
        values = {}
        for t1, t2 in POSES[1:]:
            h.move(t1, t2)
            r = h.read()
            assert r.valid and r.status == "0000"
            assert r.displacement_mm == pytest.approx(h.truth(), abs=1e-6)
            values.setdefault((t1, t2), []).append((r.displacement_mm, emu.directions))
        # (-10, 60) is reached three times: from below, from above on J1, from below again.
        (d_a, dir_a), (d_b, dir_b), (d_c, dir_c) = values[(-10.0, 60.0)]
        assert dir_a[0] == 1 and dir_b[0] == -1 and dir_c[0] == 1
        assert abs(d_a - d_b) > 1e-4  # backlash of J1 (and J2) seen by the counter
        # POSJ: commanded as sent, encoder within half a count of it.
        pos = decode_position(robot.request("POSJ"))
        cmd = np.array([pos.commanded.theta1_deg, pos.commanded.theta2_deg, pos.commanded.z_mm,
                        pos.commanded.theta4_deg])
        enc = np.array([pos.encoder.theta1_deg, pos.encoder.theta2_deg, pos.encoder.z_mm,
                        pos.encoder.theta4_deg])
        np.testing.assert_allclose(cmd, h.sent[-1], atol=1e-9)
        assert np.all(np.abs(enc - cmd) <= np.asarray(DEFAULT_ENCODER_RESOLUTION) / 2 + 1e-6)


def test_emulated_paper_campaign_equals_the_numpy_twin():
    """The whole paper campaign (1056 readings) through the ptys: same readings as simulate_vectorized."""
    setup = prepare(Scenario())
    r = setup.scenario.robot
    c = campaign_commands(setup.plan, setup.reflectors_estimate_mm, setup.theta40_estimate_deg,
                          r.nominal_L1_mm, r.nominal_L2_mm)
    measure = setup.plan.measure[c["plan_row"]]
    readings, zeros = [], []
    with Emulator(setup, seed=7) as emu, ports(emu) as (robot, counter):
        run = None
        for k in range(len(c["theta1"])):
            j = int(c["reflector"][k])
            if j != run:
                expect_ack(counter.request("REFL", str(j)))
                run = j
                zeroed = False
            expect_ack(robot.request("MOVJ", *movj_fields(c["theta1"][k], c["theta2"][k], 0.0, c["theta4"][k])))
            expect_ack(robot.request("WAIT", "30000", timeout_s=31.0))
            if measure[k]:
                if not zeroed:
                    expect_ack(counter.request("ZERO"))
                    zeros.append(emu.dead_path_mm)
                    zeroed = True
                readings.append(decode_reading(counter.request("READ")))
        np.testing.assert_array_equal(np.array(emu.direction_history)[:, [0, 1, 3]],
                                      np.column_stack([c["dir1"], c["dir2"], c["dir4"]]))
    assert len(readings) == 1056
    ref = simulate_vectorized(setup, np.random.default_rng([7, STREAM_NOISE]))
    valid = np.array([x.valid for x in readings])
    np.testing.assert_array_equal(valid, ref.columns["valid"] > 0)
    d = np.array([x.displacement_mm for x in readings])
    # θ4* goes over the wire with 6 decimals: at most one λ/64 count apart, now and then.
    step = setup.scenario.interferometer.resolution_mm
    assert np.max(np.abs(d[valid] - ref.columns["displacement_mm"][valid])) <= step + 1e-9
    np.testing.assert_allclose(zeros, setup.dead_paths_mm, atol=1e-6)


# ----------------------------------------------------------------------------- directions


def test_direction_state_follows_the_rule():
    rng = np.random.default_rng(3)
    cmd = np.array([-30.0, 45.0, 10.0, 15.0])
    sent = []
    with Emulator(quiet_scenario()) as emu, ports(emu) as (robot, _):
        assert emu.directions == (1.0, 1.0, 1.0, 1.0)
        for _ in range(40):
            moving = rng.random(4) < 0.4  # most rows hold some axes
            cmd = np.where(moving, np.round(cmd + rng.uniform(-10, 10, 4), 3), cmd)
            cmd[2] = min(max(cmd[2], 0.0), 150.0)
            expect_ack(robot.request("MOVJ", *movj_fields(*cmd)))
            sent.append(cmd.copy())
        got = np.array(emu.direction_history)
    np.testing.assert_array_equal(np.array(emu.history), np.array(sent))
    np.testing.assert_array_equal(got, approach_directions(np.array(sent)))
    held = np.vstack([np.zeros((1, 4), bool), np.diff(np.array(sent), axis=0) == 0])
    assert held.any()  # the sequence does exercise "did not move: keep the direction"
    np.testing.assert_array_equal(got[1:][held[1:]], got[:-1][held[1:]])


# ----------------------------------------------------------------------------- faults


def raw_reply(emu, request: bytes, size: int, read_s=0.3) -> bytes:
    """The bytes (at most ``size``) the robot line sends back to one request within ``read_s``."""
    with serial.Serial(emu.robot_port, 115200, timeout=read_s) as s:
        s.write(request)
        return s.read(size)


PING = encode(5, "PING")
PONG = encode(5, "PONG", "1", "ROBOT", "SCARA-EMU")
NAK_CRC = encode(5, "NAK", "CRC", "checksum mismatch")


@pytest.mark.parametrize("fault, expected", [
    (dict(drop=1.0), lambda got: got == b""),
    (dict(nak_crc=1.0), lambda got: got == NAK_CRC),
    (dict(bad_crc=1.0), lambda got: got[:-5] == PONG[:-5] and got[-5:] != PONG[-5:]),
    (dict(garble=1.0), lambda got: len(got) == len(PONG) and sum(a != b for a, b in zip(got, PONG)) == 1),
    (dict(partial=1.0), lambda got: got == PONG[:len(PONG) // 2]),
    (dict(partial=1.0, partial_delay_s=0.05), lambda got: got == PONG),
    (dict(latency_s=0.05), lambda got: got == PONG),
], ids=["drop", "nak_crc", "bad_crc", "garble", "partial", "partial_later", "latency"])
def test_each_fault_does_what_it_says_on_the_line(fault, expected):
    with Emulator(quiet_scenario(), **fault) as emu:
        got = raw_reply(emu, PING, len(NAK_CRC) if "nak_crc" in fault else len(PONG))
    assert expected(got), got
    if got != PONG:  # whatever the fault did, the host's parser never sees a PONG in it
        assert not any(isinstance(e, Frame) and e.verb == "PONG" for e in FrameParser().feed(got))


@pytest.mark.parametrize("fault, discarded", [
    (dict(drop=0.2), None),
    (dict(garble=0.25), ("ChecksumError", "NoiseError", "FrameSyntaxError", "NonAsciiError", "PartialFrame")),
    (dict(nak_crc=0.25), None),
    (dict(bad_crc=0.25), ("ChecksumError",)),
    (dict(partial=0.25), ("PartialFrame",)),
    (dict(partial=0.25, partial_delay_s=0.2), ("PartialFrame", "NoiseError")),
], ids=["drop", "garble", "nak_crc", "bad_crc", "partial", "partial_later"])
def test_host_retries_through_faults_and_never_accepts_a_wrong_value(fault, discarded):
    s = quiet_scenario()
    with Emulator(s, seed=11, **fault) as emu, ports(emu, timeout_s=0.15, retries=10) as (robot, counter):
        h = Host(robot, counter, s, wait_ms=50)
        h.move(*POSES[0])
        h.zero()
        for k in range(8):
            t1, t2 = POSES[1 + k % (len(POSES) - 1)]
            h.move(t1 + 0.5 * k, t2)
            r = h.read()
            assert r.valid
            assert r.displacement_mm == pytest.approx(h.truth(), abs=1e-6)
        # Every MOVJ executed exactly once, whatever was lost or resent.
        np.testing.assert_array_equal(np.array(emu.history), np.array(h.sent))
    counts = robot.counts + counter.counts
    assert counts["retry"] > 0
    if discarded:
        assert sum(counts[k] for k in discarded) > 0, counts


def test_forced_beam_loss_flags_the_reading_invalid():
    s = quiet_scenario()
    with Emulator(s, beam_loss=0.5, seed=2) as emu, ports(emu) as (robot, counter):
        h = Host(robot, counter, s)
        h.move(*POSES[0])
        h.zero()
        last, flags = 0.0, []
        for k in range(16):
            h.move(-30.0 + k, 45.0)
            r = h.read()
            flags.append(r.valid)
            if r.valid:
                assert r.status == "0000" and r.displacement_mm == pytest.approx(h.truth(), abs=1e-6)
                last = r.displacement_mm
            else:  # the counter's last value, flagged: beam lost (injected), data invalid
                assert r.status == "8011" and r.displacement_mm == last
    assert any(flags) and not all(flags)
    with Emulator(s, beam_loss=1.0) as emu, ports(emu) as (robot, counter):
        Host(robot, counter, s).move(*POSES[0])
        expect_ack(counter.request("ZERO"))  # ZERO is not affected by the switch
        assert decode_reading(counter.request("READ")).valid is False


def test_alarm_refuses_moves_until_cleared():
    s = quiet_scenario()
    with Emulator(s, alarm_at=2) as emu, ports(emu) as (robot, counter):
        h = Host(robot, counter, s)
        h.move(*POSES[0])
        assert decode_alarms(robot.request("ALRM")) == ()
        for _ in range(2):  # the 2nd MOVJ raises it; later ones are refused too
            with pytest.raises(NakError) as e:
                robot.request("MOVJ", *movj_fields(-10.0, 60.0, 0.0, 0.0))
            assert e.value.code == "ALARM"
        with pytest.raises(NakError) as e:
            robot.request("WAIT", "1000")
        assert e.value.code == "ALARM"
        assert decode_alarms(robot.request("ALRM")) == (ALARM_CODE,)
        assert decode_alarms(robot.request("ALRM", "CLR")) == ()
        h.move(-10.0, 60.0)
        assert emu.history == [tuple(x) for x in h.sent]


def test_disconnect_gives_the_host_a_clear_exception():
    s = quiet_scenario()
    with Emulator(s, disconnect_after=3) as emu, ports(emu) as (robot, counter):
        robot.request("PING")
        counter.request("PING")
        counter.request("READ")  # the 3rd request is still answered
        assert emu.disconnected.wait(5.0)
        for t in (robot, counter):
            with pytest.raises(LinkLost, match="serial link lost during .*PING"):
                for _ in range(3):  # the write, or the read after it, fails: never a quiet timeout
                    t.request("PING")


# ----------------------------------------------------------------------------- counter, speed, program


def test_reflector_side_channel_and_zero():
    s = quiet_scenario()
    with Emulator(s, reflector=2) as emu, ports(emu) as (robot, counter):
        assert counter.request("REFL").fields == ("2", "3")
        r = decode_reading(counter.request("READ"))
        assert not r.valid and r.status == "8002"  # never zeroed
        with pytest.raises(NakError) as e:
            counter.request("REFL", "3")
        assert e.value.code == "RANGE"
        h = Host(robot, counter, s)
        h.refl(0)
        h.move(*POSES[0])
        h.zero()
        h.move(*POSES[1])
        assert decode_reading(counter.request("READ")).valid
        h.refl(1)  # the operator moved the reflector: the count is lost until the next ZERO
        r = decode_reading(counter.request("READ"))
        assert not r.valid and r.status == "8002"
        emu.reflector = 0  # the Python side channel does the same
        assert counter.request("REFL").fields == ("0", "3")
    aimed = Scenario(reflector_estimate=ExactEstimate())  # beam loss on
    with Emulator(aimed) as emu, ports(emu) as (robot, counter):
        Host(robot, counter, aimed).move(-30.0, 45.0, t4=-120.0)  # the beam points away
        with pytest.raises(NakError) as e:
            counter.request("ZERO")
        assert e.value.code == "BEAM"
        r = decode_reading(counter.request("READ"))
        assert not r.valid and r.status == "8003"


def test_latched_beam_loss_needs_a_new_zero():
    s = Scenario(reflector_estimate=ExactEstimate(),
                 interferometer=InterferometerOptions(noise=False, quantization=False))
    with Emulator(s, latch_beam_loss=True) as emu, ports(emu) as (robot, counter):
        h = Host(robot, counter, s)
        h.move(*POSES[0])
        h.zero()
        assert decode_reading(counter.request("READ")).valid
        h.move(*POSES[1], t4=h.steer(*POSES[1]) + 30.0)  # the beam misses the reflector
        assert decode_reading(counter.request("READ")).status == "8005"
        h.move(*POSES[1])  # aimed again, but the count was lost
        assert decode_reading(counter.request("READ")).status == "8004"
        h.zero()
        assert decode_reading(counter.request("READ")).valid
        assert emu.latch_beam_loss


def test_refl_examples_in_the_doc_are_what_the_emulator_answers():
    doc = (Path(__file__).resolve().parents[2] / "docs" / "emulator.md").read_text(encoding="utf-8")
    lines = re.findall(r"^([→←]) (\$.*?\*[0-9A-F]{4})", doc, flags=re.M)
    pairs = [(a[1], b[1]) for a, b in zip(lines, lines[1:]) if a[0] == "→" and b[0] == "←"]
    assert len(pairs) == 3
    device = Responder(_Device(Emulator(quiet_scenario()), "counter"))
    for request, reply in pairs:
        assert device.feed(request.encode() + b"\n") == reply.encode() + b"\n"


def test_realistic_speed_moves_take_time():
    s = quiet_scenario()
    # A long move (60 deg at 20 deg/s: 3 s): BUSY, TMO and a POSJ in motion, without waiting for it.
    with Emulator(s, speed="realistic", speeds=(20.0, 20.0, 20.0, 20.0), settle_s=0.1) as emu, \
            ports(emu) as (robot, counter):
        expect_ack(robot.request("MOVJ", *movj_fields(-60.0, 0.0, 0.0, 0.0)))
        with pytest.raises(NakError) as e:
            robot.request("MOVJ", *movj_fields(0.0, 30.0, 0.0, 0.0))
        assert e.value.code == "BUSY"
        with pytest.raises(NakError) as e:
            robot.request("WAIT", "1", timeout_s=2.0)
        assert e.value.code == "TMO" and "J1 not in position" in e.value.text
        pos = decode_position(robot.request("POSJ"))
        assert pos.commanded.theta1_deg == -60.0 and -60.0 < pos.encoder.theta1_deg < 0.0
        assert emu.history == [(-60.0, 0.0, 0.0, 0.0)]
    # A short one (5 deg at 100 deg/s + 0.05 s): WAIT answers once it is in position.
    with Emulator(s, speed="realistic", speeds=(100.0, 100.0, 100.0, 100.0), settle_s=0.05) as emu, \
            ports(emu) as (robot, counter):
        expect_ack(robot.request("MOVJ", *movj_fields(5.0, 0.0, 0.0, 0.0)))
        expect_ack(robot.request("WAIT", "30000", timeout_s=31.0))
        assert decode_position(robot.request("POSJ")).encoder.theta1_deg == pytest.approx(5.0, abs=1e-3)
        expect_ack(robot.request("MOVJ", *movj_fields(0.0, 0.0, 0.0, 0.0)))  # not BUSY any more


def test_module_runs_as_a_program(tmp_path):
    link = str(tmp_path / "emu")
    proc = subprocess.Popen([sys.executable, "-m", "olti_drake.cli.emulator", "--seed", "3", "--link", link],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = [proc.stdout.readline() for _ in range(3)]
        assert lines[0].startswith("robot") and lines[1].startswith("counter"), lines
        assert os.path.islink(link + "-robot") and os.path.islink(link + "-counter")
        with serial.Serial(link + "-counter", 115200, timeout=0.05) as s:
            assert decode_pong(Transport(s).request("PING")).role == "COUNTER"
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
    assert proc.returncode == 0, err
    assert not os.path.lexists(link + "-robot")


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError):
        Emulator(quiet_scenario(), drop=1.5)
    with pytest.raises(ValueError):
        Emulator(quiet_scenario(), speed="warp")
    with pytest.raises(TypeError):
        Emulator(quiet_scenario(), dropp=0.1)
    with pytest.raises(ValueError):
        Emulator(quiet_scenario(), reflector=3)
    assert Faults(alarm_at=3).validate().alarm_at == 3
