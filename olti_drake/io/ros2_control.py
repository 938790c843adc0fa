"""The identified joint offsets as ros2_control parameters (``olti compensate --ros2-control-out FILE.yaml``).

ros2_control describes every joint of a transmission with an ``offset`` (``hardware_interface::JointInfo.offset``,
the ``<offset>`` of a ``<joint>`` in the URDF's ``<ros2_control>``/``<transmission>`` tag; a SimpleTransmission
maps joint = actuator / reduction + offset). The offset written here is the identified one, in **radians**
(ros2_control's unit; every other file olti writes is mm and degrees):

    offset_i = actual joint angle − commanded (encoder) angle of joint i,

so a joint state read through that transmission is the actual angle, and a joint command is sent as the
actuator angle that reaches it:

- ``dh`` result: the joint's constant angle offset ``<joint>_offset_deg``;
- ``errormap`` result: the map's level as the result states it (:meth:`SerialPositionModel.level_rows
  <olti_drake.model.serial.SerialPositionModel.level_rows>`): the map at the node-clipped command 0 deg, the
  mean of its +1 and −1 branches for a bidirectional map (the rest of the map, command- and
  direction-dependent, has no ros2_control form: the compensated commands carry it);
- a joint without an identified offset (held by the gauge, or traded with another parameter): 0.

The file is a YAML mapping joint name -> ``{offset: radians}``, in chain order, with comments stating the
units, the result and each value in degrees. The offsets alone do not carry the joints' location errors: those
are in the identified URDF (``--urdf-out``), which for a ``dh`` result already turns each joint origin by its
offset — use these offsets with the robot's nominal URDF (the controller's kinematics), not on top of that
identified URDF.
"""

from __future__ import annotations

import json

import numpy as np


def joint_offsets(model) -> dict:
    """{joint: (offset_deg, what)} of every chain joint (module docstring), chain order."""
    x = model.start_vector()
    levels = model.level_rows()
    out = {}
    for joint in model.chain.joint_names:
        if joint in levels:
            row, text = levels[joint]
            out[joint] = (float(row @ x), text)
        else:
            out[joint] = (0.0, "no offset identified (held at 0)")
    return out


def write_ros2_control_offsets(model, out_path, robot_file: str, result_path) -> dict:
    """Write ``out_path`` (module docstring); returns {joint: offset_rad}."""
    from olti_drake.io.outputs import writing

    offsets = joint_offsets(model)
    rad = {j: float(np.radians(v)) for j, (v, _) in offsets.items()}
    lines = [
        f"# olti compensate --ros2-control-out: identified joint offsets of {robot_file} ({model.kind} model, "
        f"result {result_path})",
        "# UNITS: RADIANS (ros2_control's); every other file olti writes is mm and degrees",
        "# offset = actual joint angle - commanded (encoder) angle: the ros2_control transmission joint's <offset>",
        "#   (hardware_interface::JointInfo.offset; SimpleTransmission: joint = actuator / reduction + offset)",
        "# errormap: the map's level at 0 deg (mean of +1 and -1 approaches); dh: the joint's constant offset",
        "# use with the robot's NOMINAL URDF: the identified URDF (--urdf-out) of a dh result already holds them",
    ]
    for joint, (deg, what) in offsets.items():
        lines.append(f"{json.dumps(joint)}:")
        # always with a decimal point and exponent: YAML 1.1 readers (PyYAML) take "1e-05" for a string
        lines.append(f"  offset: {rad[joint]:.16e}  # {deg:.9g} deg: {what}")
    with writing(out_path) as f:
        f.write("\n".join(lines) + "\n")
    return rad
