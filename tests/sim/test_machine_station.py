"""The machine-tool campaign (001) as a Drake diagram, against its numpy twin (mm, deg)."""

import dataclasses
import os

import numpy as np
import pytest
import yaml
from pydrake.common.yaml import yaml_load_typed
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from olti_drake.model.instrument import InterferometerOptions
from olti_drake.model.machine import (MachineScenario, VolumetricError, machine_sequence, simulate_machine_campaign,
                                square_targets)
from olti_drake.sim.machine_station import (VolumetricErrorAxes, build_machine_diagram, machine_columns,
                                        AddMachineStation, prepare_machine, run_machine_campaign)
from olti_drake.estimation.multilateration import MultilaterationOptions, align_to_commands, machine_campaign, multilaterate

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
YAML_PATH = os.path.join(ROOT, "diagrams", "paper001_machine.yaml")
QUIET = dict(noise=False, quantization=False, cosine_error=False, beam_loss=False)


def _scenario(**kw):
    interferometer = kw.pop("interferometer", {})
    return MachineScenario(interferometer=InterferometerOptions(**interferometer), **kw)


def _bidirectional():
    """The default machine with backlash on X and Y (a bidirectional machine), µm."""
    e = VolumetricError()
    return dataclasses.replace(e, EXX=dataclasses.replace(e.EXX, backlash_mdeg=6.0),
                               EYY=dataclasses.replace(e.EYY, backlash_mdeg=-4.0, backlash_slope_mdeg_per_deg=0.02))


@pytest.fixture(scope="module")
def station_diagram():
    """The station alone (no sequencer), its inputs fixed by the tests."""
    setup = prepare_machine(_scenario(interferometer=QUIET))
    builder = DiagramBuilder()
    station = AddMachineStation(builder, setup)
    diagram = builder.Build()
    return setup, station, diagram, diagram.CreateDefaultContext()


def _query(station, diagram, ctx, xyz_mm, c_rad):
    sctx = station.GetMyContextFromRoot(ctx)
    station.GetInputPort("target_command").FixValue(sctx, np.asarray(xyz_mm, dtype=float) * 1e-3)
    station.GetInputPort("table_command").FixValue(sctx, np.asarray(c_rad, dtype=float))
    station.GetInputPort("station").FixValue(sctx, [0.0])
    return station.GetOutputPort("query_object").Eval(sctx)


def test_target_is_command_plus_volumetric_error(station_diagram):
    setup, station, diagram, ctx = station_diagram
    mp = station.plant
    rng = np.random.default_rng(3)
    cmd = np.vstack([square_targets(), rng.uniform(-20.0, 120.0, (30, 2))])
    z = rng.uniform(-50.0, 50.0, len(cmd))
    expected = setup.scenario.error.actual(cmd)  # the initial direction is +1 on every axis
    assert np.max(np.abs(expected - cmd)) > 2e-3  # the error is visible (µm) ...
    for k in range(len(cmd)):
        query = _query(station, diagram, ctx, [cmd[k, 0], cmd[k, 1], z[k]], np.zeros(mp.n_stations))
        p = query.GetPoseInWorld(mp.target_frame_id).translation() * 1e3
        # ... and the plant's target (FK through SceneGraph) is exactly command + error; Z moves z only.
        np.testing.assert_allclose(p[:2], expected[k], rtol=0, atol=1e-9)
        assert p[2] == pytest.approx(mp.beam_height_m * 1e3 + z[k], abs=1e-9)


def test_beam_follows_the_table_command(station_diagram):
    setup, station, diagram, ctx = station_diagram
    mp = station.plant
    assert mp.n_stations == 3
    angles = np.radians([[0.0, 90.0, -135.0], [37.5, 181.0, -2.0], [-90.0, 10.0, 359.0]])
    for c in angles:
        query = _query(station, diagram, ctx, [50.0, 50.0, 0.0], c)
        for j in range(mp.n_stations):
            X_WL = query.GetPoseInWorld(mp.laser_frame_ids[j]) @ mp.lasers_in_body[j]
            # The beam leaves the C axis at the station, at the target's height, along (cos C, sin C, 0).
            np.testing.assert_allclose(X_WL.translation() * 1e3, [*setup.stations_mm[j], mp.beam_height_m * 1e3],
                                       rtol=0, atol=1e-9)
            np.testing.assert_allclose(X_WL.rotation().matrix()[:, 0], [np.cos(c[j]), np.sin(c[j]), 0.0],
                                       rtol=0, atol=1e-12)


def test_directions_and_backlash_of_a_bidirectional_machine():
    error = _bidirectional()
    system = VolumetricErrorAxes(error)
    sim = Simulator(system)
    ctx = sim.get_mutable_context()
    # X: 10 -> 30 (+) -> 30 (kept) -> 20 (-) -> 20 (kept) -> 40 (+); Y: 0 (initial +) -> 0 -> 15 (+) -> 5 (-) ...
    cmds = np.array([[10, 0, 0], [30, 0, 0], [30, 15, 0], [20, 5, 0], [20, 5, -8], [40, 25, -8]], dtype=float)
    dirs, pos = [], []
    for k, c in enumerate(cmds):
        system.get_input_port(0).FixValue(ctx, c * 1e-3)
        dirs.append(system.GetOutputPort("direction").Eval(ctx).copy())
        pos.append(system.GetOutputPort("position").Eval(ctx) * 1e3)
        sim.AdvanceTo(k + 1.0)  # one step: the per-step update remembers the command
    dirs, pos = np.array(dirs), np.array(pos)
    assert dirs[:, 0].tolist() == [1, 1, 1, -1, -1, 1]
    assert dirs[:, 1].tolist() == [1, 1, 1, -1, -1, 1]
    assert dirs[:, 2].tolist() == [1, 1, 1, 1, -1, -1]
    np.testing.assert_allclose(pos[:, :2], error.actual(cmds[:, :2], dirs[:, 0], dirs[:, 1]), rtol=0, atol=1e-9)
    assert pos[:, 2] == pytest.approx(cmds[:, 2], abs=1e-12)
    # The backlash shows: the same X command from the two sides differs by the 6 µm backlash.
    assert pos[3, 0] - error.actual([[20.0, 5.0]], 1.0, -1.0)[0, 0] == pytest.approx(-6e-3, abs=1e-12)


def test_bidirectional_campaign_reads_the_directional_positions():
    s = _scenario(error=_bidirectional(), interferometer=QUIET)
    setup = prepare_machine(s)
    diagram, rec, seq = build_machine_diagram(setup)
    simulator = Simulator(diagram)
    simulator.AdvanceTo(seq.duration_s)
    cols = machine_columns(rec, simulator.get_context())
    q = machine_sequence(setup.commands_mm, len(setup.stations_mm))
    assert np.any(q["dir_x"] < 0) and np.any(q["dir_y"] < 0)
    actual = s.error.actual(setup.commands_mm[q["target"]], q["dir_x"], q["dir_y"])
    np.testing.assert_allclose(rec.GetActual(simulator.get_context()), actual, rtol=0, atol=1e-9)
    dist = np.hypot(*(actual - setup.stations_mm[q["station"]]).T)
    np.testing.assert_allclose(cols["displacement_mm"], dist - setup.dead_paths_mm[q["station"]], rtol=0, atol=1e-9)
    first = [np.flatnonzero(cols["station"] == j)[0] for j in range(3)]
    assert cols["displacement_mm"][first] == pytest.approx(0.0, abs=1e-9)  # counters zeroed at the first target


@pytest.mark.parametrize("kw", [
    dict(interferometer=QUIET),
    # Cosine error on, no noise: the steering (station estimates, zero-angle errors) must match too.
    dict(interferometer=dict(noise=False, quantization=False)),
    # Coarse estimates: cosine errors of µm and beam loss over a whole station and part of another.
    dict(interferometer=dict(noise=False, quantization=False), station_estimate_sigma_um=1500.0,
         zero_angle_sigma_urad=3000.0),
    dict(interferometer=QUIET, seed=5, stations_mm=[[-150.0, 30.0], [180.0, -120.0], [160.0, 210.0], [-60.0, 200.0]]),
], ids=["quiet", "cosine", "coarse-estimates", "four-stations"])
def test_readings_equal_the_numpy_twin(kw):
    # The diagram takes the twin's station-estimate and zero-angle draws (default_rng(seed), same order:
    # prepare_machine), so with the noise off both steer and read identically.
    s = _scenario(**kw)
    cols, truth = run_machine_campaign(s)
    twin, twin_truth = simulate_machine_campaign(s)
    assert list(cols) == list(twin) and list(truth) == list(twin_truth)
    for key in ("station", "target", "valid"):
        assert cols[key].dtype == twin[key].dtype and np.array_equal(cols[key], twin[key]), key
    for key in ("x_cmd_mm", "y_cmd_mm"):
        np.testing.assert_allclose(cols[key], twin[key], rtol=0, atol=1e-12)
    np.testing.assert_allclose(cols["displacement_mm"], twin["displacement_mm"], rtol=0, atol=1e-9)  # NaN = NaN
    for key, value in twin_truth.items():
        if isinstance(value, list):
            np.testing.assert_allclose(truth[key], value, rtol=0, atol=1e-12, err_msg=key)
        else:
            assert truth[key] == value, key
    if "station_estimate_sigma_um" in kw:
        assert 0 < np.sum(cols["valid"] == 0) < 40  # beam loss seen, and not everywhere
    if kw["interferometer"].get("cosine_error", True):
        quiet, _ = simulate_machine_campaign(dataclasses.replace(s, interferometer=InterferometerOptions(**QUIET)))
        assert np.nanmax(np.abs(quiet["displacement_mm"] - twin["displacement_mm"])) > 1e-7  # the cosine error shows


def test_noisy_campaign_is_reproducible_and_within_the_budget():
    s = _scenario()
    cols, truth = run_machine_campaign(s)
    again, _ = run_machine_campaign(s)
    np.testing.assert_array_equal(cols["displacement_mm"], again["displacement_mm"])
    quiet, _ = simulate_machine_campaign(dataclasses.replace(s, interferometer=InterferometerOptions(
        noise=False, quantization=False)))
    noise = cols["displacement_mm"] - quiet["displacement_mm"]
    # 001 Table 4: about 2.5 µm (k = 2) on the reading; λ/64 counter steps.
    assert 0.3e-3 < np.std(noise) < 2.5e-3
    steps = cols["displacement_mm"] / s.interferometer.resolution_mm
    assert steps == pytest.approx(np.round(steps), abs=1e-6)


def test_multilateration_recovers_the_targets():
    s = _scenario(interferometer=QUIET)
    cols, truth = run_machine_campaign(s)
    res = multilaterate(machine_campaign(cols), MultilaterationOptions(stations_mm=truth["stations_estimate_mm"]))
    targets, stations = align_to_commands(truth["targets_mm"], truth["commands_mm"], truth["stations_mm"])
    np.testing.assert_allclose(res.targets_mm, targets, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.stations_mm, stations, rtol=0, atol=1e-9)
    np.testing.assert_allclose(res.dead_paths_mm, truth["dead_paths_mm"], rtol=0, atol=1e-9)
    # The volumetric error itself (µm) is what is recovered, not just the commands.
    assert np.max(np.abs(np.asarray(truth["targets_mm"]) - truth["commands_mm"])) > 5e-3


def test_yaml_scenario_equals_the_defaults():
    assert yaml_load_typed(schema=MachineScenario, filename=YAML_PATH) == MachineScenario()
    with open(YAML_PATH, encoding="utf-8") as f:
        keys = set(yaml.load(f, Loader=yaml.BaseLoader))  # BaseLoader: tags are not resolved
    fields = {f.name for f in dataclasses.fields(MachineScenario)}
    assert keys == fields  # every field is written out
