"""Serial chains of revolute joints from a URDF or SDFormat model, in 3D.

The position model of a serial robot generalizes 000 Eq. (3): the tool
point is carried through the chain of joint frames,

    p = Π_i [ T_i · Δ_i · Rot(a_i, θ_i) ] · T_tool · t ,

where T_i is the nominal fixed transform from the previous joint's moving
frame (the world for joint 1) to joint i's frame, Δ_i = Trans(δx, δy, δz) ·
Rx(δrx) Ry(δry) Rz(δrz) its location error (the position and orientation of
the joint frame relative to its parent: the general form of the axis average
line errors of 000 §3.1), a_i the joint axis in that frame, θ_i the *actual*
joint angle (command + Δθ_i(θ*_i, dir_i), 000 Eq. (7); the error map is
applied by the caller) and t the tool point's offset from the tool frame.

Units: mm and degrees everywhere in this module (angles, angle offsets,
Jacobian columns: mm/deg for angles, mm/mm for translations); SI only at the
Drake plant (converted in ``load_serial_chain`` and ``drake_kinematics``).
Frame: the model's root frame, welded to the world at the model's origin.

``SerialChain.positions`` / ``jacobian`` evaluate the model vectorized over
poses (numpy, analytic Jacobians); tests hold them equal to Drake's
``CalcPointsPositions`` / ``CalcJacobianTranslationalVelocity`` on the same
plant (``drake_kinematics``) to 1e-9 mm.
"""

from __future__ import annotations

import dataclasses
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence, Tuple

import numpy as np
import scipy.linalg

DEG = np.pi / 180.0
#: Per joint, the location-error parameters (mm, mm, mm, deg, deg, deg).
GEOMETRIC_SUFFIXES = ("dx_mm", "dy_mm", "dz_mm", "drx_deg", "dry_deg", "drz_deg")
TOOL_NAMES = ("tool_x_mm", "tool_y_mm", "tool_z_mm")
FRAME_NAMES = ("frame_x_mm", "frame_y_mm", "frame_z_mm",
               "frame_rx_deg", "frame_ry_deg", "frame_rz_deg")
#: Joint-angle range used where a joint has no limit (continuous joints), deg.
UNLIMITED_RANGE_DEG = 180.0
_FLOATING_TYPES = ("quaternion_floating", "rpy_floating")


@dataclass(frozen=True, eq=False)
class SerialChain:
    """The revolute joints from a model's root to a tool frame, in chain order.

    ``fixed_mm[i]`` (4×4, mm) is the nominal transform from joint i-1's moving
    frame (the world for i = 0) to joint i's frame; ``fixed_mm[N]`` the one to
    the tool frame. ``axes[i]`` is joint i's unit axis in its own frame.
    ``lower_deg`` / ``upper_deg`` are the model's joint limits (±inf for a
    continuous joint). ``notes`` are the things said once about the load
    (geometry ignored, meshes missing). ``plant`` is the finalized Drake plant
    the chain was read from (nominal geometry; no SceneGraph).
    """

    path: str
    tool_frame: str
    root: str
    joint_names: Tuple[str, ...]
    lower_deg: np.ndarray
    upper_deg: np.ndarray
    fixed_mm: np.ndarray
    axes: np.ndarray
    notes: Tuple[str, ...] = ()
    plant: object = field(default=None, repr=False)
    tool_frame_index: object = field(default=None, repr=False)

    def __reduce__(self):
        # Pickled (to worker processes: estimation.trials) without the Drake plant, which does not pickle: the
        # numbers travel as they are, the receiving process reads the plant from ``path`` once (_unpickled_chain).
        state = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                 if f.name not in ("plant", "tool_frame_index")}
        return _unpickled_chain, (state,)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    # ----------------------------------------------------------------- names
    def parameter_names(self) -> Tuple[str, ...]:
        """Names of the model parameters: 6 location errors per joint, then the tool offset."""
        geo = [f"{j}_{s}" for j in self.joint_names for s in GEOMETRIC_SUFFIXES]
        return tuple(geo) + TOOL_NAMES

    def jacobian_names(self) -> Tuple[str, ...]:
        """Names of the Jacobian columns: the joint angles, then ``parameter_names()``."""
        return tuple(f"{j}_deg" for j in self.joint_names) + self.parameter_names()

    def nominal_parameters(self, tool_offset_mm: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        """Zero location errors and the given tool offset (mm)."""
        return np.concatenate([np.zeros(6 * self.n_joints), np.asarray(tool_offset_mm, float)])

    def random_angles(self, n_poses: int, seed: int) -> np.ndarray:
        """(n_poses, N) joint angles (deg) uniform within the model's limits.

        A joint without limits ranges over ±``UNLIMITED_RANGE_DEG``.
        """
        lo = np.where(np.isfinite(self.lower_deg), self.lower_deg, -UNLIMITED_RANGE_DEG)
        hi = np.where(np.isfinite(self.upper_deg), self.upper_deg, UNLIMITED_RANGE_DEG)
        return np.random.default_rng(seed).uniform(lo, hi, size=(n_poses, self.n_joints))

    # ------------------------------------------------------------ kinematics
    def positions(self, theta_deg, params=None) -> np.ndarray:
        """Tool point (M, 3) mm in the root frame for joint angles ``theta_deg`` (M, N) deg.

        ``params`` (6N + 3): the location errors of every joint frame and the
        tool offset (``parameter_names()``; mm, deg); None = nominal, tool
        point at the tool frame's origin. 000 Eq. (3) in 3D.
        """
        return self._forward(theta_deg, params, jacobian=False)[0]

    def jacobian(self, theta_deg, params=None):
        """Tool point (M, 3) mm and its Jacobian (M, 3, 7N + 3), analytic.

        Columns as ``jacobian_names()``: ∂p/∂θ_i (mm/deg; also the sensitivity
        to the error map Δθ_i of 000 Eq. (7)), ∂p/∂δ (mm/mm, mm/deg) for the six
        location errors of each joint frame, ∂p/∂t (mm/mm) for the tool offset.
        """
        return self._forward(theta_deg, params, jacobian=True)

    def _forward(self, theta_deg, params, jacobian: bool):
        n = self.n_joints
        th = np.atleast_2d(np.asarray(theta_deg, dtype=float))
        if th.shape[1] != n:
            raise ValueError(f"joint angles: {th.shape[1]} columns, the chain has {n} joints")
        params = self.nominal_parameters() if params is None else np.asarray(params, float)
        if params.shape != (6 * n + 3,):
            raise ValueError(f"parameters: {params.size} values, expected {6 * n + 3}")
        if not (np.all(np.isfinite(th)) and np.all(np.isfinite(params))):
            raise ValueError("joint angles or parameters: a value is not finite")
        geo = params[:6 * n].reshape(n, 6)
        m = th.shape[0]
        rot = np.broadcast_to(np.eye(3), (m, 3, 3))  # moving frame of joint i-1 in the root
        org = np.zeros((m, 3))
        cols = []  # per joint: (origin of F_i, axis, R_G, u_rx, u_ry, u_rz), in the root frame
        for i in range(n):
            fixed = self.fixed_mm[i]
            rx, ry, rz = (_axis_rotation(e, geo[i, 3 + k] * DEG) for k, e in enumerate(np.eye(3)))
            rot_g = _times(rot, fixed[:3, :3])
            org_f = org + _times(rot, fixed[:3, 3]) + _times(rot_g, geo[i, :3])
            rot_f = _times(rot_g, rx @ ry @ rz)
            axis = _times(rot_f, self.axes[i])
            if jacobian:
                cols.append((org_f, axis, rot_g, _times(rot_g, rx[:, 0]),
                             _times(rot_g, (rx @ ry)[:, 1]), rot_f[..., 2]))
            rot = _rotate_about(rot_f, self.axes[i], th[:, i] * DEG)
            org = org_f
        tool = self.fixed_mm[n]
        rot_t = _times(rot, tool[:3, :3])
        p = org + _times(rot, tool[:3, 3]) + _times(rot_t, params[6 * n:])
        if not jacobian:
            return p, None
        jac = np.empty((m, 3, 7 * n + 3))
        for i, (org_f, axis, rot_g, ux, uy, uz) in enumerate(cols):
            r = p - org_f
            jac[:, :, i] = _cross(axis, r) * DEG
            base = n + 6 * i
            jac[:, :, base:base + 3] = rot_g
            for k, u in enumerate((ux, uy, uz)):
                jac[:, :, base + 3 + k] = _cross(u, r) * DEG
        jac[:, :, 7 * n:] = rot_t
        return p, jac


#: (path, tool frame) -> (plant, tool frame index) read in this process by :func:`_unpickled_chain`.
_PLANTS = {}


def _unpickled_chain(state: dict) -> SerialChain:
    """A pickled :class:`SerialChain` with its plant read again from its file, once per process; without a plant
    where the file is not (a cluster's worker on another machine: the chain's kinematics need none)."""
    key = (state["path"], state["tool_frame"])
    if key not in _PLANTS:
        try:
            loaded = load_serial_chain(*key)
            _PLANTS[key] = (loaded.plant, loaded.tool_frame_index)
        except ValueError:  # (the file is not on this machine)
            _PLANTS[key] = (None, None)
    plant, frame = _PLANTS[key]
    return SerialChain(**state, plant=plant, tool_frame_index=frame)


def _times(stack, const):
    """Stacked rotations (M, 3, 3) times a constant 3×3 matrix or 3-vector, as one GEMM."""
    m = stack.shape[0]
    out = np.reshape(stack, (3 * m, 3)) @ const
    return out.reshape((m, 3, 3) if np.ndim(const) == 2 else (m, 3))


def _rotate_about(stack, axis, angle_rad):
    """stack · Rot(axis, angle) for (M,) angles, Rodrigues: R + sin·(R K) + (1 - cos)·(R K²)."""
    k = _skew(axis)
    s = np.sin(angle_rad)[:, None, None]
    c = np.cos(angle_rad)[:, None, None]
    return stack + s * _times(stack, k) + (1.0 - c) * _times(stack, k @ k)


def _cross(a, b):
    """Row-wise cross product of (M, 3) arrays (cheaper than np.cross for small rows)."""
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1],
                     a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _axis_rotation(axis, angle_rad: float) -> np.ndarray:
    """The 3×3 rotation about a unit ``axis`` by a scalar ``angle_rad`` (Rodrigues)."""
    k = _skew(axis)
    return np.eye(3) + np.sin(angle_rad) * k + (1.0 - np.cos(angle_rad)) * (k @ k)


# --------------------------------------------------------------------- loading
def load_serial_chain(path, tool_frame: str) -> SerialChain:
    """Read a URDF/SDFormat file with Drake's ``Parser`` and take the chain to ``tool_frame``.

    The plant has no SceneGraph, so visual and collision geometry are never
    loaded: a model without geometry, or whose meshes cannot be found, loads
    for calibration (kinematics only) and ``notes`` says so. The model's root
    (its first body without a parent joint) is welded to the world at the
    model's origin. The revolute joints (URDF ``continuous`` ones included)
    from the root to the tool frame are the chain, in chain order; fixed
    joints on it are folded into the fixed transforms; joints off it (fingers,
    other branches) are ignored. Raises ValueError (one line, naming the file
    and the frame or joint) when the tool frame is missing or not downstream
    of the root, or a joint on the chain is not revolute.
    """
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"robot model {path}: file not found")
    if path.name.endswith(".xacro"):  # ROS macro files are not robot descriptions until expanded
        raise ValueError(f"robot model {path}: a xacro file; expand it first (xacro {path.name} > robot.urdf) and "
                         f"give the URDF")
    _check_limits(path)
    plant = MultibodyPlant(0.0)
    parser = Parser(plant)
    try:
        instances = parser.AddModels(str(path))
    except (RuntimeError, ValueError, SystemExit) as exc:  # (pydrake raises SystemExit for a failed Drake check)
        raise ValueError(f"robot model {path}: {_first_line(exc)}") from None
    root = _weld_root(plant, instances, path)
    plant.Finalize()
    frame = _find_tool_frame(plant, instances, path, tool_frame)
    joints = _chain_joints(plant, frame, root, path)
    context = plant.CreateDefaultContext()
    fixed = []
    previous = plant.world_frame()
    for joint in joints:
        fixed.append(_pose_mm(plant.CalcRelativeTransform(context, previous, joint.frame_on_parent())))
        previous = joint.frame_on_child()
    fixed.append(_pose_mm(plant.CalcRelativeTransform(context, previous, frame)))
    limits = np.array([[j.position_lower_limits()[0], j.position_upper_limits()[0]] for j in joints])
    return SerialChain(
        path=str(path), tool_frame=tool_frame, root=root,
        joint_names=tuple(j.name() for j in joints),
        lower_deg=limits[:, 0] / DEG, upper_deg=limits[:, 1] / DEG,
        fixed_mm=np.array(fixed), axes=np.array([j.revolute_axis() for j in joints]),
        notes=tuple(_geometry_notes(path, parser.package_map())), plant=plant,
        tool_frame_index=frame.index())


def _check_limits(path: Path) -> None:
    """Joint limits read before Drake sees them: a lower limit above the upper one (URDF ``<limit lower upper>``,
    SDFormat ``<axis><limit><lower>/<upper>``) would end the process in a Drake assertion; refused naming the file
    and the joint. A file that is not XML is left to Drake's parser (its message names the line)."""
    import xml.etree.ElementTree as ET

    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        return
    for joint in root.iter():
        if _local(joint.tag) != "joint":
            continue
        limit = next((c for c in joint.iter() if _local(c.tag) == "limit"), None)
        if limit is None:
            continue
        bounds = [limit.get(k) for k in ("lower", "upper")]
        if bounds == [None, None]:  # SDFormat: the bounds are child elements
            bounds = [next((c.text for c in limit if _local(c.tag) == k), None) for k in ("lower", "upper")]
        try:
            lower, upper = (float(b) for b in bounds)
        except (TypeError, ValueError):
            continue  # (absent or not a number: Drake's parser says so, naming the line)
        if not lower <= upper:
            raise ValueError(f"robot model {path}: joint '{joint.get('name')}' has its lower limit {lower:g} above "
                             f"its upper limit {upper:g} (rad for a revolute joint): swap them")


def _first_line(exc) -> str:
    """The first non-empty line of Drake's message without its own ``error:`` (the CLI puts one first):
    ``FILE:LINE: error: text`` -> ``line LINE: text`` (the file is named by the caller), ``error: text`` -> text."""
    import re

    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    first = lines[0] if lines else type(exc).__name__
    located = re.match(r"^.*?:(\d+): error: (.*)$", first)
    if located:
        return f"line {located.group(1)}: {located.group(2)}"
    return first[len("error:"):].strip() if first.lower().startswith("error:") else first


def _pose_mm(transform) -> np.ndarray:
    pose = transform.GetAsMatrix4()
    pose[:3, 3] *= 1000.0
    return pose


def _weld_root(plant, instances, path) -> str:
    """Weld the model's root body to the world at its default pose; return its name.

    The root is the first body of the model that no joint has as child. If
    the model is already attached to the world (a URDF ``world`` link), the
    root is the world. Other free bodies stay floating (nothing downstream of
    them can be on the chain).
    """
    children = {plant.get_joint(j).child_body().index() for j in plant.GetJointIndices()}
    bodies = [plant.get_body(b) for m in instances for b in plant.GetBodyIndices(m)]
    free = [b for b in bodies if b.index() not in children]
    if not bodies:
        raise ValueError(f"robot model {path}: no links")
    if not free:
        return plant.world_body().name()
    root = free[0]
    plant.WeldFrames(plant.world_frame(), root.body_frame(),
                     plant.GetDefaultFloatingBaseBodyPose(root))
    return root.name()


def _find_tool_frame(plant, instances, path, name):
    frames = [plant.get_frame(f) for m in instances for f in plant.GetFrameIndices(m)]
    matches = [f for f in frames if f.name() == name]
    if len(matches) == 1:
        return matches[0]
    if matches:
        raise ValueError(f"tool frame '{name}' is ambiguous in {path}: "
                         f"{len(matches)} frames have that name")
    joint_frames = set()
    for j in plant.GetJointIndices():
        joint = plant.get_joint(j)
        joint_frames |= {joint.frame_on_parent().index(), joint.frame_on_child().index()}
    names = [f.name() for f in frames
             if f.index() not in joint_frames or f.index() == f.body().body_frame().index()]
    shown = ", ".join(names[:25]) + (", ..." if len(names) > 25 else "")
    raise ValueError(f"tool frame '{name}' not found in {path}; frames: {shown}")


def _chain_joints(plant, frame, root, path):
    """The revolute joints from the world to ``frame``'s body, in chain order."""
    inboard = {plant.get_joint(j).child_body().index(): plant.get_joint(j)
               for j in plant.GetJointIndices()}
    world = plant.world_body().index()
    body = frame.body()
    chain = []
    while body.index() != world:
        joint = inboard[body.index()]
        kind = joint.type_name()
        if kind in _FLOATING_TYPES:
            raise ValueError(f"tool frame '{frame.name()}' is not downstream of the root '{root}' "
                             f"in {path}: it hangs on the free body '{body.name()}'")
        if kind == "revolute":
            chain.append(joint)
        elif kind != "weld":
            raise ValueError(f"joint '{joint.name()}' on the chain from '{root}' to "
                             f"'{frame.name()}' in {path} is {kind}: only revolute joints are "
                             f"supported (choose a tool frame before it)")
        body = joint.parent_body()
    if not chain:
        raise ValueError(f"no revolute joint between the root '{root}' and the tool frame "
                         f"'{frame.name()}' in {path}")
    return chain[::-1]


# -------------------------------------------------------------------- geometry
def _geometry_notes(path: Path, package_map) -> list:
    """What to say once about the model's geometry (none, or meshes that cannot be found)."""
    try:
        tree = ET.parse(path)
    except ET.ParseError:
        return []
    tags = [(_local(e.tag), e) for e in tree.iter()]
    if not any(t in ("visual", "collision") for t, _ in tags):
        return [f"{path}: no visual or collision geometry; loaded for calibration (kinematics only)"]
    uris = [e.get("filename") for t, e in tags if t == "mesh" and e.get("filename")]
    parents = {child: parent for parent in tree.iter() for child in parent}
    uris += [(e.text or "").strip() for t, e in tags
             if t == "uri" and e in parents and _local(parents[e].tag) == "mesh"]
    missing = [u for u in uris if u and not _mesh_found(u, path.parent, package_map)]
    if not missing:
        return []
    return [f"{path}: {len(missing)} mesh file(s) cannot be found (first: '{missing[0]}'); "
            f"loaded for calibration (kinematics only), without those shapes"]


def _local(tag) -> str:
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _mesh_found(uri: str, folder: Path, package_map) -> bool:
    """Whether a mesh URI resolves to an existing file (no download is attempted)."""
    for scheme in ("package://", "model://"):
        if uri.startswith(scheme):
            package, _, rest = uri[len(scheme):].partition("/")
            if not package_map.Contains(package):
                return False
            if package == "drake_models":  # a remote package: would need the network
                return True
            return os.path.exists(os.path.join(package_map.GetPath(package), rest))
    if uri.startswith("file://"):
        return os.path.exists(uri[len("file://"):])
    return os.path.exists(folder / uri)


# --------------------------------------------------------------- Drake oracle
def _posed(chain: SerialChain, theta_deg):
    """Yield (k, the nominal plant's context with the chain's joints at row k of ``theta_deg`` (M, N) deg);
    joints off the chain stay at their defaults. One context, re-posed: use it before the next row."""
    plant = chain.plant
    context = plant.CreateDefaultContext()
    joints = [plant.GetJointByName(name) for name in chain.joint_names]
    for k, row in enumerate(np.atleast_2d(np.asarray(theta_deg, dtype=float)) * DEG):
        for joint, angle in zip(joints, row):
            joint.set_angle(context, angle)
        yield k, context


def drake_kinematics(chain: SerialChain, theta_deg, tool_offset_mm=(0.0, 0.0, 0.0),
                     jacobian: bool = True):
    """The same tool point and joint-angle Jacobian from the Drake plant, one pose at a time.

    Nominal geometry only (the plant's). Returns positions (M, 3) mm and, if
    asked, ∂p/∂θ (M, 3, N) mm/deg by ``CalcPointsPositions`` and
    ``CalcJacobianTranslationalVelocity``. The reference the vectorized model
    is tested against, and the baseline of ``benchmarks/bench_chain.py``.
    """
    from pydrake.multibody.tree import JacobianWrtVariable

    plant = chain.plant
    starts = [plant.GetJointByName(name).position_start() for name in chain.joint_names]
    frame = plant.get_frame(chain.tool_frame_index)
    world = plant.world_frame()
    point = np.asarray(tool_offset_mm, float).reshape(3, 1) / 1000.0
    m = np.atleast_2d(theta_deg).shape[0]
    positions = np.empty((m, 3))
    jac = np.empty((m, 3, chain.n_joints)) if jacobian else None
    for k, context in _posed(chain, theta_deg):
        positions[k] = plant.CalcPointsPositions(context, frame, point, world)[:, 0] * 1000.0
        if jacobian:
            full = plant.CalcJacobianTranslationalVelocity(
                context, JacobianWrtVariable.kQDot, frame, point, world, world)
            jac[k] = full[:, starts] * 1000.0 * DEG
    return positions, jac


def gravity_torques(chain: SerialChain, theta_deg, payload_kg: float = 0.0, tool_offset_mm=(0.0, 0.0, 0.0)):
    """Torque gravity applies about each chain joint, (M, N) N·m, at joint angles (M, N) deg.

    From the model file's masses and centres of mass by Drake's ``CalcGravityGeneralizedForces``
    (the nominal plant; joints off the chain at their default positions), plus an optional point
    ``payload_kg`` at the tool point. The sign is Drake's: the generalized force gravity exerts, so a
    compliant joint deflects by +c·τ (the joint compliance model of ``--compliance``). A model
    without inertial data gives zeros (and the compliance is then not identifiable, said by name).
    """
    from pydrake.multibody.tree import JacobianWrtVariable

    plant = chain.plant
    vstarts = [plant.GetJointByName(name).velocity_start() for name in chain.joint_names]
    frame = plant.get_frame(chain.tool_frame_index)
    world = plant.world_frame()
    point = np.asarray(tool_offset_mm, float).reshape(3, 1) / 1000.0
    weight = np.array([0.0, 0.0, -9.81 * payload_kg])
    out = np.empty(np.atleast_2d(theta_deg).shape)
    for k, context in _posed(chain, theta_deg):
        tau = plant.CalcGravityGeneralizedForces(context)
        out[k] = tau[vstarts]
        if payload_kg:
            jv = plant.CalcJacobianTranslationalVelocity(context, JacobianWrtVariable.kV, frame, point, world, world)
            out[k] += (jv[:, vstarts].T @ weight)
    return out


# ------------------------------------------------------------------- base set
@dataclass(frozen=True)
class BaseSet:
    """An identifiable (base) set of the model's parameters.

    ``kept`` names the parameters identified, ``dropped`` pairs each other
    parameter with the reason. ``independence`` is, per parameter, the part of
    its (unit-normalized) Jacobian column that the parameters before it in
    priority order cannot explain (pivoted QR diagonal); a parameter is kept
    when that exceeds ``rtol``.
    """

    kept: Tuple[str, ...]
    dropped: Tuple[Tuple[str, str], ...]
    independence: dict
    rtol: float
    n_poses: int
    seed: int

    @property
    def gap(self) -> float:
        """Smallest kept independence over the largest dropped one (a clear cut is ≫ 1)."""
        kept = min(self.independence[n] for n in self.kept)
        dropped = max((self.independence[n] for n, _ in self.dropped), default=0.0)
        return kept / dropped if dropped > 0 else np.inf


#: Relative size (of the reach) below which the tool points of random poses count as lying in one plane.
PLANAR_RTOL = 1e-9


def planar_axis(chain: SerialChain, params=None, *, n_poses: int = 40, seed: int = 0):
    """The root axis (0, 1, 2 for x, y, z) normal to the plane the tool point never leaves, or None.

    A planar robot (every joint axis along one root axis, e.g. the SCARA's J1, J2 about z) keeps
    its nominal tool point at one height along that axis over any pose: tested on ``n_poses``
    seeded random poses within the limits (spread below :data:`PLANAR_RTOL` of the reach). A plane
    not normal to a root axis is not recognised (None): the model file's root frame is expected
    to have the axes along one of its own axes, as a SCARA's has.
    """
    p = chain.positions(chain.random_angles(n_poses, seed), params)
    reach = max(float(np.abs(p).max()), 1.0)
    spread = np.ptp(p, axis=0)
    flat = np.flatnonzero(spread < PLANAR_RTOL * reach)
    return int(flat[0]) if flat.size == 1 else None


def planar_normal(chain: SerialChain, params=None, *, n_poses: int = 40, seed: int = 0):
    """The unit normal (3,) of the plane the tool point never leaves, whatever its direction (a SCARA whose
    model file tilts its base), or None: the smallest singular value of the centred tool points of ``n_poses``
    seeded random poses below :data:`PLANAR_RTOL` of the reach. :func:`planar_axis` is the root-axis case."""
    p = chain.positions(chain.random_angles(n_poses, seed), params)
    reach = max(float(np.abs(p).max()), 1.0)
    _, sv, vt = np.linalg.svd(p - p.mean(axis=0), full_matrices=False)
    if sv[-1] >= PLANAR_RTOL * reach * np.sqrt(len(p)) or sv[-2] < PLANAR_RTOL * reach * np.sqrt(len(p)):
        return None
    n = vt[-1] / np.linalg.norm(vt[-1])
    # Oriented up the root z (then along its largest component): "below the plane" is then the floor's side.
    lead = 2 if abs(n[2]) > 1e-12 else int(np.argmax(np.abs(n)))
    return n if n[lead] > 0 else -n


def robot_plane(chain: SerialChain, params=None):
    """A planar robot's plane: the root axis normal to it (:func:`planar_axis`, an int), else its unit normal
    (:func:`planar_normal`, (3,): a model file that tilts the robot's base), else None (not planar)."""
    axis = planar_axis(chain, params)
    return axis if axis is not None else planar_normal(chain, params)


def plane_frame(plane):
    """(n (3,), E (3, 2), h): the unit normal of ``plane`` (a root axis 0-2, or a normal (3,)), an
    orthonormal in-plane basis E, and the root axis h along which the normal is largest. For a root axis
    (or a normal along one) E is the other two root axes in order and n that axis: projections on them are
    the plain coordinates, bit for bit."""
    if np.ndim(plane) == 0 or np.count_nonzero(plane) == 1:
        h = int(plane) if np.ndim(plane) == 0 else int(np.flatnonzero(plane)[0])
        return np.eye(3)[h], np.eye(3)[:, [c for c in range(3) if c != h]], h
    n = np.asarray(plane, float) / np.linalg.norm(plane)
    E = np.linalg.svd(np.eye(3) - np.outer(n, n))[0][:, :2]
    return n, E, int(np.argmax(np.abs(n)))


#: How :func:`planar_reason` begins: what marks a parameter the planar reduction held (results keep the reason).
PLANAR_REASON = "out of the plane"


def planar_reason(plane) -> str:
    """Why a planar robot's readings cannot see a parameter that moves the tool point out of its plane
    (``plane``: a root axis or a unit normal, :func:`robot_plane`)."""
    if np.ndim(plane) == 0:
        name = "xyz"[int(plane)]
        where = f"every joint axis along {name}) keeps the tool point at one {name}"
    else:
        normal = ", ".join(f"{c:.4g}" for c in plane_frame(plane)[0])
        where = f"every joint axis along its plane's normal ({normal})) keeps the tool point in one plane"
    return (f"{PLANAR_REASON}: a planar robot ({where}, and readings in that plane see this parameter only at "
            f"second order (cosine) or as a combination of the in-plane ones; held at its start value")


def base_parameter_set(chain: SerialChain, params=None, *, n_poses: int = 60, seed: int = 0,
                       rtol: float = 1e-8, measurement_frame: str = "known",
                       offsets: bool = True, planar: Optional[int] = None) -> BaseSet:
    """Reduce the position model's parameters to an identifiable set (position-only readings).

    The Jacobian of the tool point at ``n_poses`` seeded random poses within
    the joint limits, columns scaled to unit norm, is factorized group by
    group in priority order by QR with column pivoting (``scipy.linalg.qr``),
    each group after projecting out the columns kept before it:

    1. ``frame_*`` — the 6 freedoms of an unknown measurement frame
       (``measurement_frame="unknown"``: a tracker, or stations whose
       placement is estimated); absent when readings are in the root frame;
    2. ``tool_*`` — the tool-point offset (3, mm);
    3. ``<joint>_offset_deg`` — a constant angle offset per joint, i.e. the
       constant part of its error map (000 Eq. (7)); ``offsets=False`` leaves
       them out (a model without error maps);
    4. the six location errors of every joint frame (``parameter_names()``).

    A parameter is kept when more than ``rtol`` of its column is independent
    of those kept before it. Each dropped one is reported with the kept
    parameters it trades with (least-squares combination of their columns).
    For a generic chain of R revolute joints the known count of independent
    kinematic parameters with full-pose readings is 4R + 6; with position
    readings the tool orientation (3) is unobservable, so 4R + 3 remain.

    ``planar``: a planar robot's plane (:func:`robot_plane`: the root axis normal to it, or its unit
    normal), for readings in that plane (distances to stations at the tool point's height, 000 Eq. (10)).
    Every parameter whose column has a component along the normal at some pose (a shift along it, a
    tilt of a joint frame, the tool offset along it) is dropped first with :func:`planar_reason`, and
    the rest is ranked on the in-plane components only: the SCARA's J1, J2 keep 2R + 2 = 6 (J1 dx, dy and offset: the
    base's place and turn; J2 dx = L1 − 325 mm, tool x = L2 − 225 mm, tool y; J2's offset θ20 trades
    with tool y: (L2, θ20) in polar form).
    """
    if measurement_frame not in ("known", "unknown"):
        raise ValueError(f"measurement_frame: 'known' or 'unknown', not {measurement_frame!r}")
    params = chain.nominal_parameters() if params is None else np.asarray(params, float)
    n = chain.n_joints
    p, jac = chain.jacobian(chain.random_angles(n_poses, seed), params)
    names = list(chain.jacobian_names())
    names[:n] = [f"{j}_offset_deg" for j in chain.joint_names]
    columns = jac.reshape(-1, jac.shape[2])
    groups = [list(range(7 * n, 7 * n + 3)), list(range(n, 7 * n))]
    if offsets:
        groups.insert(1, list(range(n)))
    if measurement_frame == "unknown":
        frame = _frame_columns(p)
        columns = np.hstack([columns, frame])
        names += list(FRAME_NAMES)
        groups.insert(0, list(range(7 * n + 3, 7 * n + 9)))
    if planar is None:
        return _staged_rank(columns, names, groups, rtol, n_poses, seed)
    rows = columns.reshape(-1, 3, columns.shape[1])
    n_vec, E, _ = plane_frame(planar)
    normal = np.abs(np.einsum("i,mik->mk", n_vec, rows)).max(axis=0)
    out = normal > 1e-9 * max(np.abs(columns).max(), 1e-300)
    groups = [[c for c in g if not out[c]] for g in groups]
    in_plane = np.einsum("ij,mik->mjk", E, rows)  # (a root axis: the other two coordinates, exactly)
    base = _staged_rank(in_plane.reshape(-1, columns.shape[1]), names, groups, rtol, n_poses, seed)
    held = tuple((names[c], planar_reason(planar)) for c in np.flatnonzero(out))
    return dataclasses.replace(base, dropped=held + base.dropped,
                               independence={**base.independence, **{name: 0.0 for name, _ in held}})


def _frame_columns(p) -> np.ndarray:
    """Jacobian (3M, 6) of the points under a small rigid motion of the frame (mm, deg)."""
    m = p.shape[0]
    out = np.zeros((m, 3, 6))
    out[:, :, :3] = np.eye(3)
    for k, e in enumerate(np.eye(3)):
        out[:, :, 3 + k] = np.cross(e, p) * DEG
    return out.reshape(3 * m, 6)


def _staged_rank(columns, names, groups, rtol, n_poses, seed) -> BaseSet:
    norms = np.linalg.norm(columns, axis=0)
    scale = np.where(norms > 0, norms, 1.0)
    unit = columns / scale
    touched = norms > 1e-12 * norms.max()
    basis = np.zeros((unit.shape[0], 0))
    kept, independence, untouched = [], {}, []
    for group in groups:
        idx = [c for c in group if touched[c]]
        untouched += [c for c in group if not touched[c]]
        if not idx:
            continue
        rest = unit[:, idx] - basis @ (basis.T @ unit[:, idx])
        q, r, piv = scipy.linalg.qr(rest, mode="economic", pivoting=True)
        diag = np.abs(np.diag(r))
        diag = np.concatenate([diag, np.zeros(len(idx) - diag.size)])
        for d, c in zip(diag, np.asarray(idx)[piv]):
            independence[names[c]] = float(d)
        count = int(np.sum(diag > rtol))
        kept += [idx[k] for k in piv[:count]]
        basis = np.hstack([basis, q[:, :count]])
    kept_set = set(kept)
    order = [c for g in groups for c in g]
    kept = [c for c in order if c in kept_set]
    dropped = [(names[c], "no reading depends on it") for c in untouched]
    independence.update({names[c]: 0.0 for c in untouched})
    for c in order:
        if c not in kept_set and touched[c]:
            dropped.append((names[c], _trade_reason(unit, c, kept, names)))
    dropped.sort(key=lambda item: order.index(names.index(item[0])))
    return BaseSet(tuple(names[c] for c in kept), tuple(dropped), independence,
                   rtol, n_poses, seed)


def _trade_reason(unit, column, kept, names) -> str:
    """The kept parameters whose columns combine into this one (in priority order)."""
    coef, *_ = np.linalg.lstsq(unit[:, kept], unit[:, column], rcond=None)
    residual = np.linalg.norm(unit[:, kept] @ coef - unit[:, column])
    partners = [names[c] for c, a in zip(kept, coef) if abs(a) >= 0.1 * np.abs(coef).max()]
    text = ", ".join(partners[:4]) + (", ..." if len(partners) > 4 else "")
    if residual < 1e-9:
        return f"trades with {text}"
    return f"nearly trades with {text} (independent part {residual:.1e})"
