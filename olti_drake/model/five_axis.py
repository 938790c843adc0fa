"""A five-axis machine tool from its model file, and its numpy kinematic twin (issue 25, item 1).

The machine is a URDF or SDFormat file that Drake's ``Parser`` reads (formats.md, "Five-axis machine tools"):
prismatic joints named ``X``, ``Y``, ``Z`` (the linear axes), revolute joints named ``A``, ``B``, ``C`` (the
rotary axes, turning about x, y, z of the machine base at zero commands), fixed joints anywhere, and two named
frames: the workpiece frame (on the table) and the tool frame (on the spindle). The tool point relative to the
workpiece is the kinematic loop workpiece → base → tool, so table/table, head/head and head/table machines are
all model files (``docs/five_axis.md``).

:class:`FiveAxisMachine` keeps the loop as a numpy twin: the ordered elements from the workpiece frame to the
tool frame, fixed transforms (4×4, mm) and axis motions (each with its unit axis in the loop's sense), so that
tool points of many commands are vectorized numpy (no Drake call per pose); :meth:`FiveAxisMachine.drake_transforms`
evaluates the same loop with ``MultibodyPlant.CalcRelativeTransform``, the reference of the tests.

Units: commands in mm (prismatic) and degrees (revolute), lengths in mm; Drake's SI only inside this module.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Tuple, Union

import numpy as np

from olti_drake.errors import InputError

LINEAR, ROTARY = "XYZ", "ABC"
#: The command order of the axes a machine has: X, Y, Z, then A, B, C.
AXIS_ORDER = LINEAR + ROTARY
DEG = np.pi / 180.0
#: An axis whose direction at zero commands is farther than this (rad) from its letter's is refused.
AXIS_ALIGNMENT_RAD = 1e-6


@dataclass(frozen=True, eq=False)
class AxisLink:
    """One axis motion in the loop workpiece → tool: ``letter``, ``kind`` ('prismatic' | 'revolute'), the unit
    ``axis`` in the loop's sense (a table-side joint is traversed backwards: its file axis negated), expressed in
    the frame the element starts in; ``side`` 'table' (between workpiece and base) or 'head' (between base and
    tool); ``column`` its index in the command vector."""

    letter: str
    kind: str
    axis: np.ndarray
    side: str
    column: int


Element = Union[np.ndarray, AxisLink]


def _rotation(axis, angle_rad) -> np.ndarray:
    """(M, 3, 3) rotations about the unit ``axis`` by ``angle_rad`` (M,) (Rodrigues)."""
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    s, c = np.sin(angle_rad)[:, None, None], np.cos(angle_rad)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


def motion(link: AxisLink, q) -> Tuple[np.ndarray, np.ndarray]:
    """(R (M, 3, 3), o (M, 3) mm) of ``link`` at commands q (M,) (mm or deg): Trans(q s) or Rot(s, q)."""
    q = np.asarray(q, float)
    if link.kind == "prismatic":
        return np.broadcast_to(np.eye(3), (len(q), 3, 3)), q[:, None] * link.axis
    return _rotation(link.axis, q * DEG), np.zeros((len(q), 3))


@dataclass(frozen=True, eq=False)
class FiveAxisMachine:
    """A machine tool's kinematic loop workpiece → base → tool, read from a model file (:meth:`from_file`).

    ``axes``: the axis letters in command order (X, Y, Z, then A, B, C: e.g. ``('X', 'Y', 'Z', 'A', 'C')``);
    ``lower``/``upper``: their travel from the file (mm, deg; ±inf for a revolute joint without limits);
    ``loop``: the elements from the workpiece frame to the tool frame (4×4 fixed transforms in mm, or
    :class:`AxisLink`); ``base_index``: where the base sits in ``loop`` (elements before it are the table side,
    traversed workpiece → base); ``plant``/``frames``: Drake's plant and the (workpiece, tool) frames.
    """

    path: str
    workpiece_frame: str
    tool_frame: str
    axes: Tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    loop: Tuple[Element, ...]
    base_index: int
    plant: object = None
    frames: tuple = ()
    notes: Tuple[str, ...] = ()

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_file(cls, path, workpiece_frame: str = "workpiece", tool_frame: str = "tool") -> "FiveAxisMachine":
        """Read a URDF/SDFormat machine model with Drake's ``Parser`` (a plant without SceneGraph: geometry is
        never loaded). The model's root body is welded to the world (the machine base). Raises
        :class:`~olti_drake.errors.InputError`, one line naming the file and the frame or joint, for: a missing
        file or frame, a parse error, a joint that is neither prismatic, revolute nor fixed, an axis joint not
        named by its letter (X, Y, Z prismatic; A, B, C revolute), a letter used twice, an axis off the loop or
        not along its letter's direction at zero commands, a prismatic axis without finite limits, and frames
        not connected through the base."""
        from pydrake.multibody.parsing import Parser
        from pydrake.multibody.plant import MultibodyPlant

        from olti_drake.model.chain import _check_limits, _first_line

        path = Path(path)
        where = f"machine model {path}"
        if not path.is_file():
            raise InputError(f"{where}: file not found")
        try:
            _check_limits(path)  # (a lower limit above the upper one would end the process in a Drake assertion)
        except ValueError as exc:
            raise InputError(str(exc).replace("robot model", "machine model", 1)) from None
        plant = MultibodyPlant(0.0)
        try:
            instances = Parser(plant).AddModels(str(path))
        except (RuntimeError, ValueError, SystemExit) as exc:
            raise InputError(f"{where}: {_first_line(exc)}") from None
        joints = [plant.get_joint(j) for j in plant.GetJointIndices()]
        _check_joints(joints, where)
        _weld_root(plant, instances, where)
        plant.Finalize()
        frames = tuple(_find_frame(plant, instances, name, what, where)
                       for name, what in ((workpiece_frame, "workpiece"), (tool_frame, "tool")))
        work_path, tool_path = (_path_from_base(plant, f, where) for f in frames)
        shared = 0  # joints both paths share move workpiece and tool together: no axis of the loop
        while (shared < min(len(work_path), len(tool_path))
               and work_path[shared].index() == tool_path[shared].index()):
            shared += 1
        on_loop = {j.name() for j in work_path[shared:] + tool_path[shared:]}
        for j in joints:
            if j.type_name() != "weld" and j.name() not in on_loop:
                raise InputError(f"{where}: joint '{j.name()}' is not on the loop {workpiece_frame} → base → "
                                 f"{tool_frame}: it moves neither frame relative to the other")
        axes = tuple(a for a in AXIS_ORDER if a in on_loop)
        loop, base_index = _loop(plant, frames, work_path, tool_path, shared, axes)
        lower, upper = _limits(plant, axes, where)
        machine = cls(str(path), workpiece_frame, tool_frame, axes, lower, upper, loop, base_index, plant, frames,
                      tuple(f"{a}: no travel limits in the file (a continuous joint)" for a, lo in zip(axes, lower)
                            if not np.isfinite(lo)))
        machine._check_directions(where)
        return machine

    def _check_directions(self, where: str) -> None:
        """Each axis along its letter's machine direction at zero commands (A about x, X along x, ...): the ISO
        names of its errors mean that direction."""
        for k, link in enumerate(self.loop):
            if isinstance(link, AxisLink):
                n = self.base_rotation(k) @ link.axis * (-1.0 if link.side == "table" else 1.0)  # the file's sense
                want = np.eye(3)[(LINEAR if link.kind == "prismatic" else ROTARY).index(link.letter)]
                if np.arccos(min(1.0, abs(float(n @ want)))) > AXIS_ALIGNMENT_RAD:
                    verb = "moves along" if link.kind == "prismatic" else "turns about"
                    along = "xyz"[int(np.argmax(want))]
                    raise InputError(f"{where}: joint '{link.letter}' {verb} {np.round(n + 0.0, 6).tolist()} in the "
                                     f"base frame at zero commands; {link.letter} must be along {along}")

    # ------------------------------------------------------------------ the twin
    @property
    def rotary(self) -> Tuple[str, ...]:
        return tuple(a for a in self.axes if a in ROTARY)

    @property
    def linear(self) -> Tuple[str, ...]:
        return tuple(a for a in self.axes if a in LINEAR)

    def link(self, letter: str) -> Tuple[int, AxisLink]:
        """(loop index, :class:`AxisLink`) of axis ``letter``."""
        for k, e in enumerate(self.loop):
            if isinstance(e, AxisLink) and e.letter == letter:
                return k, e
        raise KeyError(letter)

    def zero_rotations(self) -> list:
        """R_wp_k (3, 3): the rotation from the workpiece frame to the start of loop element k, all commands 0
        (k = 0 .. len(loop))."""
        out, acc = [], np.eye(3)
        for e in self.loop:
            out.append(acc)
            acc = acc @ (e[:3, :3] if isinstance(e, np.ndarray) else np.eye(3))  # an axis at 0 does not turn
        return out + [acc]

    def base_rotation(self, k: int) -> np.ndarray:
        """R_base_k (3, 3): the base-frame orientation of the start of loop element k at zero commands (the
        machine directions that the ISO names of the errors there refer to)."""
        R = self.zero_rotations()
        return R[self.base_index].T @ R[k]

    def check_commands(self, commands, what: str = "commands") -> np.ndarray:
        """(M, n_axes) finite commands (mm, deg; columns :attr:`axes`) within the travel: one-line InputError
        naming the row and the axis."""
        c = np.asarray(commands, float)
        c = c.reshape(1, -1) if c.ndim == 1 else c
        if c.ndim != 2 or c.shape[1] != len(self.axes):
            raise InputError(f"{what}: expected (M, {len(self.axes)}) columns {', '.join(self.axes)} (mm, deg), "
                             f"got shape {np.shape(commands)}")
        bad = np.argwhere(~np.isfinite(c) | (c < self.lower - 1e-9) | (c > self.upper + 1e-9))
        if bad.size:
            i, k = bad[0]
            unit = "mm" if self.axes[k] in LINEAR else "deg"
            raise InputError(f"{what}: row {i}: {self.axes[k]} = {c[i, k]:g} {unit} is outside its travel "
                             f"[{self.lower[k]:g}, {self.upper[k]:g}] {unit} ({self.path})")
        return c

    def transforms(self, commands, frame: str = "workpiece") -> np.ndarray:
        """(M, 4, 4) the tool frame in the workpiece frame (``frame`` 'workpiece') or in the base frame
        ('base') for commands (M, n_axes), mm: the nominal loop, vectorized."""
        c = self.check_commands(commands)
        start = {"workpiece": 0, "base": self.base_index}[frame]
        R = np.broadcast_to(np.eye(3), (len(c), 3, 3))
        o = np.zeros((len(c), 3))
        for e in self.loop[start:]:
            if isinstance(e, np.ndarray):
                Re, oe = e[:3, :3], e[:3, 3]
            else:
                Re, oe = motion(e, c[:, e.column])
            o = o + np.einsum("mij,mj->mi", R, np.broadcast_to(oe, o.shape))
            R = R @ Re
        T = np.zeros((len(c), 4, 4))
        T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, o, 1.0
        return T

    def tool_points(self, commands, offset_mm=(0.0, 0.0, 0.0), frame: str = "workpiece") -> np.ndarray:
        """(M, 3) mm: the point ``offset_mm`` of the tool frame (mm, tool-frame axes) in ``frame``."""
        T = self.transforms(commands, frame)
        return T[:, :3, 3] + np.einsum("mij,j->mi", T[:, :3, :3], np.asarray(offset_mm, float))

    def drake_transforms(self, commands) -> np.ndarray:
        """(M, 4, 4) mm: ``plant.CalcRelativeTransform(context, workpiece, tool)`` per command (the reference
        of the twin; slow, one Drake call per pose)."""
        c = self.check_commands(commands)
        context = self.plant.CreateDefaultContext()
        out = np.empty((len(c), 4, 4))
        for i, row in enumerate(c):
            for a, q in zip(self.axes, row):
                joint = self.plant.GetJointByName(a)
                if joint.type_name() == "prismatic":
                    joint.set_translation(context, q / 1000.0)
                else:
                    joint.set_angle(context, q * DEG)
            out[i] = _mm(self.plant.CalcRelativeTransform(context, *self.frames))
        return out


# ---------------------------------------------------------------------- reading helpers
def _check_joints(joints, where: str) -> None:
    """Every joint fixed, or an axis named by its letter; no letter twice."""
    seen = {}
    for j in joints:
        kind, name = j.type_name(), j.name()
        if kind == "weld":
            continue
        if kind not in ("prismatic", "revolute"):
            raise InputError(f"{where}: joint '{name}' is {kind}; a machine axis is prismatic (X, Y, Z) or revolute "
                             f"(A, B, C), any other joint fixed")
        letters = LINEAR if kind == "prismatic" else ROTARY
        if name not in letters:
            raise InputError(f"{where}: {kind} joint '{name}' is not named by an axis letter "
                             f"({', '.join(letters)} for a {kind} joint)")
        if name in seen:
            raise InputError(f"{where}: axis letter '{name}' names two joints")
        seen[name] = j


def _weld_root(plant, instances, where: str) -> None:
    """Weld the first body no joint has as child (the machine base) to the world at its default pose."""
    children = {plant.get_joint(j).child_body().index() for j in plant.GetJointIndices()}
    bodies = [plant.get_body(b) for m in instances for b in plant.GetBodyIndices(m)]
    if not bodies:
        raise InputError(f"{where}: no links")
    free = [b for b in bodies if b.index() not in children]
    if free:
        plant.WeldFrames(plant.world_frame(), free[0].body_frame(), plant.GetDefaultFloatingBaseBodyPose(free[0]))


def _find_frame(plant, instances, name: str, what: str, where: str):
    frames = [plant.get_frame(f) for m in instances for f in plant.GetFrameIndices(m)]
    matches = [f for f in frames if f.name() == name]
    if len(matches) == 1:
        return matches[0]
    if matches:
        raise InputError(f"{where}: {what} frame '{name}' is ambiguous: {len(matches)} frames have that name")
    names = sorted({f.name() for f in frames if f.index() == f.body().body_frame().index()})
    raise InputError(f"{where}: no {what} frame '{name}' (links: {', '.join(names[:12])}"
                     f"{', ...' if len(names) > 12 else ''})")


def _path_from_base(plant, frame, where: str) -> list:
    """The joints from the world (the welded base) down to ``frame``'s body, base first; refused when the body
    hangs in a tree not attached to the base (Drake gave it a floating joint)."""
    parent_joint = {plant.get_joint(j).child_body().index(): plant.get_joint(j) for j in plant.GetJointIndices()}
    out, body = [], frame.body()
    while body.index() != plant.world_body().index():
        joint = parent_joint[body.index()]
        if joint.is_ephemeral():
            raise InputError(f"{where}: frame '{frame.name()}' is not connected to the machine base (its link "
                             f"'{body.name()}' starts a tree of its own): no loop joins the workpiece and the tool")
        out.append(joint)
        body = joint.parent_body()
    return out[::-1]


def _mm(transform) -> np.ndarray:
    T = transform.GetAsMatrix4()
    T[:3, 3] *= 1000.0
    return T


def _physical(plant, frame, path, shared: int) -> list:
    """Elements of the physical chain from the loop's base (the last shared body) to ``frame``: fixed 4×4 (mm)
    and (joint, file axis). Fixed joints are folded into the fixed transforms (between two frames joined by welds
    only, CalcRelativeTransform does not depend on the commands)."""
    context = plant.CreateDefaultContext()
    previous = path[shared - 1].frame_on_child() if shared else plant.world_frame()
    out = []
    for joint in path[shared:]:
        if joint.type_name() == "weld":
            continue
        out.append(_mm(plant.CalcRelativeTransform(context, previous, joint.frame_on_parent())))
        axis = joint.translation_axis() if joint.type_name() == "prismatic" else joint.revolute_axis()
        out.append((joint, np.asarray(axis, float)))
        previous = joint.frame_on_child()
    out.append(_mm(plant.CalcRelativeTransform(context, previous, frame)))
    return out


def _loop(plant, frames, work_path, tool_path, shared: int, axes):
    """(loop elements workpiece → tool, base index): the table side inverted (fixed transforms inverted, axes
    negated: Rot(u, q)⁻¹ = Rot(−u, q)), then the head side. Element ``base index`` starts at the base."""
    table, head = (_physical(plant, f, p, shared) for f, p in zip(frames, (work_path, tool_path)))
    back = [np.linalg.inv(e) if isinstance(e, np.ndarray) else
            AxisLink(e[0].name(), e[0].type_name(), -e[1], "table", axes.index(e[0].name())) for e in reversed(table)]
    ahead = [e if isinstance(e, np.ndarray) else
             AxisLink(e[0].name(), e[0].type_name(), e[1], "head", axes.index(e[0].name())) for e in head]
    return tuple(back + ahead), len(back)


def _limits(plant, axes, where: str):
    """Travel (lower, upper) per axis in mm / deg; a prismatic axis must have finite limits."""
    lower, upper = [], []
    for a in axes:
        j = plant.GetJointByName(a)
        scale = 1000.0 if a in LINEAR else 1.0 / DEG
        lo, hi = j.position_lower_limits()[0] * scale, j.position_upper_limits()[0] * scale
        if a in LINEAR and not (np.isfinite(lo) and np.isfinite(hi)):
            raise InputError(f"{where}: prismatic joint '{a}' has no finite travel limits (<limit lower upper>)")
        lower.append(lo)
        upper.append(hi)
    return np.array(lower), np.array(upper)
