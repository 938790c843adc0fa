import numpy as np
import pytest
from pydrake.common.yaml import yaml_load_typed
from pydrake.systems.analysis import Simulator

from olti_drake.model.scara import DEG, PAPER_L1_MM as L1, PAPER_L2_MM as L2, forward_kinematics
from olti_drake.sim.tracker import LaserTracker, LaserTrackerSpec, measure_positions, path_commands


def test_noise_statistics_match_spec():
    spec = LaserTrackerSpec()
    for p in ([200.0, 0.0], [200.0, 500.0]):
        d_m = np.hypot(p[0] + 1500.0, p[1]) * 1e-3
        u_mm = (15.0 + 6.0 * d_m) / (2.0 * np.sqrt(3.0)) * 1e-3
        pts = np.tile(p, (20000, 1))
        err = measure_positions(pts, spec, np.random.default_rng(5)) - pts
        np.testing.assert_allclose(err.std(axis=0), u_mm, rtol=0.1)
        assert np.all(np.abs(err.mean(axis=0)) < 0.05 * u_mm)
    a = measure_positions(pts, spec, 3)
    np.testing.assert_array_equal(a, measure_positions(pts, spec, 3))  # seeded


def test_zero_spec_gives_exact_positions():
    spec = LaserTrackerSpec(u_const_um=0.0, u_per_m_um=0.0)
    p = np.array([[100.0, -300.0], [400.0, 50.0]])
    np.testing.assert_array_equal(measure_positions(p, spec, 1), p)
    with pytest.raises(ValueError, match="coverage_k"):
        measure_positions(p, LaserTrackerSpec(coverage_k=0.0), 1)


def test_spec_loads_from_yaml():
    spec = yaml_load_typed(schema=LaserTrackerSpec, data="position_mm: [-1000.0, 200.0]\nu_const_um: 10.0\n")
    assert spec.position_mm == [-1000.0, 200.0] and spec.u_const_um == 10.0 and spec.coverage_k == 2.0


def test_path_commands_directions_and_positions():
    y = np.linspace(-500.0, 500.0, 21)
    x = np.full_like(y, 200.0)
    t1, t2, d1, d2 = path_commands(x, y, L1, L2)
    n = y.size
    assert t1.size == 2 * n
    p, _ = forward_kinematics(t1, t2, L1, L2)
    np.testing.assert_allclose(p, np.concatenate([np.stack([x, y], 1), np.stack([x, y], 1)[::-1]]),
                               atol=1e-9)
    for q, d in ((t1, d1), (t2, d2)):
        for s in (slice(0, n), slice(n, 2 * n)):  # forward pass, return pass
            qs, ds = q[s], d[s]
            motion = np.sign(np.diff(qs))
            assert np.all(motion != 0)
            np.testing.assert_array_equal(ds[1:], motion)
            assert ds[0] == motion[0]  # the overrun makes the first approach follow the pass
    # a straight Cartesian path reverses both joints mid-way, so directions are per axis
    assert len(set(d1[:n])) == 2 and len(set(d2[:n])) == 2
    t1f, _, _, _ = path_commands(x, y, L1, L2, bidirectional=False)
    assert t1f.size == n


def _tracker_context(tracker, q_rad):
    ctx = tracker.CreateDefaultContext()
    tracker.get_input_port(0).FixValue(ctx, q_rad)
    return ctx


def test_laser_tracker_system_reproducible_and_updates():
    spec = LaserTrackerSpec()
    q = np.array([30.0, 60.0]) * DEG
    tr = LaserTracker(spec, L1, L2, seed=11)
    ctx = _tracker_context(tr, q)
    out = tr.GetOutputPort("position")
    y0 = out.Eval(ctx).copy()
    np.testing.assert_array_equal(out.Eval(ctx), y0)
    # same seed and counter in another instance -> same reading
    tr2 = LaserTracker(spec, L1, L2, seed=11)
    np.testing.assert_array_equal(tr2.GetOutputPort("position").Eval(_tracker_context(tr2, q)), y0)
    p, _ = forward_kinematics([30.0], [60.0], L1, L2)
    assert np.linalg.norm(y0 * 1e3 - p[0]) < 0.05  # metres on the port, tens of µm noise
    sim = Simulator(tr, ctx)
    sim.AdvanceTo(0.5)  # periodic update at t = 0
    assert ctx.get_discrete_state(0).value()[0] == 1
    y1 = out.Eval(ctx).copy()
    assert not np.array_equal(y1, y0)
    np.testing.assert_array_equal(out.Eval(ctx), y1)
    exact = LaserTracker(LaserTrackerSpec(u_const_um=0.0, u_per_m_um=0.0), L1, L2, seed=0)
    np.testing.assert_allclose(exact.GetOutputPort("position").Eval(_tracker_context(exact, q)),
                               p[0] * 1e-3, atol=1e-15)
