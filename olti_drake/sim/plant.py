"""Drake model of the SCARA robot, the laser head and the cat's-eye reflectors.

The API takes mm and degrees, like :mod:`olti_drake.model.scara`; the plant is
SI (m, rad). The robot comes from ``models/scara.sdf`` with its link lengths
rewritten, so with J1..J4 at zero the arm lies along world +x and the flange
origin is at (L1, 0) + (L2, 0), matching ``kinematics.forward_kinematics``.
The plant is purely kinematic here: a diagram feeds joint positions to
``MultibodyPositionToGeometryPose`` and reads body poses from SceneGraph.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
from pydrake.geometry import Box, SceneGraph, Sphere
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.parsing import Parser
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import FixedOffsetFrame, SpatialInertia
from pydrake.systems.rendering import MultibodyPositionToGeometryPose

SDF_PATH = Path(__file__).resolve().parent.parent / "models" / "scara.sdf"
JOINT_NAMES = ("J1", "J2", "J3", "J4")
REFLECTOR_RADIUS_M = 0.0127  # 1 inch cat's eye
MM = 1e-3


@dataclass
class ScaraPlant:
    """A finalized SCARA plant and the handles a diagram needs.

    ``position_input``, ``query_output`` and ``to_pose`` are set only by
    :func:`AddScaraPlant`.
    """

    plant: MultibodyPlant
    scene_graph: SceneGraph
    flange: object
    laser_head: object
    reflector_bodies: list
    position_input: object = None
    query_output: object = None
    to_pose: Optional[MultibodyPositionToGeometryPose] = None
    joint_names: tuple = field(default=JOINT_NAMES, init=False)

    def positions(self, theta1_rad, theta2_rad, z3_m, theta4_rad) -> np.ndarray:
        """Plant position vector q (SI) from the joint values; arrays broadcast.

        Returns shape ``broadcast_shape + (nq,)``, i.e. (nq,) for scalars.
        """
        vals = np.broadcast_arrays(*(np.asarray(v, dtype=float)
                                     for v in (theta1_rad, theta2_rad, z3_m, theta4_rad)))
        q = np.zeros(vals[0].shape + (self.plant.num_positions(),))
        for name, v in zip(JOINT_NAMES, vals):
            q[..., self.plant.GetJointByName(name).position_start()] = v
        return q

    @property
    def laser_head_in_flange(self) -> RigidTransform:
        """X_FL: the laser head frame (beam along +x) in the flange body frame, m."""
        return self.laser_head.GetFixedPoseInBodyFrame()

    @property
    def flange_frame_id(self):
        """SceneGraph FrameId of the flange body (for QueryObject.GetPoseInWorld)."""
        return self.plant.GetBodyFrameIdOrThrow(self.flange.index())

    @property
    def reflector_frame_ids(self) -> list:
        """SceneGraph FrameIds of the reflector bodies, index j = reflector j."""
        return [self.plant.GetBodyFrameIdOrThrow(b.index()) for b in self.reflector_bodies]

    def reflector_positions_m(self) -> np.ndarray:
        """(Nt, 3) world positions of the reflector centres, m."""
        ctx = self.plant.CreateDefaultContext()
        return np.array([self.plant.EvalBodyPoseInWorld(ctx, b).translation()
                         for b in self.reflector_bodies]).reshape(-1, 3)


def _set_joint_x(root: ET.Element, joint: str, x_m: float) -> None:
    """Set the x offset of ``<joint name=joint><pose>`` (the link length)."""
    pose = root.find(f"./model/joint[@name='{joint}']/pose")
    if pose is None:
        raise ValueError(f"scara.sdf: no <pose> for joint '{joint}' to set its link length")
    values = pose.text.split()
    values[0] = repr(float(x_m))
    pose.text = " ".join(values)


def _set_arm_visual(root: ET.Element, link: str, length_m: float) -> None:
    """Stretch the link's ``arm`` box so Meshcat shows the actual length."""
    visual = root.find(f"./model/link[@name='{link}']/visual[@name='arm']")
    if visual is None:
        raise ValueError(f"scara.sdf: no visual 'arm' on link '{link}'")
    pose, size = visual.find("pose"), visual.find("geometry/box/size")
    for elem, value in ((pose, length_m / 2), (size, length_m)):
        values = elem.text.split()
        values[0] = repr(float(value))
        elem.text = " ".join(values)


def scara_sdf_text(L1_mm: float, L2_mm: float) -> str:
    """The shipped SDF with link lengths L1, L2 (mm) written into J2/J3 poses (m)."""
    for name, value in (("L1_mm", L1_mm), ("L2_mm", L2_mm)):
        if not (np.isscalar(value) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a positive finite length in mm, got {value!r}")
    root = ET.parse(SDF_PATH).getroot()
    for joint, link, length_mm in (("J2", "link1", L1_mm), ("J3", "link2", L2_mm)):
        _set_joint_x(root, joint, length_mm * MM)
        _set_arm_visual(root, link, length_mm * MM)
    return ET.tostring(root, encoding="unicode")


def _zero_pose_height(plant: MultibodyPlant) -> float:
    """World z (m) of the flange origin with all joints at zero (before Finalize)."""
    X = RigidTransform()
    for name in JOINT_NAMES:
        joint = plant.GetJointByName(name)
        X = (X @ joint.frame_on_parent().GetFixedPoseInBodyFrame()
             @ joint.frame_on_child().GetFixedPoseInBodyFrame().inverse())
    return float(X.translation()[2])


def make_scara_plant(L1_mm, L2_mm, reflectors_mm, theta40_deg=0.0,
                     beam_offset_mm=(0.0, 0.0), scene_graph=None) -> ScaraPlant:
    """Build and finalize the continuous SCARA plant with laser head and reflectors.

    Args:
        L1_mm, L2_mm: link lengths (J1-J2 and J2-J4 axis distances), mm.
        reflectors_mm: (Nt, 2) reflector XY positions, mm; each becomes a body
            ``reflector_i`` welded to the world at the flange height (J3 = 0),
            so the beam is horizontal.
        theta40_deg: beam angle relative to the flange x axis (J4 zero offset), deg.
        beam_offset_mm: (a, e) beam origin in the flange, mm: ``a`` along the
            beam, ``e`` to its left (+y of the beam-aligned frame).
        scene_graph: SceneGraph to register the geometry with; a new one if None.

    The laser head is the FixedOffsetFrame ``laser_head`` on ``flange``:
    X_FL = RotZ(θ40) with origin RotZ(θ40)·(a, e, 0); the beam is its +x axis.
    """
    refl = np.asarray(reflectors_mm, dtype=float).reshape(-1, 2)
    a_mm, e_mm = (float(v) for v in beam_offset_mm)
    for name, value in (("theta40_deg", theta40_deg), ("beam_offset_mm", a_mm + e_mm),
                        ("reflectors_mm", refl.sum())):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value!r}")
    text = scara_sdf_text(L1_mm, L2_mm)

    if scene_graph is None:
        scene_graph = SceneGraph()
    plant = MultibodyPlant(time_step=0.0)
    plant.RegisterAsSourceForSceneGraph(scene_graph)
    (model,) = Parser(plant).AddModelsFromString(text, "sdf")
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base", model))
    flange = plant.GetBodyByName("flange", model)

    R_FL = RotationMatrix.MakeZRotation(math.radians(theta40_deg))
    X_FL = RigidTransform(R_FL, R_FL @ np.array([a_mm * MM, e_mm * MM, 0.0]))
    laser_head = plant.AddFrame(FixedOffsetFrame("laser_head", flange.body_frame(), X_FL))
    # Box behind the beam origin, so the beam leaves its front face.
    plant.RegisterVisualGeometry(flange, X_FL @ RigidTransform([-0.03, 0.0, 0.0]),
                                 Box(0.06, 0.04, 0.04), "laser_head", [0.1, 0.4, 0.9, 1.0])

    z_beam = _zero_pose_height(plant)
    reflectors = plant.AddModelInstance("reflectors")
    bodies = []
    for i, (x, y) in enumerate(refl):
        body = plant.AddRigidBody(f"reflector_{i}", reflectors,
                                  SpatialInertia.SolidSphereWithMass(0.05, REFLECTOR_RADIUS_M))
        plant.WeldFrames(plant.world_frame(), body.body_frame(),
                         RigidTransform([x * MM, y * MM, z_beam]))
        plant.RegisterVisualGeometry(body, RigidTransform(), Sphere(REFLECTOR_RADIUS_M),
                                     f"reflector_{i}", [0.85, 0.1, 0.1, 1.0])
        bodies.append(body)
    plant.Finalize()
    return ScaraPlant(plant, scene_graph, flange, laser_head, bodies)


def AddScaraPlant(builder, L1_mm, L2_mm, reflectors_mm, theta40_deg=0.0,
                    beam_offset_mm=(0.0, 0.0), name="plant") -> ScaraPlant:
    """Add the kinematic SCARA (SceneGraph + position-to-pose system) to ``builder``.

    Arguments as :func:`make_scara_plant` (mm, deg). The plant itself is not a
    diagram system: ``MultibodyPositionToGeometryPose`` (named ``name``) takes
    q (plant order, SI; see :meth:`ScaraPlant.positions`) on ``position_input``
    and poses the geometry in SceneGraph, whose QueryObject is on
    ``query_output``. The returned object keeps the plant alive.
    """
    scene_graph = builder.AddNamedSystem("scene_graph", SceneGraph())
    sp = make_scara_plant(L1_mm, L2_mm, reflectors_mm, theta40_deg, beam_offset_mm,
                          scene_graph=scene_graph)
    to_pose = builder.AddNamedSystem(name, MultibodyPositionToGeometryPose(sp.plant))
    builder.Connect(to_pose.get_output_port(),
                    scene_graph.get_source_pose_port(sp.plant.get_source_id()))
    sp.to_pose = to_pose
    sp.position_input = to_pose.get_input_port()
    sp.query_output = scene_graph.get_query_output_port()
    return sp
