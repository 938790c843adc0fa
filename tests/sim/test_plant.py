"""The Drake SCARA plant reproduces the numpy kinematics (mm, deg)."""

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder

from olti_drake.sim import plant as plant_mod
from olti_drake.model.scara import PAPER_L1_MM, PAPER_L2_MM, forward_kinematics
from olti_drake.sim.plant import AddScaraPlant, make_scara_plant

REFLECTORS_MM = np.array([[700.0, 100.0], [-50.0, 650.0], [400.0, -500.0]])
LENGTHS = [(PAPER_L1_MM, PAPER_L2_MM), (324.97, 225.004)]


def random_poses(n=200, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.uniform(-180, 180, n), rng.uniform(-170, 170, n),
            rng.uniform(-0.15, 0.15, n), rng.uniform(-180, 180, n))


def test_sdf_ships_nominal_lengths():
    root = ET.parse(plant_mod.SDF_PATH).getroot()
    xs = {j: float(root.find(f"./model/joint[@name='{j}']/pose").text.split()[0])
          for j in ("J2", "J3")}
    assert xs == {"J2": 0.325, "J3": 0.225}


@pytest.mark.parametrize("L1, L2", LENGTHS)
def test_flange_matches_forward_kinematics(L1, L2):
    sp = make_scara_plant(L1, L2, REFLECTORS_MM)
    ctx = sp.plant.CreateDefaultContext()
    t1, t2, z3, t4 = random_poses()
    p_ref, _ = forward_kinematics(t1, t2, L1, L2)
    z0 = None
    for k in range(t1.size):
        sp.plant.SetPositions(ctx, sp.positions(math.radians(t1[k]), math.radians(t2[k]),
                                                z3[k], math.radians(t4[k])))
        p = sp.plant.EvalBodyPoseInWorld(ctx, sp.flange).translation()
        np.testing.assert_allclose(p[:2] * 1e3, p_ref[k], rtol=0, atol=1e-9)
        z0 = p[2] - z3[k] if z0 is None else z0
        assert p[2] - z3[k] == pytest.approx(z0, abs=1e-12)  # J3 moves along z only


@pytest.mark.parametrize("L1, L2", LENGTHS)
def test_diagram_query_object_matches_forward_kinematics(L1, L2):
    builder = DiagramBuilder()
    sp = AddScaraPlant(builder, L1, L2, REFLECTORS_MM)
    diagram = builder.Build()
    ctx = diagram.CreateDefaultContext()
    t1, t2, z3, t4 = random_poses(seed=1)
    p_ref, _ = forward_kinematics(t1, t2, L1, L2)
    q = sp.positions(np.radians(t1), np.radians(t2), z3, np.radians(t4))
    for k in range(t1.size):
        sp.position_input.FixValue(sp.to_pose.GetMyContextFromRoot(ctx), q[k])
        query = sp.query_output.Eval(sp.scene_graph.GetMyContextFromRoot(ctx))
        p = query.GetPoseInWorld(sp.flange_frame_id).translation()
        np.testing.assert_allclose(p[:2] * 1e3, p_ref[k], rtol=0, atol=1e-9)
    # World-welded reflectors have their own SceneGraph frames, posed correctly.
    for body, xyz in zip(sp.reflector_bodies, sp.reflector_positions_m()):
        X = query.GetPoseInWorld(sp.plant.GetBodyFrameIdOrThrow(body.index()))
        np.testing.assert_allclose(X.translation(), xyz, atol=1e-15)


@pytest.mark.parametrize("theta40, offset", [(0.0, (0.0, 0.0)), (0.0, (31.5, -4.2)),
                                             (12.5, (31.5, -4.2)), (-95.0, (-8.0, 17.0))])
def test_laser_head_frame(theta40, offset):
    L1, L2 = 324.97, 225.004
    sp = make_scara_plant(L1, L2, REFLECTORS_MM, theta40, offset)
    ctx = sp.plant.CreateDefaultContext()
    a, e = offset
    for t1, t2, z3, t4 in zip(*random_poses(n=50, seed=2)):
        sp.plant.SetPositions(ctx, sp.positions(*np.radians([t1, t2]), z3, np.radians(t4)))
        X_WF = sp.plant.EvalBodyPoseInWorld(ctx, sp.flange)
        X_WL = sp.laser_head.CalcPoseInWorld(ctx)
        beam = math.radians(t1 + t2 + t4 + theta40)
        c, s = math.cos(beam), math.sin(beam)
        expected = X_WF.translation()[:2] * 1e3 + np.array([c * a - s * e, s * a + c * e])
        np.testing.assert_allclose(X_WL.translation()[:2] * 1e3, expected, rtol=0, atol=1e-9)
        assert X_WL.translation()[2] == pytest.approx(X_WF.translation()[2], abs=1e-15)
        np.testing.assert_allclose(X_WL.rotation().col(0), [c, s, 0.0], atol=1e-12)
        np.testing.assert_allclose(X_WL.rotation().col(2), [0.0, 0.0, 1.0], atol=1e-12)
        # With theta40 = 0 the offset is simply (a, e) in the flange frame.
        if theta40 == 0.0:
            g = math.radians(t1 + t2 + t4)
            np.testing.assert_allclose(
                X_WL.translation()[:2] * 1e3 - X_WF.translation()[:2] * 1e3,
                [math.cos(g) * a - math.sin(g) * e, math.sin(g) * a + math.cos(g) * e],
                rtol=0, atol=1e-9)
    np.testing.assert_allclose(sp.laser_head_in_flange.GetAsMatrix4(),
                               sp.laser_head.GetFixedPoseInBodyFrame().GetAsMatrix4())


def test_reflectors_where_requested_at_beam_height():
    sp = make_scara_plant(PAPER_L1_MM, PAPER_L2_MM, REFLECTORS_MM)
    assert [b.name() for b in sp.reflector_bodies] == ["reflector_0", "reflector_1", "reflector_2"]
    xyz = sp.reflector_positions_m()
    np.testing.assert_allclose(xyz[:, :2] * 1e3, REFLECTORS_MM, rtol=0, atol=1e-12)
    ctx = sp.plant.CreateDefaultContext()  # all joints zero: J3 = 0
    z_flange = sp.plant.EvalBodyPoseInWorld(ctx, sp.flange).translation()[2]
    np.testing.assert_allclose(xyz[:, 2], z_flange, atol=1e-15)


def test_positions_uses_plant_order():
    sp = make_scara_plant(PAPER_L1_MM, PAPER_L2_MM, REFLECTORS_MM)
    q = sp.positions(0.1, 0.2, 0.03, 0.4)
    assert q.shape == (sp.plant.num_positions(),)
    for name, v in zip(sp.joint_names, (0.1, 0.2, 0.03, 0.4)):
        assert q[sp.plant.GetJointByName(name).position_start()] == v


@pytest.mark.parametrize("kwargs, name", [
    (dict(L1_mm=-325.0, L2_mm=225.0), "L1_mm"),
    (dict(L1_mm=325.0, L2_mm=float("nan")), "L2_mm"),
    (dict(L1_mm=0.0, L2_mm=225.0), "L1_mm"),
    (dict(L1_mm=325.0, L2_mm=float("inf")), "L2_mm"),
])
def test_bad_link_length_raises(kwargs, name):
    with pytest.raises(ValueError, match=name):
        make_scara_plant(reflectors_mm=REFLECTORS_MM, **kwargs)


def test_missing_sdf_element_raises(monkeypatch, tmp_path):
    text = plant_mod.SDF_PATH.read_text().replace('name="J3"', 'name="J3x"')
    broken = tmp_path / "scara.sdf"
    broken.write_text(text)
    monkeypatch.setattr(plant_mod, "SDF_PATH", broken)
    with pytest.raises(ValueError, match="J3"):
        make_scara_plant(PAPER_L1_MM, PAPER_L2_MM, REFLECTORS_MM)
