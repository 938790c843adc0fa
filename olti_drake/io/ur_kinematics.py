"""The identified kinematics as a UR-style ``default_kinematics.yaml`` (``olti compensate --ur-kinematics-out``;
issue 26, item 3).

Universal Robots' ROS description (``ur_description``) builds the arm's URDF from a kinematics file: under
``kinematics``, per segment ``shoulder, upper_arm, forearm, wrist_1, wrist_2, wrist_3`` the origin of the joint
that moves it (shoulder_pan, shoulder_lift, elbow, wrist_1, wrist_2, wrist_3) as ``x, y, z`` (metres) and
``roll, pitch, yaw`` (radians, the URDF's fixed-axis convention), and a ``hash`` naming the calibration
(``ur_calibration`` writes the robot's own). Written here, chain order, for a six-joint chain:

    origin_i ← origin_i · Δ_i · Rot(axis_i, offset_i)

the joint's nominal origin (the robot's URDF) with its identified location error Δ_i and its identified angle
offset (``dh``: the constant offset; ``errormap``: the map's level, :func:`olti_drake.io.ros2_control.joint_offsets`)
folded in -- the same composition as the identified URDF (:func:`olti_drake.io.identified_urdf.identified_origins`).
The ``hash`` is ``calib_olti_`` and the first 16 hex digits of the values' sha256.

What the file cannot hold: the error maps' command- and direction-dependent part (beyond their level), the joint
compliance, and the tool point (a UR controller takes it as its TCP setting): :func:`write_ur_kinematics` states
them, and the **residual** they leave, measured by re-simulating: the file's kinematics (the URDF with these
origins, rebuilt by :func:`urdf_with_origins` and Drake's parser) against the identified model on
:data:`RESIDUAL_POSES` seeded random poses within the identified ranges.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass, field

import numpy as np

from olti_drake.errors import InputError

#: The segments of a UR kinematics file, in chain order (the link each joint moves).
UR_SEGMENTS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
#: Random poses of the residual's re-simulation (issue 26: 10⁴).
RESIDUAL_POSES = 10_000


@dataclass
class UrKinematicsReport:
    """What a written file holds: ``segments`` {segment: (x, y, z m, roll, pitch, yaw rad)}, ``hash``; and what
    it leaves: ``cannot_hold`` (phrases), ``residual_rms_mm`` / ``residual_max_mm`` of the tool point over the
    re-simulated poses (the file's kinematics with the identified tool point vs the identified model)."""

    segments: dict
    hash: str
    cannot_hold: list = field(default_factory=list)
    residual_rms_mm: float = 0.0
    residual_max_mm: float = 0.0


def ur_segments(model, source_path) -> dict:
    """{segment: (x, y, z, roll, pitch, yaw)} (m, rad) of ``model``'s identified origins (module docstring)."""
    from pydrake.math import RollPitchYaw

    from olti_drake.io.identified_urdf import identified_origins, read_urdf
    from olti_drake.io.ros2_control import joint_offsets

    chain = model.chain
    if chain.n_joints != len(UR_SEGMENTS):
        raise InputError(f"--ur-kinematics-out: a UR kinematics file holds {len(UR_SEGMENTS)} joints, the robot has "
                         f"{chain.n_joints} ({', '.join(chain.joint_names)})")
    _, root = read_urdf(source_path, "--ur-kinematics-out")
    levels = joint_offsets(model)
    offsets = {i: levels[j][0] for i, j in enumerate(chain.joint_names)}
    out = {}
    for segment, (_, origin) in zip(UR_SEGMENTS, identified_origins(model, root, os.fspath(source_path), offsets)):
        out[segment] = tuple(float(v) for v in origin.translation()) + \
            tuple(float(v) for v in RollPitchYaw(origin.rotation()).vector())
    return out


def _hash(segments: dict) -> str:
    text = ";".join(f"{k}:" + ",".join(repr(v) for v in segments[k]) for k in UR_SEGMENTS)
    return "calib_olti_" + hashlib.sha256(text.encode()).hexdigest()[:16]


def _number(v: float) -> str:
    # always a decimal point and an exponent: YAML 1.1 readers take "1e-05" for a string
    return f"{float(v):.17e}"


def write_ur_kinematics(model, source_path, out_path, robot_file: str, result_path) -> UrKinematicsReport:
    """Write ``out_path`` (module docstring); returns its :class:`UrKinematicsReport` (residual re-simulated)."""
    from olti_drake.io.outputs import writing

    segments = ur_segments(model, source_path)
    report = UrKinematicsReport(segments, _hash(segments))
    report.cannot_hold = _cannot_hold(model)
    report.residual_rms_mm, report.residual_max_mm = residual(model, source_path, segments)
    lines = [f"# olti compensate --ur-kinematics-out: identified kinematics of {robot_file} ({model.kind} model, "
             f"result {result_path})",
             "# UNITS: METRES and RADIANS (ur_description's); every other file olti writes is mm and degrees",
             "# per segment the origin of the joint that moves it, with the identified location error and angle "
             "offset folded in",
             f"# tool point (the controller's TCP, tool frame {model.chain.tool_frame}): "
             + ", ".join(f"{v:.6f}" for v in _tool(model)) + " mm",
             *(f"# not held: {t}" for t in report.cannot_hold),
             f"# residual of the tool point, this file vs the identified model, {RESIDUAL_POSES} random poses: RMS "
             f"{1e3 * report.residual_rms_mm:.4g} um, max {1e3 * report.residual_max_mm:.4g} um",
             "kinematics:"]
    for segment in UR_SEGMENTS:
        lines.append(f"  {segment}:")
        for key, v in zip(("x", "y", "z", "roll", "pitch", "yaw"), segments[segment]):
            lines.append(f"    {key}: {_number(v)}")
    lines.append(f"  hash: {report.hash}")
    with writing(out_path) as f:
        f.write("\n".join(lines) + "\n")
    return report


def _tool(model) -> np.ndarray:
    """The identified tool point (3,) mm in the tool frame (the chain's last three parameters)."""
    return model.chain_parameters(model.start_vector())[-3:]


def _cannot_hold(model) -> list:
    out = []
    if model.maps:
        out.append("the error maps' command- and direction-dependent part (their level is folded in as the joints' "
                   "offsets; the compensated commands or --tables carry the rest)")
    if len(getattr(model, "compliance_joints", ())):
        out.append("the joint compliance (gravity-dependent)")
    out.append("the tool point: set it as the controller's TCP")
    return out


def residual(model, source_path, segments, poses: int = RESIDUAL_POSES, seed: int = 0):
    """(RMS, max) mm of ‖p_file − p_model‖ over ``poses`` seeded random commands within the identified ranges (a
    map's grid, else the joint's limits) and random directions: p_file the tool point of the URDF whose chain
    joints carry ``segments`` as origins (loaded by Drake's parser), at the identified tool point."""
    from olti_drake.model.chain import load_serial_chain

    chain = model.chain
    rng = np.random.default_rng(seed)
    lo, hi = _ranges(model)
    cmd = rng.uniform(lo, hi, (poses, chain.n_joints))
    dirs = np.where(rng.random((poses, chain.n_joints)) < 0.5, -1.0, 1.0)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "ur_kinematics.urdf")
        urdf_with_origins(source_path, segments, chain.joint_names, path)
        file_chain = load_serial_chain(path, chain.tool_frame)
    p_file = tool_points(file_chain, cmd, _tool(model))
    p_model = model.positions(cmd, dirs if model.maps else None)
    d = np.linalg.norm(p_file - p_model, axis=1)
    return float(np.sqrt(np.mean(d ** 2))), float(d.max())


def _ranges(model):
    chain = model.chain
    lo = np.where(np.isfinite(chain.lower_deg), chain.lower_deg, -180.0)
    hi = np.where(np.isfinite(chain.upper_deg), chain.upper_deg, 180.0)
    for m in model.maps:
        i = list(chain.joint_names).index(m.joint)
        lo[i], hi[i] = m.emap.grid_deg[0], m.emap.grid_deg[-1]
    return lo, hi


def tool_points(chain, commands_deg, tool_mm) -> np.ndarray:
    """The tool points (M, 3) mm of a chain at its file's geometry (no errors) and the tool offset ``tool_mm``."""
    params = np.asarray(chain.nominal_parameters(), float).copy()
    params[-3:] = tool_mm
    return chain.positions(np.asarray(commands_deg, float), params)


def urdf_with_origins(source_path, segments, joint_names, out_path) -> None:
    """``source_path``'s URDF with the chain joints' origins set to ``segments`` (a UR kinematics file's values,
    chain order; m, rad): the robot the file describes."""
    import xml.etree.ElementTree as ET

    from olti_drake.io.identified_urdf import read_urdf

    tree, root = read_urdf(source_path, "a UR kinematics file")
    for joint_name, segment in zip(joint_names, UR_SEGMENTS):
        joint = root.find(f"joint[@name='{joint_name}']")
        origin = joint.find("origin")
        if origin is None:
            origin = ET.SubElement(joint, "origin")
        v = segments[segment]
        origin.set("xyz", " ".join(repr(float(a)) for a in v[:3]))
        origin.set("rpy", " ".join(repr(float(a)) for a in v[3:]))
    tree.write(out_path, encoding="unicode", xml_declaration=True)
