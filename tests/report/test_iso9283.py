"""ISO 9283 pose accuracy and repeatability (issue 26, item 4): the characteristics of clause 7.2 from a validation
campaign with repeated cycles, on the test cube's poses (clause 6.2), with verdicts against stated tolerances."""

import numpy as np
import pytest

from olti_drake.errors import InputError
from olti_drake.report.iso9283 import CYCLE_ORDER, iso_cube_poses, pose_characteristics, verdicts


def test_the_cube_poses_lie_on_the_diagonal_plane_at_a_tenth_of_its_diagonals():
    P = iso_cube_poses([500.0, 0.0, 400.0], 300.0)
    assert P.shape == (5, 3) and np.allclose(P[0], [500.0, 0.0, 400.0])
    h = 150.0
    corners = np.array([[-h, -h, -h], [h, -h, -h], [h, h, h], [-h, h, h]]) + P[0]
    diag = np.linalg.norm(corners[0] - corners[2])
    for k in range(4):
        assert np.linalg.norm(P[k + 1] - corners[k]) == pytest.approx(0.1 * diag, rel=1e-12)
    # every pose on the plane through the two edges: normal (0, 1, -1)/sqrt2
    assert np.allclose((P - P[0]) @ np.array([0.0, 1.0, -1.0]), 0.0)
    assert sorted(CYCLE_ORDER) == [1, 2, 3, 4, 5]
    with pytest.raises(InputError, match="side_mm"):
        iso_cube_poses([0, 0, 0], -1.0)


def _cycles(offset, sigma, n=30, seed=0, orient=None):
    rng = np.random.default_rng(seed)
    P = iso_cube_poses([600.0, 100.0, 300.0], 400.0)
    pose = np.tile(np.arange(1, 6), n)
    cmd = P[pose - 1]
    att = cmd + np.asarray(offset) + sigma * rng.standard_normal(cmd.shape)
    if orient is not None:
        a_cmd = np.tile([[179.9, 0.0, -90.0]], (len(pose), 1))
        a_att = a_cmd + np.asarray(orient) + 0.01 * rng.standard_normal(a_cmd.shape)
        cmd, att = np.hstack([cmd, a_cmd]), np.hstack([att, a_att])
    return pose, cmd, att


def test_accuracy_and_repeatability_follow_the_standards_formulas():
    pose, cmd, att = _cycles([0.05, -0.02, 0.01], 0.01)
    chars = pose_characteristics(pose, cmd, att)
    assert [c.pose for c in chars] == [1, 2, 3, 4, 5] and all(c.cycles == 30 for c in chars)
    for c in chars:
        sel = pose == c.pose
        mean = att[sel].mean(axis=0)
        assert c.AP_xyz == pytest.approx(mean - cmd[sel][0], abs=1e-12)
        l = np.linalg.norm(att[sel] - mean, axis=1)
        assert c.RP_l == pytest.approx(l.mean() + 3 * np.std(l, ddof=1), rel=1e-12)
        assert c.AP_P == pytest.approx(np.linalg.norm([0.05, -0.02, 0.01]), abs=0.01)  # the bias, within noise
        assert 0.02 < c.RP_l < 0.06  # 3D noise of 10 um: l ~ 16 um mean, 3 S_l ~ 20 um


def test_orientation_across_the_180_degree_seam():
    """A = 179.9 deg commanded, attained 180.05 (= -179.95): AP_a is +0.15 deg, not -359.85."""
    pose, cmd, att = _cycles([0, 0, 0], 0.001, orient=[0.15, 0.0, -0.02])
    att[:, 3] = (att[:, 3] + 180.0) % 360.0 - 180.0
    chars = pose_characteristics(pose, cmd, att)
    for c in chars:
        assert c.AP_abc[0] == pytest.approx(0.15, abs=0.01) and c.AP_abc[2] == pytest.approx(-0.02, abs=0.01)
        assert 0.01 < c.RP_abc[0] < 0.06


def test_verdicts_against_tolerances_and_bad_input_in_one_line():
    pose, cmd, att = _cycles([0.2, 0, 0], 0.005)
    chars = pose_characteristics(pose, cmd, att)
    lines = verdicts(chars, {"AP_P": 0.1, "RP_l": 0.05, "AP_abc": 0.1})
    assert lines[0].startswith("AP_P FAIL") and lines[1].startswith("RP_l PASS") and "not available" in lines[2]
    with pytest.raises(InputError, match="tolerance 'AP'"):
        verdicts(chars, {"AP": 0.1})
    with pytest.raises(InputError, match="needs at least 2"):
        pose_characteristics(pose[:5], cmd[:5], att[:5])
    cmd2 = cmd.copy()
    cmd2[5, 0] += 0.1  # pose 1 of cycle 2 commanded elsewhere
    with pytest.raises(InputError, match="pose 1: its commanded x differs"):
        pose_characteristics(pose, cmd2, att)
    att[3, 1] = np.nan
    with pytest.raises(InputError, match=":5: a pose value"):
        pose_characteristics(pose, cmd, att)


def test_the_order_of_the_rows_changes_nothing():
    pose, cmd, att = _cycles([0.03, 0.01, -0.04], 0.01, seed=3)
    perm = np.random.default_rng(1).permutation(len(pose))
    a = pose_characteristics(pose, cmd, att)
    b = pose_characteristics(pose[perm], cmd[perm], att[perm])
    for x, y in zip(a, b):
        assert x.AP_P == pytest.approx(y.AP_P, abs=1e-12) and x.RP_l == pytest.approx(y.RP_l, abs=1e-12)
