"""The Drake systems on their own: ErrorMapJoint direction tracking and Eq. (7)."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from olti_drake.model.errormap import ErrorMap
from olti_drake.sim.systems import ErrorMapJoint

J1 = ErrorMap([0.0, 10.0, 20.0], [0.010, 0.030, 0.020], [-0.010, 0.000, 0.040], axis="J1")


def _step_through(commands_deg):
    """Feed commands one simulator step each; return (directions, actual angles deg) after each."""
    system = ErrorMapJoint([J1, None], revolute=[True, False])
    sim = Simulator(system)
    ctx = sim.get_mutable_context()
    dirs, pos = [], []
    for k, (a, b_mm) in enumerate(commands_deg):
        system.get_input_port(0).FixValue(ctx, [np.radians(a), b_mm / 1e3])
        dirs.append(system.GetOutputPort("direction").Eval(ctx).copy())
        pos.append(system.GetOutputPort("position").Eval(ctx).copy())
        sim.AdvanceTo(k + 1.0)  # one step: the per-step update remembers the command
    pos = np.array(pos)
    return np.array(dirs), np.column_stack([np.degrees(pos[:, 0]), pos[:, 1] * 1e3])


def test_directions_follow_the_command_history():
    # J1: 5 -> 15 (+) -> 15 (stays +) -> 12 (-) -> 12 (stays -) -> 18 (+)
    # J3 (prismatic, mm): 0 -> 0 (initial +1 kept) -> -3 (-) -> -3 (kept) -> 2 (+) -> 2 (kept)
    cmds = [(5, 0), (15, 0), (15, -3), (12, -3), (12, 2), (18, 2)]
    dirs, _ = _step_through(cmds)
    assert dirs[:, 0].tolist() == [1, 1, 1, -1, -1, 1]
    assert dirs[:, 1].tolist() == [1, 1, -1, -1, 1, 1]


def test_actual_angle_is_command_plus_directional_map():
    cmds = [(5, 0), (15, 0), (12, 0), (18, 0)]
    dirs, pos = _step_through(cmds)
    # Hand-computed Eq. (7), corrected weights:
    # 5 (+): 0.5*0.010 + 0.5*0.030 = 0.020; 15 (+): 0.5*0.030 + 0.5*0.020 = 0.025
    # 12 (-): 0.8*0.000 + 0.2*0.040 = 0.008; 18 (+): 0.2*0.030 + 0.8*0.020 = 0.022
    assert pos[:, 0] - [5, 15, 12, 18] == pytest.approx([0.020, 0.025, 0.008, 0.022], abs=1e-12)
    assert pos[:, 1] == pytest.approx(0.0, abs=1e-15)  # no deviation model on J3


def test_outputs_are_right_at_the_instant_the_command_changes():
    # Before any update the stored command is unknown: the first command keeps the initial +1.
    system = ErrorMapJoint([J1], revolute=[True], initial_direction=-1.0)
    ctx = system.CreateDefaultContext()
    system.get_input_port(0).FixValue(ctx, [np.radians(10.0)])
    assert system.GetOutputPort("direction").Eval(ctx)[0] == -1
    assert np.degrees(system.GetOutputPort("position").Eval(ctx)[0]) == pytest.approx(10.0)
