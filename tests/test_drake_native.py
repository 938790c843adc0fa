"""Drake-native systems (issue 12.4): scalar conversion, Parameters in the Context, readings in the
Context (two Simulators on one diagram), default names."""

import dataclasses

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd, InitializeAutoDiff
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram

from olti_drake.model.errormap import ErrorMap, HarmonicDeviation
from olti_drake.model.interferometer import InterferometerOptions
from olti_drake.sim.campaign import build_campaign_diagram, prepare, run_campaign
from olti_drake.sim.scenario import Scenario
from olti_drake.sim.systems import BeamSteering, CampaignRecorder, ErrorMapJoint, ErrorMapJoint_, PlanSequencer

GRID = np.array([-10.0, 0.0, 10.0, 20.0])
MAP = ErrorMap(GRID, [0.001, 0.002, -0.001, 0.0], [0.003, 0.0, 0.001, 0.002], "J1")


def _small(**interferometer):
    s = Scenario(interferometer=InterferometerOptions(**interferometer))
    s.plan = dataclasses.replace(s.plan, theta1_start=-40.0, theta1_stop=0.0, theta2_start=40.0,
                                 theta2_stop=100.0, theta2_step=30.0)
    return s


def _position(system, context, theta_deg):
    system.get_input_port(0).FixValue(context, np.radians(theta_deg))
    return system.GetOutputPort("position").Eval(context)


@pytest.mark.parametrize("theta, direction", [(4.0, 1.0), (4.0, -1.0), (17.5, 1.0), (-10.0, -1.0)])
def test_autodiff_position_derivative_wrt_map_nodes_is_the_map_jacobian(theta, direction):
    joint = ErrorMapJoint([MAP, None], revolute=[True, True], initial_direction=direction)
    ad = joint.ToAutoDiffXd()
    assert isinstance(ad, ErrorMapJoint_[AutoDiffXd])
    ctx = ad.CreateDefaultContext()
    ad.SetMapValues(ctx, 0, InitializeAutoDiff(MAP.values).ravel())
    # Approach from beyond the command in the given direction, so the direction is as planned.
    ad.get_input_port(0).FixValue(ctx, [AutoDiffXd(np.radians(theta)), AutoDiffXd(0.0)])
    if direction < 0:
        ctx.SetDiscreteState(np.array([AutoDiffXd(v) for v in (theta + 5.0, 0.0, -1.0, 1.0)]))
    out = ad.GetOutputPort("position").Eval(ctx)
    expected = np.radians(MAP.weights([theta], [direction]).toarray()[0])  # dθ/d node, rad/deg
    np.testing.assert_allclose(out[0].derivatives(), expected, rtol=1e-12, atol=1e-15)
    assert out[0].value() == pytest.approx(np.radians(theta + MAP([theta], [direction])[0]), abs=1e-15)
    assert not np.any(out[1].derivatives())


def test_map_parameter_lives_in_the_context_and_moves_the_position_as_numpy_predicts():
    joint = ErrorMapJoint([MAP, HarmonicDeviation(), None], revolute=[True, True, False])
    a, b = joint.CreateDefaultContext(), joint.CreateDefaultContext()
    np.testing.assert_array_equal(joint.GetMapValues(a, 0), MAP.values)
    new = MAP.values + np.linspace(0.001, 0.008, 8)
    joint.SetMapValues(b, 0, new)
    command = np.array([7.0, 3.0, 0.0])
    pa, pb = _position(joint, a, command), _position(joint, b, command)
    assert np.degrees(pa[0]) == pytest.approx(7.0 + MAP([7.0], [1.0])[0], abs=1e-12)
    assert np.degrees(pb[0]) == pytest.approx(7.0 + MAP.with_values(new)([7.0], [1.0])[0], abs=1e-12)
    assert pa[1] == pb[1] and pa[2] == pb[2]   # other axes: no parameter, unchanged
    np.testing.assert_array_equal(joint.GetMapValues(a, 0), MAP.values)   # the other context is untouched


def test_two_simulators_on_one_diagram_give_the_same_readings_not_twice_as_many():
    setup = prepare(_small())
    diagram, rec, seq = build_campaign_diagram(setup)
    sims = [Simulator(diagram), Simulator(diagram)]
    for sim in sims:
        sim.AdvanceTo(seq.duration_s)
    a, b = (rec.GetReadings(sim.get_context()) for sim in sims)
    n_measured = int(np.sum(setup.plan.measure)) * len(setup.reflectors_mm)
    assert len(a) == len(b) == n_measured > 0
    np.testing.assert_array_equal(np.array(a, dtype=float), np.array(b, dtype=float))
    # ... and equal to a campaign run on its own diagram (same seed, same noise).
    np.testing.assert_array_equal(np.array(a, dtype=float)[:, 5],
                                  run_campaign(setup).columns["displacement_mm"])


def _names(diagram, prefix=""):
    out = []
    for system in diagram.GetSystems():
        out.append(prefix + system.get_name())
        if isinstance(system, Diagram):
            out += _names(system, prefix + system.get_name() + "/")
    return out


def test_systems_have_default_names():
    assert ErrorMapJoint([None], [True]).get_name() == "error_map_joint"
    assert ErrorMapJoint([None], [True]).ToAutoDiffXd().get_name() == "error_map_joint"
    assert BeamSteering(325.0, 225.0, [[600.0, 0.0]], 0.0).get_name() == "beam_steering"
    assert CampaignRecorder(1.0).get_name() == "campaign_recorder"
    assert PlanSequencer([0.0], [0.0], [True], 1, 1.0).get_name() == "plan_sequencer"
    diagram, _, _ = build_campaign_diagram(prepare(_small()))
    names = _names(diagram)
    assert "station/error_map_joint" in names and "station/laser_interferometer" in names
    assert not [n for n in names if "@" in n], names   # no unnamed (address-named) system


def test_reflector_estimates_and_dead_paths_are_context_parameters():
    from olti_drake.model.steering import beam_command_deg

    setup = prepare(_small(quantization=False))
    diagram, rec, seq = build_campaign_diagram(setup)
    steer = diagram.GetSubsystemByName("beam_steering")
    laser = diagram.station.GetSubsystemByName("laser_interferometer")
    ctx = diagram.CreateDefaultContext()
    steer_ctx, laser_ctx = steer.GetMyContextFromRoot(ctx), laser.GetMyContextFromRoot(ctx)
    P, theta40 = steer.GetReflectorEstimates(steer_ctx)
    np.testing.assert_array_equal(P, setup.reflectors_estimate_mm)
    np.testing.assert_array_equal(laser.GetDeadPaths(laser_ctx), setup.dead_paths_mm)
    before = laser.GetOutputPort("displacement").Eval(laser_ctx)[0]
    laser.SetDeadPaths(laser_ctx, setup.dead_paths_mm + 1.0)   # 1 mm more dead path: 1 mm less reading
    assert laser.GetOutputPort("displacement").Eval(laser_ctx)[0] == pytest.approx(before - 1e-3, abs=1e-12)
    moved = setup.reflectors_estimate_mm + [[5.0, -3.0]]
    steer.SetReflectorEstimates(steer_ctx, moved, theta40 + 0.5)
    t1, t2 = np.degrees(steer.get_input_port(0).Eval(steer_ctx))
    r = setup.scenario.robot
    expected = beam_command_deg(t1, t2, moved[0], r.nominal_L1_mm, r.nominal_L2_mm, theta40 + 0.5)
    assert np.degrees(steer.GetOutputPort("joint_command").Eval(steer_ctx)[3]) == pytest.approx(
        float(np.ravel(expected)[0]), abs=1e-9)
    # A fresh context has the defaults again: the parameters are per context, not on the system.
    np.testing.assert_array_equal(steer.GetReflectorEstimates(
        steer.GetMyContextFromRoot(diagram.CreateDefaultContext()))[0], setup.reflectors_estimate_mm)


def test_record_log_copies_share_storage_and_fork_on_a_divergent_append():
    """The recorders' abstract state: copying is O(1) (Drake deep-copies Python state on every update),
    yet each copy keeps its own records: an append to an older copy forks instead of leaking."""
    import copy

    from olti_drake.sim.systems import RecordLog

    a = RecordLog().appended((1,)).appended((2,))
    b = copy.deepcopy(a)
    assert b._items is a._items and list(b) == [(1,), (2,)]
    a2 = a.appended((3,))           # the tip extends the shared list in place
    b2 = b.appended((4,))           # b is no longer the tip: it forks
    assert list(a2) == [(1,), (2,), (3,)] and list(b2) == [(1,), (2,), (4,)]
    assert list(a) == list(b) == [(1,), (2,)] and len(a) == 2 and a[-1] == (2,) and a[0:1] == [(1,)]
    with pytest.raises(IndexError):
        a[2]
