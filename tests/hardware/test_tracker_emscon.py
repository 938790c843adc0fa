"""The emScon laser tracker (olti_drake/hardware/emscon.py, tracker_emulator.py, tracker_station.py) over real
TCP sockets on ephemeral ports: the maintainers' sequence with an independent struct-level client written here
from the published layout; the beam pointed away gives the error status, never a measurement; fuzzed and
truncated packets never yield a reading nor stop the server; a six-axis campaign on the tracker station under
``olti run``, SIGKILLed at seeded random moments and resumed: every planned reading exactly once, the
environment on every row, beam interruptions flagged and never recorded as readings."""

import json
import math
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import time

import numpy as np
import pytest

from olti_drake.hardware import emscon as E
from olti_drake.hardware.tracker_emulator import TrackerEmulator
from olti_calls import olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SIX_AXIS = os.path.join(ROOT, "diagrams", "six_axis.yaml")
REFLECTOR = (1800.0, -400.0, 250.0)     # mm, tracker frame


# ------------------------------------------------------------------ an independent client (struct level)
# From ES_C_API_Def.h: little-endian, pack 4, long and enums 4 bytes. PacketHeaderT {long size; type},
# BasicCommandCT = header + command (12 bytes), BasicCommandRT = + status (16), SingleMeasResultT =
# header, status, measMode, bIsTryMode, 17 doubles (156). Commands: Initialize 7, SetUnits 5,
# GetEnvironmentParams 21, StartMeasurement 49, PointLaser 58. Data types: command 0, single result 2.

def _cmd(command, fmt="", *values):
    size = 12 + struct.calcsize("<" + fmt)
    return struct.pack("<iii" + fmt, size, 0, command, *values)


def _packets(sock, timeout=2.0, count=None):
    """The packets the server sends, [(type, bytes)]: ``count`` of them, or (None) all until it closes or goes
    quiet for ``timeout`` s (then 0.3 s after the first bytes)."""
    data, out = b"", []
    while (count is None or len(out) < count) and select.select([sock], [], [], timeout)[0]:
        try:
            chunk = sock.recv(65536)
        except ConnectionResetError:          # the server dropped a connection whose framing was lost
            break
        if not chunk:
            break
        data += chunk
        timeout = 0.3
        while len(data) >= 8 and len(data) >= struct.unpack_from("<i", data)[0] >= 12:
            size, kind = struct.unpack_from("<ii", data)
            out.append((kind, data[:size]))
            data = data[size:]
    assert not data, f"the server sent a cut packet or a bad size field: {data.hex()}"
    return out


def _ask(sock, packet, count=None, timeout=2.0):
    sock.sendall(packet)
    return _packets(sock, timeout, count)


def _status(packet):
    return struct.unpack_from("<i", packet, 12)[0]


@pytest.fixture(scope="module")
def verb_emulator():
    """``olti tracker-emulator --port 0 --reflector-mm ...`` in a subprocess; yields its port."""
    p = subprocess.Popen([sys.executable, "-m", "olti_drake.cli", "tracker-emulator", "--port", "0", "--reflector-mm",
                          ",".join(map(str, REFLECTOR)), "--seed", "5"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
    line = p.stdout.readline()
    assert line.startswith("tracker 127.0.0.1:"), line + p.stderr.read()
    yield int(line.split(":")[1].split()[0])
    p.send_signal(signal.SIGINT)
    assert p.wait(10) == 0


def test_maintainers_sequence_with_an_independent_client(verb_emulator):
    with socket.create_connection(("127.0.0.1", verb_emulator), timeout=5) as s:
        (kind, rt), = _ask(s, _cmd(7), 1)                                   # Initialize
        assert (kind, len(rt), _status(rt), struct.unpack_from("<i", rt, 8)[0]) == (0, 16, 0, 7)
        (kind, env), = _ask(s, _cmd(21), 1)                                 # GetEnvironmentParams
        assert kind == 0 and len(env) == 40 and _status(env) == 0
        t, p, h = struct.unpack_from("<3d", env, 16)
        assert 15 < t < 25 and 950 < p < 1050 and 0 <= h <= 100       # °C, hPa, %RH: the session's default
        near = np.add(REFLECTOR, [2.0, -1.5, 1.0])                       # within the capture range (5 mm)
        (kind, rt), = _ask(s, _cmd(58, "3d", *near), 1)                     # PointLaser(x, y, z) mm
        assert _status(rt) == 0
        (k1, rt), (k2, res) = _ask(s, _cmd(49), 2)                          # StartMeasurement
        assert (k1, _status(rt), k2, len(res)) == (0, 0, 2, 156)
        status, mode, trying = struct.unpack_from("<3i", res, 8)
        v = struct.unpack_from("<17d", res, 20)
        assert (status, mode, trying) == (0, 0, 0)
        std = np.array(v[3:6])
        u = (15.0 + 6.0 * np.linalg.norm(REFLECTOR) / 1e3) / (2 * math.sqrt(3)) / 1e3   # the documented spec
        np.testing.assert_allclose(std, u, rtol=1e-12)
        assert np.all(np.abs(np.array(v[:3]) - REFLECTOR) < 5 * std)      # the reflector, within the noise
        assert abs(v[14] - t) < 1 and abs(v[15] - p) < 5 and abs(v[16] - h) < 5   # the environment, drifting
        # The beam well away from the reflector: the tracker's error status, never a measurement.
        (kind, rt), = _ask(s, _cmd(58, "3d", REFLECTOR[0], REFLECTOR[1] + 300.0, REFLECTOR[2]), 1)
        assert _status(rt) == 0
        answers = _ask(s, _cmd(49), timeout=1.0)
        assert [k for k, _ in answers] == [0] and _status(answers[0][1]) == E.RS_MEAS_STATUS_NOT_READY
        # SetUnits to metres (lenUnitType 0): the point comes in m.
        (kind, rt), = _ask(s, _cmd(5, "5i", 0, 1, 0, 1, 0), 1)
        assert _status(rt) == 0
        _ask(s, _cmd(58, "3d", *(np.array(REFLECTOR) / 1e3)), 1)
        (_, rt), (_, res) = _ask(s, _cmd(49), 2)
        np.testing.assert_allclose(struct.unpack_from("<3d", res, 20), np.array(REFLECTOR) / 1e3, atol=5e-3 * 1e-3 * 5)


def test_client_against_the_emulator_units_environment_and_refusals():
    with TrackerEmulator(REFLECTOR, seed=2) as emu:
        t = E.EmsconTracker.open("127.0.0.1", emu.port, 2.0)
        try:
            with pytest.raises(E.EmsconError, match="status 39"):         # not initialized yet
                t.point_laser(REFLECTOR)
            t.initialize()
            assert t.get_units() == E.UNITS_MM
            t.set_environment(21.5, 990.0, 30.0)
            assert t.environment() == (21.5, 990.0, 30.0)
            with pytest.raises(E.EmsconError, match="status 4"):           # SetUnits: length unit foot (3)
                t.set_units((3, 1, 0, 1, 0))
            t.go_position(np.add(REFLECTOR, [0.0, 4.0, 0.0]))
            m = t.measure()
            assert np.linalg.norm(np.subtract(m.point_mm, REFLECTOR)) < 0.05
            assert abs(m.temperature_c - 21.5) < 0.1 and m.spherical()[2] == pytest.approx(np.linalg.norm(REFLECTOR))
            t.point_laser(np.add(REFLECTOR, [0.0, 0.0, 6.0]))            # just outside the 5 mm capture range
            with pytest.raises(E.BeamLost):
                t.measure()
            t.request(E.C_SET_MEAS_MODE, E.MM_STATIONARY)
            assert t.request(E.C_GET_COORD_TYPE) == (E.CS_RHR,)
            with pytest.raises(E.EmsconError, match="status 4"):           # continuous modes: not implemented
                t.request(E.C_SET_MEAS_MODE, 1)
            with pytest.raises(E.EmsconError, match="not a finite number"):
                t.point_laser((math.nan, 0.0, 0.0))
        finally:
            t.close()
        assert emu.measurements == 1 and emu.refused == 1


def _mutations(rng, packet):
    """A seeded corruption of a request: cut, a changed byte, a size field, a type, junk appended."""
    kind = rng.integers(5)
    b = bytearray(packet)
    if kind == 0:
        return bytes(b[:rng.integers(1, len(b))])
    if kind == 1:
        i = rng.integers(len(b))
        b[i] = (b[i] + rng.integers(1, 256)) % 256
        return bytes(b)
    if kind == 2:
        size = int(rng.choice([-1, 0, 7, 11, len(b) - 4, len(b) + 4, 2 ** 31 - 1, E.MAX_PACKET + 1]))
        return struct.pack("<i", size) + bytes(b[4:])
    if kind == 3:
        return bytes(b[:4]) + struct.pack("<i", int(rng.integers(1, 12))) + bytes(b[8:])
    return bytes(b) + rng.bytes(int(rng.integers(1, 40)))


def test_fuzzed_requests_never_yield_a_reading_nor_stop_the_server():
    requests = [_cmd(49), _cmd(7), _cmd(21), _cmd(58, "3d", *REFLECTOR), _cmd(55, "3di", *REFLECTOR, 1),
                _cmd(5, "5i", 1, 1, 0, 1, 0), _cmd(20, "3d", 20.0, 1000.0, 40.0)]
    start = _cmd(49)
    rng = np.random.default_rng(11)
    with TrackerEmulator(REFLECTOR, seed=1, initialized=True) as emu:
        taken = 0
        for case in range(300):
            bad = _mutations(rng, requests[case % len(requests)])
            with socket.create_connection(("127.0.0.1", emu.port), timeout=2) as s:
                assert _status(_ask(s, _cmd(58, "3d", *REFLECTOR), 1)[0][1]) == 0      # the beam on the reflector
                try:
                    s.sendall(bad)
                    s.shutdown(socket.SHUT_WR)                            # a cut packet ends at EOF
                except OSError:                                           # the server closed first: framing lost
                    pass
                answers = _packets(s, 2.0)
            # A result only when the bytes start with an intact StartMeasurement (what follows it is the
            # next packet of the stream, refused or cut on its own).
            results = [p for k, p in answers if k == E.DT_SINGLE_RESULT]
            assert len(results) == bad.startswith(start), (case, bad.hex(), answers)
            taken += bad.startswith(start)
        with socket.create_connection(("127.0.0.1", emu.port), timeout=2) as s:   # still serving
            _ask(s, _cmd(58, "3d", *REFLECTOR), 1)
            assert [k for k, _ in _ask(s, start, 2)] == [0, 2]
        assert emu.measurements == taken + 1 and emu.bad_packets > 100


def _answers_of_a_measurement():
    rt = E.encode_answer(E.C_START_MEASUREMENT, 0)
    return rt, E.encode_result([1000.0, 2.0, 3.0] + [0.005] * 4 + [0.0] * 3 + [0.005] * 4 + [20.0, 1013.0, 45.0])


def _framing_mutation(rng, rt, res):
    """A seeded corruption of the framing of the answer + result bytes (values untouched: no checksum)."""
    data = bytearray(rt + res)
    heads = [0, 4, 8, 12, 16, 16 + 8]               # sizes, types, command, status, result's status
    kind = rng.integers(4)
    if kind == 0:
        return bytes(data[:rng.integers(0, len(data))])
    if kind == 1:
        at = int(rng.choice(heads))
        old = struct.unpack_from("<i", data, at)[0]
        struct.pack_into("<i", data, at, old + int(rng.choice([-8, -4, -1, 1, 4, 8, 10000, -(2 ** 30)])))
        return bytes(data)
    if kind == 2:
        at = int(rng.integers(1, 16 + 12))           # within or between the headers
        return bytes(data[:at]) + rng.bytes(int(rng.integers(1, 9))) + bytes(data[at:])
    struct.pack_into("<d", data, 16 + 20 + 8 * int(rng.integers(3)), math.nan)   # a NaN coordinate
    return bytes(data)


def test_malformed_or_truncated_answers_never_yield_a_reading():
    rt, res = _answers_of_a_measurement()
    rng = np.random.default_rng(4)
    for case in range(200):
        bad = _framing_mutation(rng, rt, res)
        a, b = socket.socketpair()
        with a, b:
            client = E.EmsconTracker(a, timeout_s=0.2)
            b.sendall(bad)
            b.shutdown(socket.SHUT_WR)
            with pytest.raises(E.EmsconError):
                client.measure()
    for at, value in ((4, E.DT_ERROR), (4, E.DT_STATUS_CHANGE), (16 + 4, E.DT_COMMAND), (16 + 8, 1)):
        bad = bytearray(rt + res)                    # the data types and statuses that must never pass
        struct.pack_into("<i", bad, at, value)
        a, b = socket.socketpair()
        with a, b:
            b.sendall(bytes(bad))
            b.shutdown(socket.SHUT_WR)
            with pytest.raises(E.EmsconError):
                E.EmsconTracker(a, timeout_s=0.2).measure()
    a, b = socket.socketpair()                       # the untouched bytes are a reading
    with a, b:
        b.sendall(rt + res)
        assert E.EmsconTracker(a, timeout_s=0.2).measure().point_mm == (1000.0, 2.0, 3.0)


# ------------------------------------------------------------------ olti run on the tracker station

def _scenario(tmp_path, station="!Tracker {beam_break: 0.15, reflector_lost: 0.05}", name="trk.yaml"):
    """diagrams/six_axis.yaml with a small plan (60° nodes, one pose per node and direction) on the tracker."""
    path = tmp_path / name
    path.write_text(f"base: {SIX_AXIS}\nstation: {station}\nplan: {{step_deg: 60.0, poses_per_node: 1}}\n")
    return str(path)


def _log(out, n=6):
    from olti_drake.io.csvio import read_table

    names = (tuple(f"theta{i + 1}_deg" for i in range(n)) + tuple(f"dir{i + 1}" for i in range(n)) +
             ("x_mm", "y_mm", "z_mm", "valid", "temperature_c", "pressure_hpa", "humidity_pct", "plan_row", "step",
              "session", "status", "reads"))
    return read_table(os.path.join(out, "campaign.csv"), names)


def _lines(path):
    return open(path, "rb").read().count(b"\n") if os.path.exists(path) else 0


def _check_points(setup, t):
    """Valid rows: the robot's true tool point in the true tracker frame, within 5 u of the stated noise, and
    off the commanded one by the robot's errors; rows without beam: NaN. Returns the valid mask."""
    from olti_drake.hardware.tracker_station import base_to_tracker, nominal_targets

    n = setup.n_joints
    cmd = np.column_stack([t[f"theta{i + 1}_deg"] for i in range(n)])
    dirs = np.column_stack([t[f"dir{i + 1}"] for i in range(n)])
    true = base_to_tracker(setup.truth.positions(cmd, dirs), setup.tracker_true)
    got = np.column_stack([t["x_mm"], t["y_mm"], t["z_mm"]])
    ok = t["valid"] == 1
    u = (15.0 + 6.0 * np.linalg.norm(true, axis=1) / 1e3) / (2 * math.sqrt(3)) / 1e3
    err = np.abs(got - true)[ok] / u[ok, None]
    assert np.all(err < 5), err.max()
    assert np.all(np.isnan(got[~ok]))                                   # no beam: never a reading
    off = np.linalg.norm(got[ok] - nominal_targets(setup, cmd[ok]), axis=1)   # the robot's errors, seen
    assert np.median(off) > 20 * u.max(), np.median(off)
    return ok


def test_six_axis_campaign_on_the_tracker_killed_at_random_moments_and_resumed(tmp_path):
    from olti_drake.hardware.runner import run
    from olti_drake.hardware.tracker_station import prepare_tracker
    from olti_drake.sim.serial_scenario import load_serial_scenario

    scenario, out = _scenario(tmp_path), str(tmp_path / "run")
    setup = prepare_tracker(load_serial_scenario(scenario))
    planned = np.flatnonzero(setup.measure)
    csv = os.path.join(out, "campaign.csv")
    rng = np.random.default_rng(26)
    kills = np.sort(rng.choice(np.arange(3, len(planned) - 3), 2, replace=False))
    for k, at in enumerate(kills):
        cmd = [sys.executable, "-m", "olti_drake.cli", "run", scenario, "--out", out] + (["--resume"] if k else [])
        lines = _lines(csv)
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if _lines(csv) >= max(3 + at, lines + 1):     # this session took a reading, and `at` are on disk
                break
            time.sleep(0.002)
        time.sleep(rng.uniform(0.0, 0.05))                 # a line may be cut short
        proc.kill()                                         # SIGKILL: no clean-up of any kind
        assert proc.wait(10) == -signal.SIGKILL, proc.stderr.read()
    result = run(scenario, out, resume=True)
    assert result.complete and result.session == len(kills) and result.on_disk == result.planned == len(planned)
    t = _log(out)
    assert np.array_equal(np.sort(t["step"]), planned)                  # every planned reading exactly once
    assert set(t["session"]) <= set(range(len(kills) + 1)) and len(set(t["session"])) >= 2
    by_step = np.argsort(t["step"])
    np.testing.assert_allclose(np.column_stack([t[f"theta{i + 1}_deg"] for i in range(6)])[by_step],
                               setup.commands_deg[planned], rtol=0, atol=1e-9)
    for key, lo, hi in (("temperature_c", 19.0, 21.0), ("pressure_hpa", 1008.0, 1018.0), ("humidity_pct", 40, 50)):
        assert np.all((t[key] > lo) & (t[key] < hi)), key                # the environment on every row
    ok = _check_points(setup, t)
    events = [json.loads(line) for line in open(os.path.join(out, "events.jsonl"))]
    interrupted = [e for e in events if e["kind"] == "beam_interrupted"]
    retried = int(np.sum(t["reads"] - ok))                              # failed attempts behind the rows on disk
    assert retried > 0 and len(interrupted) >= retried                   # every one flagged in the events
    assert all(e["status"] == E.RS_MEAS_STATUS_NOT_READY for e in interrupted)
    assert np.all(t["status"][t["reads"] > 1] == E.RS_MEAS_STATUS_NOT_READY)  # flagged on the row too
    assert np.all(t["status"][t["reads"] == 1] == 0)
    assert any(e["kind"] == "reapproach" and e["session"] > 0 for e in events)
    # Open loop: the beam was sent to the COMMANDED tool point (nominal kinematics, nominal tracker placement),
    # not to the true one, which is off by the robot's errors.
    from olti_drake.hardware.tracker_station import nominal_targets

    cmd = np.array([e["command"] for e in interrupted])
    np.testing.assert_allclose([e["target_mm"] for e in interrupted], nominal_targets(setup, cmd), rtol=0, atol=1e-9)
    assert os.path.exists(os.path.join(out, "truth.json"))
    from olti_drake.io.serial_io import read_serial_campaign

    c = read_serial_campaign(csv, 6)                                    # a point campaign of formats.md
    assert c.kind == "point" and len(c.points_mm) == int(ok.sum()) and c.n_skipped == int((~ok).sum())


def test_a_tracker_and_a_robot_started_apart_as_a_real_bench(tmp_path):
    """``olti tracker-emulator --scenario`` (the robot on a pty, the tracker on TCP), then ``olti run`` with
    ``!Tracker {host, port, robot_port}``: the path of a real tracker on port 700."""
    from olti_drake.hardware.runner import run
    from olti_drake.hardware.tracker_station import prepare_tracker
    from olti_drake.sim.serial_scenario import load_serial_scenario

    bench = _scenario(tmp_path, "!Tracker {}", "bench.yaml")
    p = subprocess.Popen([sys.executable, "-m", "olti_drake.cli", "tracker-emulator", "--port", "0", "--scenario",
                          bench], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        robot = p.stdout.readline().split()
        tracker = p.stdout.readline().split()
        assert robot[0] == "robot" and tracker[0] == "tracker", p.stderr.read()
        host, port = tracker[1].split(":")
        scenario = _scenario(tmp_path, f"!Tracker {{host: {host}, port: {port}, robot_port: {robot[1]}}}")
        result = run(scenario, str(tmp_path / "run"))
    finally:
        p.send_signal(signal.SIGINT)
        p.wait(10)
    assert p.returncode == 0 and "served 23 measurements (0 refused" in p.stderr.read()
    assert result.complete and result.invalid == 0
    t = _log(str(tmp_path / "run"))
    assert np.all(_check_points(prepare_tracker(load_serial_scenario(bench)), t))
    assert not os.path.exists(tmp_path / "run" / "truth.json")          # a real bench has no truth to write


@pytest.mark.parametrize("args, match", [
    ([], "give --reflector-mm x,y,z"),
    (["--reflector-mm", "1,2,3", "--scenario", "x.yaml"], "one of them"),
    (["--reflector-mm", "1,2"], "expected v,v,v"),
])
def test_tracker_emulator_refuses_bad_input_in_one_line(args, match):
    r = olti_sub("tracker-emulator", "--port", "0", *args, timeout=60, expect=2)
    assert match in r.stderr


def test_the_doc_states_the_layout_and_numbers_the_code_uses():
    """docs/tracker.md's table of commands (number, request and answer bytes) and its quoted noise figures are
    the code's (what the maintainers' independent client is written from)."""
    import re

    text = open(os.path.join(ROOT, "docs", "tracker.md"), encoding="utf-8").read()
    rows = re.findall(r"^\| (\w+) \| (\d+) \| (\d+) \| .*? \| (\d+) \|", text, re.M)
    assert len(rows) == len(E.COMMANDS) == 12
    for name, number, request, answer in rows:
        c = {v: k for k, v in E.NAMES.items()}[name]
        assert (c, E.REQUESTS[c].size, E.ANSWERS[c].size) == (int(number), int(request), int(answer)), name
    flat = " ".join(text.split())
    assert f"`SingleMeasResultT` of {E.RESULT.size} bytes" in flat
    assert f"{E.RS_MEAS_STATUS_NOT_READY} `ES_RS_MeasurementStatusNotReady`" in flat
    quoted = re.findall(r"([\d.]+) µm at ([\d.]+) m\b", flat)
    assert len(quoted) == 2
    for um, d_m in quoted:
        assert (15.0 + 6.0 * float(d_m)) / (2 * math.sqrt(3)) == pytest.approx(float(um), abs=0.06), (um, d_m)
