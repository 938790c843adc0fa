"""Error map interpolation (000 Eq. 7-9, corrected weights) and the direction rule."""

import numpy as np
import pytest

from olti_drake.model.errormap import (ErrorMap, Harmonic, HarmonicDeviation, OutsideGridError,
                                 approach_directions, sample_map)


def _map(**kw):
    return ErrorMap([0.0, 10.0, 30.0], [1.0, 3.0, -1.0], [0.5, 0.0, 2.0], axis="J1", **kw)


def test_interpolation_matches_hand_computed_values():
    m = _map()
    # Forward block: at 2.5 deg alpha = 0.25 -> 0.75*1 + 0.25*3 = 1.5; at 20 deg -> 0.5*3 + 0.5*(-1) = 1.
    assert m([2.5, 20.0], [1, 1]) == pytest.approx([1.5, 1.0], abs=1e-15)
    # Reverse block: at 25 deg alpha = 0.75 -> 0.25*0 + 0.75*2 = 1.5.
    assert m([25.0], [-1]) == pytest.approx([1.5], abs=1e-15)


def test_node_value_is_exact_at_the_node():
    # Eq. (7) as printed would give the node i+1 value here; the corrected form gives node i.
    m = _map()
    assert m([0.0, 10.0, 30.0], 1) == pytest.approx([1.0, 3.0, -1.0], abs=0)
    assert m([0.0, 10.0, 30.0], -1) == pytest.approx([0.5, 0.0, 2.0], abs=0)


def test_weights_are_the_jacobian():
    m = _map()
    th, d = np.array([1.0, 12.0, 29.0]), np.array([1, -1, 1])
    w = m.weights(th, d).toarray()
    assert np.allclose(w.sum(axis=1), 1.0)
    eps = 1e-6
    for i in range(6):
        v = m.values.copy()
        v[i] += eps
        fd = (m.with_values(v)(th, d) - m(th, d)) / eps
        assert fd == pytest.approx(w[:, i], abs=1e-8)


def test_outside_policy():
    with pytest.raises(OutsideGridError, match=r"J1.*-5 deg.*\[0, 30\]"):
        _map()([-5.0], 1)
    clamped = _map(outside="clamp")
    assert clamped([-5.0, 40.0], [1, -1]) == pytest.approx([1.0, 2.0])


def test_bad_maps_and_directions_are_rejected():
    with pytest.raises(ValueError, match="ascending"):
        ErrorMap([0, 0], [0, 0], [0, 0])
    with pytest.raises(ValueError, match="forward_deg has 1"):
        ErrorMap([0, 1], [0], [0, 0])
    with pytest.raises(ValueError, match="direction must be"):
        _map()([1.0], [0])


def test_single_node_map_is_constant_per_direction():
    m = ErrorMap([5.0], [0.1], [-0.1], outside="clamp")
    assert m([0.0, 9.0], [1, -1]) == pytest.approx([0.1, -0.1])


def test_direction_rule_keeps_direction_of_an_axis_that_did_not_move():
    cmds = np.array([[0, 0], [10, 0], [10, 5], [10, 5], [5, 5], [5, 10]], dtype=float)
    d = approach_directions(cmds, last_command_deg=[-1, 1], last_direction=[-1, -1])
    expected = [[1, -1], [1, -1], [1, 1], [1, 1], [-1, 1], [-1, 1]]
    assert d.tolist() == expected


def test_direction_rule_before_any_motion_uses_the_given_direction():
    assert approach_directions([3.0, 3.0, 4.0], last_direction=-1).tolist() == [-1, -1, 1]


def test_harmonic_deviation_is_continuous_with_backlash():
    h = HarmonicDeviation(offset_mdeg=2.0, harmonics=[Harmonic(10.0, 360.0, 90.0)], backlash_mdeg=8.0)
    # sin(0 + 90 deg) = 1: 2 + 10 +- 4 mdeg.
    assert h([0.0, 0.0], [1, -1]) == pytest.approx([16e-3, 8e-3])
    m = sample_map(h, [0.0, 90.0], axis="J2")
    assert m.forward_deg - m.reverse_deg == pytest.approx([8e-3, 8e-3])
    # Between nodes a harmonic truth is not piecewise linear: interpolation differs from truth.
    assert abs(m([45.0], 1)[0] - h([45.0], 1)[0]) > 1e-3
