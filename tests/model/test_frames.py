"""The rigid frames written once (olti_drake.model.frames): both angle conventions, their Jacobian, the rigid fit."""

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.model.frames import (DEG, URAD, into_frame, left_jacobian, out_of_frame, rigid_fit, rotation_matrix,
                                     turn_rows, xyz_angles, xyz_rotation)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fixed_angles_round_trip_and_jacobian(seed):
    rng = np.random.default_rng(seed)
    a = np.concatenate([rng.uniform(-170, 170, 1), rng.uniform(-80, 80, 1), rng.uniform(-170, 170, 1)])
    R, axes = xyz_rotation(a)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(xyz_angles(R), a, atol=1e-9)
    p = rng.normal(0, 500, (4, 3))
    q = p @ R.T
    jac = turn_rows(q, axes, DEG)  # (4, 3, 3) mm/deg
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        fd = (p @ xyz_rotation(a + e)[0].T - p @ xyz_rotation(a - e)[0].T) / (2 * h)
        assert np.allclose(jac[:, :, k], fd, rtol=1e-6, atol=1e-6)


def test_rotation_vector_jacobian_is_the_same_rule():
    rng = np.random.default_rng(4)
    w = rng.normal(0, 0.8, 3)  # rad: far from small
    p = rng.normal(0, 300, (5, 3))
    jac = turn_rows(p @ rotation_matrix(w).T, left_jacobian(w), URAD)  # mm/µrad
    h = 1e-3  # µrad
    for k in range(3):
        e = np.zeros(3)
        e[k] = h * URAD
        fd = (p @ rotation_matrix(w + e).T - p @ rotation_matrix(w - e).T) / (2 * h)
        assert np.allclose(jac[:, :, k], fd, rtol=1e-5, atol=1e-9)


def test_frame_in_and_out_and_the_rigid_fit():
    rng = np.random.default_rng(7)
    frame = np.array([1200.0, -300.0, 450.0, 12.0, -35.0, 160.0])
    p = rng.uniform(-800, 800, (30, 3))
    m = into_frame(p, frame)
    assert np.allclose(out_of_frame(m, frame), p, atol=1e-9)
    R, t = rigid_fit(p, m)
    assert np.allclose(np.concatenate([t, xyz_angles(R)]), frame, atol=1e-8)
    with pytest.raises(InputError, match="one line"):
        rigid_fit(np.outer(np.arange(5.0), [1.0, 2.0, 3.0]), np.outer(np.arange(5.0), [3.0, 2.0, 1.0]))
