"""Plan design for N-joint robots (olti_drake.estimation.serial_plan): coverage per joint and
direction recounted from the returned plan, limits, line of sight and acceptance checked
independently, travel ordering, and the linear-method report (identifiable / named not)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import olti_drake
from olti_drake.model.errormap import approach_directions
from olti_drake.estimation import serial_plan as sp
from olti_drake.model import aiming3d as a
from olti_drake.model.chain import load_serial_chain

UR5 = Path(olti_drake.__file__).parent / "models" / "ur5.urdf"
TOOL = (40.0, -25.0, 60.0)
RANGES = np.array([[-100.0, 80.0], [-170.0, -10.0], [-120.0, 120.0], [-90.0, 90.0], [-60.0, 150.0],
                   [-180.0, 180.0]])
STATIONS = np.array([[1300.0, 0.0, -300.0], [0.0, 1300.0, -300.0], [-1300.0, 0.0, -300.0], [0.0, -1300.0, -300.0]])
RULES = sp.PlanRules(step_deg=20.0, ranges_deg=RANGES, floor_z_mm=-350.0)
U_MM = 0.0158


@pytest.fixture(scope="module")
def chain():
    return load_serial_chain(UR5, "tool0")


@pytest.fixture(scope="module")
def plan(chain):
    return sp.generate_plan(chain, STATIONS, RULES, tool_offset_mm=TOOL, seed=1)


@pytest.fixture(scope="module")
def report(chain, plan):
    return sp.plan_report(chain, plan, STATIONS, U_MM, tool_offset_mm=TOOL)


def test_coverage_per_joint_and_direction_as_reported(plan, report):
    """Directions recomputed from the robot's motion sequence by the formats.md rule; counts of
    readings per (joint, node, direction) recounted by loops; every pair has ≥ poses_per_node ×
    min_stations readings; the report shows the same counts."""
    seq = plan.motion_sequence()
    dirs = approach_directions(seq, last_direction=1.0)[1::2]
    assert np.array_equal(dirs, plan.dirs)
    pose, station = plan.readings()
    assert len(pose) == plan.visible.sum() and np.all(plan.visible[pose, station])
    for i, name in enumerate(plan.joint_names):
        grid = plan.grids[name]
        assert np.all(np.isin(plan.commands_deg[:, i], grid))  # every pose on a node
        counts = np.zeros((grid.size, 2), int)
        for k in pose:
            node = int(np.flatnonzero(grid == plan.commands_deg[k, i])[0])
            counts[node, 0 if plan.dirs[k, i] > 0 else 1] += 1
        assert np.array_equal(counts, plan.coverage()[name])
        assert np.array_equal(counts, report.coverage[name])
        assert counts.min() >= RULES.poses_per_node * RULES.min_stations
        assert grid[0] >= RANGES[i, 0] and grid[-1] <= RANGES[i, 1] and np.all(np.diff(grid) == 20.0)
    assert any(f"{name}: {plan.grids[name].size} nodes" in line for line in report.lines()
               for name in plan.joint_names)


def test_limits_respected_by_poses_and_approach_moves(chain, plan):
    seq = plan.motion_sequence()
    assert np.all(seq >= chain.lower_deg) and np.all(seq <= chain.upper_deg)
    assert np.all(plan.commands_deg >= RANGES[:, 0]) and np.all(plan.commands_deg <= RANGES[:, 1])


def test_every_reading_in_line_of_sight_and_acceptance(chain, plan):
    """Checked independently: the viewing angle from the tool frame of aiming3d, the line of sight
    by sampling the beam densely against the capsules (point-to-segment distances)."""
    robot = a.nominal_robot(chain, TOOL)
    pose, station = plan.readings()
    cmd = plan.commands_deg[pose]
    pts = a.tool_frame_points(robot, cmd, None, np.vstack([TOOL, np.add(TOOL, RULES.catseye_axis_tool)]))
    tip, axis = pts[:, 0], pts[:, 1] - pts[:, 0]
    beam = tip - STATIONS[station]
    unit = beam / np.linalg.norm(beam, axis=1, keepdims=True)
    assert np.all(np.degrees(np.arccos(np.sum(axis * -unit, axis=1))) <= 80.0 + 1e-9)
    links = sp.link_points(chain, cmd, TOOL)
    assert np.allclose(links[:, -1], tip, atol=1e-9)
    for s in np.linspace(0.0, 1.0, 400):
        p = STATIONS[station] + s * (beam - RULES.clearance_mm * unit)
        a0, b0 = links[:, :-1], links[:, 1:]
        d = b0 - a0
        t = np.clip(np.sum((p[:, None] - a0) * d, -1) / np.maximum(np.sum(d * d, -1), 1e-12), 0, 1)
        dist = np.linalg.norm(p[:, None] - a0 - t[..., None] * d, axis=-1).min(axis=1)
        assert dist.min() > RULES.link_radius_mm - 0.5  # sampling step along ≤ 4 mm


def test_segment_distance_against_brute_force():
    rng = np.random.default_rng(2)
    p0, p1, q0, q1 = (rng.normal(size=(200, 3)) for _ in range(4))
    q1[:20] = q0[:20]  # degenerate segments (points)
    p1[20:30] = p0[20:30]
    p1[30:35], q1[30:35] = p0[30:35], q0[30:35]
    p1[35:45] = p0[35:45] + 2 * (q1[35:45] - q0[35:45])  # parallel
    s = np.linspace(0, 1, 401)
    brute = np.array([np.linalg.norm((p0[k] + s[:, None] * (p1[k] - p0[k]))[:, None]
                                     - (q0[k] + s[:, None] * (q1[k] - q0[k]))[None], axis=-1).min()
                      for k in range(200)])
    exact = sp.segment_distance(p0, p1, q0, q1)
    assert np.all(exact <= brute + 1e-12) and np.all(brute - exact < 1e-2)


def test_ordering_shorter_than_random_orders(plan):
    rng = np.random.default_rng(5)
    random_travel = [np.linalg.norm(np.diff(plan.commands_deg[rng.permutation(len(plan.commands_deg))], axis=0),
                                    axis=1).sum() for _ in range(20)]
    assert plan.travel_deg() < 0.6 * min(random_travel)


def test_report_identifiable_plan(report, plan):
    assert report.identifiable and report.rank == report.n_params and np.isfinite(report.condition)
    for name in plan.joint_names:
        umax, umed = report.node_uncertainty_deg[name]
        assert 0 < umed <= umax < 1.0  # deg, finite


def test_more_poses_lower_the_predicted_uncertainty(chain, report):
    denser = sp.generate_plan(chain, STATIONS, dataclasses.replace(RULES, poses_per_node=6),
                              tool_offset_mm=TOOL, seed=1)
    better = sp.plan_report(chain, denser, STATIONS, U_MM, tool_offset_mm=TOOL)
    for name, (umax, umed) in report.node_uncertainty_deg.items():
        assert better.node_uncertainty_deg[name][1] < umed


def test_degenerate_plan_reported_unidentifiable_by_name(chain, plan):
    """The elbow never moved (held at 0 deg): its map nodes and the location errors it would
    separate are named, the node uncertainties are inf, the condition number inf."""
    cmd = plan.commands_deg.copy()
    cmd[:, 2] = 0.0
    bad = sp.plan_report(chain, dataclasses.replace(plan, commands_deg=cmd), STATIONS, U_MM, tool_offset_mm=TOOL)
    assert not bad.identifiable and bad.rank < bad.n_params and bad.condition == np.inf
    assert "elbow_joint_forward_deg[3]" in bad.unidentifiable and "elbow_joint_reverse_deg[0]" in bad.unidentifiable
    assert bad.node_uncertainty_deg["elbow_joint"][0] == np.inf
    assert bad.coverage["elbow_joint"][:, 0].sum() == 0 or bad.coverage["elbow_joint"].min() == 0
    assert any(line.startswith("unidentifiable: ") and "elbow_joint" in line for line in bad.lines())
    assert not any(n.startswith("wrist_1_joint_forward") for n in bad.unidentifiable)


def test_unreadable_layout_refused_by_joint_and_node(chain):
    hidden = np.array([[0.0, 0.0, 10.0], [0.0, 0.0, 20.0]])  # inside the base capsule
    with pytest.raises(ValueError, match=r"plan: joint shoulder_pan_joint node -?\d+ deg direction [+-]1 not covered"):
        sp.generate_plan(chain, hidden, dataclasses.replace(RULES, max_batches=3), tool_offset_mm=TOOL)


def test_empty_range_refused(chain):
    ranges = RANGES.copy()
    ranges[2] = [200.0, 210.0]  # beyond the elbow's ±180 limit
    with pytest.raises(ValueError, match="plan range of elbow_joint: empty"):
        sp.plan_ranges(chain, dataclasses.replace(RULES, ranges_deg=ranges))


def test_report_names_a_map_the_readings_cannot_see(chain, plan):
    """Tool point on the last joint's axis: no reading depends on wrist_3's angle; the report says
    its map is not in the model (with the reason), instead of a silent gap."""
    rep = sp.plan_report(chain, plan, STATIONS, U_MM, tool_offset_mm=(0.0, 0.0, 60.0))
    assert "wrist_3_joint" not in rep.node_uncertainty_deg
    assert any(line.startswith("not in the model: wrist_3_joint error map (no reading depends on it")
               for line in rep.lines())
