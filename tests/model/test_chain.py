"""Serial chains in 3D (olti_drake.model.chain): loading rules, the vectorized
position model against Drake and against finite differences, the base set."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix

import olti_drake
from olti_drake.model.scara import forward_kinematics
from olti_drake.model.chain import (DEG, GEOMETRIC_SUFFIXES, base_parameter_set,
                                    drake_kinematics, load_serial_chain)

MODELS = Path(olti_drake.__file__).parent / "models"
DATA = Path(__file__).resolve().parents[1] / "data"
UR5 = MODELS / "ur5.urdf"
ARM7 = DATA / "arm7_floating.urdf"
SCARA = MODELS / "scara.sdf"
CASES = {"ur5": (UR5, "tool0"), "arm7": (ARM7, "tcp"), "scara": (SCARA, "link2")}


@pytest.fixture(scope="module", params=sorted(CASES))
def chain(request):
    return load_serial_chain(*CASES[request.param])


def random_parameters(chain, seed, tool=(30.0, -20.0, 50.0)):
    """Non-zero location errors (about 1 mm, 0.3 deg) and a tool offset, mm and deg."""
    rng = np.random.default_rng(seed)
    geo = rng.normal(0.0, 1.0, (chain.n_joints, 6))
    geo[:, 3:] *= 0.3
    return np.concatenate([geo.ravel(), tool])


# ----------------------------------------------------------------- the models
def ur5_dh_positions(theta_deg):
    """Flange origin (M, 3) mm by the standard D-H product of UR's published UR5 table."""
    a = [0.0, -425.0, -392.25, 0.0, 0.0, 0.0]
    d = [89.159, 0.0, 0.0, 109.15, 94.65, 82.3]
    alpha = [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]
    out = []
    for row in np.radians(theta_deg):
        t = np.eye(4)
        for th, ai, di, al in zip(row, a, d, alpha):
            ct, st, ca, sa = np.cos(th), np.sin(th), np.cos(al), np.sin(al)
            t = t @ np.array([[ct, -st * ca, st * sa, ai * ct], [st, ct * ca, -ct * sa, ai * st],
                              [0.0, sa, ca, di], [0.0, 0.0, 0.0, 1.0]])
        out.append(t[:3, 3])
    return np.array(out)


def test_ur5_model_is_the_published_dh_arm():
    chain = load_serial_chain(UR5, "tool0")
    assert chain.joint_names == ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                 "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
    np.testing.assert_array_equal(chain.upper_deg, [360, 360, 180, 360, 360, 360])
    np.testing.assert_array_equal(chain.lower_deg, -chain.upper_deg)
    assert chain.notes == ()  # primitive shapes only: nothing to say
    theta = chain.random_angles(200, seed=7)
    dh = ur5_dh_positions(theta)
    drake, _ = drake_kinematics(chain, theta, jacobian=False)
    assert np.abs(drake - dh).max() < 1e-9
    assert np.abs(chain.positions(theta) - dh).max() < 1e-9
    np.testing.assert_allclose(chain.positions(np.zeros((1, 6)))[0], [-817.25, -191.45, -5.491],
                               atol=1e-9)


def test_ur5_has_plausible_masses():
    plant = load_serial_chain(UR5, "tool0").plant
    ctx = plant.CreateDefaultContext()
    masses = [plant.GetBodyByName(n).get_mass(ctx) for n in
              ("shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link",
               "wrist_2_link", "wrist_3_link")]
    assert 15.0 < sum(masses) < 25.0  # UR5: 18.4 kg arm
    assert all(m > 0 for m in masses)


def test_scara_chain_stops_before_the_prismatic_axis():
    """J1, J2 to link2 (the J2 frame); the tool offset (L2, 0, 0) reaches the J4 axis."""
    chain = load_serial_chain(SCARA, "link2")
    assert chain.joint_names == ("J1", "J2")
    theta = chain.random_angles(50, seed=3)
    p = chain.positions(theta, chain.nominal_parameters((225.0, 0.0, 0.0)))
    xy = forward_kinematics(theta[:, 0], theta[:, 1], 325.0, 225.0)[0]
    assert np.abs(p[:, :2] - xy).max() < 1e-9
    assert np.abs(p[:, 2] - 460.0).max() < 1e-9  # column 0.4 m + J2 0.06 m


# --------------------------------------------------------- vectorized vs Drake
def test_vectorized_model_equals_drake(chain):
    theta = chain.random_angles(200, seed=11)
    tool = (12.0, -34.0, 56.0)
    p, jac = chain.jacobian(theta, chain.nominal_parameters(tool))
    p_drake, jac_drake = drake_kinematics(chain, theta, tool)
    assert np.abs(p - p_drake).max() < 1e-9
    assert np.abs(jac[:, :, :chain.n_joints] - jac_drake).max() < 1e-9


def test_jacobian_equals_central_differences(chain):
    theta = chain.random_angles(20, seed=5)
    params = random_parameters(chain, seed=6)
    _, jac = chain.jacobian(theta, params)
    n, h = chain.n_joints, 1e-4
    assert jac.shape[2] == len(chain.jacobian_names()) == 7 * n + 3
    for col in range(jac.shape[2]):
        step = np.zeros(n + params.size)
        step[col] = h
        plus = chain.positions(theta + step[:n], params + step[n:])
        minus = chain.positions(theta - step[:n], params - step[n:])
        fd = (plus - minus) / (2 * h)
        scale = max(np.abs(jac[:, :, col]).max(), 1e-3)
        assert np.abs(jac[:, :, col] - fd).max() < 1e-6 * scale, chain.jacobian_names()[col]


def perturbed_urdf(src: Path, chain, params, dst: Path) -> Path:
    """The URDF with every chain joint's origin moved by its location error.

    New origin = old · Trans(δx, δy, δz) · Rx(δrx) Ry(δry) Rz(δrz) — the model's
    definition, built independently with Drake's RigidTransform.
    """
    tree = ET.parse(src)
    joints = {j.get("name"): j for j in tree.getroot().iter("joint")}
    for name, d in zip(chain.joint_names, params[:6 * chain.n_joints].reshape(-1, 6)):
        origin = joints[name].find("origin")
        if origin is None:
            origin = ET.SubElement(joints[name], "origin")
        xyz = [float(v) for v in origin.get("xyz", "0 0 0").split()]
        rpy = [float(v) for v in origin.get("rpy", "0 0 0").split()]
        rot = (RotationMatrix.MakeXRotation(d[3] * DEG) @ RotationMatrix.MakeYRotation(d[4] * DEG)
               @ RotationMatrix.MakeZRotation(d[5] * DEG))
        new = RigidTransform(RollPitchYaw(rpy), xyz) @ RigidTransform(rot, d[:3] / 1000.0)
        origin.set("xyz", " ".join(repr(float(v)) for v in new.translation()))
        origin.set("rpy", " ".join(repr(float(v)) for v in RollPitchYaw(new.rotation()).vector()))
    tree.write(dst)
    return dst


@pytest.mark.parametrize("case", ["ur5", "arm7"])
def test_location_errors_equal_drake_of_the_moved_model(case, tmp_path):
    path, tool_frame = CASES[case]
    chain = load_serial_chain(path, tool_frame)
    params = random_parameters(chain, seed=21)
    moved = load_serial_chain(perturbed_urdf(path, chain, params, tmp_path / path.name), tool_frame)
    theta = chain.random_angles(200, seed=22)
    p, jac = chain.jacobian(theta, params)
    p_drake, jac_drake = drake_kinematics(moved, theta, params[-3:])
    assert np.abs(p - p_drake).max() < 1e-9
    assert np.abs(jac[:, :, :chain.n_joints] - jac_drake).max() < 1e-9
    assert np.abs(p - chain.positions(theta, chain.nominal_parameters(params[-3:]))).max() > 1.0


def test_wrong_shapes_are_refused():
    chain = load_serial_chain(SCARA, "link2")
    with pytest.raises(ValueError, match="3 columns, the chain has 2 joints"):
        chain.positions(np.zeros((4, 3)))
    with pytest.raises(ValueError, match="expected 15"):
        chain.positions(np.zeros((4, 2)), np.zeros(14))
    with pytest.raises(ValueError, match="not finite"):
        chain.jacobian(np.array([[0.0, np.nan]]))


# --------------------------------------------------------------- loading rules
def test_floating_root_is_welded_and_branches_ignored():
    chain = load_serial_chain(ARM7, "tcp")
    assert chain.root == "arm_base"
    assert chain.joint_names == tuple(f"j{i}" for i in range(1, 8))  # not the fingers
    assert chain.plant.num_positions() == 9  # 7 arm joints + 2 fingers, no floating base
    assert np.isinf(chain.lower_deg[6]) and np.isinf(chain.upper_deg[6])  # continuous j7
    np.testing.assert_allclose([chain.lower_deg[3], chain.upper_deg[3]],
                               np.degrees([-3.0718, -0.0698]))
    theta = chain.random_angles(500, seed=1)
    lower = np.where(np.isfinite(chain.lower_deg), chain.lower_deg, -180.0)
    upper = np.where(np.isfinite(chain.upper_deg), chain.upper_deg, 180.0)
    assert np.all((theta >= lower) & (theta <= upper))
    assert theta[:, 5].max() > 180.0  # j6 reaches 215 deg: limits, not a fixed range
    assert len(chain.notes) == 1 and "no visual or collision geometry" in chain.notes[0]


def test_missing_meshes_load_with_one_note(tmp_path):
    chain = load_serial_chain(DATA / "missing_mesh.urdf", "tool")
    assert chain.joint_names == ("j1", "j2")
    assert len(chain.notes) == 1
    assert "3 mesh file(s) cannot be found" in chain.notes[0]
    assert "kinematics only" in chain.notes[0]
    sdf = tmp_path / "mesh.sdf"
    sdf.write_text(SCARA.read_text().replace(
        "<geometry><cylinder><radius>0.08</radius><length>0.4</length></cylinder></geometry>",
        "<geometry><mesh><uri>meshes/column.obj</uri></mesh></geometry>"))
    notes = load_serial_chain(sdf, "link2").notes
    assert len(notes) == 1 and "1 mesh file(s) cannot be found (first: 'meshes/column.obj')" in notes[0]


@pytest.mark.parametrize("path, tool_frame, message", [
    (DATA / "two_trees.urdf", "gripper",
     "tool frame 'gripper' not found in .*two_trees.urdf; frames: base, link1, tool, "),
    (DATA / "two_trees.urdf", "camera",
     "tool frame 'camera' is not downstream of the root 'base' in .*two_trees.urdf: "
     "it hangs on the free body 'camera_stand'"),
    (DATA / "prismatic_chain.urdf", "tool",
     "joint 'slide' on the chain from 'base' to 'tool' in .*prismatic_chain.urdf is prismatic: "
     "only revolute joints are supported"),
    (SCARA, "flange", "joint 'J3' .* is prismatic: only revolute joints are supported"),
    (ARM7, "arm_base", "no revolute joint between the root 'arm_base' and the tool frame 'arm_base'"),
    (DATA / "no_such_robot.urdf", "tool", "robot model .*no_such_robot.urdf: file not found"),
])
def test_refusals_name_the_frame_or_joint(path, tool_frame, message):
    with pytest.raises(ValueError, match=message) as info:
        load_serial_chain(path, tool_frame)
    assert "\n" not in str(info.value)


def test_unreadable_model_is_one_line(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text('<robot name="r"><link name="a"/><joint name="j" type="revolute">'
                   '<parent link="a"/><child link="missing"/></joint></robot>')
    with pytest.raises(ValueError, match="robot model .*bad.urdf: ") as info:
        load_serial_chain(bad, "a")
    assert "\n" not in str(info.value) and "error:" not in str(info.value).lower()  # Drake's own prefix dropped
    xacro = tmp_path / "arm.urdf.xacro"
    xacro.write_text('<robot name="r" xmlns:xacro="http://www.ros.org/wiki/xacro"><link name="a"/></robot>')
    with pytest.raises(ValueError, match=r"a xacro file; expand it first \(xacro arm.urdf.xacro > robot.urdf\)"):
        load_serial_chain(xacro, "a")


def test_model_files_that_crash_drake_are_one_line_naming_the_file(tmp_path):
    """Crash class of issue 24: inverted joint limits ended in a Drake assertion (joint.h:159, raised as
    SystemExit), a NaN origin gave Drake's message without the file. Both are now one line naming the file
    (and the joint), URDF and SDFormat alike."""
    import re

    text = UR5.read_text()
    limit = re.search(r'<limit[^>]*lower="([^"]+)"[^>]*upper="([^"]+)"', text).group(0)
    swapped = re.sub(r'lower="[^"]+"', 'lower="2.0"', re.sub(r'upper="[^"]+"', 'upper="-2.0"', limit))
    (tmp_path / "inverted.urdf").write_text(text.replace(limit, swapped, 1))
    origin = re.search(r'<origin[^>]*xyz="([^"]+)"', text)
    (tmp_path / "nan.urdf").write_text(text.replace(origin.group(0), origin.group(0).replace(origin.group(1),
                                                                                               "nan 0 0"), 1))
    (tmp_path / "inverted.sdf").write_text(
        '<sdf version="1.9"><model name="m"><link name="a"/><link name="b"/>'
        '<joint name="j1" type="revolute"><parent>a</parent><child>b</child>'
        '<axis><xyz>0 0 1</xyz><limit><lower>1.5</lower><upper>-1.5</upper></limit></axis></joint>'
        '</model></sdf>')
    for name, message in (("inverted.urdf", r"joint 'shoulder_pan_joint' has its lower limit 2 above its upper "
                                            r"limit -2"),
                          ("nan.urdf", r"robot model .*nan.urdf: .*xyz"),
                          ("inverted.sdf", r"joint 'j1' has its lower limit 1.5 above its upper limit -1.5")):
        with pytest.raises(ValueError, match=message) as info:
            load_serial_chain(tmp_path / name, "tool0" if name.endswith("urdf") else "b")
        assert "\n" not in str(info.value) and str(tmp_path / name) in str(info.value)


# -------------------------------------------------------------------- base set
def test_ur5_base_set_has_4R_plus_3_parameters():
    """Position-only readings of a 6R arm: 4·6 + 3 = 27 identifiable parameters."""
    chain = load_serial_chain(UR5, "tool0")
    tool = chain.nominal_parameters((40.0, -25.0, 60.0))
    base = base_parameter_set(chain, tool)
    assert len(base.kept) == 27
    assert len(base.kept) + len(base.dropped) == 7 * 6 + 3
    assert base.gap > 1e6
    reasons = dict(base.dropped)
    for i, joint in enumerate(chain.joint_names[:5]):
        # every axis is the frame's z: a rotation about it is the angle offset
        assert reasons[f"{joint}_drz_deg"] == f"trades with {joint}_offset_deg"
    assert reasons["wrist_3_joint_dz_mm"] == "trades with tool_z_mm"
    assert reasons["wrist_3_joint_offset_deg"] == "trades with tool_x_mm, tool_y_mm"
    assert {"tool_x_mm", "tool_y_mm", "tool_z_mm"} <= set(base.kept)
    # without error maps, the location errors take over the offsets: same count
    assert len(base_parameter_set(chain, tool, offsets=False).kept) == 27


def test_base_set_in_an_unknown_frame_keeps_the_frame_and_the_count():
    chain = load_serial_chain(UR5, "tool0")
    tool = chain.nominal_parameters((40.0, -25.0, 60.0))
    base = base_parameter_set(chain, tool, measurement_frame="unknown", seed=3)
    assert len(base.kept) == 27 and base.gap > 1e6
    assert base.kept[:6] == ("frame_x_mm", "frame_y_mm", "frame_z_mm",
                             "frame_rx_deg", "frame_ry_deg", "frame_rz_deg")
    # the first joint's axis line and angle offset are rigid motions of every point
    dropped = dict(base.dropped)
    assert "frame_rz_deg" in dropped["shoulder_pan_joint_offset_deg"]
    with pytest.raises(ValueError, match="measurement_frame"):
        base_parameter_set(chain, measurement_frame="tracker")


@pytest.mark.parametrize("case, joints", [("arm7", 7), ("scara", 2)])
def test_base_set_count_for_other_chains(case, joints):
    chain = load_serial_chain(*CASES[case])
    base = base_parameter_set(chain, chain.nominal_parameters((30.0, 20.0, 10.0)), seed=4)
    assert chain.n_joints == joints
    assert len(base.kept) == 4 * joints + 3 and base.gap > 1e6


def test_parameters_no_reading_sees_are_named():
    """With the tool point on the last axis, that joint's angle cannot move it."""
    chain = load_serial_chain(UR5, "tool0")
    reasons = dict(base_parameter_set(chain).dropped)
    assert reasons["wrist_3_joint_offset_deg"] == "no reading depends on it"
    assert reasons["wrist_3_joint_drz_deg"] == "no reading depends on it"
    assert GEOMETRIC_SUFFIXES[5] == "drz_deg"


def test_tool_frame_may_be_an_sdformat_frame(tmp_path):
    sdf = tmp_path / "scara_tcp.sdf"
    sdf.write_text(SCARA.read_text().replace(
        "  </model>",
        '<frame name="tcp" attached_to="link2"><pose>0.225 0 -0.1 0 0 0</pose></frame></model>'))
    chain = load_serial_chain(sdf, "tcp")
    link2 = load_serial_chain(SCARA, "link2")
    assert chain.joint_names == ("J1", "J2")
    theta = chain.random_angles(20, seed=8)
    expected = link2.positions(theta, link2.nominal_parameters((225.0, 0.0, -100.0)))
    assert np.abs(chain.positions(theta) - expected).max() < 1e-9


def test_tool_frame_in_two_models_is_ambiguous(tmp_path):
    model = SCARA.read_text().split("<sdf version=\"1.9\">")[1].split("</sdf>")[0]
    world = tmp_path / "two_scaras.sdf"
    world.write_text('<?xml version="1.0"?><sdf version="1.9"><world name="cell">'
                     + model + model.replace('model name="scara"', 'model name="scara2"')
                     + "</world></sdf>")
    with pytest.raises(ValueError, match="tool frame 'link2' is ambiguous in .*two_scaras.sdf: "
                                         "2 frames have that name"):
        load_serial_chain(world, "link2")


def test_a_model_attached_to_the_world_keeps_its_attachment(tmp_path):
    """A URDF ``world`` link: nothing is welded, the world is the root, the mount pose counts."""
    urdf = tmp_path / "ur5_on_pedestal.urdf"
    urdf.write_text(UR5.read_text().replace(
        '<robot name="ur5">',
        '<robot name="ur5"><link name="world"/><joint name="pedestal" type="fixed">'
        '<parent link="world"/><child link="base_link"/>'
        '<origin xyz="0.1 -0.2 0.5" rpy="0 0 1.5707963267948966"/></joint>'))
    chain = load_serial_chain(urdf, "tool0")
    assert chain.root == "world"
    theta = chain.random_angles(20, seed=9)
    base = load_serial_chain(UR5, "tool0").positions(theta)
    mounted = np.column_stack([100.0 - base[:, 1], -200.0 + base[:, 0], 500.0 + base[:, 2]])
    assert np.abs(chain.positions(theta) - mounted).max() < 1e-9


@pytest.mark.parametrize("kind, drake_kind", [("ball", "ball_rpy"), ("screw", "screw")])
def test_other_joint_types_on_the_chain_are_refused_by_name(kind, drake_kind, tmp_path):
    sdf = tmp_path / f"scara_{kind}.sdf"
    sdf.write_text(SCARA.read_text().replace('<joint name="J2" type="revolute">',
                                             f'<joint name="J2" type="{kind}">'))
    with pytest.raises(ValueError, match=f"joint 'J2' on the chain .* is {drake_kind}: "
                                         "only revolute joints are supported"):
        load_serial_chain(sdf, "link2")


def test_root_is_welded_at_the_model_origin(tmp_path):
    """An SDFormat root link posed in its model: the model frame, not the link, is the world."""
    sdf = tmp_path / "raised.sdf"
    sdf.write_text(SCARA.read_text().replace('<link name="base">',
                                             '<link name="base"><pose>0 0 0.5 0 0 0</pose>'))
    theta = np.array([[10.0, 20.0], [-30.0, 45.0]])
    raised = load_serial_chain(sdf, "link2").positions(theta)
    plain = load_serial_chain(SCARA, "link2").positions(theta)
    np.testing.assert_allclose(raised - plain, [[0, 0, 500.0]] * 2, atol=1e-9)


def test_ur5_shapes_load_for_meshcat():
    """The shipped model's simple shapes load into a SceneGraph (what Meshcat draws)."""
    from pydrake.geometry import Role
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
    from pydrake.systems.framework import DiagramBuilder

    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
    Parser(plant).AddModels(str(UR5))
    plant.Finalize()
    inspector = scene_graph.model_inspector()
    text = UR5.read_text()
    assert text.count("<mesh") == 0
    assert inspector.NumGeometriesWithRole(Role.kIllustration) == text.count("<visual") > 6
    assert inspector.NumGeometriesWithRole(Role.kProximity) == text.count("<collision") > 6
