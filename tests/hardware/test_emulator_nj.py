"""The N-joint emulator (olti_drake/hardware/serial_emulator.py): a UR5 from its model file and its tracer
heads behind protocol version 2 on pseudo-terminals; readings equal the model's truth; faults as the SCARA's;
the drivers and the hardware station for N joints; a six-axis campaign killed mid-way and resumed."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import serial

from olti_drake.hardware import protocol as P
from olti_drake.hardware.serial_emulator import SerialEmulator
from olti_drake.model.aiming3d import pan_tilt_commands
from olti_drake.model.errormap import approach_directions
from olti_drake.model.instrument import InterferometerOptions
from olti_calls import error_line, olti_sub

EXACT = InterferometerOptions(noise=False, quantization=False, cosine_error=False, beam_loss=False)
POSES = np.array([[10.0, -80.0, 95.0, -30.0, -90.0, 45.0], [20.0, -70.0, 80.0, -40.0, -80.0, 30.0],
                  [10.0, -80.0, 95.0, -30.0, -90.0, 45.0], [0.0, -90.0, 100.0, -20.0, -95.0, 60.0],
                  [10.0, -80.0, 95.0, -30.0, -90.0, 45.0]])


@contextlib.contextmanager
def lines(emu, timeout_s=1.0, retries=2):
    """Transports on the robot line and every head line (pyserial on the pty slaves)."""
    streams = [serial.Serial(p, 115200, timeout=0.05) for p in [emu.robot_port] + emu.head_ports]
    try:
        yield [P.Transport(s, timeout_s=timeout_s, retries=retries, seq=100 * k) for k, s in enumerate(streams)]
    finally:
        for s in streams:
            s.close()


def _layout(t) -> P.AxisLayout:
    return P.AxisLayout([P.decode_axis(t.request("INFO", str(k)), k) for k in range(P.decode_info(t.request("INFO")))])


def _aim(emu, h, q):
    """Head h's pan/tilt command at the NOMINAL tool point of q (what a host computes), deg."""
    chain = emu.truth.chain
    p = chain.positions(q[None], chain.nominal_parameters(emu.truth.chain_params[-3:]))
    return pan_tilt_commands(emu.heads_true, [h], p)[0]


def _move(robot, layout, q):
    P.expect_ack(robot.request("MOVJ", *layout.fields(q)))
    P.expect_ack(robot.request("WAIT", "2000"))


def test_devices_announce_their_axes_and_refuse_what_is_not_theirs():
    with SerialEmulator("ur5", options=EXACT) as emu, lines(emu) as (robot, head, *_):
        assert P.decode_pong(robot.request("PING")) == P.Pong(2, "ROBOT", "UR5-EMU")
        assert P.decode_pong(head.request("PING")) == P.Pong(2, "HEAD", "TRACER-EMU")
        layout = _layout(robot)
        assert layout.labels[2] == "elbow_joint_deg" and (layout.axes[2].lower, layout.axes[2].upper) == (-180, 180)
        assert _layout(head) == P.PAN_TILT_LAYOUT
        for t, verb in ((robot, "READ"), (robot, "AIM"), (head, "MOVJ"), (head, "REFL"), (robot, "FOO")):
            with pytest.raises(P.NakError) as e:
                t.request(verb)
            assert e.value.code == "VERB"
        bad = list(POSES[0])
        bad[2] = 190.0
        with pytest.raises(P.NakError, match="elbow_joint_deg 190.000000 outside -180..180") as e:
            robot.request("MOVJ", *layout.fields(bad, check_range=False))
        assert e.value.code == "RANGE"
        with pytest.raises(P.NakError, match="expects 6 fields") as e:
            robot.request("MOVJ", *layout.fields(POSES[0])[:5])
        assert e.value.code == "SYN"
        with pytest.raises(P.NakError, match="tilt_deg 101.000000 outside") as e:
            head.request("AIM", "0.000000", "101.000000")
        assert e.value.code == "RANGE"
        with pytest.raises(P.NakError, match="axis 6 outside 0..5"):
            robot.request("INFO", "6")
        _move(robot, layout, POSES[0])
        pos = P.decode_position_n(robot.request("POSJ"), layout)
        assert pos.commanded == tuple(POSES[0])
        assert np.max(np.abs(np.subtract(pos.encoder, POSES[0]))) <= 360.0 / 2 ** 21 + 1e-6


def test_noise_free_readings_equal_the_model_truth_with_the_approach_directions():
    """|T − C| − d0 with T the truth's tool point at the commands and the rule's directions: the
    emulator tracks directions per joint (backlash) and reads at the pose the robot is at."""
    with SerialEmulator("ur5", options=EXACT) as emu, lines(emu) as (robot, *heads):
        layout = _layout(robot)
        sequence = np.tile(POSES, (len(heads), 1))              # the robot goes through the poses once per head
        all_dirs = approach_directions(sequence, last_direction=1.0)
        for h, head in enumerate(heads):
            centre = emu.heads_true.centres_mm[h]
            dirs = all_dirs[h * len(POSES):(h + 1) * len(POSES)]
            truth = emu.truth.positions(POSES, dirs)
            got = []
            for k, q in enumerate(POSES):
                _move(robot, layout, q)
                P.expect_ack(head.request("AIM", *P.PAN_TILT_LAYOUT.fields(_aim(emu, h, q), "AIM")))
                if k == 0:
                    P.expect_ack(head.request("ZERO"))
                got.append(P.decode_reading(head.request("READ")).displacement_mm)
            want = np.linalg.norm(truth - centre, axis=1)
            np.testing.assert_allclose(got, want - want[0], rtol=0, atol=2e-9)
            np.testing.assert_allclose(emu.head_dead_paths_mm[h], want[0], rtol=0, atol=1e-9)
        # Poses 0, 2, 4 are the same command approached from different sides: backlash shows.
        assert np.any(dirs[2] != dirs[0]) and abs(got[2] - got[0]) > 1e-4


def test_beam_and_zero_follow_the_head_aim_and_the_counter_rules():
    opts = InterferometerOptions(noise=False, quantization=False)        # cosine error and beam loss on
    with SerialEmulator("ur5", options=opts, head_error_mdeg=0) as emu, lines(emu) as (robot, head, *_):
        layout = _layout(robot)
        _move(robot, layout, POSES[0])
        r = P.decode_reading(head.request("READ"))
        assert not r.valid and r.status == "8003"              # aimed at (0, 0): no beam, and not zeroed yet
        with pytest.raises(P.NakError) as e:
            head.request("ZERO")                                 # no beam to zero on
        assert e.value.code == "BEAM"
        # Aimed with the true head at the true tool point, head 0 sees the cat's eye from this pose.
        aim = pan_tilt_commands(emu.heads_true, [0], emu.truth.positions(POSES[:1]))[0]
        P.expect_ack(head.request("AIM", *P.PAN_TILT_LAYOUT.fields(aim, "AIM")))
        P.expect_ack(head.request("ZERO"))
        assert P.decode_reading(head.request("READ")) == P.Reading(0.0, True, "0000")
        P.expect_ack(head.request("AIM", *P.PAN_TILT_LAYOUT.fields(aim + [0.1, 0.0], "AIM")))  # ~3 mm off at 2 m
        assert P.decode_reading(head.request("READ")) == P.Reading(0.0, False, "8001")
        hpos = P.decode_position_n(head.request("POSH"), P.PAN_TILT_LAYOUT, "HPOS")
        np.testing.assert_allclose(hpos.encoder, hpos.commanded, atol=360.0 / 2 ** 20)


def _script(emu, robot, heads, layout):
    out = []
    for k, q in enumerate(POSES):
        _move(robot, layout, q)
        for h, head in enumerate(heads):
            P.expect_ack(head.request("AIM", *P.PAN_TILT_LAYOUT.fields(_aim(emu, h, q), "AIM")))
            if k == 0:
                P.expect_ack(head.request("ZERO"))
            r = P.decode_reading(head.request("READ"))
            out.append((r.displacement_mm, r.valid))
        out.append(P.decode_position_n(robot.request("POSJ"), layout).encoder)
    return out


@pytest.mark.parametrize("fault", [dict(drop=0.15), dict(garble=0.1, nak_crc=0.1, bad_crc=0.1, partial=0.1)])
def test_host_retries_through_faults_on_every_line_and_gets_the_same_values(fault):
    """Seeded noise (budget on): the same requests give the same values with faults as without
    (a lost reply is resent from the stored one, never re-executed: no extra noise draw)."""
    from olti_drake.model.budget import paper000_budget

    opts = InterferometerOptions(beam_loss=False)
    results = []
    for f in ({}, fault):
        with SerialEmulator("ur5", options=opts, budget=paper000_budget(), seed=4, **f) as emu, \
                lines(emu, timeout_s=0.15, retries=8) as (robot, *heads):
            results.append(_script(emu, robot, heads, _layout(robot)))
            counts = sum((t.counts for t in [robot, *heads]), start=__import__("collections").Counter())
        if f:
            assert counts["retry"] > 0, counts
    assert results[0] == results[1]
    assert len({d for d, _ in results[0][0:4]}) > 1          # noise is on: not all equal


def test_alarm_and_disconnect_on_the_n_joint_robot():
    with SerialEmulator("ur5", options=EXACT, alarm_at=2) as emu, lines(emu) as (robot, *_):
        layout = _layout(robot)
        _move(robot, layout, POSES[0])
        with pytest.raises(P.NakError) as e:
            robot.request("MOVJ", *layout.fields(POSES[1]))
        assert e.value.code == "ALARM"
        assert P.decode_alarms(robot.request("ALRM", "CLR")) == ()
        _move(robot, layout, POSES[1])
        assert emu.history == [tuple(POSES[0]), tuple(POSES[1])]
    with SerialEmulator("ur5", options=EXACT, disconnect_after=3) as emu, lines(emu) as (robot, head, *_):
        robot.request("PING"), head.request("PING"), robot.request("INFO")
        with pytest.raises(P.LinkLost):
            for _ in range(5):
                head.request("READ")
                time.sleep(0.05)


def test_module_runs_the_n_joint_emulator_as_a_program(tmp_path):
    link = str(tmp_path / "ur5")
    proc = subprocess.Popen([sys.executable, "-m", "olti_drake.cli.emulator", "--robot", "ur5", "--link", link,
                             "--seed", "3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        seen = [proc.stdout.readline() for _ in range(6)]
        assert seen[0].startswith("robot") and seen[4].startswith("head3"), seen
        with serial.Serial(link + "-robot", 115200, timeout=0.05) as s:
            assert P.decode_pong(P.Transport(s).request("PING")).model == "UR5-EMU"
        with serial.Serial(link + "-head2", 115200, timeout=0.05) as s:
            assert P.decode_pong(P.Transport(s).request("PING")).role == "HEAD"
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(10) == 0
    assert not os.path.lexists(link + "-robot")
    bad = subprocess.run([sys.executable, "-m", "olti_drake.cli.emulator", "--robot", "ur5", "--reflector", "1"],
                         capture_output=True, text=True, timeout=60)
    error_line(bad.returncode, bad.stderr)
    assert bad.stderr.startswith("error: --robot")


def test_hardware_station_for_n_joints_and_tracer_heads_keeps_the_port_contract():
    """AddHardwareStation on the N-joint drivers: ports sized by the announced joints, measured_position
    = the encoders, the head aimed from head_command, readings = the truth's distance changes."""
    from types import SimpleNamespace

    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    from olti_drake.hardware.drivers import OltiHead, OltiRobot, TracerHeads
    from olti_drake.hardware.station import AddHardwareStation

    with SerialEmulator("ur5", options=EXACT, seed=2) as emu:
        robot = OltiRobot.open(emu.robot_port, 115200, 1.0, 2)
        heads = TracerHeads([OltiHead.open(p, 115200, 1.0, 2) for p in emu.head_ports])
        try:
            assert robot.layout.n == 6 and [h.layout for h in heads.heads] == [P.PAN_TILT_LAYOUT] * 4
            builder = DiagramBuilder()
            setup = SimpleNamespace(scenario=SimpleNamespace(period_s=1.0))
            station = AddHardwareStation(builder, setup, (robot, heads))
            assert station.get_input_port(0).size() == 6 and station.GetOutputPort("measured_position").size() == 6
            assert station.GetInputPort("head_command").size() == 2
            for port in ("joint_command", "reflector", "head_command"):
                builder.ExportInput(station.GetInputPort(port), port)
            diagram = builder.Build()
            sim = Simulator(diagram)
            ctx = sim.get_mutable_context()
            sctx = station.GetMyContextFromRoot(ctx)
            got = []
            for k, q in enumerate(POSES[:3]):
                diagram.GetInputPort("joint_command").FixValue(ctx, np.radians(q))
                diagram.GetInputPort("reflector").FixValue(ctx, [1.0])
                diagram.GetInputPort("head_command").FixValue(ctx, np.radians(_aim(emu, 1, q)))
                sim.AdvanceTo(k + 0.5)
                assert station.GetOutputPort("valid").Eval(sctx)[0] == 1.0
                got.append(station.GetOutputPort("displacement").Eval(sctx)[0] * 1e3)
                np.testing.assert_allclose(np.degrees(station.GetOutputPort("measured_position").Eval(sctx)), q,
                                           atol=360.0 / 2 ** 20)
                np.testing.assert_allclose(np.degrees(station.GetOutputPort("head_position").Eval(sctx)),
                                           _aim(emu, 1, q), atol=360.0 / 2 ** 20)
            dirs = approach_directions(POSES[:3], last_direction=1.0)
            d = np.linalg.norm(emu.truth.positions(POSES[:3], dirs) - emu.heads_true.centres_mm[1], axis=1)
            np.testing.assert_allclose(got, d - d[0], rtol=0, atol=2e-9)
            assert emu.history == [tuple(q) for q in POSES[:3]]
        finally:
            robot.close()
            heads.close()


# ------------------------------------------------------------------ olti run: a six-axis campaign

SIX_AXIS = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "diagrams", "six_axis.yaml")


def _six_axis(tmp_path, station="!Emulated {}"):
    """diagrams/six_axis.yaml with a small plan (60° nodes, one pose per node and direction: 47 readings),
    noise-free so that every reading is reproducible."""
    path = tmp_path / "six.yaml"
    path.write_text(f"base: {SIX_AXIS}\nstation: {station}\nplan: {{step_deg: 60.0, poses_per_node: 1}}\n"
                    "interferometer: {noise: false, quantization: false}\n")
    return str(path)


@pytest.fixture(scope="module")
def six_axis_reference(tmp_path_factory):
    from olti_drake.hardware.runner import run

    tmp = tmp_path_factory.mktemp("six")
    result = run(_six_axis(tmp), str(tmp / "run"))
    assert result.complete and result.taken == result.on_disk == result.planned > 30
    return result


def _columns(out, n=6):
    from olti_drake.io.csvio import read_table

    names = (("station",) + tuple(f"theta{i + 1}_deg" for i in range(n)) + tuple(f"dir{i + 1}" for i in range(n))
             + ("displacement_mm", "valid", "plan_row", "step", "session"))
    return read_table(os.path.join(out, "campaign.csv"), names)


def test_emulated_six_axis_campaign_equals_the_simulated_diagram(six_axis_reference):
    """The emulator behind the hardware station reads what the simulated N-joint station reads (same truth,
    heads, aim); the counter zeros differ (emulated: the run's first row), so compare within each run."""
    from olti_drake.sim.serial_scenario import load_serial_scenario
    from olti_drake.sim.serial_station import prepare_serial, run_serial_campaign

    emu = _columns(six_axis_reference.out_dir)
    sim = run_serial_campaign(prepare_serial(load_serial_scenario(os.path.join(
        os.path.dirname(six_axis_reference.out_dir), "six.yaml")))).columns
    for k in ["station", "valid"] + [f"dir{i + 1}" for i in range(6)]:
        np.testing.assert_array_equal(emu[k], sim[k], err_msg=k)
    for k in [f"theta{i + 1}_deg" for i in range(6)]:      # the log writes 12 significant digits
        np.testing.assert_allclose(emu[k], sim[k], rtol=0, atol=1e-9, err_msg=k)
    assert np.all(emu["valid"] == 1)
    for j in np.unique(emu["station"]):
        m = emu["station"] == j
        de, ds = emu["displacement_mm"][m], sim["displacement_mm"][m]
        np.testing.assert_allclose(de - de[0], ds - ds[0], rtol=0, atol=1e-6)


def test_six_axis_campaign_killed_mid_way_and_resumed_has_every_reading_once(tmp_path, six_axis_reference):
    from olti_drake.hardware.runner import run

    scenario, out = _six_axis(tmp_path), str(tmp_path / "run")
    csv = os.path.join(out, "campaign.csv")
    proc = subprocess.Popen([sys.executable, "-m", "olti_drake.cli", "run", scenario, "--out", out],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if os.path.exists(csv) and open(csv, "rb").read().count(b"\n") >= 3 + 15:
            break
        time.sleep(0.005)
    proc.kill()                                            # SIGKILL mid-way: no clean-up of any kind
    proc.wait(10)
    before = _columns(out)
    assert 15 <= len(before["step"]) < six_axis_reference.planned
    result = run(scenario, out, resume=True)
    assert result.complete and result.session == 1 and result.start_step > 0
    assert result.on_disk == result.planned == six_axis_reference.planned
    t, ref = _columns(out), _columns(six_axis_reference.out_dir)
    assert np.array_equal(np.sort(t["step"]), ref["step"]) and len(np.unique(t["step"])) == len(t["step"])
    assert set(t["session"]) == {0, 1}
    for k in ["station", "valid", "plan_row"] + [f"theta{i + 1}_deg" for i in range(6)] + [f"dir{i + 1}" for i in range(6)]:
        np.testing.assert_array_equal(t[k], ref[k], err_msg=k)
    # The resumed readings equal the uninterrupted ones: same approach sides, same counter zero.
    np.testing.assert_allclose(t["displacement_mm"], ref["displacement_mm"], rtol=0, atol=1e-9)
    events = [json.loads(line) for line in open(os.path.join(out, "events.jsonl"))]
    assert any(e["kind"] == "reapproach" and e["session"] == 1 for e in events)
    assert any(e["kind"] == "zero" and e["session"] == 1 and e["again"] and "aim" in e for e in events)
    assert json.load(open(os.path.join(out, "run.json")))["complete"]
    assert os.path.exists(os.path.join(out, "truth.json"))
    again = run(scenario, out, resume=True)                # nothing left: nothing taken, nothing written twice
    assert again.taken == 0 and _columns(out)["step"].size == t["step"].size


def test_six_axis_hardware_station_on_one_port_per_head(tmp_path, six_axis_reference):
    """station: !Hardware {robot_port, head_ports}: the real-device path (here the N-joint emulator's ptys,
    started from the same scenario) reads what the emulated station reads."""
    from olti_drake.hardware.runner import run
    from olti_drake.hardware.station import serial_emulator_for
    from olti_drake.sim.scenario import Emulated
    from olti_drake.sim.serial_scenario import load_serial_scenario
    from olti_drake.sim.serial_station import prepare_serial

    emu = serial_emulator_for(prepare_serial(load_serial_scenario(_six_axis(tmp_path))), None, Emulated()).start()
    try:
        ports = ", ".join(emu.head_ports)
        out = str(tmp_path / "run")
        result = run(_six_axis(tmp_path, f"!Hardware {{robot_port: {emu.robot_port}, head_ports: [{ports}]}}"), out)
    finally:
        emu.stop()
    assert result.complete and result.on_disk == six_axis_reference.planned
    t, ref = _columns(out), _columns(six_axis_reference.out_dir)
    np.testing.assert_array_equal(t["station"], ref["station"])
    np.testing.assert_allclose(t["displacement_mm"], ref["displacement_mm"], rtol=0, atol=1e-9)


def test_six_axis_run_refuses_what_it_cannot_do_in_one_line(tmp_path):
    for station, extra, match in (("!Hardware {}", [], "head_ports"),
                                  ("!Hardware {robot_port: /dev/null, head_ports: [a, b]}", [],
                                   "4 in station order (got 2)"),
                                  ("!Emulated {}", ["--meshcat"], "--meshcat: olti run shows the live view of SCARA")):
        proc = olti_sub("run", _six_axis(tmp_path, station), "--out", tmp_path / "x", *extra, timeout=120, expect=2)
        assert match in proc.stderr and not os.path.exists(tmp_path / "x")


def test_six_axis_simulated_station_runs_and_resumes_as_the_simulated_diagram(tmp_path):
    """station: !Simulated under olti run: the readings of run_serial_campaign (olti simulate's diagram); with
    noise, a campaign stopped twice and resumed reads what the uninterrupted one reads (the joints' last
    command and directions and the laser's sample count are restored)."""
    from olti_drake.hardware.runner import run
    from olti_drake.sim.serial_scenario import load_serial_scenario
    from olti_drake.sim.serial_station import prepare_serial, run_serial_campaign

    path = tmp_path / "sim.yaml"
    path.write_text(f"base: {SIX_AXIS}\nstation: !Simulated {{}}\nplan: {{step_deg: 60.0, poses_per_node: 1}}\n")
    whole = run(str(path), str(tmp_path / "whole"), fsync=False)
    assert whole.complete and whole.planned == whole.on_disk > 30
    t = _columns(str(tmp_path / "whole"))
    ref = run_serial_campaign(prepare_serial(load_serial_scenario(str(path)))).columns
    for k in ["station", "valid", "plan_row"] + [f"dir{i + 1}" for i in range(6)]:
        np.testing.assert_array_equal(t[k], ref[k], err_msg=k)
    np.testing.assert_allclose(t["displacement_mm"], ref["displacement_mm"], rtol=0, atol=1e-9)
    out, done = str(tmp_path / "cut"), {"n": 0}
    for k, stop_at in enumerate((9, 30)):
        r = run(str(path), out, resume=k > 0, fsync=False, progress=lambda n, planned: done.update(n=n),
                should_stop=lambda stop_at=stop_at: "test" if done["n"] >= stop_at else None)
        assert r.stopped == "test" and r.on_disk == stop_at
    assert run(str(path), out, resume=True, fsync=False).complete
    cut = _columns(out)
    np.testing.assert_array_equal(cut["step"], t["step"])
    np.testing.assert_allclose(cut["displacement_mm"], t["displacement_mm"], rtol=0, atol=1e-12)
    assert os.path.exists(os.path.join(out, "truth.json"))


def test_six_axis_run_takes_an_extend_hook(tmp_path, six_axis_reference):
    """run(extend=...) on the six-axis path: the hook gets the builder and the station, sequencer, steering and
    recorder by keyword (as the SCARA's); a logger LeafSystem added there sees every reading of the run log."""
    from pydrake.systems.framework import LeafSystem

    from olti_drake.hardware.runner import run

    class ReadingLogger(LeafSystem):
        def __init__(self, period_s):
            super().__init__()
            self.rows = []
            for name in ("displacement", "valid", "measure"):
                self.DeclareVectorInputPort(name, 1)
            self.DeclarePeriodicPublishEvent(period_s, 0.5 * period_s, self._log)

        def _log(self, context):
            self.rows.append(tuple(self.get_input_port(i).Eval(context)[0] for i in range(3)))

    seen = {}

    def extend(builder, *, setup, station, sequencer, steering, recorder):
        logger = builder.AddNamedSystem("reading_logger", ReadingLogger(setup.scenario.period_s))
        builder.Connect(station.GetOutputPort("displacement"), logger.GetInputPort("displacement"))
        builder.Connect(station.GetOutputPort("valid"), logger.GetInputPort("valid"))
        builder.Connect(sequencer.GetOutputPort("measure"), logger.GetInputPort("measure"))
        seen.update(logger=logger, steering=steering, recorder=recorder)

    out = str(tmp_path / "run")
    result = run(_six_axis(tmp_path), out, extend=extend, fsync=False)
    assert result.complete and seen["steering"].get_name() == "pan_tilt_steering"
    assert seen["recorder"].get_name() == "campaign_recorder"
    rows = np.array(seen["logger"].rows)
    rows = rows[rows[:, 2] > 0.5]
    t, ref = _columns(out), _columns(six_axis_reference.out_dir)
    assert len(rows) == len(t["step"]) == six_axis_reference.planned
    np.testing.assert_allclose(rows[:, 0] * 1e3, t["displacement_mm"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(t["displacement_mm"], ref["displacement_mm"], rtol=0, atol=1e-9)


def test_six_axis_beam_losses_are_reread_and_rezeroed_with_the_head_aimed_as_at_its_zero(tmp_path,
                                                                                          six_axis_reference):
    """Injected beam losses on the head lines: the policy re-reads, then re-zeroes at the run's reference
    pose with the head aimed as then; the readings equal the undisturbed campaign's."""
    from olti_drake.hardware.runner import run

    out = str(tmp_path / "run")
    result = run(_six_axis(tmp_path, "!Emulated {beam_loss: 0.3, nak_crc: 0.05}"), out)
    t, ref = _columns(out), _columns(six_axis_reference.out_dir)
    assert result.complete and np.array_equal(t["step"], ref["step"]) and np.all(t["valid"] == 1)
    np.testing.assert_allclose(t["displacement_mm"], ref["displacement_mm"], rtol=0, atol=1e-9)
    events = [json.loads(line) for line in open(os.path.join(out, "events.jsonl"))]
    again = [e for e in events if e["kind"] == "zero" and e["again"]]
    first = {e["reflector"]: e for e in events if e["kind"] == "zero" and not e["again"]}
    assert again and all(e["aim"] == first[e["reflector"]]["aim"] for e in again)
    assert sum(e["kind"] == "invalid_reading" for e in events) > 10


def test_exact_encoders_on_robot_and_heads():
    with SerialEmulator("ur5", options=EXACT, encoder_resolution=0.0) as emu, lines(emu) as (robot, head, *_):
        layout = _layout(robot)
        q = POSES[0] + 1e-4
        _move(robot, layout, q)
        assert P.decode_position_n(robot.request("POSJ"), layout).encoder == tuple(np.round(q, 6))
        P.expect_ack(head.request("AIM", "12.345678", "-3.210987"))
        assert P.decode_position_n(head.request("POSH"), P.PAN_TILT_LAYOUT, "HPOS").encoder == (12.345678, -3.210987)
