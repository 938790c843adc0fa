"""``olti run``: readings on disk as they arrive, resume without loss or duplicates, retry policies.

Campaigns run through the emulator's real pseudo-terminals with pyserial. Noise-free scenarios
make every reading reproducible, so a resumed campaign is compared with an uninterrupted one
reading by reading: a wrong approach direction or counter zero after a resume would show.
"""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.io.csvio import read_table
from olti_calls import error_line, olti_sub

PLANNED = 1056
COLS = ("reflector", "theta1_deg", "theta2_deg", "dir1", "dir2", "displacement_mm", "valid", "step", "session",
        "reads", "rezeros")


def _scenario(tmp_path, name="scenario.yaml", station="!Emulated {}", noise=False, seed=0):
    """The paper scenario (defaults) with exact steering, optionally without noise, on ``station``."""
    interferometer = "" if noise else "interferometer: {noise: false}\n"
    text = f"reflector_estimate: !ExactEstimate {{}}\n{interferometer}seed: {seed}\nstation: {station}\n"
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _table(out_dir):
    return read_table(os.path.join(out_dir, "campaign.csv"), COLS)


def _run(*args, **kw):
    return olti_sub("run", *args, timeout=300, **kw)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The uninterrupted noise-free emulated campaign (in process)."""
    from olti_drake.hardware.runner import run

    tmp = tmp_path_factory.mktemp("reference")
    out = str(tmp / "run")
    summary = run(_scenario(tmp), out)
    assert summary.complete and summary.taken == summary.on_disk == PLANNED
    return _table(out)


def _assert_same_campaign(t, ref):
    """Exactly the plan's readings, once each, in plan order, equal to the uninterrupted campaign's."""
    assert len(t["step"]) == PLANNED
    assert np.array_equal(np.sort(t["step"]), ref["step"]) and np.all(np.diff(t["step"]) > 0)
    for c in ("reflector", "theta1_deg", "theta2_deg", "dir1", "dir2", "valid"):
        assert np.array_equal(t[c], ref[c]), c
    ok = ref["valid"] == 1
    assert np.all(np.isnan(t["displacement_mm"][~ok]))
    np.testing.assert_allclose(t["displacement_mm"][ok], ref["displacement_mm"][ok], rtol=0, atol=1e-9)


def _lines(path):
    try:
        with open(path, "rb") as f:
            return f.read().count(b"\n")
    except FileNotFoundError:
        return 0


def test_sigkill_at_random_points_then_resume_loses_and_duplicates_nothing(tmp_path, reference):
    scenario, out = _scenario(tmp_path), str(tmp_path / "run")
    csv = os.path.join(out, "campaign.csv")
    header = 3
    kills = np.sort(np.random.default_rng(7).choice(np.arange(40, PLANNED - 40), 3, replace=False))
    on_disk = []
    for k, target in enumerate(kills):
        p = subprocess.Popen([sys.executable, "-m", "olti_drake.cli", "run", scenario, "--out", out]
                             + (["--resume"] if k else []), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 120
        while _lines(csv) - header < target and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.001)
        p.send_signal(signal.SIGKILL)
        p.wait()
        assert p.returncode == -signal.SIGKILL, "the run ended before it could be killed"
        on_disk.append(_lines(csv) - header)
    assert on_disk == sorted(on_disk) and on_disk[-1] < PLANNED
    done = _run(scenario, "--out", out, "--resume")
    assert done.returncode == 0, done.stderr
    assert f"{PLANNED} of {PLANNED} planned readings" in done.stdout
    t = _table(out)
    _assert_same_campaign(t, reference)
    assert set(np.unique(t["session"])) == {0, 1, 2, 3}
    events = [json.loads(line) for line in open(os.path.join(out, "events.jsonl"))]
    assert sum(e["kind"] == "reapproach" for e in events) == 3   # once per resumed session
    manifest = json.load(open(os.path.join(out, "run.json")))
    assert manifest["complete"] and len(manifest["sessions"]) == 4
    again = _run(scenario, "--out", out, "--resume")
    assert again.returncode == 0 and "already complete" in again.stdout


def test_ctrl_c_stops_after_the_reading_in_progress_and_resume_completes(tmp_path, reference):
    scenario, out = _scenario(tmp_path), str(tmp_path / "run")
    csv = os.path.join(out, "campaign.csv")
    p = subprocess.Popen([sys.executable, "-m", "olti_drake.cli", "run", scenario, "--out", out],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while _lines(csv) < 300 and p.poll() is None:
        time.sleep(0.001)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    assert "interrupted by SIGINT" in err and "--resume" in err and "Traceback" not in err
    assert open(csv, "rb").read().endswith(b"\n")  # stopped between readings, not in one
    assert _run(scenario, "--out", out, "--resume").returncode == 0
    _assert_same_campaign(_table(out), reference)


def test_disconnect_is_a_one_line_error_and_resume_on_a_fixed_line_completes(tmp_path, reference):
    out = str(tmp_path / "run")
    broken = _scenario(tmp_path, station="!Emulated {disconnect_after: 1500, timeout_s: 0.2, retries: 1}")
    r = _run(broken, "--out", out)
    assert r.returncode == 3
    err = r.stderr.strip()
    assert err.startswith("error: station:") and "\n" not in err and "--resume" in err
    assert "LinkLost" in err or "TimeoutError" in err
    n = len(_table(out)["step"])
    assert 0 < n < PLANNED
    fixed = _scenario(tmp_path, station="!Emulated {}")   # same file name: the cable was replaced
    assert fixed == broken
    assert _run(fixed, "--out", out, "--resume").returncode == 0
    _assert_same_campaign(_table(out), reference)


def test_beam_loss_is_reread_and_a_lost_count_rezeroed_at_the_reference_pose(tmp_path, reference):
    from olti_drake.hardware.runner import run

    # Injected interruptions, counter that keeps counting: re-reads recover every reading.
    out = str(tmp_path / "transient")
    run(_scenario(tmp_path, "a.yaml", "!Emulated {beam_loss: 0.05}"), out)
    t = _table(out)
    _assert_same_campaign(t, reference)
    assert np.sum(t["reads"] > 1) > 20 and np.all(t["rezeros"] == 0)

    # A counter that loses its count: re-reading cannot help; zeroing again where the run was
    # zeroed, approached the same way, restores the run's dead path exactly.
    out = str(tmp_path / "latched")
    run(_scenario(tmp_path, "b.yaml", "!Emulated {beam_loss: 0.02, latch_beam_loss: true, policy: {rezeros: 3}}"), out)
    t = _table(out)
    _assert_same_campaign(t, reference)
    assert np.sum(t["rezeros"] > 0) > 5

    # Without a policy the lost readings are kept, flagged, and nothing made up.
    out = str(tmp_path / "none")
    run(_scenario(tmp_path, "c.yaml", "!Emulated {beam_loss: 0.05, policy: {rereads: 0, rezeros: 0}}"), out)
    t = _table(out)
    lost = (t["valid"] == 0) & (reference["valid"] == 1)
    assert len(t["step"]) == PLANNED and lost.sum() > 20
    assert np.all(np.isnan(t["displacement_mm"][t["valid"] == 0]))
    ok = t["valid"] == 1
    np.testing.assert_allclose(t["displacement_mm"][ok], reference["displacement_mm"][ok], rtol=0, atol=1e-9)


def test_alarm_is_cleared_per_policy_and_the_pose_reapproached(tmp_path, reference):
    from olti_drake.hardware.station import StationError
    from olti_drake.hardware.runner import run

    out = str(tmp_path / "cleared")
    run(_scenario(tmp_path, "a.yaml", "!Emulated {alarm_at: 500, policy: {clear_alarms: 1}}"), out)
    _assert_same_campaign(_table(out), reference)
    kinds = [json.loads(line)["kind"] for line in open(os.path.join(out, "events.jsonl"))]
    assert kinds.count("alarm") == 1 and kinds.count("alarm_cleared") == 1

    out = str(tmp_path / "stopped")
    with pytest.raises(StationError, match=r"controller alarm EMU_INJECTED at the move to.*then resume"):
        run(_scenario(tmp_path, "b.yaml", "!Emulated {alarm_at: 500}"), out)
    assert 0 < len(_table(out)["step"]) < PLANNED
    run(_scenario(tmp_path, "b.yaml", "!Emulated {}"), out, resume=True)
    _assert_same_campaign(_table(out), reference)


def test_simulated_run_resumed_in_process_equals_the_uninterrupted_one(tmp_path):
    """The simulated station resumes too (joint directions, laser noise stream), noise on."""
    from olti_drake.hardware.runner import run

    scenario = _scenario(tmp_path, station="!Simulated {}", noise=True)
    whole = str(tmp_path / "whole")
    run(scenario, whole)

    class Stop(Exception):
        pass

    def stop_at(n):
        def progress(done, planned):
            if done >= n:
                raise Stop
        return progress

    out = str(tmp_path / "parts")
    for k, n in enumerate((100, 500)):
        with pytest.raises(Stop):
            run(scenario, out, resume=bool(k), progress=stop_at(n))
    run(scenario, out, resume=True)
    a, b = _table(out), _table(whole)
    assert np.array_equal(a["step"], b["step"])
    np.testing.assert_array_equal(a["displacement_mm"], b["displacement_mm"])
    assert set(np.unique(a["session"])) == {0, 1, 2}


def test_a_cut_last_line_is_dropped_and_taken_again(tmp_path):
    from olti_drake.hardware.runner import run

    scenario = _scenario(tmp_path, station="!Simulated {}")
    whole, out = str(tmp_path / "whole"), str(tmp_path / "cut")
    run(scenario, whole)
    text = open(os.path.join(whole, "campaign.csv"), encoding="utf-8").read()
    lines = text.splitlines(keepends=True)
    os.makedirs(out)
    for name in ("run.json", "events.jsonl"):
        with open(os.path.join(whole, name), encoding="utf-8") as f:
            open(os.path.join(out, name), "w", encoding="utf-8").write(f.read())
    # 400 readings on disk and half of the 401st, as a kill in the middle of a write leaves it.
    open(os.path.join(out, "campaign.csv"), "w", encoding="utf-8").write(
        "".join(lines[:403]) + lines[403][:25])
    run(scenario, out, resume=True)
    a, b = _table(out), _table(whole)
    assert np.array_equal(a["step"], b["step"])
    np.testing.assert_array_equal(a["displacement_mm"], b["displacement_mm"])
    events = [json.loads(line) for line in open(os.path.join(out, "events.jsonl"))]
    assert any(e["kind"] == "dropped_partial_line" and e["text"] == lines[403][:25] for e in events)


def test_bad_starts_and_resumes_are_one_line_errors(tmp_path):
    from olti_drake.hardware.runner import run

    scenario, out = _scenario(tmp_path, station="!Simulated {}"), str(tmp_path / "run")
    with pytest.raises(InputError, match=r"run\.json: no campaign to resume"):
        run(scenario, out, resume=True)
    run(scenario, out)
    r = _run(scenario, "--out", out)
    error_line(r.returncode, r.stderr, "exists: continue that campaign with --resume")
    other_plan = tmp_path / "other_plan.yaml"
    other_plan.write_text(open(scenario).read() + "plan: !BidirectionalGrid {theta1_step: 40.0}\n")
    with pytest.raises(InputError, match=r"command sequence differs"):
        run(str(other_plan), out, resume=True)
    emulated = _scenario(tmp_path, "emu.yaml", station="!Emulated {}")
    with pytest.raises(InputError, match=r"ran on a simulated station.*emulated"):
        run(emulated, out, resume=True)


def test_another_device_family_is_one_driver_class_per_device(tmp_path):
    """A Hardware scenario naming other drivers runs the campaign with no other change."""
    import memory_devices

    from olti_drake.sim.campaign import prepare
    from olti_drake.hardware.runner import run
    from olti_drake.sim.scenario import load_scenario

    station = ("!Hardware {robot_port: mem0, counter_port: mem1, robot_driver: 'memory_devices:MemoryRobot', "
               "counter_driver: 'memory_devices:MemoryCounter'}")
    def exact(path):
        text = open(path).read().replace("interferometer: {noise: false}",
                                         "interferometer: {noise: false, quantization: false, beam_loss: false}")
        open(path, "w").write(text)
        return path

    path = exact(_scenario(tmp_path, station=station))
    memory_devices.MemoryRobot.setup = prepare(load_scenario(path))
    out = str(tmp_path / "run")
    summary = run(path, out)
    assert summary.complete and summary.on_disk == PLANNED
    t = read_table(os.path.join(out, "campaign.csv"), COLS)
    sim = str(tmp_path / "sim")
    run(exact(_scenario(tmp_path, "sim.yaml", station="!Simulated {}")), sim)
    s = read_table(os.path.join(sim, "campaign.csv"), COLS)
    for c in ("step", "dir1", "dir2", "theta1_deg"):
        assert np.array_equal(t[c], s[c]), c
    # Zeroed at the first pose of each run rather than the first measured one: compare within runs.
    for j in range(3):
        m = (t["reflector"] == j) & (s["valid"] == 1)
        d = t["displacement_mm"][m] - s["displacement_mm"][m]
        assert np.ptp(d) < 2.1e-9, (j, np.ptp(d))   # the file has 1e-9 mm digits
    with pytest.raises(InputError, match=r"robot_driver: driver 'nowhere:Robot': cannot import"):
        run(_scenario(tmp_path, "bad.yaml", station="!Hardware {robot_port: a, counter_port: b, "
                                                    "robot_driver: 'nowhere:Robot'}"), str(tmp_path / "bad"))


def test_a_port_that_cannot_be_opened_leaves_no_run_directory_behind(tmp_path):
    scenario = _scenario(tmp_path, station="!Hardware {robot_port: /dev/olti-no-such-port, counter_port: /dev/x}")
    out = tmp_path / "run"
    r = _run(scenario, "--out", str(out))
    error_line(r.returncode, r.stderr, "/dev/olti-no-such-port")
    assert not (out / "campaign.csv").exists() and not (out / "run.json").exists()


def test_a_hardware_station_refuses_a_simulated_reflector_search(tmp_path):
    path = tmp_path / "hw.yaml"
    path.write_text("station: !Hardware {robot_port: /dev/a, counter_port: /dev/b}\n")
    r = _run(str(path), "--out", str(tmp_path / "run"))
    assert r.returncode == 2 and "needs reflector_estimate: !ExactEstimate" in r.stderr


# -- the log's guarantees, each caught by a test when it is removed (issue 11) -------------------------------
@pytest.fixture(scope="module")
def simulated_run(tmp_path_factory):
    """(scenario, run directory) of a whole noise-free simulated campaign; tests copy the directory."""
    from olti_drake.hardware.runner import run

    tmp = tmp_path_factory.mktemp("simulated")
    scenario, out = _scenario(tmp, station="!Simulated {}"), str(tmp / "whole")
    assert run(scenario, out).complete
    return scenario, out


def _copy_run(src, dst, keep=None):
    """A copy of run directory ``src``; ``keep(step)`` selects the campaign rows copied (default all)."""
    import shutil

    shutil.copytree(src, dst)
    if keep is not None:
        lines = open(os.path.join(src, "campaign.csv"), encoding="utf-8").read().splitlines(keepends=True)
        n_head = next(i for i, ln in enumerate(lines) if not ln.startswith("#")) + 1   # comments + header
        head, rows = lines[:n_head], lines[n_head:]
        step_col = head[-1].strip().split(",").index("step")
        open(os.path.join(dst, "campaign.csv"), "w", encoding="utf-8").write(
            "".join(head + [r for r in rows if keep(int(r.split(",")[step_col]))]))
    return dst


def test_every_reading_and_event_is_fsynced_after_it_is_written(tmp_path, monkeypatch):
    """The run log's promise (a power cut loses nothing written): fsync after each line, the line flushed
    before it; --no-fsync (fsync=False) skips it."""
    import types

    from olti_drake.hardware import runlog

    synced = []
    real = os.fsync
    monkeypatch.setattr(runlog.os, "fsync", lambda fd: (synced.append((fd, os.fstat(fd).st_size)), real(fd)))
    status = types.SimpleNamespace(raw="OK", reads=1, rezeros=0)
    record = (0, -140.0, 0.0, 1, 1, 12.5, 0.8, 1, 3)
    for fsync in (True, False):
        out = str(tmp_path / f"run{fsync}")
        log = runlog.CampaignLog.create(out, {"planned": 1}, fsync=fsync)
        synced.clear()
        log.append(3, record, status)
        log.event("zero", reflector=0)
        csv_fd, ev_fd = log._csv.fileno(), log._events.fileno()
        sizes = {fd: os.fstat(fd).st_size for fd in (csv_fd, ev_fd)}
        log.close()
        if fsync:
            assert synced == [(csv_fd, sizes[csv_fd]), (ev_fd, sizes[ev_fd])], synced
        else:
            assert synced == []
    assert _table_steps(os.path.join(str(tmp_path / "runTrue"), "campaign.csv")) == [3]


def _table_steps(csv):
    return read_table(csv, ("step",))["step"].astype(int).tolist()


def test_resume_never_records_a_step_already_on_disk(tmp_path, simulated_run):
    """Readings 100..149 missing in the middle: the resume takes exactly those, not the later ones again."""
    from olti_drake.hardware.runner import run

    scenario, whole = simulated_run
    out = _copy_run(whole, str(tmp_path / "gap"), keep=lambda step: not 100 <= step < 150)
    before = _table_steps(os.path.join(out, "campaign.csv"))
    s = run(scenario, out, resume=True)
    steps = _table_steps(os.path.join(out, "campaign.csv"))
    assert len(steps) == len(set(steps)) == PLANNED and s.complete
    assert s.taken == PLANNED - len(before) > 0    # only the readings of the gap were taken


def test_a_step_recorded_twice_is_refused_on_resume(tmp_path, simulated_run):
    from olti_drake.hardware.runlog import CampaignLog

    scenario, whole = simulated_run
    out = _copy_run(whole, str(tmp_path / "twice"))
    csv = os.path.join(out, "campaign.csv")
    lines = open(csv, encoding="utf-8").read().splitlines(keepends=True)
    open(csv, "a", encoding="utf-8").write(lines[-5])        # a reading already on disk, again
    with pytest.raises(InputError, match=r"campaign\.csv:\d+: step \d+ is recorded twice"):
        CampaignLog.reopen(out)
    r = _run(scenario, "--out", out, "--resume")
    error_line(r.returncode, r.stderr, "is recorded twice")


def test_a_resume_that_finds_every_reading_on_disk_marks_the_run_complete(tmp_path, simulated_run):
    """Interrupted after its last reading: run.json said complete false; the resume completes it."""
    from olti_drake.hardware.runner import run

    scenario, whole = simulated_run
    out = _copy_run(whole, str(tmp_path / "last"))
    manifest = json.load(open(os.path.join(out, "run.json")))
    manifest["complete"] = False
    manifest["sessions"][-1]["outcome"] = "interrupted (SIGINT)"
    json.dump(manifest, open(os.path.join(out, "run.json"), "w"))
    os.remove(os.path.join(out, "truth.json"))
    s = run(scenario, out, resume=True)
    assert s.complete and s.taken == 0
    manifest = json.load(open(os.path.join(out, "run.json")))
    assert manifest["complete"] is True and manifest["sessions"][-1]["outcome"] == "complete"
    assert os.path.exists(os.path.join(out, "truth.json"))
    r = _run(scenario, "--out", out, "--resume")
    assert r.returncode == 0 and "already complete" in r.stdout


# -- NEW (issue 12): the runner from Python ---------------------------------------------------------------------
def test_run_from_python_stops_when_another_thread_asks_and_resume_completes_it(tmp_path, simulated_run):
    """should_stop set from another thread ends the session between readings (none half-written, none
    lost); the result carries the diagram, its context and the log; resume completes the campaign."""
    import threading

    from olti_drake.hardware.runner import run
    from olti_drake.sim.scenario import load_scenario

    scenario, whole = simulated_run
    out = str(tmp_path / "stopped")
    stop = threading.Event()
    seen = []

    def progress(done, planned):
        seen.append(done)
        if done == 200:           # another thread asks; the runner only sees the flag when it polls
            threading.Thread(target=stop.set).start()

    s = run(load_scenario(scenario), out, should_stop=stop.is_set, progress=progress)
    assert s.stopped == "should_stop" and not s.complete
    assert 200 <= s.on_disk < PLANNED and s.on_disk == s.taken == len(_table(out)["step"])
    assert s.log_path == os.path.join(out, "campaign.csv")
    assert s.diagram.GetSubsystemByName("plan_sequencer") is not None
    assert s.context.get_time() > 0
    manifest = json.load(open(os.path.join(out, "run.json")))
    assert manifest["sessions"][-1]["outcome"] == "interrupted (should_stop)" and not manifest["complete"]
    done = run(scenario, out, resume=True, should_stop=lambda: False)
    assert done.complete and done.stopped is None and done.taken == PLANNED - s.on_disk
    a, b = _table(out), _table(whole)
    assert np.array_equal(a["step"], b["step"])
    np.testing.assert_array_equal(a["displacement_mm"], b["displacement_mm"])


def test_olti_run_takes_a_named_scenario_and_overrides(tmp_path):
    """olti run FILE --scenario NAME --scenario-text YAML: the named scenario, overridden; the resume hint
    repeats both options."""
    named = tmp_path / "named.yaml"
    named.write_text(f"quick:\n  base: {os.path.join(os.path.dirname(__file__), '..', '..', 'diagrams', 'paper000_scara.yaml')}\n"
                     "  plan: !BidirectionalGrid {theta1_step: 100.0, theta2_step: 70.0}\n"
                     "  reflector_estimate: !ExactEstimate {}\n")
    out = tmp_path / "run"
    r = _run(str(named), "--scenario", "quick", "--scenario-text", "{seed: 5}", "--out", str(out))
    assert r.returncode == 0, r.stderr
    manifest = json.load(open(out / "run.json"))
    assert manifest["seed"] == 5 and manifest["readings_planned"] < PLANNED / 4
    r = _run(str(named), "--scenario", "nope", "--out", str(tmp_path / "other"))
    error_line(r.returncode, r.stderr, "no scenario named 'nope'")


def test_the_bench_driver_sends_refl_so_a_hardware_scenario_runs_on_a_separate_emulator(tmp_path, reference):
    """NEW (issue 12): ``counter_driver: bench`` (olti_drake.hardware.drivers.BenchCounter) sets each
    reflector position with REFL: a !Hardware scenario on an emulator started on its own runs the whole
    campaign unattended (the plain olti counter driver prompts an operator instead) and reads what the
    in-process emulated station reads."""
    from olti_drake.hardware.drivers import BenchCounter, driver_class
    from olti_drake.hardware.emulator import Emulator
    from olti_drake.hardware.runner import run

    assert driver_class("bench", 1) is BenchCounter
    with Emulator(_scenario(tmp_path, "emu.yaml")) as emu:
        seen = []
        original = emu.on_REFL

        def on_refl(frame):
            seen.append(tuple(frame.fields))
            return original(frame)

        emu.on_REFL = on_refl
        ports = f"robot_port: {emu.robot_port}, counter_port: {emu.counter_port}"
        bench = _scenario(tmp_path, "bench.yaml", station=f"!Hardware {{{ports}, counter_driver: bench}}")
        s = run(bench, str(tmp_path / "bench"))
        assert s.complete and s.on_disk == PLANNED
        assert seen == [("0",), ("1",), ("2",)] and emu.reflector == 2   # one REFL per reflector run
        _assert_same_campaign(_table(str(tmp_path / "bench")), reference)
