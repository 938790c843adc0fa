"""The simulated robot's truth in plain numpy (000 Eq. 3 with Eq. 7, and Fig. 2).

The Drake diagram computes the same thing through ``ErrorMapJoint`` and the
``MultibodyPlant``; this numpy twin serves the places that need the truth
without running a diagram (the counter zero, the Eq. (2) search, the tracker
paths, truth.json). Tests hold the two equal.

Units: mm and degrees.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Dict

import numpy as np

from olti_drake.model.errormap import NoDeviation
from olti_drake.model.scara import forward_kinematics

Deviation = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class TrueRobot:
    """True link lengths (mm), joint deviations Δθ(θ*, dir) (deg) and laser mount.

    ``deviations`` maps "J1", "J2", "J4" to deviation callables (missing =
    perfect axis). The J2 deviation includes the offset θ20. The laser beam
    leaves the point ``beam_offset_mm`` = (along, lateral) of the J4 frame
    rotated by θ40, along that frame's x axis.
    """

    L1_mm: float
    L2_mm: float
    deviations: Dict[str, Deviation] = field(default_factory=dict)
    theta40_deg: float = 0.0
    beam_offset_mm: tuple = (0.0, 0.0)

    def deviation(self, axis: str) -> Deviation:
        return self.deviations.get(axis) or NoDeviation()

    def actual_angles(self, axis: str, theta_cmd_deg, direction):
        """θ = θ* + Δθ(θ*, dir) for one axis, deg (Eq. (7) of 000)."""
        th = np.asarray(theta_cmd_deg, dtype=float)
        return th + self.deviation(axis)(th, direction)

    def end_effector(self, theta1_cmd_deg, theta2_cmd_deg, dir1, dir2):
        """Actual J4-axis position (N, 2) mm for commanded J1/J2 angles and directions."""
        t1 = self.actual_angles("J1", theta1_cmd_deg, dir1)
        t2 = self.actual_angles("J2", theta2_cmd_deg, dir2)
        return forward_kinematics(t1, t2, self.L1_mm, self.L2_mm)[0]

    def laser_beam(self, theta1_cmd_deg, theta2_cmd_deg, theta4_cmd_deg, dir1, dir2, dir4):
        """Actual beam origin (N, 2) mm and world beam angle (N,) deg.

        The beam angle is θ1 + θ2 + θ4 + θ40 of the *actual* angles: open-loop
        steering misses the reflector by the joint deviations (000 §5).
        """
        t1 = self.actual_angles("J1", theta1_cmd_deg, dir1)
        t2 = self.actual_angles("J2", theta2_cmd_deg, dir2)
        t4 = self.actual_angles("J4", theta4_cmd_deg, dir4)
        p = forward_kinematics(t1, t2, self.L1_mm, self.L2_mm)[0]
        angle = t1 + t2 + t4 + self.theta40_deg
        a = np.radians(angle)
        da, de = self.beam_offset_mm
        origin = p + np.stack([da * np.cos(a) - de * np.sin(a), da * np.sin(a) + de * np.cos(a)], -1)
        return origin, angle
