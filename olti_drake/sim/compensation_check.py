"""Compensated commands run through the Drake diagram: the simulation proof of :mod:`olti_drake.estimation.compensation`.

In sim/ because it builds Drake systems (``ErrorMapJoint``, the SCARA ``MultibodyPlant``); the compensation
itself (estimation/) stays free of the simulator. Units: mm, degrees.
"""

import numpy as np

from olti_drake.model.scara import JointCommands


def drake_end_effector(truth, commands: JointCommands):
    """The commands run, one simulator step each, through the Drake ``ErrorMapJoint`` and ``MultibodyPlant``.

    ``ErrorMapJoint`` (true J1, J2 deviations, Eq. 7 of 000) derives each
    approach direction from the command sequence itself, as a controller
    would; the plant (true L1, L2) gives the flange position. Returns
    (positions (N, 2) mm, directions (N, 2) ±1) -- compare with
    :func:`positioning_errors` and ``commands.dir1/dir2``. ``truth``: TrueRobot.
    """
    from pydrake.systems.analysis import Simulator

    from olti_drake.sim.plant import make_scara_plant
    from olti_drake.sim.systems import ErrorMapJoint

    joint = ErrorMapJoint([truth.deviation("J1"), truth.deviation("J2")], revolute=[True, True])
    sim = Simulator(joint)
    ctx = sim.get_mutable_context()
    sp = make_scara_plant(truth.L1_mm, truth.L2_mm, np.zeros((0, 2)))
    pctx = sp.plant.CreateDefaultContext()
    pos, dirs = [], []
    for k, q in enumerate(np.radians(np.column_stack([commands.theta1_deg, commands.theta2_deg]))):
        joint.get_input_port(0).FixValue(ctx, q)
        actual = joint.GetOutputPort("position").Eval(ctx)
        dirs.append(joint.GetOutputPort("direction").Eval(ctx).copy())
        sp.plant.SetPositions(pctx, sp.positions(actual[0], actual[1], 0.0, 0.0))
        pos.append(sp.plant.EvalBodyPoseInWorld(pctx, sp.flange).translation()[:2] * 1e3)
        sim.AdvanceTo(k + 1.0)  # one step: the per-step update remembers the command
    return np.array(pos).reshape(-1, 2), np.array(dirs).reshape(-1, 2)
