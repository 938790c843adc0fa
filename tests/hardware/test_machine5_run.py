"""``olti run`` on the five-axis machine tool (issue 25 item 4, last part): the distance campaign of
``diagrams/machine_5axis.yaml`` on the five-axis emulator (hardware/machine5_emulator.py: the model file's X, Y, Z,
A, C controller and a pan/tilt head line per station, protocol version 2, through real pseudo-terminals) and on the
hardware station against an emulator started as its own program; the emulated readings equal the simulated
campaign's; a campaign killed with SIGKILL at seeded moments and resumed has every planned reading exactly once;
``olti identify --machine`` reads the run's campaign.csv; bad input is one line."""

import contextlib
import io
import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
import serial

from olti_drake.hardware import protocol as P
from olti_calls import error_line
from run_files import kill_twice, olti_here, run_events, run_table

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
YAML = os.path.join(ROOT, "diagrams", "machine_5axis.yaml")
TRUNNION = os.path.join(ROOT, "olti_drake", "models", "trunnion_ac.urdf")
TOOLS = "0,0,0;0,60,30"
COLUMNS = ("x_cmd_mm", "y_cmd_mm", "z_cmd_mm", "a_cmd_deg", "c_cmd_deg", "dir_x", "dir_y", "dir_z", "dir_a", "dir_c",
           "tool", "station", "displacement_mm", "valid")
LOG = COLUMNS + ("plan_row", "step", "session", "reads", "rezeros")
N = 120   # 12 poses x 2 tools x 5 heads


def _log(out):
    return run_table(out, LOG)



def _scenario(tmp_path, station="!Emulated {}", name="m5.yaml", extra="", noise=False):
    """diagrams/machine_5axis.yaml without its R-test nests, 12 poses (x 2 tools x 5 heads = 120 readings),
    noise-free unless ``noise`` (then the 001 Table 4 budget and λ/64); the rotary ranges inside the travel (a
    re-approach overruns by 2 deg)."""
    path = tmp_path / name
    path.write_text(f"base: {YAML}\ntracking: {{poses: 12, ranges_deg: {{A: [-40.0, 25.0], C: [-170.0, 170.0]}}}}\n"
                    f"rtest: {{nests_mm: []}}\nstation: {station}\n{extra}"
                    + ("" if noise else "interferometer: {noise: false, quantization: false}\n"))
    return str(path)





@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The noise-free small campaign, uninterrupted on the emulator, and the simulated twin of its scenario."""
    from olti_drake.hardware.runner import run
    from olti_drake.sim.five_axis_station import load_five_axis_scenario, simulate_five_axis_campaign

    tmp = tmp_path_factory.mktemp("m5")
    path = _scenario(tmp)
    result = run(path, str(tmp / "run"), fsync=False)
    assert result.complete and result.taken == result.on_disk == result.planned == N
    return result, simulate_five_axis_campaign(load_five_axis_scenario(path)), tmp


# ------------------------------------------------------------------ the emulator on the wire

def test_emulator_announces_the_model_files_axes_and_reads_the_true_tool_point(tmp_path):
    """The controller is a version-2 ROBOT with the model file's axes (X, Y, Z mm, A, C deg, limits = the travel); a
    command outside the travel is NAK,RANGE; a head riding on the table (workpiece frame) reads the change of the
    distance to the TRUE tool point (the truth with the approach directions the controller saw), aimed open loop at
    the commanded one."""
    from olti_drake.hardware.machine5_emulator import Machine5Emulator
    from olti_drake.model.aiming3d import pan_tilt_commands
    from olti_drake.sim.five_axis_station import load_five_axis_scenario, nominal_frames, prepare_five_axis

    run = prepare_five_axis(load_five_axis_scenario(_scenario(tmp_path)))
    m = run.machine
    with Machine5Emulator(run, encoder_resolution=0.0) as emu:
        streams = [serial.Serial(p, 115200, timeout=0.05) for p in [emu.robot_port] + emu.head_ports]
        try:
            robot, head = (P.Transport(x, timeout_s=1.0, retries=1) for x in (streams[0], streams[4]))
            assert P.decode_pong(robot.request("PING")) == P.Pong(2, "ROBOT", "XYZAC-EMU")
            assert P.decode_pong(head.request("PING")).role == "HEAD" and len(emu.head_ports) == 5
            n = P.decode_info(robot.request("INFO"))
            axes = [P.decode_axis(robot.request("INFO", str(k)), k) for k in range(n)]
            assert [(a.name, a.unit, a.lower, a.upper) for a in axes] == [
                (x, "mm" if x in "XYZ" else "deg", round(lo, 6), round(hi, 6))
                for x, lo, hi in zip(m.axes, m.lower, m.upper)]
            with pytest.raises(P.NakError, match="RANGE"):
                robot.request("MOVJ", "0.0", "0.0", "100.0", "30.000001", "0.0")
            layout = P.AxisLayout(axes)
            q = np.array([[-20.0, 30.0, 80.0, -10.0, 40.0], [25.0, -10.0, 60.0, -25.0, -60.0],
                          [10.0, 20.0, 70.0, 5.0, 90.0],
                          [-20.0, 30.0, 80.0, -10.0, 40.0]])    # back to the first pose from the other side
            readings = []
            for k, c in enumerate(q):
                P.expect_ack(robot.request("MOVJ", *layout.fields(c)))
                P.expect_ack(robot.request("WAIT", "1000"))
                aim = pan_tilt_commands(run.heads_est, [3], nominal_frames(m, c[None], run.tool_offsets_mm[:1],
                                                                           run.catseye_axis_tool)["workpiece"][0])[0]
                P.expect_ack(head.request("AIM", *P.PAN_TILT_LAYOUT.fields(aim, "AIM")))
                if k == 0:
                    P.expect_ack(head.request("ZERO"))
                r = P.decode_reading(head.request("READ"))
                assert r.valid
                readings.append(r.displacement_mm)
        finally:
            for s in streams:
                s.close()
    dirs = np.array([[1.0, 1.0], [-1.0, -1.0], [1.0, 1.0], [-1.0, -1.0]])
    true = run.truth.truth_positions(q, dirs, [0] * 4, "workpiece")
    d = np.linalg.norm(true - run.heads_true.centres_mm[3], axis=1)
    np.testing.assert_allclose(readings, d - d[0], rtol=0, atol=2e-5)   # (cosine error: the miss is µm)
    assert abs(readings[3]) > 1e-4      # the backlash: the same command approached the other way reads otherwise


def test_emulated_run_equals_the_simulated_campaign(reference):
    """Noise-free, the run's rows are the twin's (commands, directions, tool, station, beam lost where it is lost)
    and its readings the twin's re-zeroed where each head's counter was zeroed (its first reading with a beam),
    within 3e-6 mm: the wire's 6 decimals of the rotary commands; one zero per head, at its first valid row (the
    policy's re-zeroings after a lost beam return there)."""
    result, (sim, truth), _ = reference
    t = _log(result.out_dir)
    np.testing.assert_array_equal(t["step"], np.arange(N))
    for k in COLUMNS[:10]:
        np.testing.assert_allclose(t[k], sim[k], rtol=0, atol=1e-9, err_msg=k)
    for k in ("tool", "station", "valid"):
        np.testing.assert_array_equal(t[k], sim[k], err_msg=k)
    assert 0 < np.sum(sim["valid"] == 0) < 10       # the campaign has lost beams (a table head's first row too)
    events = [e for e in run_events(result.out_dir) if e["kind"] == "zero"]
    zeros = {e["reflector"]: e for e in events if not e["again"]}
    assert sorted(zeros) == [0, 1, 2, 3, 4] and len(zeros) == sum(not e["again"] for e in events)
    lost = set(sim["station"][sim["valid"] == 0].astype(int).tolist())
    assert {e["reflector"] for e in events if e["again"]} <= lost   # re-zeroed (policy) only after a lost beam
    for j in range(5):
        rows = sim["station"] == j
        z = int(np.flatnonzero(rows & (sim["valid"] == 1))[0])
        np.testing.assert_allclose(zeros[j]["command"], [sim[k][z] for k in COLUMNS[:5]], rtol=0, atol=1e-9)
        np.testing.assert_allclose(t["displacement_mm"][rows], sim["displacement_mm"][rows] - sim["displacement_mm"][z],
                                   rtol=0, atol=3e-6, err_msg=f"head {j}")
    written = json.load(open(os.path.join(result.out_dir, "truth.json")))
    assert written["format"] == truth["format"] and written["location_errors"] == pytest.approx(
        truth["location_errors"], abs=1e-12) and written["n_readings"] == int(np.sum(sim["valid"]))


def test_killed_twice_at_random_moments_and_resumed_has_every_reading_once(tmp_path, reference):
    """`olti run` in a subprocess, SIGKILLed at a seeded random reading count and delay (a line may be cut short),
    resumed with --resume and killed again, then resumed to the end: every planned reading exactly once; each
    resumed session re-approaches from the plan's sides and zeroes each head again at its reference pose aimed as
    then, so the readings equal the uninterrupted campaign's (the backlash is there: a wrong side would show)."""
    from olti_drake.hardware.runner import run

    rng = np.random.default_rng(25)
    scenario, out = _scenario(tmp_path), str(tmp_path / "run")
    kill_twice(scenario, out, rng, N, cut_s=0.01, cwd=ROOT)
    result = run(scenario, out, resume=True, fsync=False)
    assert result.complete and result.session == 2 and result.on_disk == result.planned == N
    t, ref = _log(out), _log(reference[0].out_dir)
    order = np.argsort(t["step"])
    np.testing.assert_array_equal(t["step"][order], np.arange(N))    # every step once
    assert set(t["session"]) == {0, 1, 2}
    for k in ("tool", "station", "valid", "plan_row", "dir_a", "dir_c"):
        np.testing.assert_array_equal(t[k][order], ref[k], err_msg=k)
    np.testing.assert_allclose(t["displacement_mm"][order], ref["displacement_mm"], rtol=0, atol=1e-9)
    events = run_events(out)
    for s in (1, 2):
        assert any(e["kind"] == "reapproach" and e["session"] == s for e in events)
        again = [e for e in events if e["kind"] == "zero" and e["session"] == s and e["again"]]
        first = {e["reflector"]: e for e in events if e["kind"] == "zero" and not e["again"]}
        assert again and all(e["aim"] == first[e["reflector"]]["aim"] for e in again)
    assert json.load(open(os.path.join(out, "run.json")))["complete"]


def test_noisy_emulated_readings_differ_from_the_simulated_by_the_budget_only(tmp_path):
    """With the 001 budget and λ/64 the emulator (its own noise stream) and the twin agree within the reading noise:
    after each head's zero (where both have a beam) the difference has the spread of two independent readings plus
    the zero's own, no offset, no outlier."""
    from olti_drake.hardware.runner import run
    from olti_drake.sim.five_axis_station import load_five_axis_scenario, simulate_five_axis_campaign

    path = _scenario(tmp_path, noise=True)
    result = run(path, str(tmp_path / "emu"), fsync=False)
    doc = load_five_axis_scenario(path)
    sim = simulate_five_axis_campaign(doc)[0]
    t = _log(str(tmp_path / "emu"))
    assert result.complete
    budget = doc.load_budget()
    sigma = np.hypot(budget.combined("reading"), budget.combined("pose")) * np.sqrt(2.0)
    both = (t["valid"] == 1) & (sim["valid"] == 1)
    d = []
    for j in range(5):
        rows = np.flatnonzero((sim["station"] == j) & both)
        d.append(t["displacement_mm"][rows[1:]] - (sim["displacement_mm"][rows[1:]] - sim["displacement_mm"][rows[0]]))
    d = np.concatenate(d)
    assert len(d) > 90 and not np.allclose(d, 0.0, rtol=0, atol=1e-9)     # the noise is there ...
    assert 0.5 * sigma < np.std(d) < 2.0 * sigma                            # ... and only the noise
    assert abs(np.mean(d)) < 4 * sigma + 1e-5 and np.max(np.abs(d)) < 8 * sigma + 1e-5


def test_simulated_campaign_stopped_and_resumed_equals_the_uninterrupted_one(tmp_path):
    """`olti run` on the simulated five-axis station resumes too (the laser's sample count): with noise, a campaign
    stopped twice and resumed reads what the uninterrupted one reads, and that is the twin's campaign."""
    from olti_drake.hardware.runner import run
    from olti_drake.sim.five_axis_station import load_five_axis_scenario, simulate_five_axis_campaign

    path = _scenario(tmp_path, "!Simulated {}", noise=True)
    whole = run(path, str(tmp_path / "whole"), fsync=False)
    out, done = str(tmp_path / "cut"), {"n": 0}
    for k, stop_at in enumerate((17, 64)):
        r = run(path, out, resume=k > 0, fsync=False, progress=lambda n, planned: done.update(n=n),
                should_stop=lambda stop_at=stop_at: "test" if done["n"] >= stop_at else None)
        assert r.stopped == "test" and r.on_disk == stop_at
    r = run(path, out, resume=True, fsync=False)
    assert whole.complete and r.complete and r.start_step == 64
    a, b = _log(out), _log(str(tmp_path / "whole"))
    np.testing.assert_array_equal(a["step"], b["step"])
    np.testing.assert_allclose(a["displacement_mm"], b["displacement_mm"], rtol=0, atol=1e-12)
    sim = simulate_five_axis_campaign(load_five_axis_scenario(path))[0]
    np.testing.assert_array_equal(b["valid"], sim["valid"])
    np.testing.assert_allclose(b["displacement_mm"], sim["displacement_mm"], rtol=0, atol=1e-9)


def test_hardware_scenario_against_an_emulator_started_on_its_own(tmp_path, reference):
    """station: !Hardware {robot_port, head_ports}: the real-device path against `python -m olti_drake.cli.emulator
    SCENARIO --link PREFIX` started as its own program (the R-test nests of the file it is given do not matter): it
    reads what the in-process emulated station reads; no truth is written."""
    from olti_drake.hardware.runner import run

    prefix = str(tmp_path / "m5")
    emu = subprocess.Popen([sys.executable, "-m", "olti_drake.cli.emulator", _scenario(tmp_path), "--link", prefix],
                           stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, cwd=ROOT, text=True)
    try:
        assert "Ctrl-C stops" in "".join(emu.stdout.readline() for _ in range(7))   # 6 lines, then the status
        heads = ", ".join(f"{prefix}-head{h}" for h in range(5))
        out = str(tmp_path / "hw")
        result = run(_scenario(tmp_path, f"!Hardware {{robot_port: {prefix}-robot, head_ports: [{heads}]}}", "hw.yaml"),
                     out, fsync=False)
    finally:
        emu.send_signal(signal.SIGTERM)
        emu.wait(20)
    assert emu.returncode == 0 and result.complete and result.on_disk == N
    t, ref = _log(out), _log(reference[0].out_dir)
    np.testing.assert_array_equal(t["valid"], ref["valid"])
    np.testing.assert_allclose(t["displacement_mm"], ref["displacement_mm"], rtol=0, atol=1e-9)
    assert not os.path.exists(os.path.join(out, "truth.json"))
    assert json.load(open(os.path.join(out, "run.json")))["station"] == "hardware"


def test_the_run_campaign_identifies_as_the_simulated_one(tmp_path, reference):
    """`olti identify --machine trunnion_ac.urdf --model geometric` reads the run's campaign.csv (run-log columns
    after the five-axis ones): the location errors equal those identified from the simulated campaign of the same
    seed within 1 % of their u (the counters' zeros are dead paths, identified), and the truth (harmonic motions,
    outside the geometric family) lies within 3 u of every separable one."""
    from olti_drake.sim.five_axis_station import write_campaign

    result, (sim, truth), _ = reference
    write_campaign(tmp_path / "sim.csv", sim)
    docs = []
    for csv in (os.path.join(result.out_dir, "campaign.csv"), tmp_path / "sim.csv"):
        out = tmp_path / f"r{len(docs)}.json"
        code, _, err = olti_here("identify", csv, "--machine", TRUNNION, "--model", "geometric", "--tool-offsets-mm",
                             TOOLS, "--out", out)
        assert code == 0, err
        docs.append(json.load(open(out)))
    emu, simulated = docs
    u = emu["uncertainty"]["location_errors"]
    assert emu["dropped"] == simulated["dropped"] and len(u) == 10
    kept = [n for n in u if n not in emu["dropped"]]
    assert len(kept) == 8
    for n in kept:
        assert abs(emu["location_errors"][n] - simulated["location_errors"][n]) < 0.01 * u[n], n
        assert abs(emu["location_errors"][n] - truth["location_errors"][n]) < 3 * u[n], n


# ------------------------------------------------------------------ bad input

def test_bad_stations_and_scenarios_are_one_line_and_write_nothing(tmp_path):
    from olti_drake.hardware.machine5_emulator import Machine5Emulator
    from olti_drake.sim.five_axis_station import load_five_axis_scenario, prepare_five_axis

    swivel = tmp_path / "swivel.yaml"     # a B/C swivel head: the same heads, other rotary letters
    swivel.write_text("machine_model: {file: swivel_head_bc}\ntracking: {bed_heads_mm: [[-450.0, -350.0, 150.0], "
                      "[450.0, -350.0, 150.0], [0.0, 450.0, 100.0]], table_heads_mm: [[150.0, 150.0, 20.0], "
                      "[-150.0, -150.0, 20.0]], poses: 4, box_mm: [[-50.0, 50.0], [-50.0, 50.0], [-50.0, 0.0]], "
                      "ranges_deg: {B: [-30.0, 30.0]}}\n")
    with Machine5Emulator(prepare_five_axis(load_five_axis_scenario(str(swivel)))) as emu:
        wrong = f"!Hardware {{robot_port: {emu.robot_port}, head_ports: [{', '.join(emu.head_ports)}]}}"
        cases = [
            (wrong, "", "announces X_mm, Y_mm, Z_mm, B_deg, C_deg; the machine file needs the axes X_mm, Y_mm, Z_mm, "
                        "A_deg, C_deg"),
            ("!Hardware {robot_port: /dev/null, head_ports: [a, b]}", "", "5 in the order of heads_mm (got 2)"),
            ("!Hardware {robot_port: /dev/nonexistent-olti, head_ports: [a, b, c, d, e]}", "",
             "cannot open the robot port /dev/nonexistent-olti"),
            ("!Emulated {drop: 2}", "", "drop"),
            ("!Simulated {}", "", "no campaign to resume")]
        paths = [(_scenario(tmp_path, station, f"bad{i}.yaml", extra), match)
                 for i, (station, extra, match) in enumerate(cases)]
        shipped = tmp_path / "nests.yaml"     # the shipped file: its 3 R-test nests are not on the line protocol
        shipped.write_text(f"base: {YAML}\nstation: !Emulated {{}}\n")
        paths.append((str(shipped), "olti run takes five-axis distance campaigns only: rtest.nests_mm gives 3 R-test "
                                    "nests, but the line protocol carries one displacement per READ"))
        paths.append((_scenario(tmp_path, name="meshcat.yaml"), "--meshcat: olti run shows the live view of SCARA "
                                                               "campaigns only"))
        for path, match in paths:
            out = tmp_path / "x"
            flags = ["--resume"] if "resume" in match else ["--meshcat"] if "meshcat" in match else []
            code, _, err = olti_here("run", path, "--out", out, *flags)
            error_line(code, err, match)
            assert not (out / "campaign.csv").exists()
    from olti_drake.cli.emulator import main as emulator

    err = io.StringIO()
    with contextlib.redirect_stderr(err):      # the emulator program: one line, before any line is opened
        code = emulator([_scenario(tmp_path), "--reflector", "1"])
    error_line(code, err.getvalue())
    assert "a five-axis scenario: --tool-frame and --reflector do not apply" in err.getvalue()
    code, _, err = olti_here("run", _scenario(tmp_path, "!Simulated {}"), "--out", tmp_path / "ok", "--no-fsync")
    assert code == 0, err
    code, _, err = olti_here("run", _scenario(tmp_path, "!Simulated {}", extra="seed: 4\n"), "--out", tmp_path / "ok",
                         "--resume")
    assert code == 2 and "command sequence differs" in err
