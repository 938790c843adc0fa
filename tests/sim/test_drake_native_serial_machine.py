"""Drake-native systems of the six-axis robot and the 3D machine tool (issue 22 item 4), as the SCARA's
(tests/sim/test_drake_native.py): public and named, scalar-convertible with the identified quantities as numeric
Parameters of the Context, a reading's AutoDiffXd derivative equal to the identification's Jacobian entry,
the tabulated truth a Parameter; the campaigns they run are those the numpy twins read
(tests/sim/test_six_axis.py, tests/sim/test_machine3d_diagram.py, tests/report/test_diagrams.py)."""

import dataclasses
import os

import numpy as np
import pytest
from pydrake.autodiffutils import AutoDiffXd
from pydrake.systems.framework import Diagram, DiagramBuilder

from olti_drake.model.errormap import ErrorMap, HarmonicDeviation
from olti_drake.model.instrument import InterferometerOptions
from olti_drake.sim import systems

#: The identification's model family: no cosine error, noise, quantization or beam loss (the reading is
#: ‖p − P_j‖ − d0_j, 000 Eq. (10) in 3D, 001 Eq. (3)).
EXACT = InterferometerOptions(noise=False, quantization=False, cosine_error=False, beam_loss=False)
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SIX_AXIS = os.path.join(ROOT, "diagrams", "six_axis.yaml")
SMALL = "{plan: {step_deg: 30.0, poses_per_node: 1}}"


def _names(diagram, prefix=""):
    """(path name, system) of every system of ``diagram``, sub-diagrams' systems included."""
    out = []
    for system in diagram.GetSystems():
        out.append((prefix + system.get_name(), system))
        if isinstance(system, Diagram):
            out += _names(system, prefix + system.get_name() + "/")
    return out


def _seeded(values, seeds):
    """AutoDiffXd copies of ``values`` (flat): entry ``i`` of ``seeds`` {index: derivative slot} gets the unit
    derivative of its slot, the others zero derivatives; the slot count is ``seeds.n``."""
    flat = np.ravel(np.asarray(values, float))
    out = []
    for i, v in enumerate(flat):
        d = np.zeros(seeds.n)
        if i in seeds:
            d[seeds[i]] = 1.0
        out.append(AutoDiffXd(v, d))
    return np.array(out, dtype=object)


def _assert_columns_close(got, expected, names, rtol=1e-9):
    """Each column (one parameter) equal to ``rtol`` of its own largest entry: mm/deg, mm/mm and mm/µrad
    columns differ by orders of magnitude, so one tolerance for all would not test the small ones."""
    for k, name in enumerate(names):
        scale = np.abs(expected[:, k]).max()
        np.testing.assert_allclose(got[:, k], expected[:, k], rtol=rtol, atol=rtol * scale, err_msg=name)


class _Seeds(dict):
    def __init__(self, items, n):
        super().__init__(items)
        self.n = n


# ------------------------------------------------------------------ (a) public, named, subclassable
def test_systems_are_public_and_diagrams_show_their_class_names():
    from olti_drake.sim import machine3d_station as m3, serial_station as ss
    from olti_drake.sim.serial_scenario import load_serial_scenario

    public = ("PanTiltSteering", "SerialLaserInterferometer", "SerialLaserInterferometer_", "SerialCampaignRecorder",
              "VolumetricTool", "VolumetricTool_", "PanTiltInterferometer", "PanTiltInterferometer_",
              "Machine3DRecorder", "AddPanTiltSteering", "AddSerialInterferometer")
    for name in public:
        obj = getattr(systems, name)
        for cls in (obj[float], obj[AutoDiffXd]) if name.endswith("_") else (obj,):   # a template: its classes
            assert cls.__module__ == "olti_drake.sim.systems" and "<locals>" not in cls.__qualname__, name
    # The station modules offer them too (loaded on first use), and the former factories are aliases of them.
    assert ss.SerialLaserInterferometer is systems.SerialLaserInterferometer and ss.PanTiltSteering is systems.PanTiltSteering
    assert m3.VolumetricTool is systems.VolumetricTool and m3.Machine3DRecorder is systems.Machine3DRecorder
    assert ss._systems() == (systems.PanTiltSteering, systems.SerialLaserInterferometer, systems.SerialCampaignRecorder)
    assert m3._systems() == (systems.VolumetricTool, systems.PanTiltInterferometer, systems.Machine3DRecorder)
    with pytest.raises(AttributeError):
        ss.NoSuchSystem  # noqa: B018

    class MyRecorder(systems.SerialCampaignRecorder):   # subclassable: a recorder of its own
        pass

    assert MyRecorder(6, 1.0).get_name() == "my_recorder"

    setup = ss.prepare_serial(load_serial_scenario(SIX_AXIS, None, SMALL))
    diagram, _, _ = ss.build_serial_diagram(setup)
    names = dict(_names(diagram))
    assert isinstance(names["station/serial_laser_interferometer"], systems.SerialLaserInterferometer_[float])
    assert isinstance(names["campaign_recorder"], systems.SerialCampaignRecorder)
    assert isinstance(names["pan_tilt_steering"], systems.PanTiltSteering)
    dot = diagram.GetGraphvizString()
    assert "<locals>" not in dot and "_systems" not in dot
    for cls in ("SerialLaserInterferometer_", "SerialCampaignRecorder", "PanTiltSteering", "ErrorMapJoint_"):
        assert f"olti_drake.sim.systems.{cls}" in dot, cls

    machine = m3.prepare_machine3d(_machine_scenario())
    diagram3, _, _ = m3.build_machine3d_diagram(machine)
    names3 = dict(_names(diagram3))
    assert isinstance(names3["station/volumetric_tool"], systems.VolumetricTool_[float])
    assert isinstance(names3["station/laser_interferometer"], systems.PanTiltInterferometer_[float])
    assert isinstance(names3["machine_recorder"], systems.Machine3DRecorder)
    assert "<locals>" not in diagram3.GetGraphvizString()


def test_a_tabulated_truth_is_a_parameter_and_an_axis_without_a_map_refuses_in_one_line():
    """A scenario's MapTable (tabulated truth from YAML) interpolates as before and its nodes are a Parameter;
    SetMapValues on a continuous truth or a perfect axis is one line naming the axis (was a bare KeyError 0)."""
    from olti_drake.sim.scenario import MapTable

    table = MapTable([0.0, 10.0, 20.0], [0.01, 0.03, 0.02], [-0.01, 0.0, 0.04])
    joint = systems.ErrorMapJoint([table, HarmonicDeviation(offset_mdeg=3.0), None], revolute=[True] * 3)
    ctx = joint.CreateDefaultContext()
    np.testing.assert_array_equal(joint.GetMapValues(ctx, 0), [0.01, 0.03, 0.02, -0.01, 0.0, 0.04])
    joint.get_input_port(0).FixValue(ctx, np.radians([5.0, 1.0, 2.0]))
    before = np.degrees(joint.GetOutputPort("position").Eval(ctx)[0])
    assert before == 5.0 + table([5.0], [1.0])[0]            # as the table's own interpolation, bit for bit
    joint.SetMapValues(ctx, 0, [0.0, 0.1, 0.0, 0.0, 0.0, 0.0])
    assert np.degrees(joint.GetOutputPort("position").Eval(ctx)[0]) == pytest.approx(5.05, abs=1e-12)
    for axis, words in ((1, "axis 1 has a continuous HarmonicDeviation"), (2, "axis 2 has no deviation"),
                        (3, "axis 3: the system has axes 0..2")):
        with pytest.raises(ValueError, match=words) as e:
            joint.SetMapValues(ctx, axis, [0.0] * 6)
        assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="3 map values given, its map has 6"):
        joint.SetMapValues(ctx, 0, [0.0] * 3)
    ad = joint.ToAutoDiffXd()   # the table stays a Parameter through the conversion
    assert len(ad.GetMapValues(ad.CreateDefaultContext(), 0)) == 6


# ------------------------------------------------------------------ (b) the six-axis robot
UR5_GRID = np.arange(-120.0, 121.0, 30.0)
#: Poses inside the maps' grids (deg), approach directions, station: between nodes and on one.
POSES = [((10.0, -75.0, 60.0, -40.0, 95.0, 20.0), (1, 1, -1, 1, -1, 1), 0),
         ((-35.0, -50.0, 100.0, -80.0, 50.0, -60.0), (-1, 1, 1, -1, 1, -1), 1),
         ((72.0, -100.0, 35.0, -10.0, 110.0, 5.0), (1, -1, 1, 1, 1, 1), 2),
         ((-100.0, -30.0, 80.0, -115.0, 70.0, 90.0), (-1, -1, -1, 1, -1, -1), 3),
         ((45.0, -60.0, 120.0, -90.0, 60.0, -30.0), (1, 1, 1, -1, -1, 1), 1)]


@pytest.fixture(scope="module")
def ur5():
    """A UR5 truth in the identification's model family: location errors, a tool offset, per joint an error
    map on UR5_GRID (bidirectional), four stations, dead paths."""
    from olti_drake.model.chain import load_serial_chain
    from olti_drake.sim.serial_scenario import SHIPPED_MODELS

    chain = load_serial_chain(SHIPPED_MODELS["ur5"], "tool0")
    rng = np.random.default_rng(22)
    n = chain.n_joints
    geo = np.column_stack([rng.normal(0, 0.2, (n, 3)), rng.normal(0, 0.02, (n, 3))])
    params = np.concatenate([geo.ravel(), [40.0, -25.0, 60.0]])
    maps = [ErrorMap(UR5_GRID, 0.01 * rng.standard_normal(UR5_GRID.size), 0.01 * rng.standard_normal(UR5_GRID.size),
                     axis=joint) for joint in chain.joint_names]
    az = np.radians([10.0, 100.0, 190.0, 280.0])
    stations = np.column_stack([1300 * np.cos(az), 1300 * np.sin(az), [-300.0, 150.0, -500.0, 0.0]])
    return chain, params, maps, stations, rng.uniform(100, 500, 4)


def _measurement(ur5, readings_mm):
    """The identification's distance measurement of POSES at the truth (its start vector is the truth)."""
    from olti_drake.model.serial import DistanceMeasurement, JointMap, SerialPositionModel

    chain, params, maps, stations, dead = ur5
    model = SerialPositionModel(chain, "errormap", chain.parameter_names()[:6 * chain.n_joints], params,
                                maps=[JointMap(m) for m in maps])
    q = np.array([p for p, _, _ in POSES])
    d = np.array([d for _, d, _ in POSES], float)
    return DistanceMeasurement(model, q, d, [j for _, _, j in POSES], readings_mm, stations, dead)


def _serial_station(ur5, options, **beam):
    from olti_drake.sim.serial_station import AddSerialStation

    chain, params, maps, stations, dead = ur5
    builder = DiagramBuilder()
    AddSerialStation(builder, chain, maps, params, stations, dead, options, **beam)
    return builder.Build()


def _serial_read(diagram, ur5, pose, seeds=None, chain_params=None, ctx=None):
    """Displacement (m; float or AutoDiffXd) of the station of ``diagram`` at ``pose`` (of POSES), the joints
    approached in the pose's directions; ``seeds`` (AutoDiffXd diagram): the identification's names
    (location errors, tool offset, map nodes, P<j>_<c>_mm, d0_<j>_mm) that are the derivative slots, in
    order; ``chain_params`` (float diagram): location errors and tool offset set in the Context first;
    ``ctx``: the diagram's Context to use (default: a new one)."""
    from olti_drake.model.aiming3d import PanTiltHeads, pan_tilt_commands

    chain, params, maps, stations, dead = ur5
    q, dirs, j = np.asarray(pose[0], float), np.asarray(pose[1], float), pose[2]
    station = diagram.GetSubsystemByName("station")
    joints = station.GetSubsystemByName("error_map_joint")
    laser = station.GetSubsystemByName("serial_laser_interferometer")
    ctx = diagram.CreateDefaultContext() if ctx is None else ctx
    jctx, lctx, sctx = (s.GetMyContextFromRoot(ctx) for s in (joints, laser, station))
    T = float if seeds is None else AutoDiffXd
    scalar = (lambda v: np.asarray(v, float)) if T is float else (lambda v: [AutoDiffXd(x) for x in np.ravel(v)])
    jctx.SetDiscreteState(scalar(np.concatenate([q - 5.0 * dirs, dirs])))   # approached in ``dirs``
    if chain_params is not None:
        laser.SetChainParameters(lctx, chain_params)
    if seeds is not None:
        slot = {name: k for k, name in enumerate(seeds)}
        names = chain.parameter_names()
        laser.SetChainParameters(lctx, _seeded(params, _Seeds(
            {i: slot[nm] for i, nm in enumerate(names) if nm in slot}, len(seeds))))
        laser.SetStations(lctx, _seeded(stations, _Seeds(
            {3 * k + c: slot[f"P{k}_{'xyz'[c]}_mm"] for k in range(len(stations)) for c in range(3)
             if f"P{k}_{'xyz'[c]}_mm" in slot}, len(seeds))))
        laser.SetDeadPaths(lctx, _seeded(dead, _Seeds(
            {k: slot[f"d0_{k}_mm"] for k in range(len(dead)) if f"d0_{k}_mm" in slot}, len(seeds))))
        for axis, m in enumerate(maps):
            nodes = [f"{m.axis}_{b}_deg[{i}]" for b in ("forward", "reverse") for i in range(m.n_nodes)]
            joints.SetMapValues(jctx, axis, _seeded(m.values, _Seeds(
                {i: slot[nm] for i, nm in enumerate(nodes) if nm in slot}, len(seeds))))
    station.GetInputPort("joint_command").FixValue(sctx, scalar(np.radians(q)))
    station.GetInputPort("reflector").FixValue(sctx, scalar([j]))
    if station.HasInputPort("head_command"):   # floor tracers: aim at the nominal tool point
        p = chain.positions(q[None], chain.nominal_parameters(params[-3:]))
        head = pan_tilt_commands(PanTiltHeads(stations, None), [j], p)[0]
        station.GetInputPort("head_command").FixValue(sctx, scalar(np.radians(head)))
    return station.GetOutputPort("displacement").Eval(sctx)[0]


@pytest.mark.parametrize("beam", [{}, {"laser_direction": (0.0, 0.0, 1.0)}], ids=["floor_tracers", "robot_mounted"])
def test_six_axis_autodiff_reading_derivative_equals_the_identification_jacobian(ur5, beam):
    """∂reading/∂parameter through ``ToAutoDiffXd()`` of the N-joint station = the DistanceMeasurement's Jacobian
    entry for location errors (mm, deg), the tool offset, map nodes, station coordinates and dead paths.

    r = predicted − reading, so dr/dx at the truth is the reading's derivative with respect to the truth's
    parameter; the port is m, the parameters mm or deg, hence 1e3."""
    chain = ur5[0]
    j1, j2, j3, j5 = chain.joint_names[0], chain.joint_names[1], chain.joint_names[2], chain.joint_names[4]
    # Map nodes the poses read: the node at or after the command, in the pose's direction.
    node = lambda k, joint: (f"{chain.joint_names[joint]}_{'forward' if POSES[k][1][joint] > 0 else 'reverse'}_deg"
                             f"[{int(np.searchsorted(UR5_GRID, POSES[k][0][joint]))}]")
    names = [f"{j2}_dy_mm", f"{j3}_drx_deg", f"{j5}_drz_deg", f"{j1}_dz_mm", "tool_y_mm", node(0, 1), node(1, 2),
             node(3, 0), "P1_z_mm", "P3_x_mm", "d0_2_mm", "d0_1_mm"]
    ad = _serial_station(ur5, EXACT, **beam).ToAutoDiffXd()
    reads = [_serial_read(ad, ur5, pose, names) for pose in POSES]
    assert all(isinstance(r, AutoDiffXd) for r in reads)
    reading_mm = np.array([1e3 * r.value() for r in reads])
    got = np.array([1e3 * r.derivatives() for r in reads])   # mm per (mm or deg), slots in ``names`` order
    meas = _measurement(ur5, reading_mm)
    residual, jac = meas.residuals(meas.start_vector())
    np.testing.assert_allclose(residual, 0.0, atol=1e-9)   # the same model: the truth reads exactly this
    expected = jac.toarray()[:, [meas.names.index(n) for n in names]]
    assert np.all(np.any(expected != 0, axis=0)), "every parameter moves some reading"
    _assert_columns_close(got, expected, names)
    # A float station reads the same values (the AutoDiffXd path changes no value).
    floats = _serial_station(ur5, EXACT, **beam)
    np.testing.assert_allclose([1e3 * _serial_read(floats, ur5, pose) for pose in POSES], reading_mm, rtol=0,
                               atol=1e-9)


def test_six_axis_parameters_live_in_the_context_and_move_the_reading(ur5):
    """The Parameters' defaults are the constructor's; setting one in a Context moves that Context's readings as
    the identification's model predicts and leaves other Contexts alone; with noise the AutoDiffXd station
    reads the float station's noisy value."""
    diagram = _serial_station(ur5, EXACT)
    laser = diagram.GetSubsystemByName("station").GetSubsystemByName("serial_laser_interferometer")
    a, b = diagram.CreateDefaultContext(), diagram.CreateDefaultContext()
    la, lb = laser.GetMyContextFromRoot(a), laser.GetMyContextFromRoot(b)
    np.testing.assert_array_equal(laser.GetChainParameters(la), ur5[1])
    np.testing.assert_array_equal(laser.GetStations(la), ur5[3])
    np.testing.assert_array_equal(laser.GetDeadPaths(la), ur5[4])
    moved = ur5[1].copy()
    moved[-1] += 1.0                        # the tool point 1 mm further along the tool frame's z
    moved[3] += 0.05                        # the first joint frame tilted 0.05 deg about x
    laser.SetChainParameters(lb, moved)
    np.testing.assert_array_equal(laser.GetChainParameters(la), ur5[1])   # the other Context is untouched
    meas = _measurement(ur5, np.zeros(len(POSES)))
    x = meas.start_vector()
    x[meas.names.index("tool_z_mm")] += 1.0
    x[meas.names.index(f"{ur5[0].joint_names[0]}_drx_deg")] += 0.05
    got = [1e3 * _serial_read(diagram, ur5, pose, chain_params=moved) for pose in POSES]
    np.testing.assert_allclose(got, meas.predict(x), rtol=0, atol=1e-9)
    assert np.abs(meas.predict(x) - meas.predict(meas.start_vector())).min() > 1e-3
    # Changed after a first reading in the same Context: the joint frames follow (the plant is re-posed).
    station = diagram.GetSubsystemByName("station")
    first = 1e3 * _serial_read(diagram, ur5, POSES[0], ctx=a)
    assert first == pytest.approx(meas.predict(meas.start_vector())[0], abs=1e-9)
    laser.SetChainParameters(la, moved)
    again = 1e3 * station.GetOutputPort("displacement").Eval(station.GetMyContextFromRoot(a))[0]
    assert again == pytest.approx(meas.predict(x)[0], abs=1e-9)
    noisy = InterferometerOptions(beam_loss=False)
    before = _serial_read(_serial_station(ur5, noisy), ur5, POSES[0])
    ad = _serial_station(ur5, noisy).ToAutoDiffXd()
    assert 1e3 * _serial_read(ad, ur5, POSES[0], ["tool_z_mm"]).value() == pytest.approx(1e3 * before, abs=1e-9)
    with pytest.raises(ValueError, match="chain_params .* must be \\(39,\\) finite values"):
        systems.SerialLaserInterferometer(ur5[0], ur5[1][:-1], ur5[3], ur5[4], noisy)
    with pytest.raises(ValueError, match="head_errors: 2 given for 4 stations"):
        systems.SerialLaserInterferometer(ur5[0], ur5[1], ur5[3], ur5[4], noisy, head_errors=(None, None))


# ------------------------------------------------------------------ (c) the 3D machine tool
TOOLS = ((0.0, 0.0, 100.0), (80.0, 0.0, 100.0))


def _machine_scenario(**options):
    from olti_drake.model.machine import Machine3DScenario
    from olti_drake.model.volumetric3d import MachineConfig

    config = MachineConfig(tool_offsets_mm=TOOLS, knot_spacing_mm=100.0)
    return Machine3DScenario(config=config, grid=(7, 6, 6), tools=(0, 1),
                             interferometer=InterferometerOptions(**options), seed=3)


@pytest.fixture(scope="module")
def machine():
    """A planned 3D campaign whose truth is a spline of the identified model (held motions at 0), and the
    volumetric identification of its readings: (run, the spline motions, identification, its x at the truth)."""
    from olti_drake.estimation.multilateration import MachineCampaign
    from olti_drake.estimation.volumetric import VolumetricIdentification, VolumetricOptions
    from olti_drake.model.machine import machine_run_3d
    from olti_drake.model.volumetric3d import VolumetricModel, motion_unit, tool_positions

    scenario = _machine_scenario()
    run = machine_run_3d(scenario)
    model = VolumetricModel(run.config, identify_tool_offsets=True)
    rng = np.random.default_rng(5)
    names = model.parameter_names()
    scale = np.array([0.003 if n.startswith("tool") or (n[:2] == "E_" and motion_unit(n.split("[")[0]) == "mm")
                      else 4.0 for n in names])
    theta = scale * rng.standard_normal(model.n_params)

    def campaign(theta):
        actual = tool_positions(run.config, model.motions(theta), run.commands_mm, run.tool)
        i, j = run.sequence["target"], run.sequence["station"]
        d = np.linalg.norm(actual[i] - run.heads_true.centres_mm[j], axis=1) - run.dead_paths_mm[j]
        return MachineCampaign(j, i, run.commands_mm, d, np.arange(len(d)) + 2, "machine", run.tool)

    options = VolumetricOptions(tool_offsets_mm=TOOLS, knot_spacing_mm=100.0)
    first = VolumetricIdentification(campaign(theta), options)
    theta[~np.isin(np.arange(model.n_params), first.free_cols)] = 0.0   # held motions at 0: the model family
    ident = VolumetricIdentification(campaign(theta), options)
    assert ident.held == first.held and ident.model.parameter_names() == names
    x = np.concatenate([theta[ident.free_cols], run.heads_true.centres_mm.ravel(), run.dead_paths_mm])
    return run, model.motions(theta), ident, x


def _machine_read(diagram, run, k, seeds=None, names=()):
    """Displacement (m) of reading ``k`` of the run's sequence; ``seeds``: identification names -> slot."""
    from olti_drake.model.aiming3d import pan_tilt_commands

    i, j = int(run.sequence["target"][k]), int(run.sequence["station"][k])
    station = diagram.GetSubsystemByName("station")
    tool = station.GetSubsystemByName("volumetric_tool")
    laser = station.GetSubsystemByName("laser_interferometer")
    ctx = diagram.CreateDefaultContext()
    tctx, lctx, sctx = (s.GetMyContextFromRoot(ctx) for s in (tool, laser, station))
    T = float if seeds is None else AutoDiffXd
    scalar = (lambda v: np.asarray(v, float)) if T is float else (lambda v: [AutoDiffXd(x) for x in np.ravel(v)])
    if seeds is not None:
        slot = {name: s for s, name in enumerate(seeds)}
        if tool.parameter_names():   # a spline truth (a continuous one has no Parameter)
            theta = [v.value() for v in tool.GetVolumetricParameters(tctx)]
            tool.SetVolumetricParameters(tctx, _seeded(theta, _Seeds(
                {t: slot[n] for t, n in enumerate(tool.parameter_names()) if n in slot}, len(seeds))))
        P = run.heads_true.centres_mm
        laser.SetStations(lctx, _seeded(P, _Seeds({3 * h + c: slot[f"P{h}_{'xyz'[c]}_mm"] for h in range(len(P))
                                                   for c in range(3) if f"P{h}_{'xyz'[c]}_mm" in slot}, len(seeds))))
        laser.SetDeadPaths(lctx, _seeded(run.dead_paths_mm, _Seeds(
            {h: slot[f"L0_{h}_mm"] for h in range(len(P)) if f"L0_{h}_mm" in slot}, len(seeds))))
    nominal = run.commands_mm[i] + run.config.tools[run.tool[i]]
    station.GetInputPort("target_command").FixValue(sctx, scalar(run.commands_mm[i] / 1e3))
    station.GetInputPort("tool").FixValue(sctx, scalar([run.tool[i]]))
    station.GetInputPort("station").FixValue(sctx, scalar([j]))
    station.GetInputPort("head_command").FixValue(sctx, scalar(np.radians(
        pan_tilt_commands(run.heads_est, [j], nominal[None])[0])))
    return station.GetOutputPort("displacement").Eval(sctx)[0]


def _machine_station(run, motions, options):
    from olti_drake.sim.machine3d_station import AddVolumetricStation

    builder = DiagramBuilder()
    AddVolumetricStation(builder, run.config, motions, run.heads_true, run.head_error, run.dead_paths_mm,
                         (0.0, 0.0, -1.0), options)
    return builder.Build()


def test_machine3d_autodiff_reading_derivative_equals_the_identification_jacobian(machine):
    """∂reading/∂parameter through ``ToAutoDiffXd()`` of the 3D station = VolumetricIdentification's Jacobian
    entry for B-spline coefficients of a positioning (mm) and an angular (µrad) motion, a straightness, a
    squareness, a tool offset error, a head centre coordinate and a dead path."""
    run, motions, ident, x = machine
    wanted = ["E_XX[2]", "E_ZY[1]", "E_BY[3]", "E_AX[1]", "E_C0Y_urad", "E_B0Z_urad", "tool1_y_mm", "P2_x_mm",
              "P4_z_mm", "L0_1_mm", "L0_3_mm"]
    names = [n for n in wanted if n in ident.names]
    assert len(names) >= len(wanted) - 1, (set(wanted) - set(names), ident.held)   # at most one held
    rows = np.linspace(0, len(run.sequence["target"]) - 1, 9).astype(int)
    rows = np.append(rows, [k for k in range(len(run.tool)) if run.tool[run.sequence["target"][k]] == 1][:3])
    ad = _machine_station(run, motions, EXACT).ToAutoDiffXd()
    reads = [_machine_read(ad, run, k, names) for k in rows]
    got = np.array([1e3 * r.derivatives() for r in reads])
    residual, jac = ident.residuals(x)
    np.testing.assert_allclose(residual, 0.0, atol=1e-9)   # the identification's model reads the same
    expected = jac.toarray()[np.ix_(rows, [ident.names.index(n) for n in names])]
    assert np.all(np.any(expected != 0, axis=0)), "every parameter moves some reading"
    _assert_columns_close(got, expected, names)
    predicted = residual + ident.data.displacement_mm
    np.testing.assert_allclose([1e3 * r.value() for r in reads], predicted[rows], rtol=0, atol=1e-9)
    floats = _machine_station(run, motions, EXACT)
    np.testing.assert_allclose([1e3 * _machine_read(floats, run, k) for k in rows], predicted[rows], rtol=0,
                               atol=1e-9)


def test_machine3d_parameters_and_a_continuous_truth():
    """The shipped kind of truth (sums of sines) has no volumetric Parameter: asking for it is one line; the
    stations and dead paths are Parameters all the same, and the AutoDiffXd station reads the float one's value."""
    from olti_drake.sim.machine3d_station import prepare_machine3d

    setup = prepare_machine3d(_machine_scenario(beam_loss=False))
    run = setup.run
    diagram = _machine_station(run, run.truth, InterferometerOptions(beam_loss=False))
    tool = diagram.GetSubsystemByName("station").GetSubsystemByName("volumetric_tool")
    assert tool.parameter_names() == ()
    with pytest.raises(ValueError, match="continuous SineMotions, not the spline model") as e:
        tool.GetVolumetricParameters(tool.GetMyContextFromRoot(diagram.CreateDefaultContext()))
    assert "\n" not in str(e.value)
    laser = diagram.GetSubsystemByName("station").GetSubsystemByName("laser_interferometer")
    ctx = laser.GetMyContextFromRoot(diagram.CreateDefaultContext())
    np.testing.assert_array_equal(laser.GetStations(ctx), run.heads_true.centres_mm)
    ad = _machine_station(run, run.truth, InterferometerOptions(beam_loss=False)).ToAutoDiffXd()
    for k in (0, 17, 101):
        value = _machine_read(ad, run, k, ["L0_0_mm"]).value()
        assert value == pytest.approx(_machine_read(diagram, run, k), abs=1e-12)


def test_a_spline_outside_the_representation_is_refused():
    from olti_drake.model.volumetric3d import SplineMotions, VolumetricModel

    config = _machine_scenario().config
    model = VolumetricModel(config, identify_tool_offsets=True)
    motions = model.motions(model.zeros())
    coef = dict(motions.coefficients)
    coef["E_YX"] = coef["E_YX"].copy()
    coef["E_YX"][-1] = 0.002   # a straightness is 0 at both travel ends in the representation
    with pytest.raises(ValueError, match="E_YX: coefficient\\(s\\) \\[6\\] are fixed to 0"):
        systems.VolumetricTool(config, SplineMotions(config, coef, motions.squareness_urad,
                                                     motions.tool_offset_errors_mm))


# ------------------------------------------------------------------ (d) the campaigns
def test_serial_station_of_a_setup_is_the_station_of_its_chain():
    """AddSimulatedSerialStation builds the station of AddSerialStation from the setup's truth: the same
    Parameters (location errors, stations, dead paths, maps), so the campaigns of test_six_axis.py are its."""
    from olti_drake.sim import serial_station as ss
    from olti_drake.sim.serial_scenario import load_serial_scenario

    setup = ss.prepare_serial(load_serial_scenario(SIX_AXIS, None, SMALL))
    diagram, _, _ = ss.build_serial_diagram(setup)
    laser = diagram.station.GetSubsystemByName("serial_laser_interferometer")
    ctx = laser.GetMyContextFromRoot(diagram.CreateDefaultContext())
    np.testing.assert_array_equal(laser.GetChainParameters(ctx), setup.truth.chain_params)
    np.testing.assert_array_equal(laser.GetStations(ctx), setup.stations_mm)
    np.testing.assert_array_equal(laser.GetDeadPaths(ctx), setup.truth.dead_paths_mm)
    assert laser.tracers and diagram.station.HasInputPort("head_command")
    exact = dataclasses.replace(setup.scenario.interferometer, noise=False, quantization=False)
    rows = np.flatnonzero(setup.measure)[:5]
    ref = ss.numpy_readings(setup, rows, exact).reading_mm
    setup.scenario.interferometer = exact
    camp = ss.run_serial_campaign(setup)
    np.testing.assert_allclose(camp.columns["displacement_mm"][:5], ref, rtol=0, atol=1e-9)
