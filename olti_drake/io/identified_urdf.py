"""The identified URDF (``olti compensate --urdf-out``): the robot's own model file with the identified
geometry written into it, for Drake, MoveIt or a controller.

Every joint on the chain gets its identified location error folded into its ``<origin>``:
origin_i ← origin_i · Δ_i (Δ_i = Trans(δx, δy, δz) · Rx(δrx) Ry(δry) Rz(δrz), the chain model of
:mod:`olti_drake.model.chain`), and for a ``dh`` result its constant angle offset as a rotation about the
joint axis; the tool point becomes a link ``<tool frame>_tool_point`` fixed to the tool frame's link at the
identified offset. The error maps (command- and direction-dependent) have no URDF form: the file is the
model's geometric part, and the compensated commands carry the maps. Everything else in the file (links,
inertias, shapes, limits, other joints) is kept. URDF lengths are metres (converted here from the model's
mm; angles from deg to rad).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np

from olti_drake.errors import InputError


def _pose(origin):
    from pydrake.math import RigidTransform, RollPitchYaw

    xyz = [float(v) for v in (origin.get("xyz", "0 0 0") if origin is not None else "0 0 0").split()]
    rpy = [float(v) for v in (origin.get("rpy", "0 0 0") if origin is not None else "0 0 0").split()]
    return RigidTransform(RollPitchYaw(rpy), xyz)


def _set_origin(joint, pose) -> None:
    from pydrake.math import RollPitchYaw

    origin = joint.find("origin")
    if origin is None:
        origin = ET.SubElement(joint, "origin")
    origin.set("xyz", " ".join(repr(float(v)) for v in pose.translation()))
    origin.set("rpy", " ".join(repr(float(v)) for v in RollPitchYaw(pose.rotation()).vector()))


def identified_pose(chain_params, i: int, offset_deg: float = 0.0):
    """Δ_i (and Rot(axis, offset)) of joint i as a Drake RigidTransform in metres."""
    from pydrake.math import RigidTransform, RotationMatrix

    g = np.asarray(chain_params, float)[6 * i:6 * i + 6]
    rot = (RotationMatrix.MakeXRotation(np.radians(g[3])) @ RotationMatrix.MakeYRotation(np.radians(g[4]))
           @ RotationMatrix.MakeZRotation(np.radians(g[5])))
    return RigidTransform(rot, g[:3] / 1000.0), np.radians(offset_deg)


def identified_origins(model, root, name: str, offsets_deg: dict) -> list:
    """[(the URDF ``<joint>`` element, its identified origin)] of every chain joint, chain order: origin_i · Δ_i ·
    Rot(axis_i, offset_i) (metres; module docstring), ``offsets_deg`` {chain index: deg} the angle offsets to
    fold in. ``root``: the URDF's ``<robot>`` element; ``name``: the file, for messages."""
    from pydrake.common.eigen_geometry import AngleAxis
    from pydrake.math import RigidTransform, RotationMatrix

    chain = model.chain
    params = model.chain_parameters(model.start_vector())
    out = []
    for i, joint_name in enumerate(chain.joint_names):
        joint = root.find(f"joint[@name='{joint_name}']")
        if joint is None:
            raise InputError(f"{name}: joint '{joint_name}' of the chain is not a <joint> of the URDF")
        delta, angle = identified_pose(params, i, offsets_deg.get(i, 0.0))
        turn = RigidTransform(RotationMatrix(AngleAxis(angle, np.asarray(chain.axes[i], float))), np.zeros(3))
        out.append((joint, _pose(joint.find("origin")) @ delta @ turn))
    return out


def read_urdf(source_path, what: str):
    """(tree, ``<robot>`` root) of a URDF file, refused in one line naming ``what`` needs it."""
    name = os.fspath(source_path)
    try:
        tree = ET.parse(name, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    except (ET.ParseError, OSError) as e:
        raise InputError(f"{name}: cannot read it as URDF for {what} ({e})") from None
    root = tree.getroot()
    if root.tag != "robot":
        raise InputError(f"{what} writes from a URDF; the robot model {name} is not a URDF (root element "
                         f"<{root.tag}>): convert it, or leave {what} out")
    return tree, root


def write_identified_urdf(model, source_path, out_path, comment: str = "") -> str:
    """Write ``out_path``: ``source_path`` (a URDF) with ``model``'s identified geometry (module docstring)."""
    from olti_drake.io.outputs import writing

    name = os.fspath(source_path)
    tree, root = read_urdf(name, "--urdf-out")
    chain = model.chain
    params = model.chain_parameters(model.start_vector())
    offsets = dict(zip(model.offset_joints, model.offset_values))
    for joint, origin in identified_origins(model, root, name, offsets):
        _set_origin(joint, origin)
    tool_link = chain.tool_frame
    if root.find(f"link[@name='{tool_link}']") is None:
        raise InputError(f"{name}: the tool frame '{tool_link}' is not a <link> of the URDF: --urdf-out needs a "
                         f"link as tool frame")
    point = f"{tool_link}_tool_point"
    taken = {e.get("name") for e in root if e.tag in ("link", "joint")}
    while point in taken or point + "_fixed" in taken:
        point += "_"
    ET.SubElement(root, "link", name=point)
    fixed = ET.SubElement(root, "joint", name=point + "_fixed", type="fixed")
    ET.SubElement(fixed, "parent", link=tool_link)
    ET.SubElement(fixed, "child", link=point)
    ET.SubElement(fixed, "origin", xyz=" ".join(repr(float(v) / 1000.0) for v in params[-3:]), rpy="0 0 0")
    comment = comment.replace("--", "- -")  # "--" may not appear in an XML comment
    root.insert(0, ET.Comment(f" identified by olti: joint-origin location errors folded into the chain's joint "
                              f"origins; tool point = link '{point}'. {comment} "))
    ET.indent(tree, space="  ")
    with writing(out_path) as f:
        tree.write(f, encoding="unicode", xml_declaration=True)
        f.write("\n")
    return point
