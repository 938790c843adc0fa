"""Drake-native systems (issue 12.4): scalar conversion, Parameters in the Context, readings in the
Context (two Simulators on one diagram), default names."""

import dataclasses

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd, InitializeAutoDiff
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import Diagram

from olti_drake.model.errormap import ErrorMap, HarmonicDeviation
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.sim.campaign import build_campaign_diagram, prepare, run_campaign
from olti_drake.sim.scenario import ExactEstimate, Scenario
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
    from olti_drake.model.instrument import beam_command_deg

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


# -- the kinematic station: readings differentiable with respect to the map nodes (issue 12) -------------------
GRID1, GRID2 = np.array([-40.0, -30.0, -20.0, -10.0, 0.0]), np.array([40.0, 55.0, 70.0, 85.0, 100.0])
#: (θ1*, θ2* deg, dir1, dir2): commands between nodes (and one on a node), all four direction pairs.
POSES = [(-25.0, 61.0, 1.0, 1.0), (-12.5, 72.0, -1.0, 1.0), (-3.0, 95.0, 1.0, -1.0), (-33.0, 47.0, -1.0, -1.0),
         (-20.0, 88.0, 1.0, 1.0)]


def _map_truth_setup(**interferometer):
    """A scenario whose J1/J2 truth is a piecewise-linear map on the identifier's grids (the model family)."""
    rng = np.random.default_rng(12)
    s = _small(**interferometer)
    s.reflector_estimate = ExactEstimate()   # no search: its poses lie outside these grids
    s.robot.J1, s.robot.J2 = (ErrorMap(g, 0.01 * rng.standard_normal(g.size), 0.01 * rng.standard_normal(g.size),
                                       axis) for g, axis in ((GRID1, "J1"), (GRID2, "J2")))
    return prepare(s)


def _station(setup, geometry):
    from pydrake.systems.framework import DiagramBuilder

    from olti_drake.sim.campaign import AddSimulatedStation

    builder = DiagramBuilder()
    AddSimulatedStation(builder, setup, geometry=geometry)
    return builder.Build()


def _read(diagram, pose, j, theta4_deg=0.0, seed_maps=None):
    """Displacement output (m, float or AutoDiffXd) of the diagram's station at ``pose`` (see POSES), reflector j.

    The joints' state says the command was approached in the pose's directions (last command 5 deg before).
    ``seed_maps`` (AutoDiffXd diagram): indices into the J1 then J2 node values [J1 f, J1 r, J2 f, J2 r] (the
    identifier's order) that are the AutoDiff variables, derivative seed 1, in that order.
    """
    station = diagram.GetSubsystemByName("station")
    joints = station.GetSubsystemByName("error_map_joint")
    ctx = diagram.CreateDefaultContext()
    jctx = joints.GetMyContextFromRoot(ctx)
    t1, t2, d1, d2 = pose
    cmd_deg = np.array([t1, t2, 0.0, theta4_deg])
    dirs = np.array([d1, d2, 1.0, 1.0])
    T = float if seed_maps is None else AutoDiffXd
    scalar = (lambda v: np.asarray(v, dtype=float)) if T is float else (lambda v: [AutoDiffXd(x) for x in v])
    jctx.SetDiscreteState(scalar(np.concatenate([cmd_deg - 5.0 * dirs, dirs])))
    if T is AutoDiffXd:
        values = [[v.value() for v in joints.GetMapValues(jctx, axis)] for axis in (0, 1)]
        flat = np.concatenate(values)
        seed = np.zeros((flat.size, len(seed_maps)))
        seed[np.asarray(seed_maps), np.arange(len(seed_maps))] = 1.0
        ad = [AutoDiffXd(v, row) for v, row in zip(flat, seed)]
        joints.SetMapValues(jctx, 0, ad[:len(values[0])])
        joints.SetMapValues(jctx, 1, ad[len(values[0]):])
    sctx = station.GetMyContextFromRoot(ctx)
    station.GetInputPort("joint_command").FixValue(sctx, scalar(np.radians(cmd_deg) * [1, 1, 0, 1]))
    station.GetInputPort("reflector").FixValue(sctx, scalar([j]))
    assert T is float or isinstance(station.GetOutputPort("displacement").Eval(sctx)[0], AutoDiffXd)
    return station.GetOutputPort("displacement").Eval(sctx)[0]


@pytest.mark.parametrize("options", [dict(noise=False, quantization=False), dict(beam_loss=False)])
def test_kinematic_station_reads_as_the_geometry_station(options):
    setup = _map_truth_setup(**options)
    geometric, kinematic = _station(setup, True), _station(setup, False)
    assert not kinematic.GetSubsystemByName("station").HasOutputPort("query_object")   # no SceneGraph
    for pose in POSES:
        for j in range(len(setup.reflectors_mm)):
            a, b = (1e3 * _read(d, pose, j, theta4_deg=17.0) for d in (geometric, kinematic))
            assert b == pytest.approx(a, abs=1e-9)  # mm


def test_station_autodiff_reading_derivative_equals_identifier_jacobian():
    """d(reading)/d(map node) through ``ToAutoDiffXd()`` of the station = the Identifier's Jacobian entry (Eq. 10).

    r = model − reading, so the model's derivative dr/dx (mm/deg) is the reading's derivative with respect to
    the truth's node; the port is m and the node deg, hence 1e3. Cosine error, noise, quantization, beam loss
    off: the reading is ‖p − P_j‖ − d0_j, the identifier's model family.
    """
    from olti_drake.estimation.identification import IdentificationOptions, Identifier
    from olti_drake.io.csvio import CampaignData
    from olti_drake.model.scara import JointCommands

    setup = _map_truth_setup(noise=False, quantization=False, cosine_error=False, beam_loss=False)
    ad = _station(setup, False).ToAutoDiffXd()
    n_t = len(setup.reflectors_mm)
    rows = [(pose, j) for j in range(n_t) for pose in POSES]
    n_nodes = 2 * (GRID1.size + GRID2.size)
    readings = [_read(ad, pose, j, seed_maps=np.arange(n_nodes)) for pose, j in rows]
    reading_mm = np.array([1e3 * r.value() for r in readings])
    dreading = np.array([1e3 * r.derivatives() for r in readings])   # mm/deg, [J1 f, J1 r, J2 f, J2 r]
    p = np.array([pose for pose, _ in rows])
    data = CampaignData(np.array([j for _, j in rows]), JointCommands(p[:, 0], p[:, 1], p[:, 2], p[:, 3]),
                        reading_mm, np.arange(len(rows)) + 2, "station")
    ident = Identifier(data, IdentificationOptions(grid1_deg=GRID1, grid2_deg=GRID2,
                                                   nominal_L1_mm=setup.scenario.robot.L1_mm,
                                                   nominal_L2_mm=setup.scenario.robot.L2_mm))
    r = setup.scenario.robot
    x_true = np.concatenate([[r.L1_mm, r.L2_mm], r.J1.values, r.J2.values, setup.reflectors_mm.ravel(),
                             setup.dead_paths_mm])
    residual, jac = ident.residuals(x_true)
    np.testing.assert_allclose(residual, 0.0, atol=1e-9)   # the same model: the truth fits the readings exactly
    nodes = [ident.names.index(f"{a}_{b}_deg[{k}]") for a, g in (("J1", GRID1), ("J2", GRID2))
             for b in ("forward", "reverse") for k in range(g.size)]
    expected = jac.toarray()[:, nodes]
    assert np.count_nonzero(expected) >= 2 * len(rows)   # every reading touches nodes of both axes
    np.testing.assert_allclose(dreading, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    # One node alone as the variable: J2 reverse node 0 (40 deg) of POSES[3] (J2 = 47 deg approached in -1).
    k = GRID1.size * 2 + GRID2.size
    alone = _read(ad, POSES[3], 0, seed_maps=[k])
    assert alone.derivatives().shape == (1,)
    assert 1e3 * alone.derivatives()[0] == pytest.approx(expected[3, k], rel=1e-9) and expected[3, k] != 0.0


def test_kinematic_station_runs_the_campaign_of_the_geometry_station():
    """Whole campaign (noise on, same seed): the kinematic station's readings are the geometry station's."""
    from olti_drake.sim.campaign import AddSimulatedStation

    setup = prepare(_small(quantization=False))   # quantization off: a 1e-16 m pose difference could flip a count
    geometric = run_campaign(setup).columns
    kinematic = run_campaign(setup, station_factory=lambda b, s: AddSimulatedStation(b, s, geometry=False)).columns
    assert np.isfinite(geometric["displacement_mm"]).sum() > 0
    np.testing.assert_array_equal(kinematic["valid"], geometric["valid"])
    np.testing.assert_allclose(kinematic["displacement_mm"], geometric["displacement_mm"], rtol=0, atol=1e-9)
