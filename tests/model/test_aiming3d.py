"""3D open-loop aiming (olti_drake.model.aiming3d): pan/tilt heads (001 Eq. (1) in 3D) against
today's 2D table steering, robot-mounted IK aiming (constraints, continuity, hit / miss), and
the 3D initial estimates (reflector search, pan/tilt station fit) against their truths."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import olti_drake
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.model import aiming3d as a
from olti_drake.model.chain import load_serial_chain
from olti_drake.model.serial import synthetic_truth

UR5 = Path(olti_drake.__file__).parent / "models" / "ur5.urdf"
TOOL = (0.0, 0.0, 60.0)
LASER = a.LaserOnTool((0.0, 0.0, 60.0), (0.0, 0.0, 1.0))
REFLECTOR = np.array([500.0, 200.0, -300.0])
Q0 = np.array([0.0, -90.0, 90.0, -90.0, -90.0, 0.0])
EXACT = InterferometerOptions(noise=False, quantization=False)


@pytest.fixture(scope="module")
def chain():
    return load_serial_chain(UR5, "tool0")


@pytest.fixture(scope="module")
def aimer(chain):
    return a.RobotAimer(chain, LASER, TOOL)


@pytest.fixture(scope="module")
def small_truth(chain):
    """A robot with small errors: location 0.02 mm / 2 mdeg, maps ~2 mdeg."""
    return synthetic_truth(chain, 3, tool_offset_mm=TOOL, location_mm=0.02, location_deg=0.002,
                           deviation_mdeg=2.0, backlash_mdeg=1.0)


@pytest.fixture(scope="module")
def large_truth(chain):
    return synthetic_truth(chain, 3, tool_offset_mm=TOOL)


def _targets(n, seed):
    return np.array([350.0, 100.0, 350.0]) + np.random.default_rng(seed).uniform(-100, 100, (n, 3))


# ------------------------------------------------------------------ pan/tilt
def test_pan_tilt_azimuth_equals_2d_table_steering_in_the_plane():
    """z = 0: the pan command equals 001 Eq. (1) as TableSteering computes it, to 1e-12 deg, and
    the true beam's world azimuth equals the table's beam direction with zero-angle error δ."""
    from olti_drake.sim.machine_station import TableSteering

    rng = np.random.default_rng(0)
    stations = np.array([[-400.0, 150.0], [600.0, -250.0], [50.0, 700.0]])
    delta = np.array([2e-4, -3e-4, 1e-4])  # rad
    steer = TableSteering(stations, delta, aim_all=True)
    ctx = steer.CreateDefaultContext()
    heads_est = a.PanTiltHeads(np.column_stack([stations, np.zeros(3)]), np.zeros((3, 2)))
    heads_true = a.PanTiltHeads(heads_est.centres_mm, np.column_stack([np.degrees(delta), np.zeros(3)]))
    for p in rng.uniform(-300, 300, (20, 2)):
        steer.get_input_port(0).FixValue(ctx, np.array([p[0], p[1], 0.0]) / 1000.0)
        steer.get_input_port(1).FixValue(ctx, [0.0])
        table = np.degrees(steer.get_output_port(0).Eval(ctx))
        point = np.tile([p[0], p[1], 0.0], (3, 1))
        cmd = a.pan_tilt_commands(heads_est, np.arange(3), point)
        assert np.abs(cmd[:, 1]).max() == 0.0
        assert np.abs(cmd[:, 0] + np.degrees(delta) - table).max() < 1e-12
        _, u = a.pan_tilt_beam(heads_true, np.arange(3), cmd)
        assert np.abs(np.degrees(np.arctan2(u[:, 1], u[:, 0])) - table).max() < 1e-12
        assert np.abs(u[:, 2]).max() < 1e-15


def test_pan_tilt_hits_with_small_errors_and_misses_with_large(chain, small_truth, large_truth):
    """The estimated head aims at the commanded point: a perfect estimate and head hit the
    nominal robot exactly (reading = distance − d0); errors make it miss, flagged invalid."""
    cmds = chain.random_angles(400, 1)
    nominal = a.nominal_robot(chain, TOOL)
    commanded = chain.positions(cmds, nominal.chain_params)
    heads = a.PanTiltHeads([[1500.0, 0.0, -300.0], [-200.0, 1400.0, -300.0]], [[1.0, -0.5], [-2.0, 0.3]])
    station = np.arange(400) % 2
    dead = np.array([100.0, 200.0])
    dirs = np.ones_like(cmds)
    exact = a.pan_tilt_readings(nominal, cmds, dirs, station, commanded, heads, heads, dead, options=EXACT)
    assert exact.miss_mm.max() < 1e-9
    dist = np.linalg.norm(commanded - heads.centres_mm[station], axis=1)
    assert np.abs(exact.reading_mm - (dist - dead[station])).max() < 1e-9
    assert np.array_equal(exact.valid, exact.viewing_deg <= a.MAX_VIEWING_DEG)
    err = a.harmonic_head_error(4, 2.0)
    est = a.PanTiltHeads(heads.centres_mm + 0.05, heads.zeros_deg + 1e-3)
    small = a.pan_tilt_readings(small_truth, cmds, dirs, station, commanded, heads, est, dead,
                                head_error=err, options=EXACT)
    in_view = small.viewing_deg <= a.MAX_VIEWING_DEG
    assert small.miss_mm.max() < 0.5 and np.all(small.valid == in_view)
    # cosine error: the reading is the projection on the beam, shorter than the true distance
    true_c = small_truth.positions(cmds, dirs)
    true_dist = np.linalg.norm(true_c - heads.centres_mm[station], axis=1) - dead[station]
    assert np.all(small.reading_mm <= true_dist + 1e-12)
    assert np.allclose(true_dist - small.reading_mm, small.miss_mm ** 2 / (2 * dist), rtol=1e-3, atol=1e-12)
    far = a.PanTiltHeads(heads.centres_mm + 5.0, heads.zeros_deg)
    large = a.pan_tilt_readings(large_truth, cmds, dirs, station, commanded, heads, far, dead, options=EXACT)
    assert np.array_equal(large.valid, (large.miss_mm <= 1.0) & in_view)
    assert large.valid.mean() < 0.2


# --------------------------------------------------------- robot-mounted aim
def test_ik_aim_satisfies_constraints_in_the_nominal_model(aimer):
    targets = _targets(40, 1)
    res = aimer.aim(targets, REFLECTOR, Q0)
    assert res.success.all() and len(res.unreachable) == 0
    pos, miss, angle = aimer.constraint_errors(res.commands_deg, targets, REFLECTOR)
    assert pos.max() <= 1e-6 and miss.max() <= 1e-6 and angle.max() <= 1e-6
    lo, hi = aimer.chain.lower_deg, aimer.chain.upper_deg
    assert np.all(res.commands_deg >= lo - 1e-9) and np.all(res.commands_deg <= hi + 1e-9)


def test_ik_aim_is_continuous_between_close_targets(aimer):
    """Targets 4 mm apart along a path: every joint moves < 3 deg between consecutive poses
    (nearest to the previous pose: no wrist or elbow flips)."""
    path = np.array([300.0, 50.0, 300.0]) + np.linspace(0, 1, 60)[:, None] * np.array([150.0, 150.0, 50.0])
    res = aimer.aim(path, REFLECTOR, Q0)
    assert res.success.all()
    assert np.abs(np.diff(res.commands_deg, axis=0)).max() < 3.0


def test_ik_refuses_unreachable_targets_by_index(aimer):
    targets = _targets(5, 2)
    targets[2] = [3000.0, 0.0, 0.0]  # beyond the UR5's reach
    res = aimer.aim(targets, REFLECTOR, Q0)
    assert list(res.unreachable) == [2]
    assert np.all(np.isnan(res.commands_deg[2])) and np.isfinite(res.commands_deg[[0, 1, 3, 4]]).all()


def test_robot_mounted_beam_hits_with_small_errors_and_is_flagged_when_large(aimer, small_truth, large_truth):
    targets = _targets(60, 3)
    dirs = np.ones((60, 6))
    hit = aimer.aim(targets, REFLECTOR + [0.1, -0.05, 0.05], Q0)
    r = a.robot_beam_readings(small_truth, hit.commands_deg, dirs, LASER, REFLECTOR, 100.0, options=EXACT)
    assert r.valid.all() and r.miss_mm.max() < 0.5
    origin, _ = a.tool_frame_line(small_truth, hit.commands_deg, dirs, LASER.origin_mm, LASER.direction)
    dist = np.linalg.norm(REFLECTOR - origin, axis=1) - 100.0
    assert np.all(r.reading_mm <= dist) and np.all(dist - r.reading_mm < 1e-3)  # cosine error only
    miss = aimer.aim(targets, REFLECTOR + [3.0, 0.0, 0.0], Q0)
    r = a.robot_beam_readings(large_truth, miss.commands_deg, dirs, LASER, REFLECTOR, 100.0, options=EXACT)
    assert r.valid.mean() < 0.2
    assert np.array_equal(r.valid, r.miss_mm <= 1.0)


# ---------------------------------------------------------- initial estimates
def test_reflector_search_estimate_within_search_resolution(chain, aimer, small_truth):
    """Perfect robot: every hitting line passes within half a fine step diagonal (0.05/√2 mm) of
    the truth, so the intersection is within that times the lines' dilution; a robot with small
    errors adds its own error (< 0.5 mm). A guess 10 mm off, six spread search positions."""
    guess = REFLECTOR + [8.0, -5.0, 3.0]
    pts = np.array([[150.0, -250.0, 250.0], [550.0, -200.0, 300.0], [150.0, 450.0, 250.0],
                    [300.0, 150.0, 450.0], [600.0, 350.0, 100.0], [350.0, -50.0, 0.0]])
    step = 0.05
    exact = a.search_reflector(a.nominal_robot(chain, TOOL), aimer, pts, guess, REFLECTOR, Q0,
                               fine_step_mm=step, seed=1)
    _, true_miss = a.beam_geometry_3d(exact.origins_mm, exact.directions, np.tile(REFLECTOR, (6, 1)))
    assert true_miss.max() <= step / np.sqrt(2)
    assert exact.dilution < 3.0
    assert np.linalg.norm(exact.estimate_mm - REFLECTOR) < step / np.sqrt(2) * exact.dilution
    real = a.search_reflector(small_truth, aimer, pts, guess, REFLECTOR, Q0, fine_step_mm=step, seed=1)
    assert np.linalg.norm(real.estimate_mm - REFLECTOR) < 0.5
    assert not np.allclose(real.estimate_mm, exact.estimate_mm, atol=1e-3)  # the robot error shows


def test_reflector_search_refuses_when_nothing_returns(chain, aimer):
    with pytest.raises(ValueError, match="no return at search position 0"):
        a.search_reflector(a.nominal_robot(chain, TOOL), aimer, _targets(3, 4), REFLECTOR + [40.0, 0, 0],
                           REFLECTOR, Q0, search_radius_mm=10.0)


def test_parallel_lines_refused():
    with pytest.raises(ValueError, match="parallel"):
        a.intersect_lines(np.array([[0.0, 0, 0], [1.0, 0, 0]]), np.array([[0.0, 0, 1], [0.0, 0, 1]]))


@pytest.mark.parametrize("robot_kind, centre_tol, zero_tol", [("nominal", 0.03, 0.005), ("small", 0.15, 0.005)])
def test_pan_tilt_station_estimate(chain, small_truth, robot_kind, centre_tol, zero_tol):
    """001 §2.2 in 3D: centre (mm) and zero angles (deg) from 12 targets, head error 2 mdeg,
    search grid 1 mdeg; within the stated tolerance of the truth from a guess 17 mm / 3 deg off."""
    robot = a.nominal_robot(chain, TOOL) if robot_kind == "nominal" else small_truth
    head = a.PanTiltHeads([[1200.0, 300.0, -200.0]], [[3.0, -1.0]])
    guess = a.PanTiltHeads([[1190.0, 310.0, -190.0]], [[0.0, 0.0]])
    cmds = chain.random_angles(12, 5)
    commanded = chain.positions(cmds, chain.nominal_parameters(TOOL))
    est = a.estimate_pan_tilt_station(robot, cmds, np.ones_like(cmds), commanded, head, guess, 300.0,
                                      head_error=a.harmonic_head_error(2, 2.0),
                                      options=InterferometerOptions(beam_loss=False), seed=3)
    assert np.linalg.norm(est.centre_mm - head.centres_mm[0]) < centre_tol
    assert np.abs(est.zeros_deg - head.zeros_deg[0]).max() < zero_tol
    assert abs(est.dead_path_mm - 300.0) < centre_tol


def test_tool_frame_points_of_an_identified_model(chain):
    """The robot protocol also takes SerialPositionModel.with_vector(x): the tool-frame point at
    the model's tool offset is the model's own tool point (maps and location errors applied)."""
    from olti_drake.model.serial import build_position_model

    cmds = chain.random_angles(50, 7)
    dirs = np.where(np.random.default_rng(7).random(cmds.shape) < 0.5, -1.0, 1.0)
    model = build_position_model(chain, cmds, dirs, tool_offset_mm=(40.0, -25.0, 60.0))
    x = model.start_vector() + np.random.default_rng(8).normal(0, 0.01, model.n_params)
    fitted = model.with_vector(x)
    tool = fitted.chain_params[-3:]
    pts = a.tool_frame_points(fitted, cmds, dirs, tool[None])
    assert np.abs(pts[:, 0] - model.positions(cmds, dirs, x)).max() < 1e-9
