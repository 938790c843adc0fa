import numpy as np
import pytest

from olti_drake.model.scara import DEG, PAPER_L1_MM as L1, PAPER_L2_MM as L2, forward_kinematics
from olti_drake.model.instrument import (beam_command_deg, default_search_positions_mm, fit_reflectors,
                                 rigid_robot_pose, search_residuals, simulate_search)

REFLECTORS = np.array([[700.0, 300.0], [-200.0, -750.0], [650.0, -600.0]])
THETA40 = 1.7  # deg


def _rot(p, deg):
    c, s = np.cos(deg * DEG), np.sin(deg * DEG)
    return p @ np.array([[c, s], [-s, c]])


@pytest.mark.parametrize("elbow", [1, -1])
def test_perfect_robot_aims_at_reflector(elbow):
    rng = np.random.default_rng(0)
    t1 = rng.uniform(-140, 60, 50)
    t2 = elbow * rng.uniform(5, 140, 50)
    P = REFLECTORS[rng.integers(0, 3, 50)]
    t4 = beam_command_deg(t1, t2, P, L1, L2, theta40_deg=THETA40)
    assert np.all((t4 > -180) & (t4 <= 180))
    p, _ = forward_kinematics(t1, t2, L1, L2)
    beam = (t1 + t2 + t4 + THETA40) * DEG
    u = np.stack([np.cos(beam), np.sin(beam)], axis=1)
    d = P - p
    assert np.max(np.abs(u[:, 0] * d[:, 1] - u[:, 1] * d[:, 0])) < 1e-9  # on the line
    assert np.all(np.sum(u * d, axis=1) > 0)  # pointing toward P, not away
    # a single (2,) estimate broadcasts; scalars give a scalar
    assert np.isscalar(beam_command_deg(10.0, 20.0, REFLECTORS[0], L1, L2))


def test_beam_command_rejects_coincident_reflector():
    p, _ = forward_kinematics(10.0, 20.0, L1, L2)
    with pytest.raises(ValueError, match="reflector_est_mm"):
        beam_command_deg(10.0, 20.0, p, L1, L2)


def _search(actual_pose=None, theta40=THETA40, noise=0.0, seed=1):
    return simulate_search(default_search_positions_mm(L1, L2), REFLECTORS, actual_pose,
                           theta40, seed, angle_noise_mdeg=noise, L1_mm=L1, L2_mm=L2)


def test_fit_recovers_reflectors_and_theta40_without_noise():
    res = fit_reflectors(*_search(), L1, L2)
    assert np.max(np.abs(res.reflectors_mm - REFLECTORS)) < 1e-6
    assert abs(res.theta40_deg - THETA40) * 1e3 < 1e-6
    assert res.residual_rms_mdeg < 1e-6


def test_fit_with_constant_joint_offsets():
    # J4 offset o4: the beam angle is θ1*+θ2*+θ4+(o4+θ40) -> θ40 absorbs o4 exactly.
    # J1 offset o1: the whole arm and its beam turn rigidly by o1 about J1; in a
    # frame turned by -o1 the robot is perfect, so the fit returns R(-o1) P and
    # θ40 unchanged (the J1-rotation gauge of formats.md).
    o1, o4 = 0.3, -0.8
    pose = rigid_robot_pose(L1, L2, THETA40, (o1, 0.0, o4))
    res = fit_reflectors(*_search(pose, theta40=None), L1, L2)
    assert abs(res.theta40_deg - (THETA40 + o4)) * 1e3 < 1e-6
    assert np.max(np.abs(res.reflectors_mm - _rot(REFLECTORS, -o1))) < 1e-6
    # J2 offset o2 moves p non-rigidly: not absorbed exactly, residual remains.
    pose = rigid_robot_pose(L1, L2, THETA40, (0.0, 0.3, 0.0))
    res = fit_reflectors(*_search(pose, theta40=None), L1, L2)
    assert res.residual_rms_mdeg > 1.0


def test_fit_with_noise_within_a_few_sigma():
    sigma_mdeg = 5.0
    data = _search(noise=sigma_mdeg, seed=7)
    res = fit_reflectors(*data, L1, L2)
    x_true = np.append(REFLECTORS.ravel(), THETA40)
    _, J = search_residuals(x_true, *data, L1, L2)
    std = sigma_mdeg * 1e-3 * np.sqrt(np.diag(np.linalg.inv(J.T @ J)))
    err = np.append(res.reflectors_mm.ravel(), res.theta40_deg) - x_true
    assert np.all(np.abs(err) < 4 * std)
    assert 0.3 * sigma_mdeg < res.residual_rms_mdeg < 2 * sigma_mdeg


def test_default_noise_is_a_tenth_of_a_millimetre_at_the_reflector():
    res = fit_reflectors(*_search(noise=None, seed=3), L1, L2)
    assert np.max(np.abs(res.reflectors_mm - REFLECTORS)) < 1.0


def test_errors_for_under_searched_reflector():
    t1, t2, t4, j = _search()
    keep = (j != 2) | (np.arange(j.size) == np.flatnonzero(j == 2)[0])
    with pytest.raises(ValueError, match="reflector 2 has 1 search pose"):
        fit_reflectors(t1[keep], t2[keep], t4[keep], j[keep], L1, L2)
    two = np.arange(j.size) < 6  # 2 poses per reflector: 6 <= 2*3+1
    with pytest.raises(ValueError, match="2\\*Nt\\+1"):
        fit_reflectors(t1[two], t2[two], t4[two], j[two], L1, L2)


def test_search_jacobian_matches_finite_differences():
    data = _search(noise=20.0)
    x = np.append(REFLECTORS.ravel() + [3.0, -2.0, 1.0, 4.0, -5.0, 2.0], 0.5)
    _, J = search_residuals(x, *data, L1, L2)
    h = 1e-6
    Jfd = np.column_stack([(search_residuals(x + h * e, *data, L1, L2)[0]
                            - search_residuals(x - h * e, *data, L1, L2)[0]) / (2 * h)
                           for e in np.eye(x.size)])
    np.testing.assert_allclose(J, Jfd, rtol=1e-6, atol=1e-9)


def test_default_positions_are_in_the_workspace():
    xy = default_search_positions_mm(L1, L2)
    r = np.hypot(*xy.T)
    assert 6 <= len(xy) <= 9 and np.all((r > abs(L1 - L2)) & (r < L1 + L2))
