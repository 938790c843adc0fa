"""``olti run`` on the 3D machine tool (issue 22 item 4): the campaign of ``diagrams/machine_3d.yaml`` on its
simulated station, on the 3D machine emulator (hardware/machine3d_emulator.py: the X, Y, Z controller and a
pan/tilt head line per head, protocol version 2, through real pseudo-terminals) and on the hardware station
(the same drivers on ports); the emulated readings equal the simulated diagram's; a campaign killed with
SIGKILL at seeded random moments and resumed has every planned reading exactly once; an ``extend`` hook (a
logger LeafSystem) runs on every station; ``olti multilaterate`` and ``olti identify --model volumetric``
read the run's campaign."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import serial

from olti_drake.hardware import protocol as P
from olti_calls import error_line
from run_files import kill_twice, olti_here, run_events, run_table

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
YAML = os.path.join(ROOT, "diagrams", "machine_3d.yaml")
TOOLS = "0,0,100;80,0,100;0,80,140"
COLUMNS = ("station", "target", "x_cmd_mm", "y_cmd_mm", "z_cmd_mm", "tool", "displacement_mm", "valid")
LOG = COLUMNS + ("plan_row", "step", "session", "reads", "rezeros")


def _log(out):
    return run_table(out, LOG)



def _scenario(tmp_path, station="!Emulated {}", noise=False, grid="[3, 2, 2]", tools="[0, 2]", name="m3.yaml"):
    """diagrams/machine_3d.yaml on a small grid (3 x 2 x 2 commands x 2 tools = 24 targets, x 5 heads = 120 readings), noise-free unless
    ``noise`` (then the 001 Table 4 budget and λ/64)."""
    path = tmp_path / name
    text = f"base: {YAML}\ngrid: {grid}\ntools: {tools}\nstation: {station}\n"
    if not noise:
        text += "interferometer: {noise: false, quantization: false}\n"
    path.write_text(text)
    return str(path)





@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The noise-free small campaign, uninterrupted on the emulator."""
    from olti_drake.hardware.runner import run

    tmp = tmp_path_factory.mktemp("m3")
    result = run(_scenario(tmp), str(tmp / "run"), fsync=False)
    assert result.complete and result.taken == result.on_disk == result.planned == 120 and result.invalid == 0
    return result


def _simulated_columns(path):
    from olti_drake.sim.machine3d_station import load_machine3d_scenario, run_machine3d_campaign

    doc = load_machine3d_scenario(path)
    return run_machine3d_campaign(doc.scenario(), doc.load_budget(), doc.period_s)[0]


# ------------------------------------------------------------------ the emulator on the wire

def test_emulator_announces_the_machine_axes_and_the_heads():
    """The controller line is a version-2 ROBOT with X, Y, Z in mm over the travel; each head a pan/tilt HEAD;
    a command outside the travel is NAK,RANGE; a head reads the distance change to the cat's eye it aims at."""
    from olti_drake.hardware.machine3d_emulator import Machine3DEmulator
    from olti_drake.model.aiming3d import pan_tilt_commands
    from olti_drake.model.instrument import InterferometerOptions
    from olti_drake.model.machine import Machine3DScenario
    from olti_drake.model.volumetric3d import MachineConfig, tool_positions

    tools = ((0.0, 0.0, 100.0), (80.0, 0.0, 100.0))
    s = Machine3DScenario(config=MachineConfig(tool_offsets_mm=tools), grid=(2, 2, 2), tools=(0, 1), seed=3,
                          interferometer=InterferometerOptions(noise=False, quantization=False, cosine_error=False))
    with Machine3DEmulator(s, encoder_resolution=0.0) as emu:
        streams = [serial.Serial(p, 115200, timeout=0.05) for p in [emu.robot_port] + emu.head_ports]
        try:
            robot, head = (P.Transport(x, timeout_s=1.0, retries=1) for x in streams[:2])
            assert P.decode_pong(robot.request("PING")) == P.Pong(2, "ROBOT", "XYZ-EMU")
            assert P.decode_pong(head.request("PING")).role == "HEAD" and len(emu.head_ports) == 5
            assert P.decode_info(robot.request("INFO")) == 3
            axes = [P.decode_axis(robot.request("INFO", str(k)), k) for k in range(3)]
            assert [(a.name, a.unit, a.lower, a.upper) for a in axes] == [
                ("X", "mm", 0.0, 400.0), ("Y", "mm", 0.0, 300.0), ("Z", "mm", 0.0, 250.0)]
            with pytest.raises(P.NakError, match="RANGE"):
                robot.request("MOVJ", "100.000000", "300.000001", "0.000000")
            layout = P.AxisLayout(axes)
            run = emu.run
            readings = []
            for q, m in (((100.0, 50.0, 20.0), 0), ((300.0, 250.0, 200.0), 1), ((100.0, 50.0, 20.0), 1)):
                P.expect_ack(robot.request("MOVJ", *layout.fields(q)))
                P.expect_ack(robot.request("WAIT", "1000"))
                aim = pan_tilt_commands(run.heads_est, [0], (np.array(q) + np.array(tools[m]))[None])[0]
                P.expect_ack(head.request("AIM", *P.PAN_TILT_LAYOUT.fields(aim, "AIM")))
                if not readings:
                    P.expect_ack(head.request("ZERO"))
                r = P.decode_reading(head.request("READ"))
                assert r.valid
                readings.append(r.displacement_mm)
                assert P.decode_position_n(robot.request("POSJ"), layout).encoder == q
            true = tool_positions(run.config, run.truth, np.array([[100, 50, 20], [300, 250, 200], [100, 50, 20.0]]),
                                  [0, 1, 1])
            d = np.linalg.norm(true - run.heads_true.centres_mm[0], axis=1)
            np.testing.assert_allclose(readings, d - d[0], rtol=0, atol=1e-8)
        finally:
            for x in streams:
                x.close()


def test_module_runs_the_3d_machine_emulator_as_a_program(tmp_path):
    """`python -m olti_drake.cli.emulator M3.yaml`: the machine line and one line per head, linked, until Ctrl-C."""
    import signal

    link, scenario = str(tmp_path / "m3"), _scenario(tmp_path)
    proc = subprocess.Popen([sys.executable, "-m", "olti_drake.cli.emulator", scenario, "--link", link],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        seen = [proc.stdout.readline() for _ in range(7)]
        assert seen[0].startswith("robot") and seen[5].startswith("head4") and "truth seed 1" in seen[6], seen
        with serial.Serial(link + "-robot", 115200, timeout=0.05) as x:
            t = P.Transport(x)
            assert P.decode_pong(t.request("PING")).model == "XYZ-EMU" and P.decode_info(t.request("INFO")) == 3
        with serial.Serial(link + "-head4", 115200, timeout=0.05) as x:
            assert P.decode_pong(P.Transport(x).request("PING")).role == "HEAD"
    finally:
        proc.send_signal(signal.SIGINT)
        assert proc.wait(10) == 0
    assert not os.path.lexists(link + "-robot")
    bad = subprocess.run([sys.executable, "-m", "olti_drake.cli.emulator", scenario, "--reflector", "1"],
                         capture_output=True, text=True, timeout=60, cwd=ROOT)
    error_line(bad.returncode, bad.stderr, "--reflector do not apply")


# ------------------------------------------------------------------ olti run on every station

def test_emulated_campaign_equals_the_simulated_diagram(tmp_path, reference):
    """Noise off: the emulated station (through the ptys, commands and aims rounded to the wire's 6
    decimals) reads what the simulated 3D diagram reads, row for row, to 1e-6 mm; `olti run` on the
    simulated station writes the diagram's readings; each head is zeroed once, at its run's first pose."""
    from olti_drake.hardware.runner import run

    emu = _log(reference.out_dir)
    sim_run = run(_scenario(tmp_path, "!Simulated {}"), str(tmp_path / "sim"), fsync=False)
    assert sim_run.complete and sim_run.planned == 120
    sim, twin = _log(str(tmp_path / "sim")), _simulated_columns(_scenario(tmp_path, "!Simulated {}"))
    for k in ("station", "target", "tool", "valid", "step", "plan_row"):
        np.testing.assert_array_equal(emu[k], sim[k], err_msg=k)
    for k in COLUMNS:
        np.testing.assert_allclose(sim[k], twin[k], rtol=0, atol=1e-9, err_msg=k)
    np.testing.assert_allclose(emu["displacement_mm"], sim["displacement_mm"], rtol=0, atol=1e-6)
    assert np.all(emu["valid"] == 1) and np.all(emu["reads"] == 1) and np.all(emu["rezeros"] == 0)
    np.testing.assert_array_equal(emu["step"], np.arange(120))
    np.testing.assert_array_equal(emu["step"], emu["station"] * 24 + emu["target"])
    zeros = [e for e in run_events(reference.out_dir) if e["kind"] == "zero"]
    assert [e["reflector"] for e in zeros] == [0, 1, 2, 3, 4] and not any(e["again"] for e in zeros)
    assert all(len(e["command"]) == 3 and len(e["aim"]) == 2 for e in zeros)
    for out in (reference.out_dir, str(tmp_path / "sim")):
        truth = json.load(open(os.path.join(out, "truth.json")))
        assert truth["format"] == "olti-multilateration/1" and truth["n_readings"] == 120
        header = [x for x in open(os.path.join(out, "campaign.csv")) if not x.startswith("#")][0]
        assert header.startswith(",".join(COLUMNS) + ",plan_row,step,session,")


def test_noisy_emulated_readings_differ_from_the_simulated_by_the_budget_only(tmp_path):
    """With the 001 budget and λ/64 the emulator (its own noise stream) and the diagram agree within the
    reading noise: the difference has the spread of two independent readings, no offset, no outlier."""
    from olti_drake.hardware.runner import run
    from olti_drake.sim.machine3d_station import load_machine3d_scenario

    path = _scenario(tmp_path, noise=True)
    result = run(path, str(tmp_path / "emu"), fsync=False)
    assert result.complete and result.invalid == 0
    emu, sim = _log(str(tmp_path / "emu")), _simulated_columns(path)
    budget = load_machine3d_scenario(path).load_budget()
    sigma = np.hypot(budget.combined("reading"), budget.combined("pose")) * np.sqrt(2.0)
    d = emu["displacement_mm"] - sim["displacement_mm"]
    assert not np.allclose(d, 0.0, rtol=0, atol=1e-9)                  # the noise is there ...
    assert 0.5 * sigma < np.std(d) < 1.6 * sigma                        # ... and only the noise
    assert abs(np.mean(d)) < 4 * sigma / np.sqrt(len(d)) + 1e-5 and np.max(np.abs(d)) < 6 * sigma + 1e-5


def test_killed_twice_at_random_moments_and_resumed_has_every_reading_once(tmp_path, reference):
    """`olti run` in a subprocess, SIGKILLed at a seeded random reading count and delay (a line may be cut
    short), resumed with --resume and killed again, then resumed to the end: every planned reading exactly
    once, none lost, none duplicated; each resumed session re-approaches and zeroes each head again at its
    run's reference pose aimed as then, so the readings equal the uninterrupted campaign's."""
    from olti_drake.hardware.runner import run

    rng = np.random.default_rng(22)
    scenario, out = _scenario(tmp_path), str(tmp_path / "run")
    kill_twice(scenario, out, rng, 120, cut_s=0.02, cwd=ROOT)
    result = run(scenario, out, resume=True, fsync=False)
    assert result.complete and result.session == 2 and result.on_disk == result.planned == 120
    t, ref = _log(out), _log(reference.out_dir)
    order = np.argsort(t["step"])
    np.testing.assert_array_equal(t["step"][order], np.arange(120))    # every step once
    assert set(t["session"]) == {0, 1, 2}
    for k in ("station", "target", "tool", "valid", "plan_row"):
        np.testing.assert_array_equal(t[k][order], ref[k], err_msg=k)
    for k in ("x_cmd_mm", "y_cmd_mm", "z_cmd_mm"):
        np.testing.assert_allclose(t[k][order], ref[k], rtol=0, atol=1e-9, err_msg=k)
    np.testing.assert_allclose(t["displacement_mm"][order], ref["displacement_mm"], rtol=0, atol=1e-9)
    events = run_events(out)
    for s in (1, 2):
        assert any(e["kind"] == "reapproach" and e["session"] == s for e in events)
        again = [e for e in events if e["kind"] == "zero" and e["session"] == s and e["again"]]
        first = {e["reflector"]: e for e in events if e["kind"] == "zero" and not e["again"]}
        assert again and all(e["aim"] == first[e["reflector"]]["aim"] for e in again)
    manifest = json.load(open(os.path.join(out, "run.json")))
    assert manifest["complete"] and manifest["readings_planned"] == 120 and len(manifest["sessions"]) == 3
    assert os.path.exists(os.path.join(out, "truth.json"))
    again = run(scenario, out, resume=True, fsync=False)   # nothing left: nothing taken, nothing written twice
    assert again.taken == 0 and _log(out)["step"].size == 120


def test_beam_losses_and_line_faults_are_reread_and_rezeroed_with_the_head_aimed_as_at_its_zero(tmp_path,
                                                                                                   reference):
    """Injected beam losses and corrupted requests: the policy re-reads, then re-zeroes at the head's
    reference pose aimed as then; the readings equal the undisturbed campaign's."""
    from olti_drake.hardware.runner import run

    out = str(tmp_path / "run")
    result = run(_scenario(tmp_path, "!Emulated {beam_loss: 0.3, nak_crc: 0.05}"), out, fsync=False)
    t, ref = _log(out), _log(reference.out_dir)
    assert result.complete and np.array_equal(t["step"], ref["step"]) and np.all(t["valid"] == 1)
    np.testing.assert_allclose(t["displacement_mm"], ref["displacement_mm"], rtol=0, atol=1e-9)
    assert np.any(t["reads"] > 1) and np.any(t["rezeros"] > 0)
    events = run_events(out)
    first = {e["reflector"]: e for e in events if e["kind"] == "zero" and not e["again"]}
    again = [e for e in events if e["kind"] == "zero" and e["again"]]
    assert again and all(e["aim"] == first[e["reflector"]]["aim"] for e in again)
    assert all(e["command"] == first[e["reflector"]]["command"] for e in again)


def test_simulated_campaign_stopped_and_resumed_equals_the_uninterrupted_one(tmp_path):
    """The simulated station resumes too (the laser's sample count): with noise, a campaign stopped twice
    and resumed reads what the uninterrupted one reads."""
    from olti_drake.hardware.runner import run

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
    assert json.load(open(os.path.join(out, "truth.json"))) == json.load(open(os.path.join(tmp_path, "whole",
                                                                                           "truth.json")))


def test_hardware_station_on_the_machine_port_and_one_port_per_head(tmp_path, reference):
    """station: !Hardware {robot_port, head_ports}: the real-device path, here on the 3D machine emulator's
    ptys started from the same scenario, reads what the emulated station reads; no truth is written."""
    from olti_drake.hardware.runner import run
    from olti_drake.hardware.station import machine3d_emulator_for
    from olti_drake.sim.machine3d_campaign import prepare_machine3d_campaign
    from olti_drake.sim.machine3d_station import load_machine3d_scenario
    from olti_drake.sim.scenario import Emulated

    setup = prepare_machine3d_campaign(load_machine3d_scenario(_scenario(tmp_path)))
    emu = machine3d_emulator_for(setup, None, Emulated()).start()
    try:
        station = f"!Hardware {{robot_port: {emu.robot_port}, head_ports: [{', '.join(emu.head_ports)}]}}"
        out = str(tmp_path / "hw")
        result = run(_scenario(tmp_path, station, name="hw.yaml"), out, fsync=False)
    finally:
        emu.stop()
    assert result.complete and result.on_disk == 120
    t, ref = _log(out), _log(reference.out_dir)
    np.testing.assert_array_equal(t["step"], ref["step"])
    np.testing.assert_allclose(t["displacement_mm"], ref["displacement_mm"], rtol=0, atol=1e-9)
    assert not os.path.exists(os.path.join(out, "truth.json"))
    assert json.load(open(os.path.join(out, "run.json")))["station"] == "hardware"


def _logger_hook(seen):
    """An ``extend`` hook adding a logger LeafSystem on the station's displacement and valid outputs: it keeps
    every reading half a period after each move (when the recorder takes it)."""
    from pydrake.systems.framework import LeafSystem

    class ReadingLogger(LeafSystem):
        def __init__(self, period_s):
            super().__init__()
            self.rows = []
            self.DeclareVectorInputPort("displacement", 1)
            self.DeclareVectorInputPort("valid", 1)
            self.DeclarePeriodicPublishEvent(period_s, 0.5 * period_s, self._log)

        def _log(self, context):
            self.rows.append((self.get_input_port(0).Eval(context)[0], self.get_input_port(1).Eval(context)[0]))

    def extend(builder, *, setup, station, sequencer, steering, recorder):
        assert steering is not None and recorder is not None and sequencer.period_s == setup.scenario.period_s
        logger = builder.AddNamedSystem("reading_logger", ReadingLogger(setup.scenario.period_s))
        builder.Connect(station.GetOutputPort("displacement"), logger.GetInputPort("displacement"))
        builder.Connect(station.GetOutputPort("valid"), logger.GetInputPort("valid"))
        seen.append(logger)

    return extend


@pytest.mark.parametrize("station", ["!Simulated {}", "!Emulated {}"])
def test_an_extend_hook_runs_on_every_3d_station(tmp_path, station):
    """run(extend=...) adds a logger to the 3D campaign diagram on the simulated and the emulated station;
    it sees every reading the run log has (m -> mm)."""
    from olti_drake.hardware.runner import run

    seen = []
    result = run(_scenario(tmp_path, station), str(tmp_path / "run"), fsync=False, extend=_logger_hook(seen))
    assert result.complete and len(seen) == 1
    assert result.diagram.GetSubsystemByName("reading_logger").get_name() == seen[0].get_name()
    rows = np.array(seen[0].rows)
    t = _log(str(tmp_path / "run"))
    assert len(rows) == 120
    np.testing.assert_array_equal(rows[:, 1], t["valid"])
    np.testing.assert_allclose(rows[:, 0] * 1e3, t["displacement_mm"], rtol=0, atol=1e-9)


# ------------------------------------------------------------------ the campaign file, bad input

def test_the_run_campaign_is_multilaterated_and_identified(tmp_path):
    """The run's campaign.csv (its run-log columns after the 3D campaign's) is what `olti multilaterate` and
    `olti identify --model volumetric` take; the smallest grid a cubic spline allows, three tools, noise."""
    from olti_drake.estimation.multilateration import load_machine_campaign
    from olti_drake.hardware.runner import run

    out = tmp_path / "run"
    path = _scenario(tmp_path, noise=True, grid="[4, 4, 4]", tools="[0, 1, 2]")
    result = run(path, str(out), fsync=False)
    assert result.complete and result.planned == 960
    c = load_machine_campaign(out / "campaign.csv")
    assert c.n_targets == 192 and len(c.station) == 960 - result.invalid
    code, text, err = olti_here("multilaterate", out / "campaign.csv", "--out", out / "ml.json")
    assert code == 0, err
    truth = json.load(open(out / "truth.json"))
    ml = json.load(open(out / "ml.json"))
    tools = np.array([[float(v) for v in t.split(",")] for t in TOOLS.split(";")])
    assert np.max(np.abs(np.array(ml["stations_mm"]) - (np.array(truth["stations_mm"]) - tools[0]))) < 0.05
    code, text, err = olti_here("identify", out / "campaign.csv", "--model", "volumetric", "--tool-offsets-mm", TOOLS,
                            "--out", out / "vol.json")
    assert code == 0, err
    vol = json.load(open(out / "vol.json"))
    assert vol["format"] == "olti-volumetric/1" and vol["converged"] and vol["residual_rms_mm"] < 3e-3
    assert np.max(np.abs(np.array(vol["stations_mm"]) - np.array(truth["stations_mm"]))) < 0.05


def test_bad_station_and_options_are_one_line_and_write_nothing(tmp_path):
    for station, extra, match in (
            ("!Hardware {}", [], "station.robot_port is empty"),
            ("!Hardware {robot_port: /dev/null, head_ports: [a, b]}", [], "5 in the order of heads_mm (got 2)"),
            ("!Hardware {robot_port: /dev/nonexistent-olti, head_ports: [a, b, c, d, e]}", [],
             "cannot open the robot port /dev/nonexistent-olti"),
            ("!Emulated {speed: warp}", [], "station.speed"),
            ("!Emulated {drop: 2}", [], "drop"),
            ("!Emulated {}", ["--meshcat"], "--meshcat"),
            ("!Simulated {}", ["--resume"], "no campaign to resume")):
        out = tmp_path / "x"
        code, _, err = olti_here("run", _scenario(tmp_path, station), "--out", out, *extra)
        error_line(code, err, match)
        assert not (out / "campaign.csv").exists()
    # a finished campaign is never written again: resume only
    code, _, _ = olti_here("run", _scenario(tmp_path, "!Simulated {}"), "--out", tmp_path / "ok", "--no-fsync")
    assert code == 0
    before = (tmp_path / "ok" / "campaign.csv").read_bytes()
    code, _, err = olti_here("run", _scenario(tmp_path, "!Simulated {}"), "--out", tmp_path / "ok")
    assert code == 2 and "--resume" in err and (tmp_path / "ok" / "campaign.csv").read_bytes() == before
    code, _, err = olti_here("run", _scenario(tmp_path, "!Simulated {}", grid="[3, 3, 2]"), "--out", tmp_path / "ok",
                         "--resume")
    assert code == 2 and "command sequence differs" in err and (tmp_path / "ok" / "campaign.csv").read_bytes() == before
