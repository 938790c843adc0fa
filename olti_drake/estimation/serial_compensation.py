"""Compensation of an N-joint serial robot: joint commands that put the tool point on wanted points by the
identified model (000 Eq. (3) in 3D with Eq. (7) inverted), keeping the programmed tool orientation as well as
the arm allows, and the same program as pre-distorted Cartesian targets for the controller's own nominal IK.

For every target t (mm, root frame) with its nominal pose θ_nom (the program's own command, deg) and
approach directions (kept unchanged), Gauss-Newton iterations on the commands θ*, vectorized over the
targets, solve by task priority:

1. the tool point on the target, p(θ*, dir) = t (3 equations; the identified model, maps included): the hard
   task, by singularity-robust damped least squares — no damping while the position Jacobian's smallest
   singular value σ is above :data:`EPS_POSITION_MM_PER_DEG`, then λ² = :data:`LAMBDA_POSITION_MM_PER_DEG`² ·
   (1 − (σ/ε)²) (Nakamura–Hanafusa / Chiaverini), so a stretched elbow or a far target gives bounded steps;
2. in the exact null space of (1), one regularized least squares: the tool orientation of the nominal pose
   (the tips of the tool frame's axes, :data:`ORIENTATION_ARM_MM` long, relative to the tool point, where
   the identified model puts them at θ_nom — the program's orientation as it executes; position readings
   cannot see the tool orientation, so turning it toward another "programmed" one would rest on
   unidentified parameters), against the nearness to θ_nom weighed μ: μ² = :data:`NEARNESS_MM_PER_DEG`²
   (a redundant arm keeps the nominal pose's null-space choice) where the solution stays within
   :data:`NULL_SPACE_RADIUS_DEG` of θ_nom in that null space, else the damping that brings it back to that
   radius (a trust region about the nominal pose, μ by bisection: Levenberg–Marquardt's). The damping thus
   grows only as the orientation task nears a singularity, where keeping the orientation would swing the
   wrist: near a wrist singularity (UR: q5 near 0 or 180°) the orientation is kept as well as 2° of wrist motion
   allows, and the tool point still lands on the target; ``orientation_change_deg`` says by how much it turned.

Each step is limited to :data:`MAX_STEP_DEG` and halved while it moves the tool point away from its target; a
target leaves the iteration once converged (tool point within :data:`TOLERANCE_MM`, step below
:data:`STEP_TOLERANCE_DEG`). The Jacobian is the model's ∂p/∂θ at the actual angles (analytic,
:func:`frame_points`; the map's slope, ~1e-3, is left out: it only slows the convergence, whose test is the
residual itself).

Every target is solved; one that cannot be is a failed row, never a failed program
(:func:`solve_program`, ``SerialCompensation.status``): ``unreachable`` (the tool point stays above
:data:`TOLERANCE_MM` from the target after :data:`MAX_ITERATIONS`: out of reach, or off the surface a robot
with fewer than 3 effective joints can reach), ``joint_limit`` (the compensated command of a joint leaves the
model's limits; the joint is named) or ``outside_map`` (it leaves a map's grid, ``outside="error"``: the
iteration itself holds the end values, the row is flagged). A failed row keeps its nominal command
(uncompensated, what the program did before) and its reason names the file line. :func:`compensate_serial`
is the strict form: it refuses the first failed target (``InputError``). ``olti compensate`` writes every row
with its ``status`` column (the index in :data:`STATUSES`: 0 ok, 1 unreachable, 2 joint_limit, 3 outside_map; a
number, so commands.csv stays all numbers) and ``residual_mm``,
prints one line per failed target (its file line and why) to stderr and exits 3 when any failed; a program
none of whose targets can be compensated is refused (exit 2, nothing written).

Pre-distorted Cartesian targets (:func:`cartesian_targets`): the *nominal* model's forward kinematics (the
model file's geometry, no location errors, no offsets, no maps: the controller's own kinematics) of the
compensated command — the tool point (the result's tool offset in the tool frame: the controller's TCP) in
mm and the tool frame's orientation, as roll-pitch-yaw about the fixed root axes X, then Y, then Z
(R = Rz(rz) · Ry(ry) · Rx(rx), Drake's RollPitchYaw) in degrees and as the unit quaternion (qw ≥ 0). Sent to the
controller's nominal IK on the branch of the nominal pose (the IK solution nearest the program's own pose),
it returns the compensated command, which puts the real robot's tool point on the wanted point. Units: mm
and degrees (radians only in the ros2_control offsets, :mod:`olti_drake.io.ros2_control`).
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass

import numpy as np

from olti_drake.errors import InputError
from olti_drake.model.errormap import GRID_TOLERANCE_DEG

#: A compensated tool point must be on its target by the model to this, mm.
TOLERANCE_MM = 1e-6
#: Newton iterations at most (a target converged earlier leaves the iteration).
MAX_ITERATIONS = 100
#: A target has converged when its tool point is within TOLERANCE_MM and its last step below this, deg.
STEP_TOLERANCE_DEG = 1e-9
#: Length of the tool-frame axes whose tips carry the orientation, mm (1 mm of tip = 0.57 deg).
ORIENTATION_ARM_MM = 100.0
#: Weight of "stay near the nominal pose" against the orientation tips, mm per deg.
NEARNESS_MM_PER_DEG = 1e-3
#: Position task: damping starts when the position Jacobian's smallest singular value falls below this, mm/deg
#: (a UR5's is 2-15 mm/deg away from a stretched elbow) ...
EPS_POSITION_MM_PER_DEG = 0.5
#: ... and reaches this at a singular pose, mm/deg (1 mm of error then asks for at most 1 deg of step).
LAMBDA_POSITION_MM_PER_DEG = 0.5
#: Orientation task: the joints move at most this far from the nominal pose in the position task's null space
#: (the wrist, for a six-axis arm), deg; beyond, the orientation is damped (kept as well as this allows).
NULL_SPACE_RADIUS_DEG = 2.0
#: Singular values below this fraction of the largest are not inverted (rank of the tasks).
RCOND = 1e-9
#: Largest joint step of one Newton iteration, deg (a far target is approached, not jumped at).
MAX_STEP_DEG = 10.0


#: The row statuses of a compensated program; the ``status`` column of commands.csv is the index (0 = ok), so the
#: file stays all numbers for any CSV reader.
STATUSES = ("ok", "unreachable", "joint_limit", "outside_map")
STATUS_LEGEND = ", ".join(f"{i} {s}" for i, s in enumerate(STATUSES))


@dataclass(frozen=True)
class SerialCompensation:
    """Compensated commands (M, N) deg with the targets' directions (M, N) or None, the residual
    |p_model(commands) − target| (M,) mm, the tool orientation change from the nominal pose's (M,) deg
    (largest axis-tip angle), the correction command − nominal (M, N) deg, the Newton iterations (the most
    any target took). ``status`` (M,): one of :data:`STATUSES` per target; ``reasons`` (M,): '' or the one line
    (``source:line: ...``) why the target failed; a failed row's command is its nominal one (residual and
    orientation change then those of the nominal command); ``joint`` (M,): the joint a ``joint_limit`` or
    ``outside_map`` row names, else ''."""

    commands: np.ndarray
    dirs: object
    residual_mm: np.ndarray
    orientation_change_deg: np.ndarray
    correction_deg: np.ndarray
    iterations: int
    status: np.ndarray = None
    reasons: tuple = ()
    joint: tuple = ()

    @property
    def ok(self) -> np.ndarray:
        """(M,) bool: the targets compensated."""
        return np.ones(len(self.commands), bool) if self.status is None else self.status == "ok"

    @property
    def status_codes(self) -> np.ndarray:
        """(M,) int: the index of each row's status in :data:`STATUSES` (0 = ok)."""
        return np.array([STATUSES.index(s) for s in self.status], int) if self.status is not None else \
            np.zeros(len(self.commands), int)

    def failures(self) -> list:
        """The failed targets' reasons, in file order."""
        return [r for r, good in zip(self.reasons, self.ok) if not good]


def _tool_index(model) -> int:
    return model.names.index("tool_x_mm")


def frame_points(model, commands, dirs, x=None, jacobian=True):
    """The tool point and the tips of the tool frame's axes (M, 4, 3) mm, and their ∂/∂θ (M, 4, 3, N) mm/deg."""
    x = model.start_vector() if x is None else np.asarray(x, float)
    k = _tool_index(model)
    pts, jacs = [], []
    for offset in np.vstack([np.zeros(3), ORIENTATION_ARM_MM * np.eye(3)]):
        xi = x.copy()
        xi[k:k + 3] += offset
        if jacobian:
            p, jp = model.jacobian(commands, dirs, xi)
            jacs.append(jp.angle)
        else:
            p = model.positions(commands, dirs, xi)
        pts.append(p)
    return np.stack(pts, axis=1), (np.stack(jacs, axis=1) if jacobian else None)


def _damping(sigma, eps, lam):
    """λ² of singularity-robust damped least squares: 0 while ``sigma`` >= ``eps``, growing to ``lam``² at 0."""
    return lam ** 2 * np.clip(1.0 - (sigma / eps) ** 2, 0.0, 1.0)


def _steps(jp, ep, jo, eo, dq_nom):
    """Joint steps (M, N) deg of all targets at once: (1) the position task (jp (M, 3, N) mm/deg, error ep (M, 3)
    mm) by damped least squares; (2) in its null space, the orientation tips (jo (M, 9, N), eo (M, 9)) against
    the nearness to the nominal pose (dq_nom = θ_nom − θ*, deg), weighed μ that grows near a singularity."""
    n = jp.shape[2]
    u, s, vt = np.linalg.svd(jp, full_matrices=True)   # s (M, k), k = min(3, N); vt (M, N, N)
    keep = s > RCOND * np.maximum(s[:, :1], 1e-300)
    rank = keep.sum(axis=1)
    smallest = np.take_along_axis(s, np.maximum(rank - 1, 0)[:, None], axis=1)[:, 0]
    lam2 = _damping(smallest, EPS_POSITION_MM_PER_DEG, LAMBDA_POSITION_MM_PER_DEG)
    k = s.shape[1]
    gain = np.where(keep, s / (s ** 2 + lam2[:, None]), 0.0)
    d1 = np.einsum("mkn,mk->mn", vt[:, :k], gain * np.einsum("mik,mi->mk", u[:, :, :k], ep))
    out = d1.copy()
    for r in np.unique(rank):
        rows = np.flatnonzero(rank == r)
        nz = n - int(r)
        if nz == 0:
            continue
        basis = np.swapaxes(vt[rows, r:], 1, 2)           # (G, N, nz): the position task's null space
        b = jo[rows] @ basis                               # (G, 9, nz)
        near = np.einsum("gnz,gn->gz", basis, dq_nom[rows] - d1[rows])   # z of the nominal pose
        rest = eo[rows] - np.einsum("gin,gn->gi", jo[rows], d1[rows]) - np.einsum("giz,gz->gi", b, near)
        ub, sb, vbt = np.linalg.svd(b, full_matrices=False)
        beta = sb * np.einsum("gik,gi->gk", ub, rest)
        mu2 = _wrist_damping(sb, beta)
        out[rows] += np.einsum("gnz,gz->gn", basis, near + np.einsum("gkz,gk->gz", vbt, beta / (sb ** 2 + mu2)))
    return out


def _wrist_damping(sb, beta, bisections: int = 40):
    """μ² (G, 1) of the orientation task: NEARNESS² where its solution stays within NULL_SPACE_RADIUS_DEG of the
    nominal pose (in the position task's null space), else the damping (found by bisection on log μ²) that brings
    it back to that radius — it grows only where the orientation task nears a singularity (a wrist, UR: q5 near
    0 or 180 deg). ||z − z_nom||(μ²) = ||beta / (sb² + μ²)|| decreases with μ²."""
    def dev(m2, rows=slice(None)):
        return np.linalg.norm(beta[rows] / (sb[rows] ** 2 + m2[:, None]), axis=1)

    lo = np.full(len(sb), NEARNESS_MM_PER_DEG ** 2)
    far = dev(lo) > NULL_SPACE_RADIUS_DEG
    if far.any():
        a = np.log(lo[far])
        b = np.log(np.maximum(np.linalg.norm(beta[far], axis=1) / NULL_SPACE_RADIUS_DEG, lo[far]) * 2.0)
        for _ in range(bisections):
            mid = 0.5 * (a + b)
            over = dev(np.exp(mid), far) > NULL_SPACE_RADIUS_DEG
            a, b = np.where(over, mid, a), np.where(over, b, mid)
        lo[far] = np.exp(b)
    return lo[:, None]


def _clamped(model):
    """``model`` with every map holding its end values outside its grid: the iteration never stops at a map's
    end (a command that ends there is flagged by :func:`solve_program`)."""
    if all(m.emap.outside == "clamp" for m in model.maps):
        return model
    work = copy.copy(model)
    work.maps = tuple(dataclasses.replace(m, emap=dataclasses.replace(m.emap, outside="clamp")) for m in model.maps)
    return work


def solve_program(model, targets_mm, nominal_deg, dirs=None, lines=None, source: str = "targets",
                  orientation=None) -> SerialCompensation:
    """Commands putting the tool point on ``targets_mm`` (M, 3) mm by ``model``, every target solved and the
    ones that cannot be flagged by row (module docstring). ``orientation`` (M, 3, 3): the tool frame's wanted
    rotation in the root frame instead of the nominal pose's (an IK of full poses, e.g. on the nominal
    model)."""
    targets = np.atleast_2d(np.asarray(targets_mm, float))
    nominal = np.atleast_2d(np.asarray(nominal_deg, float))
    m = len(targets)
    lines = np.arange(1, m + 1) if lines is None else np.asarray(lines)
    dirs = None if dirs is None else np.broadcast_to(np.asarray(dirs, float), nominal.shape)
    work = _clamped(model)
    start, _ = frame_points(work, nominal, dirs, jacobian=False)
    if orientation is None:
        want = start[:, 1:] - start[:, :1]
    else:
        want = ORIENTATION_ARM_MM * np.swapaxes(np.asarray(orientation, float).reshape(m, 3, 3), 1, 2)
    q = nominal.copy()
    active = np.ones(m, bool)
    taken = np.zeros(m, int)
    for it in range(1, MAX_ITERATIONS + 1):
        rows = np.flatnonzero(active)
        if not rows.size:
            break
        d = None if dirs is None else dirs[rows]
        pts, jac = frame_points(work, q[rows], d)
        ep = targets[rows] - pts[:, 0]
        eo = (want[rows] - (pts[:, 1:] - pts[:, :1])).reshape(len(rows), 9)
        jo = (jac[:, 1:] - jac[:, :1]).reshape(len(rows), 9, -1)
        delta = _steps(jac[:, 0], ep, jo, eo, nominal[rows] - q[rows])
        big = np.abs(delta).max(axis=1, keepdims=True)
        delta *= np.minimum(1.0, MAX_STEP_DEG / np.maximum(big, 1e-300))
        before = np.linalg.norm(ep, axis=1)
        q[rows] = _backtrack(work, q[rows], delta, d, targets[rows], before)
        taken[rows] = it
        active[rows[(before < TOLERANCE_MM) & (np.abs(delta).max(axis=1) < STEP_TOLERANCE_DEG)]] = False
    pts, _ = frame_points(work, q, dirs, jacobian=False)
    residual = np.linalg.norm(pts[:, 0] - targets, axis=1)
    status = np.full(m, "ok", dtype=object)
    reasons, joint = [""] * m, [""] * m
    for i in np.flatnonzero(~(residual <= TOLERANCE_MM)):
        status[i] = "unreachable"
        reasons[i] = (f"{source}:{lines[i]}: target ({', '.join(f'{v:.6g}' for v in targets[i])}) mm cannot be "
                      f"reached by the model: {residual[i]:.3g} mm off after {taken[i]} Newton iterations (out of "
                      f"reach, or off the surface the robot's joints can reach)")
    _flag_limits(model.chain, q, lines, source, status, reasons, joint)
    _flag_maps(model, q, lines, source, status, reasons, joint)
    bad = status != "ok"
    if bad.any():  # a failed row keeps the program's own command
        q[bad] = nominal[bad]
        pts[bad] = start[bad]
        residual[bad] = np.linalg.norm(start[bad, 0] - targets[bad], axis=1)
    tips = pts[:, 1:] - pts[:, :1]
    turn = np.degrees(np.arcsin(np.clip(np.linalg.norm(tips - want, axis=2).max(axis=1) / ORIENTATION_ARM_MM, 0, 1)))
    return SerialCompensation(q, dirs, residual, turn, q - nominal, int(taken.max(initial=0)), status,
                              tuple(reasons), tuple(joint))


def compensate_serial(model, targets_mm, nominal_deg, dirs=None, lines=None, source: str = "targets"):
    """Commands putting the tool point on ``targets_mm`` (M, 3) mm by ``model`` (module docstring), strict: the
    first target that cannot be compensated is refused (``InputError``, its line); :func:`solve_program`
    flags it by row instead."""
    comp = solve_program(model, targets_mm, nominal_deg, dirs, lines, source)
    failed = comp.failures()
    if failed:
        raise InputError(failed[0] + (f"; {len(failed)} such target(s)" if len(failed) > 1 else ""))
    return comp


def _backtrack(model, q, delta, dirs, targets, before, halvings: int = 12):
    """q + delta, the step halved per target while it moves the tool point away from its target (Newton
    near a singular pose, e.g. a stretched elbow, overshoots)."""
    step = np.ones((len(q), 1))
    for _ in range(halvings):
        after = np.linalg.norm(model.positions(q + step * delta, dirs) - targets, axis=1)
        worse = ~(after <= before + TOLERANCE_MM)
        if not worse.any():
            break
        step[worse] *= 0.5
    return q + step * delta


def _flag_limits(chain, q, lines, source, status, reasons, joint) -> None:
    """Flag (``joint_limit``) a compensated command beyond the model's joint limits, naming the line and joint."""
    low, high = q < chain.lower_deg - 1e-9, q > chain.upper_deg + 1e-9
    for i in np.flatnonzero((low | high).any(axis=1) & (status == "ok")):
        j = int(np.flatnonzero(low[i] | high[i])[0])
        limit = chain.lower_deg[j] if low[i, j] else chain.upper_deg[j]
        status[i], joint[i] = "joint_limit", chain.joint_names[j]
        reasons[i] = (f"{source}:{lines[i]}: the compensated command of {chain.joint_names[j]} is "
                      f"{q[i, j]:.6g} deg, beyond its limit {limit:g} deg in {chain.path}")


def _flag_maps(model, q, lines, source, status, reasons, joint) -> None:
    """Flag (``outside_map``) a compensated command outside a map's grid when the model's policy is 'error'."""
    for j, mp in zip(model.map_joints, model.maps):
        if mp.emap.outside != "error":
            continue
        g = mp.emap.grid_deg
        out = (q[:, j] < g[0] - GRID_TOLERANCE_DEG) | (q[:, j] > g[-1] + GRID_TOLERANCE_DEG)
        for i in np.flatnonzero(out & (status == "ok")):
            status[i], joint[i] = "outside_map", mp.joint
            reasons[i] = (f"{source}:{lines[i]}: the compensated command leaves the identified map: error map "
                          f"{mp.joint}: command angle {q[i, j]:.6g} deg is outside the map grid [{g[0]:g}, "
                          f"{g[-1]:g}] deg (or run with --outside clamp)")


def cartesian_targets(model, commands):
    """Pre-distorted Cartesian targets of ``commands`` (M, N) deg (module docstring): the nominal model's tool
    point (M, 3) mm (the result's tool offset as the TCP) and the tool frame's rotation (M, 3, 3) in the root
    frame — what the controller's nominal IK must be given to return ``commands``."""
    chain = model.chain
    tool = model.chain_parameters(model.start_vector())[6 * chain.n_joints:]
    base = chain.nominal_parameters(tool)
    p = chain.positions(commands, base)
    rot = np.empty((len(p), 3, 3))
    for k in range(3):
        tip = base.copy()
        tip[6 * chain.n_joints + k] += ORIENTATION_ARM_MM
        rot[:, :, k] = (chain.positions(commands, tip) - p) / ORIENTATION_ARM_MM
    return p, rot


def rotation_angles(rot):
    """(rx, ry, rz) deg, fixed-axis X-Y-Z (R = Rz · Ry · Rx, Drake's RollPitchYaw), and (qw, qx, qy, qz) with
    qw >= 0, of rotations (M, 3, 3)."""
    from pydrake.math import RollPitchYaw, RotationMatrix

    rpy, quat = [], []
    for r in np.asarray(rot, float):
        rm = RotationMatrix(r)
        rpy.append(np.degrees(RollPitchYaw(rm).vector()))
        qt = rm.ToQuaternion()
        v = np.array([qt.w(), qt.x(), qt.y(), qt.z()])
        quat.append(v if v[0] >= 0 else -v)
    return np.reshape(rpy, (-1, 3)), np.reshape(quat, (-1, 4))
