"""A five-axis campaign simulated (issue 25, item 4): the Drake diagram (sim/five_axis_station.py) reads what its
numpy twin reads, the interferometers are steered OPEN LOOP from the commands (001 Eq. (1) with the rotary axes),
the plans approach every rotary axis from both directions, the R-test reads truth − nest − zero, and
`olti simulate diagrams/machine_5axis.yaml` writes a campaign the five-axis reader takes, byte-identical by seed."""

import copy
import json
import os

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.model import aiming3d
from olti_drake.model import five_axis_plan as fp
from olti_drake.model.five_axis import FiveAxisMachine
from olti_drake.sim import five_axis_station as fs
from olti_drake.sim.serial_scenario import scenario_kind
from olti_calls import error_line, olti_sub

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
YAML = os.path.join(ROOT, "diagrams", "machine_5axis.yaml")
SMALL = "{tracking: {poses: 8}, rtest: {steps: 4}}"


@pytest.fixture(scope="module")
def doc():
    d = fs.load_five_axis_scenario(YAML, text=SMALL)
    d.tracking.poses, d.rtest.steps = 12, 5
    return d


@pytest.fixture(scope="module")
def machine(doc):
    return FiveAxisMachine.from_file(doc.machine_path(), "workpiece", "tool")


def _quiet(doc, **interferometer):
    d = copy.deepcopy(doc)
    for k, v in dict(noise=False, quantization=False, **interferometer).items():
        setattr(d.interferometer, k, v)
    d.rtest.noise_um = 0.0
    return d


def test_diagram_reads_what_the_numpy_twin_reads(doc):
    """Same seed, noise and quantization on: every reading to 1e-9 mm, the same beams lost, the same R-test."""
    run = fs.prepare_five_axis(doc)
    twin, diagram = fs.twin_readings(run), fs.diagram_readings(run)
    assert np.array_equal(twin[1], diagram[1]) and np.array_equal(np.isnan(twin[0]), np.isnan(diagram[0]))
    assert np.nanmax(np.abs(twin[0] - diagram[0])) <= 1e-9
    assert np.nanmax(np.abs(twin[2] - diagram[2])) <= 1e-9
    cols, truth = fs.run_five_axis_campaign(run)
    tcols, ttruth = fs.simulate_five_axis_campaign(run)
    assert set(cols) == set(tcols) and truth == ttruth
    assert {"a_cmd_deg", "c_cmd_deg", "dir_a", "dir_c", "station_frame", "nest", "dx_mm"} <= set(cols)
    assert set(run.plan.station_frames) == {"base", "workpiece"}
    assert np.isnan(twin[0][run.plan.nest >= 0]).all() and np.isnan(twin[2][run.plan.station >= 0]).all()


def test_a_head_table_machine_too(doc):
    """The shipped swivel head (B head, C table): the B head turns the cat's eye; diagram = twin all the same."""
    d = copy.deepcopy(doc)
    d.machine_model.file = "swivel_head_bc"
    d.tracking.ranges_deg = d.rtest.ranges_deg = {"B": [-30.0, 30.0]}
    d.tracking.poses, d.rtest.steps, d.rtest.nests_mm = 6, 4, [[100.0, 0.0, 100.0]]
    d.tracking.box_mm = [[-100.0, 100.0], [-100.0, 100.0], [100.0, 200.0]]
    run = fs.prepare_five_axis(d)
    twin, diagram = fs.twin_readings(run), fs.diagram_readings(run)
    assert run.machine.rotary == ("B", "C") and np.array_equal(twin[1], diagram[1])
    assert np.nanmax(np.abs(twin[0] - diagram[0])) <= 1e-9 and np.nanmax(np.abs(twin[2] - diagram[2])) <= 1e-9


def test_nominal_plant_equals_the_twin_loop(doc, machine):
    """The diagram aims from the MultibodyPlant's nominal tool point; the twin from the numpy loop: the same."""
    run = fs.prepare_five_axis(doc)
    nominal = fs.FiveAxisNominal(run.machine, run.tool_offsets_mm, run.catseye_axis_tool)
    ctx = nominal.CreateDefaultContext()
    rev = np.array([a in "ABC" for a in machine.axes])
    twin = fs.nominal_frames(machine, run.plan.commands, run.tool_offsets_mm[run.plan.tool], run.catseye_axis_tool)
    for k in range(0, len(run.plan), 7):
        c = run.plan.commands[k]
        nominal.GetInputPort("command").FixValue(ctx, np.where(rev, np.radians(c), c / 1e3))
        nominal.GetInputPort("tool").FixValue(ctx, [float(run.plan.tool[k])])
        for f in ("base", "workpiece"):
            assert np.allclose(nominal.GetOutputPort(f"nominal_{f}").Eval(ctx) * 1e3, twin[f][0][k], atol=1e-9)
            assert np.allclose(nominal.GetOutputPort(f"catseye_axis_{f}").Eval(ctx), twin[f][1][k], atol=1e-12)


def test_open_loop_aiming_uses_the_commands(doc):
    """Location errors ×10 (0.1–0.5 mm, 0.2–1 mrad): the heads still aim at the COMMANDED tool point, so a reading
    is (T − o)·u − L0 along the commanded beam (cosine error), not the closed-loop |T − o| − L0, and the beam
    is lost exactly where the true point misses it by more than the cat's-eye acceptance."""
    d = _quiet(doc)
    d.truth.location_scale = 10.0
    run = fs.prepare_five_axis(d)
    disp, valid, _ = fs.diagram_readings(run)
    p = run.plan
    rows = np.flatnonzero(p.station >= 0)
    nominal = fs.nominal_frames(run.machine, p.commands, run.tool_offsets_mm[p.tool], run.catseye_axis_tool)
    actual = fs.true_points(run)
    along, miss, closed = (np.zeros(len(rows)) for _ in range(3))
    for i, k in enumerate(rows):
        j = int(p.station[k])
        f = p.station_frames[j]
        cmd = aiming3d.pan_tilt_commands(run.heads_est, [j], nominal[f][0][k][None])
        o, u = aiming3d.pan_tilt_beam(run.heads_true, [j], cmd, run.head_error)
        rel = actual[f][k] - o[0]
        along[i], miss[i] = rel @ u[0], np.linalg.norm(rel - (rel @ u[0]) * u[0])
        closed[i] = np.linalg.norm(rel)
    L0 = run.dead_paths_mm[p.station[rows]]
    ok = valid[rows] == 1
    assert np.max(np.abs(disp[rows][ok] - (along - L0)[ok])) <= 1e-9
    cosine = (closed - along)[ok]
    assert cosine.max() > 1e-8 and np.allclose(cosine, miss[ok] ** 2 / (2 * closed[ok]), rtol=1e-3, atol=1e-12)
    lost = miss > run.options.acceptance_mm
    assert lost.any() and not (valid[rows][lost]).any()
    # The small truth: the table heads read the (table-side) location errors, the bed heads cannot see them.
    small = fs.prepare_five_axis(_quiet(doc))
    change = np.abs(disp[rows] - fs.twin_readings(small)[0][rows])
    table = np.array([p.station_frames[j] == "workpiece" for j in p.station[rows]])
    assert np.nanmax(change[table]) > 0.05 and np.nanmax(change[~table]) < 1e-9


def test_plans_approach_every_rotary_axis_from_both_directions(machine):
    frames = ["base", "workpiece"]
    t = fp.tracking_plan(machine, frames, 20, [[-100, 100], [-100, 100], [120, 220]], {"A": [-45, 30]}, [0, 1],
                         [[0, 0, 0], [0, 0, 50]], seed=3)
    r = fp.rtest_plan(machine, [[100, 0, 150], [-80, 80, 200]], 6, {"A": [-30, 30]})
    for plan in (t, r, fp.combine(t, r)):
        machine.check_commands(plan.commands)
        for a in machine.rotary:
            d = plan.directions[:, plan.axes.index(a)]
            assert set(np.unique(d)) == {-1.0, 1.0}, a
    for n in range(2):  # each nest: forward and back on every rotary axis, the nominal ball on the nest
        rows = r.nest == n
        assert all(set(np.unique(r.directions[rows, r.axes.index(a)])) == {-1.0, 1.0} for a in machine.rotary)
        assert np.allclose(machine.tool_points(r.commands[rows]), r.nests_mm[n], atol=1e-9)
    box = machine.tool_points(t.commands)
    assert np.all((box >= [-100, -100, 120]) & (box <= [100, 100, 220]))
    again = fp.tracking_plan(machine, frames, 20, [[-100, 100], [-100, 100], [120, 220]], {"A": [-45, 30]}, [0, 1],
                             [[0, 0, 0], [0, 0, 50]], seed=3)
    assert np.array_equal(again.commands, t.commands) and len(t) == 2 * 2 * 20
    with pytest.raises(InputError, match="ranges_deg names 'B'"):
        fp.tracking_plan(machine, frames, 4, [[0, 1], [0, 1], [150, 160]], {"B": [0, 1]})


def test_rtest_reads_truth_minus_nest_zero(doc):
    run = fs.prepare_five_axis(_quiet(doc))
    _, _, rtest = fs.diagram_readings(run)
    rows = np.flatnonzero(run.plan.nest >= 0)
    n = run.plan.nest[rows]
    want = fs.true_points(run, rows)["workpiece"] - run.plan.nests_mm[n] - run.nest_zeros_mm[n]
    assert np.max(np.abs(rtest[rows] - want)) <= 1e-12
    assert np.max(np.abs(rtest[rows])) > 1e-3  # the errors show (tens of µm)


def test_simulate_end_to_end_deterministic_by_seed(tmp_path, machine):
    from olti_drake.io.five_axis_io import read_five_axis_campaign

    out = {}
    for name, seed in (("a", 0), ("b", 0), ("c", 5)):
        r = olti_sub("simulate", YAML, "--scenario-text", SMALL, "--seed", seed, "--out", tmp_path / name)
        assert r.returncode == 0, r.stderr
        out[name] = [(tmp_path / name / f).read_bytes() for f in ("campaign.csv", "truth.json")]
    assert out["a"] == out["b"] and out["a"][0] != out["c"][0]
    c = read_five_axis_campaign(tmp_path / "a" / "campaign.csv", machine)
    assert set(c.kind) == {"distance", "nest"} and set(c.frame) == {"base", "workpiece"}
    assert "five-axis campaign" in r.stdout and scenario_kind(YAML) == "machine5"
    truth = json.loads(out["a"][1])
    assert set(truth["location_errors"]) >= {"E_X0C_mm", "E_A0C_urad", "E_Y0A_mm"}
    assert truth["error_motions"]["E_CC"]["unit"] == "urad" and len(truth["station_frames"]) == 5
    r = olti_sub("simulate", YAML, "--scenario-text", SMALL, "--out", tmp_path / "a")  # never replaces a campaign
    error_line(r.returncode, r.stderr)


@pytest.mark.parametrize("text, field", [
    ("{tracking: {poses: 1}}", "poses must be >= 2"),
    ("{tracking: {poses: 100000000000}}", "tracking.poses"),
    ("{tracking: {ranges_deg: {A: [0, 99]}}}", "ranges_deg A"),
    ("{rtest: {nests_mm: [[0, 0, -900]]}}", "nest 0"),
    ("{machine_model: {file: nowhere.urdf}}", "nowhere.urdf"),
    ("{machine_model: {tool_offsets_mm: [[0, 0]]}}", "tool_offsets_mm"),
    ("{tracking: {tools: [5]}}", "tools"),
    ("{period_s: 0}", "period_s"),
])
def test_bad_fields_are_refused_in_one_line(text, field):
    with pytest.raises(InputError) as e:
        fs.prepare_five_axis(fs.load_five_axis_scenario(YAML, text=text))
    assert field in str(e.value) and "\n" not in str(e.value)


def test_olti_run_refuses_a_five_axis_scenario(tmp_path):
    r = olti_sub("run", YAML, "--out", tmp_path / "r")
    error_line(r.returncode, r.stderr, "five-axis")


def test_the_systems_are_importable_and_subclassable():
    """Drake users import and subclass the diagram's systems (issue 22): module-level classes, not factory locals."""
    from olti_drake.sim import five_axis_station as station
    from olti_drake.sim import five_axis_systems as systems

    for name in ("FiveAxisNominal", "FiveAxisSteering", "FiveAxisTruthTool", "FiveAxisInterferometer", "RTestDevice",
                 "FiveAxisRecorder"):
        cls = getattr(systems, name)
        assert getattr(station, name) is cls and "<locals>" not in cls.__qualname__, name

    class MyDevice(systems.RTestDevice):  # noqa: F841 (a subclass of one's own)
        pass
