"""Forward kinematics with the error map and its analytic Jacobians (000 Eq. 3, 7)."""

import numpy as np
import pytest

from olti_drake.model.errormap import ErrorMap
from olti_drake.model.scara import JointCommands, ScaraModel, forward_kinematics, inverse_kinematics


def _cmds(rng, n=40):
    return JointCommands(rng.uniform(-140, 60, n), rng.uniform(0, 140, n),
                         rng.choice([-1.0, 1.0], n), rng.choice([-1.0, 1.0], n))


def _errormap_model(rng):
    g1, g2 = np.arange(-140, 61, 20.0), np.arange(0, 141, 20.0)
    return ScaraModel(324.97, 225.004, None,
                      ErrorMap(g1, rng.normal(0, 0.02, g1.size), rng.normal(0, 0.02, g1.size), "J1"),
                      ErrorMap(g2, rng.normal(0, 0.02, g2.size), rng.normal(0, 0.02, g2.size), "J2"))


def test_forward_kinematics_hand_values():
    p, _ = forward_kinematics([0.0, 90.0], [0.0, 90.0], 325.0, 225.0)
    assert p == pytest.approx(np.array([[550.0, 0.0], [-225.0, 325.0]]), abs=1e-12)


@pytest.mark.parametrize("kind", ["dh", "errormap"])
def test_jacobian_matches_finite_differences(kind):
    rng = np.random.default_rng(3)
    model = ScaraModel(324.97, 225.004, -0.00555) if kind == "dh" else _errormap_model(rng)
    cmd = _cmds(rng)
    p, jx, jy = model.positions_and_jacobian(cmd)
    x0 = model.parameter_vector()
    assert jx.shape == (len(cmd), x0.size)
    for i in range(x0.size):
        h = 1e-6
        xp, xm = x0.copy(), x0.copy()
        xp[i] += h
        xm[i] -= h
        fd = (model.with_parameters(xp).positions(cmd) - model.with_parameters(xm).positions(cmd)) / (2 * h)
        assert fd[:, 0] == pytest.approx(jx[:, i].toarray().ravel(), abs=1e-6)
        assert fd[:, 1] == pytest.approx(jy[:, i].toarray().ravel(), abs=1e-6)


def test_errormap_model_equals_dh_when_maps_are_constant():
    # A map with every node equal to theta20 on J2 and zero on J1 is the D-H model (Table 1 note).
    rng = np.random.default_rng(4)
    cmd = _cmds(rng)
    g1, g2 = np.arange(-140, 61, 20.0), np.arange(0, 141, 20.0)
    t20 = -0.00555
    em = ScaraModel(325.0, 225.0, None, ErrorMap(g1, 0 * g1, 0 * g1), ErrorMap(g2, 0 * g2 + t20, 0 * g2 + t20))
    assert em.positions(cmd) == pytest.approx(ScaraModel(325.0, 225.0, t20).positions(cmd), abs=1e-12)


def test_parameter_names_follow_eq6_order():
    rng = np.random.default_rng(5)
    m = _errormap_model(rng)
    names = m.parameter_names()
    assert names[:3] == ["L1_mm", "L2_mm", "J1_forward_deg[0]"]
    assert names[2 + 11] == "J1_reverse_deg[0]" and names[-1] == "J2_reverse_deg[7]"
    assert ScaraModel().parameter_names() == ["L1_mm", "L2_mm", "theta20_deg"]


@pytest.mark.parametrize("elbow", [1, -1])
def test_inverse_kinematics_round_trip(elbow):
    rng = np.random.default_rng(6)
    t1 = rng.uniform(-170, 170, 50)
    t2 = elbow * rng.uniform(5, 150, 50)
    p, _ = forward_kinematics(t1, t2, 325.0, 225.0)
    s1, s2 = inverse_kinematics(p[:, 0], p[:, 1], 325.0, 225.0, elbow=elbow)
    assert s1 == pytest.approx(t1, abs=1e-9) and s2 == pytest.approx(t2, abs=1e-9)


def test_inverse_kinematics_names_unreachable_row():
    with pytest.raises(ValueError, match="row 1"):
        inverse_kinematics([300.0, 600.0], [0.0, 0.0], 325.0, 225.0)


def test_joint_commands_validation():
    with pytest.raises(ValueError, match="dir2"):
        JointCommands([0.0], [0.0], [1.0], [0.0])
    with pytest.raises(ValueError, match="theta1_deg contains a non-finite"):
        JointCommands([np.nan], [0.0], [1.0], [1.0])
